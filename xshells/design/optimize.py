"""Design optimization of the rest lengths (paper §5): trust-region Newton-CG, and a BFGS baseline.

Both run scipy's ``trust-constr`` on the same problem (objective, bounds,
planarity and minimum-angle constraints); ``method="newton-cg"`` gives it
exact Hessian-vector products, ``method="bfgs"`` a quasi-Newton
approximation (the paper's Fig. 7 comparison).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import BFGS, Bounds, NonlinearConstraint, minimize
from scipy.sparse.linalg import LinearOperator

from ..errors import InputError
from ..linkage.state import restore, snapshot


@dataclass(frozen=True)
class OptimizeOptions:
    """Settings of :func:`optimize`.

    Attributes
    ----------
    method : {"newton-cg", "bfgs"}
    max_iterations : int
    min_rest_length_factor : float
        Each rest length stays above this fraction of its initial value.
    planarity_tolerance : float
        The flat state counts as planar while ``‖S_z x‖² / l₀² ≤`` this
        (an exact ``= 0`` has a vanishing gradient, which trust-constr
        cannot handle).
    min_angle : float or None
        ε of the minimum-angle constraint (radians); default: the initial
        flat state's KS minimum angle less 0.5°.
    initial_radius : float
        First trust radius in the scaled variables (0.02 = ±2 %).
    gradient_tolerance : float
    """

    method: str = "newton-cg"
    max_iterations: int = 20
    min_rest_length_factor: float = 0.1
    planarity_tolerance: float = 1e-8
    min_angle: float | None = None
    initial_radius: float = 0.02
    gradient_tolerance: float = 1e-6

    def __post_init__(self):
        if self.method not in ("newton-cg", "bfgs"):
            raise InputError(f"method must be 'newton-cg' or 'bfgs', got {self.method!r}")
        if self.max_iterations < 1:
            raise InputError(f"max_iterations must be at least 1, got {self.max_iterations}")
        if not (0 < self.min_rest_length_factor < 1):
            raise InputError(f"min_rest_length_factor must lie in (0, 1), got {self.min_rest_length_factor}")


@dataclass
class OptimizeRecord:
    iteration: int
    J: float
    flat_energy: float
    deployed_energy: float
    fit: float
    planarity: float
    min_angle_deg: float
    time_s: float


@dataclass
class OptimizeResult:
    q: np.ndarray
    rest_lengths: np.ndarray
    history: list = field(default_factory=list)
    iterations: int = 0
    message: str = ""
    time_s: float = 0.0
    success: bool = False


class _Stop(Exception):
    pass


def optimize(problem, options: OptimizeOptions = OptimizeOptions(), q0=None, callback=None) -> OptimizeResult:
    """Minimize ``J`` over the scaled rest lengths.

    Parameters
    ----------
    problem : DesignProblem
    options : OptimizeOptions
    q0 : (S,) array, optional
        Starting point (default: the problem's current design).
    callback : callable(OptimizeRecord) -> bool, optional
        Called after every iteration; return True to stop (the result keeps
        the last iterate). Ctrl-C stops the same way.

    Returns
    -------
    OptimizeResult
        ``problem`` is left at the best design found.
    """
    start = time.perf_counter()
    S = len(problem.p0)
    q0 = problem._q.copy() if q0 is None else np.asarray(q0, float)
    # X-shells are assembled nearly closed, so the KS minimum is small (or
    # even negative: KS lies below the true minimum by up to s·log n)
    eps = options.min_angle if options.min_angle is not None else problem.min_angle(q0) - np.radians(0.5)
    bounds = Bounds(np.full(S, options.min_rest_length_factor), np.full(S, np.inf))

    def lin_op(hv, q, v):
        return LinearOperator((S, S), matvec=lambda d: v[0] * hv(q, np.ravel(d)), dtype=float)

    use_hessp = options.method == "newton-cg"
    failures = []

    def safe(fn, bad):
        # A trial design whose equilibria cannot be found counts as a very bad
        # point: the trust region shrinks instead of the run stopping.
        def wrapped(q):
            try:
                return fn(q)
            except ArithmeticError as exc:
                failures.append(str(exc))
                return bad
        return wrapped

    c_plan = NonlinearConstraint(safe(problem.planarity, 1e6), -np.inf, options.planarity_tolerance, jac=problem.planarity_gradient,
                                 hess=(lambda q, v: lin_op(problem.planarity_hessp, q, v)) if use_hessp else BFGS())
    c_angle = NonlinearConstraint(safe(problem.min_angle, -1e6), eps, np.inf, jac=problem.min_angle_gradient,
                                  hess=(lambda q, v: lin_op(problem.min_angle_hessp, q, v)) if use_hessp else BFGS())
    history: list[OptimizeRecord] = []
    best = {"J": np.inf, "q": q0.copy(), "states": None}

    def record(q, it):
        t = problem.terms(q)
        rec = OptimizeRecord(it, t["J"], t["flat_energy"], t["deployed_energy"], t["fit"], problem.planarity(q),
                             float(np.degrees(problem.min_angle(q))), time.perf_counter() - start)
        feasible = rec.planarity <= options.planarity_tolerance * 1.01 and problem.min_angle(q) >= eps - 1e-9
        if feasible and rec.J < best["J"]:
            best.update(J=rec.J, q=np.array(q, float), states=(snapshot(problem.flat.L), snapshot(problem.deployed.L)))
        history.append(rec)
        return rec

    record(q0, 0)
    if callback is not None:
        callback(history[-1])

    def cb(intermediate_result):
        q = np.asarray(intermediate_result.x, float)
        rec = record(q, len(history))
        if callback is not None and callback(rec):
            raise _Stop

    kw = dict(hessp=problem.hessp) if use_hessp else dict(hess=BFGS())
    message, success = "", False
    try:
        res = minimize(safe(problem.objective, 1e6), q0, jac=problem.gradient, method="trust-constr", bounds=bounds,
                       constraints=[c_plan, c_angle], callback=cb,
                       options=dict(maxiter=options.max_iterations, initial_tr_radius=options.initial_radius,
                                    gtol=options.gradient_tolerance, xtol=1e-10, verbose=0), **kw)
        message, success = str(res.message), bool(res.success)
    except _Stop:
        message = "stopped by request"
    except KeyboardInterrupt:
        message = "interrupted by the user"
    except ArithmeticError as exc:
        message = f"stopped: an equilibrium solve failed ({exc})"
    if best["states"] is not None:
        _move_to(problem, best["q"], best["states"])
    if failures:
        message += f" ({len(failures)} trial designs rejected: no equilibrium)"
    return OptimizeResult(q=best["q"], rest_lengths=best["q"] * problem.p0, history=history, iterations=len(history) - 1,
                          message=message, time_s=time.perf_counter() - start, success=success)


def _move_to(problem, q, states) -> None:
    """Put the problem back at design ``q`` with the equilibria stored for it."""
    p = q * problem.p0
    for eq, st in zip((problem.flat, problem.deployed), states):
        restore(eq.L, st)
        eq.L.set_rest_lengths(p)
        eq.factorize()
    problem._q = np.array(q, float)
    problem._cache = {}
