"""``xshells sparsify``: where to put the motors."""
from __future__ import annotations

from ..deploy.case import add_design_options, case_path_from_args
from ..errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "sparsify", help="find a sparse set of joint torques that deploys a case to its dense-actuation shape",
        description="Sparse actuation (paper §6). Deploys the case with every joint actuated, then finds few joints "
                    "whose torques reach the same shape. Torques are in the energy's units (N·mm for mm and MPa).")
    p.add_argument("case", help="a case file (.json), or a design (.obj, .msh) with --material etc.")
    p.add_argument("--eta", type=float, default=3e-4, help="sparsity weight, dimensionless (default 3e-4)")
    p.add_argument("--p", type=float, default=0.5, help="power of the lp penalty, in (0, 1] (default 0.5)")
    p.add_argument("--tau-max", type=float, help="largest torque one actuator may apply")
    p.add_argument("--candidates", help="comma-separated input vertex indices of the joints that may be actuated (default all)")
    p.add_argument("--angle", type=float, help="target average opening angle, degrees (default: the case's)")
    p.add_argument("--max-iters", type=int, default=100)
    p.add_argument("--sweep", action="store_true", help="sweep eta (8 values) for p = 1, 1/2, 1/4 and plot the trade-off (Fig. 9)")
    p.add_argument("--etas", help="comma-separated eta values for --sweep")
    p.add_argument("--ps", help="comma-separated p values for --sweep (default 1,0.5,0.25)")
    add_design_options(p, steps_default=40)
    p.add_argument("--out", default="sparsify_out", help="output folder")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_sparsify)


def _floats(text, what):
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise InputError(f"--{what} {text}: expected comma-separated numbers") from None


def _sparsify(args) -> int:
    case_path = case_path_from_args(args, "sparsify", steps_default=40)
    try:
        return _run(args, case_path)
    except InputError as exc:  # name what the user gave, not the case file written for it
        raise InputError(str(exc).replace(case_path, args.case)) from None


def _run(args, case_path) -> int:
    from .run import DEFAULT_ETAS, DEFAULT_PS, run_sparsify, run_sweep
    from .sparsify import SparsifyOptions

    if args.max_iters < 1:
        raise InputError(f"--max-iters must be at least 1, got {args.max_iters}")
    opts = SparsifyOptions(eta=args.eta, p=args.p, tau_max=args.tau_max, max_iterations=args.max_iters)
    if args.sweep:
        etas = _floats(args.etas, "etas") if args.etas else DEFAULT_ETAS
        ps = _floats(args.ps, "ps") if args.ps else DEFAULT_PS
        if not etas or not ps:
            raise InputError("--sweep needs at least one eta and one p")
        rows = run_sweep(case_path, args.out, etas=etas, ps=ps, base=opts, angle_deg=args.angle, progress=not args.no_progress)
        for r in rows:
            print(f"p = {r['p']:<5g} eta = {r['eta']:<9.3g} actuators {r['num_actuators']:>4}  fit mean {100 * r['fit_mean']:.3f}%  max {100 * r['fit_max']:.3f}%")
        print(f"  outputs in {args.out}/ (sweep.csv, sweep.png)")
        return 0
    candidates = None
    if args.candidates:
        try:
            candidates = [int(v) for v in args.candidates.split(",") if v.strip()]
        except ValueError:
            raise InputError(f"--candidates {args.candidates}: expected comma-separated vertex indices") from None
    r = run_sparsify(case_path, args.out, opts, candidates=candidates, angle_deg=args.angle, progress=not args.no_progress)
    print(f"{r['name']}: {r['num_actuators']} actuators at joints {r['actuated_joints']}")
    print(f"  torques {[round(t, 4) for t in r['torques']]} (dense: {r['dense_torque']:.4g} at every joint)")
    print(f"  distance to the dense deployment: mean {100 * r['fit_mean']:.3f}%, max {100 * r['fit_max']:.3f}% of the span")
    print(f"  work {r['work']:.6g} (dense {r['dense_work']:.6g}); {r['message']}; {r['time_s']:.1f} s "
          f"(+ {r['dense_deployment_time_s']:.1f} s dense deployment)")
    for w in r.get("warnings", []):
        print(f"  warning: {w}")
    print(f"  outputs in {args.out}/")
    return 0
