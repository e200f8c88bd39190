"""``xshells analyze``: the deployed shell on supports, under loads: stresses, reactions, stability."""
from __future__ import annotations

import os


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "analyze", help="support and load the deployed shell: stresses, reactions, stability, critical load factor",
        description="Deploys a case or design (as xshells deploy), then solves its nonlinear equilibrium on supports "
                    "under dead loads, with large displacements. Units follow the input (N, mm, MPa for the bundled data).")
    p.add_argument("input", help="a case file (.json) or a design (.obj, .msh, .3dm)")
    p.add_argument("--supports", required=True, help="lowest:N (the N lowest vertices) or joints:i,j,… (input vertex indices)")
    p.add_argument("--support-type", choices=("pinned", "clamped"), default="pinned")
    p.add_argument("--joints", choices=("locked", "free"), default="locked",
                   help="locked: the joints keep their deployed angles (as built); free: they turn, the actuation torque held")
    p.add_argument("--load", action="append", default=[], metavar="LOAD",
                   help="self-weight | point:VERTEX:FX,FY,FZ | area:Q (vertical, per horizontal projected area); repeatable")
    p.add_argument("--load-factor", type=float, default=1.0,
                   help="multiplies every --load (default 1); the critical load factor is a multiple of the --load too")
    p.add_argument("--no-critical", action="store_true", help="skip the critical load factor")
    p.add_argument("--angle", type=float, help="deploy to this average angle, degrees (default: the case's)")
    p.add_argument("--material", help="TYPE:P1,P2,... or a cross-section JSON (for a bare design)")
    p.add_argument("--young", type=float, help="for a design file: Young's modulus (default 20000, MPa)")
    p.add_argument("--poisson", type=float, help="for a design file: Poisson's ratio (default 0.3)")
    p.add_argument("--grade", help="a named material (docs/analysis.md)")
    p.add_argument("--strength", type=float, help="allowable stress (MPa for a design in mm)")
    p.add_argument("--density", type=float, help="density (t/mm³ for a design in mm)")
    p.add_argument("--steps", type=int, help="deployment increments")
    p.add_argument("--subdivision", type=int)
    p.add_argument("--out", default="analyze_out")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_analyze)


def _analyze(args) -> int:
    import numpy as np

    from ..deploy.case import (MATERIAL_OPTIONS, check_counts, load_case, material_from_spec, material_spec_from_option,
                               material_strength, refuse_case_options, resolve_grade, with_material_options)
    from .run import parse_load, parse_supports, run_analysis

    check_counts(args.subdivision, args.steps)
    supports = parse_supports(args.supports)
    loads = [parse_load(t) for t in args.load]
    if args.input.lower().endswith(".json"):
        refuse_case_options(args, MATERIAL_OPTIONS)  # --subdivision and --steps override the case's
        case = load_case(args.input)
        spec = with_material_options(case.material, args.grade, args.density, args.strength)
        kw = dict(subdivision=case.subdivision if args.subdivision is None else args.subdivision,
                  steps=case.steps if args.steps is None else args.steps,
                  target_angle=np.radians(args.angle) if args.angle is not None else case.angle_rad,
                  open_by=case.open_by_rad, rest_lengths_path=case.rest_lengths_path, name=case.name,
                  direction=case.direction, guide_path=case.guide_path)
        design = case.design_path
    else:
        spec = material_spec_from_option(args.material, args.young, args.poisson, grade=args.grade,
                                         density=args.density, strength=args.strength)
        kw = dict(subdivision=10 if args.subdivision is None else args.subdivision,
                  steps=40 if args.steps is None else args.steps,
                  target_angle=np.radians(args.angle) if args.angle is not None else None,
                  name=os.path.basename(args.input))
        design = args.input
    density_given = resolve_grade(spec).get("density") is not None
    r = run_analysis(design, material_from_spec(spec), out_dir=args.out, supports_spec=supports,
                     support_type=args.support_type, loads=loads, joints=args.joints, load_factor=args.load_factor,
                     strength=material_strength(spec), density_given=density_given, progress=not args.no_progress,
                     critical=not args.no_critical, **kw)
    print(f"{r['name']}: max displacement {r['max_displacement']:.4g} (vertex {r['max_displacement_vertex']}), "
          f"largest von Mises {r['max_von_mises']:.4g}" +
          (f", utilization {r['max_utilization']:.3g}" if r["max_utilization"] is not None else ""))
    print(f"  total load {np.round(r['total_load'], 6).tolist()}, reactions {np.round(r['reactions_total'], 6).tolist()}; "
          + _stability_line(r))
    if r["status"] != "complete":  # as xshells deploy's "stopped at …° of …°: why"
        print(f"  {r['status']} at load factor {r['load_factor_reached']:.4g} of {r['load_factor']:.4g}: {r['message']}")
    for w in r.get("warnings", []):
        print(f"  warning: {w}")
    if r.get("input"):  # how a .3dm was read (its units converted to mm): a note, with or without progress
        print(f"  note: {r['input']}")
    print(f"  outputs in {args.out}/")
    return 0 if r["status"] == "complete" else 1


def _stability_line(r) -> str:
    """How the shell stands: stable or not, the critical load factor and what happens there, buckled or not."""
    crit, kind = r["critical_load_factor"], r.get("critical_kind")
    what = {"limit point": "a limit point: it snaps through", "bifurcation": "a bifurcation: it buckles"}.get(kind, kind)
    state = "stability unknown" if r["stable"] is None else "stable" if r["stable"] else "unstable"
    if crit is not None:
        ratio = f" = {r['critical_load_ratio']:.4g}x the load applied" if r["load_factor"] != 1 else ""
        if r["buckled"] and r.get("state") == "pre-snap":  # Newton past the critical factor did not converge
            return (f"BUCKLED: the load passes the critical load factor {crit:.4g}{ratio} ({what}); the state past it "
                    f"was not found; shown: the last equilibrium before it, at load factor {r['load_factor_reached']:.4g}")
        if r["buckled"]:
            return (f"BUCKLED: the load passes the critical load factor {crit:.4g}{ratio} ({what}); the state it goes to "
                    f"is {state}")
        return f"{state}, critical load factor {crit:.4g}{ratio} ({what})"
    if r["buckled"]:
        return f"BUCKLED ({state})"
    if r["critical_searched_to"] and r["status"] != "interrupted":
        return f"{state}, no instability up to {_searched(r)}"
    return state


def _searched(r) -> str:
    """How far the critical search went, in multiples of the load applied (and of --load where they differ)."""
    to, lf = r["critical_searched_to"], r["load_factor"]
    return f"{to / lf:.3g}x the load applied" + (f" ({to:.3g}x --load)" if lf != 1 else "")
