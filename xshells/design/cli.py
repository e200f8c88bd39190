"""``xshells optimize``: low-stress rest lengths that keep the deployed shape (paper §5)."""
from __future__ import annotations

from ..deploy.case import add_design_options, case_path_from_args
from ..errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "optimize", help="optimize a case's rest lengths for low flat and deployed energy near the target shape",
        description="Design optimization (paper §5): minimizes γ/E₀·E_flat + (1−γ)/E₀·E_deployed + β/(2l₀²)·T over the "
                    "per-segment rest lengths, keeping the flat state planar and its joint angles open. Units follow the input.")
    p.add_argument("case", help="a case file (.json), or a design (.obj, .msh, .3dm) with --material etc.")
    p.add_argument("--gamma", type=float, help="share of the flat energy, in [0, 1] (default 0.9)")
    p.add_argument("--beta", type=float, help="weight of the fitting term (default 1000)")
    p.add_argument("--target-surface", help="a surface mesh (OBJ, PLY, STL, .msh or .3dm; triangles, quads or convex polygons) to fit (default: the deployed design's quads, Loop-subdivided twice)")
    p.add_argument("--angle", type=float, help="target average opening angle, degrees (default: the case's)")
    p.add_argument("--max-iters", type=int, default=20)
    p.add_argument("--method", choices=("newton-cg", "bfgs", "trust-constr"), default="newton-cg",
                   help="trust-region Newton-CG (default), the same with BFGS, or scipy's trust-constr")
    p.add_argument("--min-angle", type=float, help="smallest flat joint angle ε, degrees (default: the initial KS minimum less 0.5°, at least half of a positive one)")
    p.add_argument("--resume", action="store_true", help="start from OUT/design_parameters.txt of an earlier run")
    p.add_argument("--no-baseline", action="store_true", help="skip the BFGS comparison run")
    add_design_options(p, steps_default=20)
    p.add_argument("--out", default="optimize_out", help="output folder")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_optimize)


def _optimize(args) -> int:
    import numpy as np

    from .objective import DesignWeights
    from .optimize import OptimizeOptions

    if args.min_angle is not None and not (np.isfinite(args.min_angle) and -180.0 < args.min_angle < 180.0):
        raise InputError(f"--min-angle must be a finite angle in degrees, got {args.min_angle:g}")
    if args.max_iters < 1:  # OptimizeOptions would say "max_iterations", which is not what the user typed
        raise InputError(f"--max-iters must be at least 1, got {args.max_iters}")
    case_path = case_path_from_args(args, "optimize", steps_default=20)
    weights = DesignWeights(**{k: v for k, v in (("gamma", args.gamma), ("beta", args.beta)) if v is not None})
    opts = OptimizeOptions(method=args.method, max_iterations=args.max_iters,
                           min_angle=np.radians(args.min_angle) if args.min_angle is not None else None)
    try:
        r = _run(case_path, args, weights, opts)
    except InputError as exc:  # name what the user gave, not the case file written for it
        raise InputError(str(exc).replace(case_path, args.case)) from None
    i = r["initial"]
    print(f"{r['name']}: J {i['J']:.5g} -> {r['J']:.5g} in {r['iterations']} iterations ({r['time_s']:.1f} s)")
    print(f"  flat energy {i['energy_flat']:.5g} -> {r['energy_flat']:.5g}; deployed energy {i['energy_deployed']:.5g} -> {r['energy_deployed']:.5g}")
    print(f"  planarity {r['constraints']['planarity']:.3g}, min flat angle {r['constraints']['min_angle_deg']:.3g}°; {r['message']}")
    for w in r.get("warnings", []):
        print(f"  warning: {w}")
    if r.get("flat_angle_note"):
        print(f"  note: {r['flat_angle_note']}")
    print(f"  outputs in {args.out}/")
    return 0


def _run(case_path, args, weights, opts) -> dict:
    from .run import run_optimize

    return run_optimize(case_path, args.out, weights=weights, options=opts, angle_deg=args.angle,
                        target_surface=args.target_surface, resume=args.resume, baseline=not args.no_baseline,
                        progress=not args.no_progress)
