"""``xshells deploy`` and ``xshells demo``."""
from __future__ import annotations

import os

import numpy as np

from ..errors import InputError


DEMO_DESIGN = os.path.join(os.path.dirname(__file__), "..", "data", "examples", "manta_ray.obj")


def register(subparsers) -> None:
    p = subparsers.add_parser("deploy", help="find the assembly state of a flat design and deploy it",
                              description="Deploy a flat X-shell design by joint torques. Units follow the input (the bundled data: mm, MPa). "
                                          "Besides the meshes, pictures and result.json, a flat design's fabrication files are written "
                                          "into --out, as xshells fabricate writes them with default options: cutlist.csv, joints.csv "
                                          "(with the deployed angles), beams.svg/.dxf, assembly.svg and bom.json (docs/fabrication.md).")
    p.add_argument("input", help="a case file (.json) or a design (.obj, .msh, .3dm)")
    p.add_argument("--material", help="TYPE:P1,P2,... (e.g. rectangle:10,7) or a cross-section JSON file")
    p.add_argument("--young", type=float, help="Young's modulus (default 20000, as in the paper, MPa)")
    p.add_argument("--poisson", type=float, help="Poisson's ratio (default 0.3)")
    p.add_argument("--grade", help="a named material: gfrp-e23, softwood-c24, aluminium-6063-t6, birch-plywood "
                                   "(E, ν, density and strength; docs/analysis.md)")
    p.add_argument("--strength", type=float, help="allowable stress for the utilization (MPa for a design in mm)")
    # refused, not dropped from the parser: "unrecognized arguments" would not say where a density is used
    p.add_argument("--density", type=float, help="refused: deploy applies no self-weight and writes no mass "
                                                 "(the density is used by xshells analyze)")
    p.add_argument("--angle", type=float, help="target average opening angle, degrees")
    p.add_argument("--steps", type=int, help="deployment increments (default 40)")
    p.add_argument("--subdivision", type=int, help="edges per segment (default 10)")
    p.add_argument("--rest-lengths", help="per-segment rest lengths file (skips the rest-length solve)")
    p.add_argument("--direction", choices=["up", "down"], help="which way the flat state buckles: up = its middle rises along the layout normal "
                   "(default: the case's direction, else up)")
    p.add_argument("--guide", help="a file of deployed joint positions ('x y z' per joint): at the target angle the shell "
                                   "is held on them and let go, to settle into that equilibrium (default: the case's "
                                   "guide, else none; docs/case.md)")
    p.add_argument("--start", choices=["auto", "average", "central-joint"], default="auto",
                   help="how the assembly state is held while it first relaxes: at its average angle, or by the central "
                        "joint's angle alone (auto: the average, unless that folds a joint at once; where both do, "
                        "the average again with a first step of 2, 4 or 8 increments)")
    p.add_argument("--out", default="deploy_out", help="output folder")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_deploy)

    d = subparsers.add_parser("demo", help="deploy the bundled manta-ray design and write its outputs",
                              description="Deploy the bundled manta-ray design (data/examples/manta_ray.obj; mm, MPa) with "
                                          "a 10 x 7 mm rectangular section (E 20000 MPa, Poisson 0.3), 8 edges per segment, "
                                          "to an average opening angle of 93 degrees, and write the same outputs as xshells "
                                          "deploy into --out. No input needed: a quick check that the installation works.")
    d.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    d.add_argument("--steps", type=int, default=40, help="deployment increments from the flat to the deployed state "
                                                          "(1 to 100000, default 40)")
    d.add_argument("--no-progress", action="store_true", help="no progress bar on the terminal; the warnings are then "
                                                              "listed with the summary at the end")
    d.set_defaults(func=_demo)


def _material_spec_from_args(args) -> dict:
    from .case import material_spec_from_option

    return material_spec_from_option(args.material, args.young, args.poisson, grade=getattr(args, "grade", None),
                                     density=getattr(args, "density", None), strength=getattr(args, "strength", None))


def _deploy(args) -> int:
    from .case import (MATERIAL_OPTIONS, check_counts, check_density, load_case, material_from_spec, material_strength,
                       refuse_case_options, with_material_options)
    from .run import run_deployment

    check_counts(args.subdivision, args.steps)
    if args.density is not None:  # accepted and ignored it once: no gravity here, no mass in bom.json
        check_density(args.density)  # a bad value is named as such first, as analyze names it
        raise InputError("deploy applies no self-weight: --density is used by xshells analyze")
    if args.input.lower().endswith(".json"):
        refuse_case_options(args, MATERIAL_OPTIONS)  # --subdivision and --steps override the case's
        case = load_case(args.input)
        spec = with_material_options(case.material, args.grade, args.density, args.strength)
        material = material_from_spec(spec)
        kw = dict(subdivision=case.subdivision if args.subdivision is None else args.subdivision,
                  steps=case.steps if args.steps is None else args.steps,
                  target_angle=np.radians(args.angle) if args.angle is not None else case.angle_rad,
                  open_by=case.open_by_rad, rest_lengths_path=args.rest_lengths or case.rest_lengths_path, name=case.name,
                  direction=args.direction or case.direction, guide_path=args.guide or case.guide_path)
        design = case.design_path
    else:
        spec = _material_spec_from_args(args)
        material = material_from_spec(spec)
        kw = dict(subdivision=10 if args.subdivision is None else args.subdivision,
                  steps=40 if args.steps is None else args.steps,
                  target_angle=np.radians(args.angle) if args.angle is not None else None,
                  rest_lengths_path=args.rest_lengths, name=os.path.basename(args.input), direction=args.direction or "up",
                  guide_path=args.guide)
        design = args.input
    result = run_deployment(design, material, out_dir=args.out, start=args.start, progress=not args.no_progress,
                            strength=material_strength(spec), background=True, **kw)
    _print_summary(result, args.out, warned=not args.no_progress)
    return 0 if result["reached"] else 1


def _demo(args) -> int:
    from ..section import Material
    from .case import check_counts
    from .run import run_deployment

    check_counts(None, args.steps)
    material = Material.uniform("rectangle", [10, 7], E=20000, nu=0.3)
    result = run_deployment(DEMO_DESIGN, material, out_dir=args.out, subdivision=8, target_angle=np.radians(93),
                            steps=args.steps, progress=not args.no_progress, name="manta_ray", background=True)
    _print_summary(result, args.out, warned=not args.no_progress)
    return 0 if result["reached"] else 1


# units follow the input, never converted (README: Units); the bundled data's are named as an example
_STRESS_UNIT = "the input's stress unit: MPa for mm and MPa"


def _print_summary(result, out, warned=False) -> None:
    """``warned``: the warnings were printed when the run started (with its progress bar)."""
    d, f = result["deployed"], result["flat"]
    print(f"{result['name']}: {result['segments']} segments, {result['joints']} joints, {result['dof']} DoF")
    print(f"  flat:     energy {f['energy']:.6g}, average angle {f['average_angle_deg']:.2f}°")
    print(f"  deployed: energy {d['energy']:.6g}, average angle {d['average_angle_deg']:.2f}°, max |z| {d['max_abs_z']:.4g}, torque {d.get('torque', float('nan')):.4g}")
    print(f"  {result['message']}; {result['newton_iterations']} Newton iterations, {result['timings_s']['total']:.1f} s")
    st = result.get("stress") or {}
    if st.get("strength") is not None:
        ff = st.get("first_failure")
        print(f"  stress: largest von Mises {st['max_von_mises']:.4g} ({_STRESS_UNIT}), utilization {st['utilization_max']:.3g} of "
              f"strength {st['strength']:.4g}" + (f"; a beam would break at {ff['angle_deg']:.1f}° (beam {ff['beam']}, "
                                                  f"near joint {ff['nearest_joint']})" if ff else "; no beam breaks"))
    for w in [] if warned else result.get("warnings", []):
        print(f"  warning: {w}")
    print(f"  outputs in {out}/")
