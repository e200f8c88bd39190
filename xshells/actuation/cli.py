"""``xshells sparsify``: where to put the motors."""
from __future__ import annotations

import re

import numpy as np

from ..deploy.case import add_design_options, case_path_from_args
from ..errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "sparsify", help="find a sparse set of joint torques that deploys a case to its dense-actuation shape",
        description="Sparse actuation (paper §6). Deploys the case with every joint actuated, then finds the fewest "
                    "joints whose torques reach the same shape within --max-fit (or N joints with --actuators N), and the "
                    "trade-off curve on the way. Torques are in the energy's units (N·mm for mm and MPa). Writes "
                    "result.json, torques.txt, actuators.png, actuated.3dm and (not with --eta) sweep.csv, sweep.png "
                    "into --out, removing those of an earlier run there.")
    # "-inf" and "-1e-3" as values (--tau-max -inf gets the option's own check, not "expected one argument")
    p._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+|inf(inity)?|nan)([eE][-+]?\d+)?$", re.IGNORECASE)
    p.add_argument("case", help="a case file (.json), or a design (.obj, .msh, .3dm) with --material etc.")
    p.add_argument("--max-fit",
                   help="the fewest actuators whose mean joint deviation from the dense deployment stays within this "
                        "share of the span: a percentage (1%%) or a fraction (0.01); default 1%%. With --eta: an "
                        "answer above it is reported as not converged (exit 1)")
    p.add_argument("--actuators", type=int,
                   help="N actuators instead of a deviation limit: eliminated down to N, then improved by exchanging "
                        "single joints (a local search: the best N is not guaranteed)")
    p.add_argument("--eta", type=float, help="experts: solve the paper's eq. 8 with this sparsity weight instead "
                                             "(dimensionless, e.g. 3e-4)")
    p.add_argument("--p", type=float, help="with --eta: power of the lp penalty, in (0, 1] (default 0.5)")
    p.add_argument("--tau-max", type=float, help="largest torque one actuator may apply")
    p.add_argument("--candidates", help="comma-separated input vertex indices of the joints that may be actuated (default all)")
    p.add_argument("--angle", type=float, help="target average opening angle, degrees (default: the case's)")
    p.add_argument("--max-iters", type=int, help="with --eta: trust-region iterations (default 100)")
    p.add_argument("--sweep", action="store_true",
                   help="the whole trade-off curve (Fig. 9): go on eliminating down to one actuator (with --actuators N: "
                        "down to N); with --etas, solve eq. 8 for each eta and p instead (--candidates, --tau-max and "
                        "--max-iters apply; Ctrl-C keeps the finished runs)")
    p.add_argument("--etas", help="with --sweep: comma-separated eta values of eq. 8")
    p.add_argument("--ps", help="with --sweep --etas: comma-separated p values (default 1,0.5,0.25)")
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


def parse_fraction(text: str, what: str = "--max-fit") -> float:
    """'1%' or '0.01' as a fraction of the span; a clear error for anything else."""
    t = str(text).strip()
    try:
        value = float(t[:-1]) / 100.0 if t.endswith("%") else float(t)
    except ValueError:
        raise InputError(f"{what} {text}: expected a percentage (1%) or a fraction of the span (0.01)") from None
    if not (np.isfinite(value) and 0 < value < 1):
        raise InputError(f"{what} {text}: must lie between 0 and 100% of the span (a fraction like 0.01, or 1%)")
    return value


def _run(args, case_path) -> int:
    from .run import DEFAULT_PS, run_selection, run_sparsify, run_sweep
    from .selection import SelectionOptions
    from .sparsify import SparsifyOptions

    eq8 = args.eta is not None or bool(args.etas)
    if args.p is not None:
        _options(SparsifyOptions, p=args.p)  # validates
    if args.tau_max is not None:
        _options(SparsifyOptions, tau_max=args.tau_max)
    for flag, value in (("--p", args.p), ("--max-iters", args.max_iters), ("--ps", args.ps)):
        if value is not None and not eq8:
            raise InputError(f"{flag} applies to eq. 8 only: give --eta (or --sweep --etas) too")
    if args.max_iters is not None and args.max_iters < 1:
        raise InputError(f"--max-iters must be at least 1, got {args.max_iters}")
    p = 0.5 if args.p is None else args.p
    max_iters = 100 if args.max_iters is None else args.max_iters
    if args.actuators is not None and args.actuators < 1:
        raise InputError(f"--actuators must be at least 1, got {args.actuators}")
    if args.eta is not None and args.actuators is not None:
        raise InputError("--eta and --actuators choose the count in two different ways: give one of them")
    if args.etas and not args.sweep:
        raise InputError("--etas needs --sweep")
    if args.sweep and args.etas:
        for flag, value in (("--eta", args.eta), ("--actuators", args.actuators), ("--max-fit", args.max_fit)):
            if value is not None:
                raise InputError(f"{flag} does not apply to --sweep --etas (each run takes its eta from --etas and "
                                 f"its count from eq. 8); leave it out, or run without --etas")
    if args.max_fit is not None and args.actuators is not None:
        raise InputError("--max-fit limits the deviation of the default mode: it does not apply with --actuators; "
                         "give one of them")
    max_fit = parse_fraction("1%" if args.max_fit is None else args.max_fit)
    candidates = None
    if args.candidates is not None:  # an empty list is a mistake, not "all joints"
        try:
            candidates = [int(v) for v in args.candidates.split(",") if v.strip()]
        except ValueError:
            raise InputError(f"--candidates {args.candidates}: expected comma-separated vertex indices") from None
        if not candidates:
            raise InputError(f"--candidates {args.candidates!r}: no vertex index given (leave the option out for all joints)")
    if args.sweep and args.etas:
        from .run import SweepInterrupted

        opts = _options(SparsifyOptions, p=p, tau_max=args.tau_max, max_iterations=max_iters)
        etas = _floats(args.etas, "etas")
        ps = _floats(args.ps, "ps") if args.ps else DEFAULT_PS
        if not etas or not ps:
            raise InputError("--sweep needs at least one eta and one p")
        for eta in etas:
            _options(SparsifyOptions, eta=eta)
        for value in ps:
            _options(SparsifyOptions, p=value)
        try:
            rows = run_sweep(case_path, args.out, etas=etas, ps=ps, base=opts, candidates=candidates, angle_deg=args.angle,
                             progress=not args.no_progress)
        except SweepInterrupted as stop:
            _sweep_summary(stop.rows, args.out)
            print(f"  interrupted: {len(stop.rows)} of {stop.total} runs finished and are written; the one cut short is "
                  f"not kept")
            raise KeyboardInterrupt from None
        _sweep_summary(rows, args.out)
        failed = sum(not r["converged"] for r in rows)
        if failed:
            print(f"  {failed} of {len(rows)} runs did not converge (converged and message in sweep.csv; open markers "
                  f"in sweep.png)")
        return 0
    if args.eta is not None:
        from .run import ETA_ACCEPT_FIT

        opts = _options(SparsifyOptions, eta=args.eta, p=p, tau_max=args.tau_max, max_iterations=max_iters)
        r = run_sparsify(case_path, args.out, opts, candidates=candidates, angle_deg=args.angle, progress=not args.no_progress,
                         accept_fit=ETA_ACCEPT_FIT if args.max_fit is None else max_fit)
    else:
        opts = _options(SelectionOptions, max_fit=max_fit, actuators=args.actuators, tau_max=args.tau_max,
                        full_curve=args.sweep)
        r = run_selection(case_path, args.out, opts, candidates=candidates, angle_deg=args.angle, progress=not args.no_progress)
    _summary(r, args.out)
    if r.get("status") == "interrupted":  # the best answer so far is written; the exit says it was cut short
        raise KeyboardInterrupt
    return 0 if r["converged"] else 1  # as `xshells deploy` does for a run that stops short


FLAGS = {"eta": "--eta", "p": "--p", "tau_max": "--tau-max", "max_iterations": "--max-iters", "max_fit": "--max-fit",
         "actuators": "--actuators"}


def _options(cls, **kwargs):
    """``cls(**kwargs)`` with a bad value's error naming the command-line option, not the field."""
    try:
        return cls(**kwargs)
    except InputError as exc:
        text = str(exc)
        name = text.split(" ", 1)[0]
        raise InputError(FLAGS[name] + text[len(name):] if name in FLAGS else text) from None


def _sweep_summary(rows, out: str) -> None:
    for r in rows:
        print(f"p = {r['p']:<5g} eta = {r['eta']:<9.3g} actuators {r['num_actuators']:>4}  fit mean {100 * r['fit_mean']:.3f}%  "
              f"max {100 * r['fit_max']:.3f}%" + ("" if r["converged"] else f"  NOT CONVERGED: {r['message']}"))
    print(f"  outputs in {out}/ (sweep.csv, sweep.png)")


def _summary(r: dict, out: str) -> None:
    def listed(values, fmt):
        text = ", ".join(fmt(v) for v in values[:12])
        return f"[{text}{', … (all in result.json)' if len(values) > 12 else ''}]"

    k = r['num_actuators']
    print(f"{r['name']}: {k} actuator{'' if k == 1 else 's'} at joint{'' if k == 1 else 's'} {listed(r['actuated_joints'], str)}")
    print(f"  torques {listed(r['torques'], lambda t: f'{t:.4g}')} (dense: {r['dense_torque']:.4g} at every joint)")
    limit = f" (limit {100 * r['max_fit']:g}%)" if r.get("method") == "elimination" and not r.get("actuators_requested") else ""
    print(f"  joints' distance to the dense deployment: mean {100 * r['fit_mean']:.3f}%{limit}, max {100 * r['fit_max']:.3f}% of the span")
    if r.get("free_end_fit_mean") is not None:
        print(f"  free ends' distance (not fitted): mean {100 * r['free_end_fit_mean']:.3f}%, max "
              f"{100 * r['free_end_fit_max']:.3f}% of the span ({r['num_free_ends']} free ends)")
    print(f"  work {r['work']:.6g} (dense {r['dense_work']:.6g}); {r['time_s']:.1f} s "
          f"(+ {r['dense_deployment_time_s']:.1f} s dense deployment)")
    state = "finished" if r["converged"] else "NOT CONVERGED"
    print(f"  {state}: {r['message']}")
    if r.get("suggestion"):
        print(f"  suggestion: {r['suggestion']}")
    for w in r.get("warnings", []):
        print(f"  warning: {w}")
    files = "result.json, torques.txt, actuators.png, actuated.3dm" + (", sweep.csv, sweep.png" if r.get("method") == "elimination" else "")
    print(f"  outputs in {out}/ ({files})")
