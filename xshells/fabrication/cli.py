"""``xshells fabricate``: the cut list, joint table, strips on stock, assembly drawing and bill of materials."""
from __future__ import annotations

import os


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fabricate", help="cut list, holes, nesting and assembly drawing of a flat design",
        description="Traces every continuous beam of a flat design, places its holes from the rest lengths (solved, as "
                    "xshells deploy does, or read from the case's file), nests the strips onto stock and writes "
                    "cutlist.csv, joints.csv, beams.svg/.dxf, assembly.svg and bom.json. Lengths are in mm: a design "
                    "drawn in other units takes --units and is converted (and says so); a .3dm states its own units "
                    "and is converted to mm as it is read.")
    p.add_argument("input", help="a case file (.json) or a flat design (.obj, .msh, .3dm)")
    p.add_argument("--material", help="for a design file: TYPE:P1,P2,... (default rectangle:10,7) or a cross-section JSON")
    p.add_argument("--young", type=float, help="for a design file: Young's modulus (default 20000, MPa)")
    p.add_argument("--poisson", type=float, help="for a design file: Poisson's ratio (default 0.3)")
    p.add_argument("--subdivision", type=int, help="edges per segment for the rest-length solve (default: the case's, else 10)")
    p.add_argument("--rest-lengths", help="per-segment rest lengths file (design_parameters.txt): skips the solve")
    p.add_argument("--end-margin", type=float, help="mm of strip beyond the outermost hole or free end "
                                                     "(default: half the section width)")
    p.add_argument("--hole-diameter", type=float, help="rivet holes, mm (default: a third of the section width)")
    p.add_argument("--stock-length", type=float, help="nest the strips onto bars this long, mm")
    p.add_argument("--sheet", help="nest the strips onto sheets WxH, mm (for laser cutting), e.g. 2500x1250")
    p.add_argument("--kerf", type=float, default=3.0, help="material lost per cut, mm (default 3)")
    p.add_argument("--units", default="mm", help="the length unit of an .obj or .msh design: mm (default), cm, m, in, ft (a .3dm "
                                                 "states its own)")
    p.add_argument("--top", choices=("A", "B"), default="A", help="the family of strips on the upper layer")
    p.add_argument("--out", default="fabricate_out")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_fabricate)


def _fabricate(args) -> int:
    from ..deploy.case import check_counts, load_case, material_from_spec, material_spec_from_option
    from .nesting import parse_sheet
    from .run import FabricationOptions, run_fabrication

    check_counts(args.subdivision, None)
    options = FabricationOptions(end_margin=args.end_margin, hole_diameter=args.hole_diameter,
                                 stock_length=args.stock_length, sheet=parse_sheet(args.sheet) if args.sheet else None,
                                 kerf=args.kerf, units=args.units, top=args.top)
    if args.input.lower().endswith(".json"):
        from ..deploy.case import MATERIAL_OPTIONS, refuse_case_options

        refuse_case_options(args, MATERIAL_OPTIONS)  # --subdivision overrides the case's
        case = load_case(args.input)
        spec, subdivision, name = case.material, case.subdivision, case.name
        rest = args.rest_lengths or case.rest_lengths_path
        design = case.design_path
    else:
        spec = material_spec_from_option(args.material, args.young, args.poisson)
        subdivision, name, rest, design = 10, os.path.basename(args.input), args.rest_lengths, args.input
    r = run_fabrication(design, material_from_spec(spec), out_dir=args.out, options=options,
                        subdivision=subdivision if args.subdivision is None else args.subdivision,
                        rest_lengths_path=rest, name=name, progress=not args.no_progress)
    b = r["bom"]
    secs = "; ".join(f"{s['section']}: {s['beams']} beams, {s['total_length_mm'] / 1000:.3f} m" for s in b["sections"])
    print(f"{r['name']}: {b['beams']} beams (A {b['beams_per_family']['A']}, B {b['beams_per_family']['B']}), "
          f"{b['rivets']} rivets, {b['holes']} holes; {secs}")
    st = b["stock"]
    if st["kind"] != "none":
        print(f"  {st['stock_count']} {st['kind']}, utilization {100 * st['utilization']:.1f} %")
    if b["design_units"] != "mm":
        print(f"  {b['units_note']}")
    for w in b["warnings"]:  # parts that make no sense, with or without progress
        print(f"  warning: {w}")
    if r.get("input"):  # how a .3dm was read (its units converted to mm): a note, with or without progress
        print(f"  note: {r['input']}")
    print(f"  outputs in {args.out}/")
    return 0
