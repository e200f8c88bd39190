"""Design optimization of the rest lengths (paper §5): trust-region Newton-CG, and a BFGS baseline.

``method="newton-cg"`` (default) and ``method="bfgs"`` run the same
trust-region iteration (:func:`_trust_region`) on the same problem and
differ only in the model Hessian: exact Hessian-vector products (Appendix B)
against a quasi-Newton BFGS matrix, the paper's Fig. 7 comparison. The
subproblem is solved by Steihaug–Toint CG on the variables not held at
their lower bound (projected, as in Lin & Moré's TRON).

The flat-state constraints are kept *feasible at every accepted iterate*:
a trial design whose flat equilibrium leaves the plane (``c > tolerance``),
whose KS minimum angle falls below ε, or whose equilibria cannot be found
is rejected and the trust region shrinks. The planarity constraint suits
this well: by mirror symmetry the planar state is an exact equilibrium
while it is stable, so ``c`` is either round-off (about 1e-26 l₀²) or
large (the flat state buckled); it has no useful gradient at ``c = 0``.

``method="trust-constr"`` hands the problem with its constraints to
scipy's interior-point ``trust-constr`` instead. Measured on the wiggly
banana it lowered the deployed energy by only 2.6 % in 15 iterations (111 s),
where the trust-region iteration here reaches the paper's result; it is
kept for comparison.
"""
from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import Bounds, NonlinearConstraint, minimize
from scipy.sparse.linalg import LinearOperator

from ..deploy.simulate import folded_joint
from ..errors import InputError
from ..linkage.state import restore, snapshot
from ..solve.trust_region import steihaug


@dataclass(frozen=True)
class OptimizeOptions:
    """Settings of :func:`optimize`.

    Attributes
    ----------
    method : {"newton-cg", "bfgs", "trust-constr"}
    max_iterations : int
    min_rest_length_factor : float
        Each rest length stays above this fraction of its initial value.
    planarity_tolerance : float
        The flat state counts as planar while ``c / l₀² = ‖S_z x‖² / l₀² ≤``
        this: 1e-12 keeps every joint within 1e-6 l₀ of the plane (a planar
        equilibrium has about 1e-26). (An exact ``= 0`` has a vanishing
        gradient, which trust-constr cannot handle.)
    min_angle : float or None
        ε of the minimum-angle constraint (radians); default: the initial
        flat state's KS minimum angle less 0.5°, but at least half of it
        when it is positive. KS lies below every angle, so ``KS ≥ ε > 0``
        keeps all joints open; whatever ε, a trial design whose flat state
        folds a joint (an angle at or beyond 0° or 180°) is rejected.
    initial_radius : float
        First trust radius: for the trust-region methods, this fraction of
        the first preconditioned gradient's length (1 would be a full
        Newton step of the model); for ``"trust-constr"``, 0.08 × this in
        the scaled variables (0.25 → ±2 %).
    gradient_tolerance : float
        Stop when the projected gradient of ``J`` (in the scaled variables)
        falls below this.
    objective_tolerance : float
        Stop when an accepted step that the trust region did not cut, or
        three accepted steps in a row, lower ``J`` by less than this
        fraction.
    max_cg_iterations : int
        Hessian-vector products per trust-region subproblem.
    barrier : float
        Weight ``μ / J(q₀)`` of the log barriers on the minimum angle and
        the flat state's stability (trust-region methods). Besides keeping
        iterates feasible, it keeps them away from the boundaries, where
        steps get rejected: on the wiggly banana 1e-2 reached J = 0.125 in
        20 iterations, 1e-4 stalled at 0.266 against the angle bound.
    angle_curvature : bool
        Newton-CG: while the minimum angle is within 0.25° of ε, the model
        Hessian includes the angle barrier's curvature term
        ``−(μ/(KS − ε)) ∇²KS`` (one more Hessian-vector product per CG
        iteration), not only its Gauss–Newton part. Without it, steps along
        the active bound leave it at second order and are rejected: with
        ε = 1.16° (0.2° below the initial KS) the wiggly banana stalled at
        J = 0.198 after 30 iterations; with it, J = 0.143 after 30 and
        0.125 after 60.
    min_stability : float
        Floor ``σ_min`` of the flat state's stability measure (its lowest
        eigenvalues relative to the initial design's; see
        :meth:`DesignProblem.flat_stability`).
    hold_stability : bool
        Keep the lowest ``stability_modes`` flat eigenvalues unchanged to
        first order in every trust-region step.
    stability_modes : int
    min_clearance : float or None
        Trust-region methods: the beams' width (design units; None, the
        default: off). A log barrier keeps the flat state's beams of one
        family at least this far apart (their smooth minimum distance,
        :meth:`DesignProblem.flat_clearance`), or, where the starting design
        has them closer, at least 0.9 of its distance (then a run that
        starts where another ended at the width keeps the width, not 0.9
        of it, as the inverse design's stages do): a design whose flat
        beams overlap cannot be built (the inverse design's checks refuse
        it), and the energy alone does not keep them apart.
    trial_newton_iterations : int
        Newton steps allowed to the equilibria of a trial design before it
        is rejected (the trust region shrinks); a flat state that turns
        indefinite is rejected at once.
    """

    method: str = "newton-cg"
    max_iterations: int = 20
    min_rest_length_factor: float = 0.1
    planarity_tolerance: float = 1e-12
    min_angle: float | None = None
    initial_radius: float = 0.25
    gradient_tolerance: float = 1e-6
    objective_tolerance: float = 1e-4
    max_cg_iterations: int = 50
    barrier: float = 1e-2
    angle_curvature: bool = True
    min_stability: float = 0.1
    hold_stability: bool = True
    stability_modes: int = 4
    trial_newton_iterations: int = 30
    min_clearance: float | None = None

    def __post_init__(self):
        if self.method not in ("newton-cg", "bfgs", "trust-constr"):
            raise InputError(f"method must be 'newton-cg', 'bfgs' or 'trust-constr', got {self.method!r}")
        if self.max_iterations < 1:
            raise InputError(f"max_iterations must be at least 1, got {self.max_iterations}")
        if not (0 < self.min_rest_length_factor < 1):
            raise InputError(f"min_rest_length_factor must lie in (0, 1), got {self.min_rest_length_factor}")
        if self.min_clearance is not None and not (self.min_clearance > 0 and np.isfinite(self.min_clearance)):
            raise InputError(f"min_clearance must be a positive length, got {self.min_clearance}")
        if self.min_clearance is not None and self.method == "trust-constr":
            raise InputError("min_clearance applies to the trust-region methods (newton-cg, bfgs), not trust-constr")


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
    # how it ended, for callers (the message gains suffixes: rejected trials, an invalid state)
    interrupted: bool = False  # Ctrl-C or SIGTERM
    stopped: bool = False  # the callback asked to stop


_log = logging.getLogger(__name__)


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
        the best feasible iterate). Ctrl-C stops the same way.

    Returns
    -------
    OptimizeResult
        ``problem`` is left at the best feasible design found.
    """
    start = time.perf_counter()
    q0 = problem._q.copy() if q0 is None else np.asarray(q0, float)
    # X-shells are assembled nearly closed, so the KS minimum is small (or
    # even negative: KS lies below the true minimum by up to s·log n)
    ks0 = problem.min_angle(q0)
    # KS ≤ the true minimum: a positive ε keeps every joint open, so at most half of KS₀ below it. Where
    # KS₀ ≤ 0 (many small angles) no positive ε is feasible; trial designs that fold a joint are then
    # rejected outright (below), as KS cannot tell.
    eps = options.min_angle if options.min_angle is not None else (
        max(ks0 - np.radians(0.5), 0.5 * ks0) if ks0 > 0 else ks0 - np.radians(0.5))
    if ks0 < eps:
        raise InputError(f"the minimum-angle bound ε = {np.degrees(eps):.4g}° is infeasible: the starting design's "
                         f"KS minimum angle is {np.degrees(ks0):.4g}°")
    history: list[OptimizeRecord] = []
    best = {"J": np.inf, "q": q0.copy(), "states": None}

    def feasible(plan, ang):
        return plan <= options.planarity_tolerance * 1.01 and ang >= eps - 1e-9 and not folded_joint(problem.flat.L)

    def record(q, it):
        t = problem.terms(q)
        rec = OptimizeRecord(it, t["J"], t["flat_energy"], t["deployed_energy"], t["fit"], problem.planarity(q),
                             float(np.degrees(problem.min_angle(q))), time.perf_counter() - start)
        if feasible(rec.planarity, problem.min_angle(q)) and rec.J < best["J"]:
            best.update(J=rec.J, q=np.array(q, float), states=tuple(snapshot(eq.L) for eq in _equilibria(problem)))
        history.append(rec)
        if callback is not None and callback(rec):
            raise _Stop
        return rec

    failures: list[str] = []
    message, success = "", False
    interrupted = stopped = False
    try:
        record(q0, 0)
        if options.method == "trust-constr":
            message, success = _scipy_trust_constr(problem, q0, options, eps, record, failures)
        else:
            message, success = _trust_region(problem, q0, options, eps, record, failures)
    except _Stop:
        message, stopped = "stopped by request", True
    except KeyboardInterrupt:
        message, interrupted = "interrupted by the user", True
    except ArithmeticError as exc:
        message = f"stopped: an equilibrium solve failed ({exc})"
    if best["states"] is not None:
        _move_to(problem, best["q"], best["states"])
    for name, eq in (("flat", problem.flat), ("deployed", problem.deployed)):
        folded = folded_joint(eq.L)  # the energy alone does not keep a joint from crossing 0° or 180°
        if folded:
            message += f"; the {name} state is not valid: {folded}"
            success = False
    if failures:
        message += f" ({len(failures)} trial designs rejected)"
    return OptimizeResult(q=best["q"], rest_lengths=best["q"] * problem.p0, history=history, iterations=len(history) - 1,
                          message=message, time_s=time.perf_counter() - start, success=success,
                          interrupted=interrupted, stopped=stopped)


def _trust_region(problem, q0, options, eps, record, failures):
    """Projected trust-region iteration with exact (Newton-CG) or BFGS model Hessians.

    It minimizes ``Φ = J − μ log(KS − ε) − μ log(σ − σ_min)``: log barriers
    keep the minimum angle above ε and the flat state's stability measure
    ``σ`` (:meth:`DesignProblem.flat_stability`) above ``σ_min``, so that
    the flat state stays planar; their model Hessians are the Gauss–Newton
    terms ``μ ∇c∇cᵀ/(c − f)²``. ``μ`` is ``barrier · J(q₀)``. Every accepted
    iterate is feasible (see the module notes); a rejected trial puts the
    equilibria back at the last accepted design from their stored states,
    so no re-solve can jump to another branch.
    """
    lb = options.min_rest_length_factor
    exact = options.method == "newton-cg"
    q = np.maximum(np.array(q0, float), lb)
    # a segment to a free end keeps its rest length: nothing in J depends on it (its end slides freely), so
    # its curvature is round-off and the preconditioned step along it would be arbitrary
    fixed = free_end_parameters(problem)
    mu = options.barrier * problem.objective(q)
    sigma_min = options.min_stability

    width = options.min_clearance
    if width is not None:  # the width, or below the starting design's own distance: its iterates start feasible
        start_gap = problem.flat_clearance(q, width)[0]
        clear_min = width if start_gap > width else 0.9 * start_gap

    def barrier_parts(q):
        ang = problem.min_angle(q)
        sig, dsig = problem.flat_stability(q, options.stability_modes)
        parts = ((ang - eps, problem.min_angle_gradient(q)), (sig - sigma_min, dsig))
        if width is None:
            return parts
        gap, dgap = problem.flat_clearance(q, width)
        return (*parts, (gap - clear_min, dgap))

    def merit(q):
        J = problem.objective(q)
        parts = barrier_parts(q)
        if min(c for c, _ in parts) <= 0:
            return J, np.inf, parts
        return J, J - mu * sum(np.log(c) for c, _ in parts), parts

    def merit_gradient(gJ, parts):
        g = gJ
        for c, dc in parts:
            g = g - mu / c * dc
        return g

    J, f, parts = merit(q)
    if not np.isfinite(f):
        raise InputError("the starting design violates the minimum-angle or flat-stability bound")
    gJ = problem.gradient(q)
    g = merit_gradient(gJ, parts)
    states = tuple(snapshot(eq.L) for eq in _equilibria(problem))
    B = None  # BFGS matrix of J, scaled after the first step
    radius = None  # set on the first iteration, relative to the preconditioned gradient
    small = 0  # consecutive accepted steps that lowered J by less than the tolerance
    for it in range(1, options.max_iterations + 1):
        held = ((q <= lb) & (g > 0)) | fixed
        pg = np.where(held, 0.0, g)
        gnorm = float(np.linalg.norm(pg))
        if gnorm <= options.gradient_tolerance:
            return "projected gradient below tolerance", True
        free = ~held
        nf = int(free.sum())
        gn = [(np.sqrt(mu) / c) * dc for c, dc in parts]

        curv = exact and options.angle_curvature and parts[0][0] < np.radians(0.25)

        def model_hessp(v, q=q, gn=gn, w_ang=mu / parts[0][0], curv=curv):
            hv = problem.hessp(q, v) if exact else (v if B is None else B @ v)
            for u in gn:
                hv = hv + u * float(u @ v)
            if curv:
                # the angle barrier's own curvature −(μ/c)∇²KS: near the bound the
                # steps follow the bound's curvature instead of leaving it at second order
                hv = hv - w_ang * problem.min_angle_hessp(q, v)
            return hv

        # Preconditioner: a dense model of the Hessian on the free variables
        # (for Newton-CG the reduced energy Hessians, exact, plus the fitting
        # term's Gauss–Newton part; for BFGS its own matrix), taken in
        # absolute value. CG runs in y = |Λ|^½ Vᵀ s, where the preconditioned
        # model Hessian is close to ±I, and the trust region is the
        # ellipsoid ‖y‖ ≤ radius: J's Hessian spans five orders of magnitude
        # (nearly-closed flat state), and a round trust region lets every
        # step run along the stiff directions.
        if exact:
            Hd = problem.dense_hessian(q)
        else:
            Hd = np.eye(len(q)) if B is None else B
        Hd = Hd[np.ix_(free, free)] + sum(np.outer(u[free], u[free]) for u in gn)
        lam, V = np.linalg.eigh(0.5 * (Hd + Hd.T))
        lam = np.maximum(np.abs(lam), 1e-10 * np.abs(lam).max())
        T = V / np.sqrt(lam)[None, :]  # s_free = T y

        # Steps keep the lowest flat eigenvalues unchanged to first order
        # (the buckling boundary is close and strongly curved: on the wiggly
        # banana a 0.5 % step along −∇J crosses it), and the minimum angle
        # when it is nearly active.
        held_grads = []
        if options.hold_stability:
            held_grads.extend(problem.flat_stability_modes(q, options.stability_modes)[1])
        if parts[0][0] < np.radians(0.25):
            held_grads.append(parts[0][1])
        Q = np.linalg.qr(T.T @ np.array(held_grads)[:, free].T)[0] if held_grads else np.zeros((nf, 0))

        def project(y):
            return y - Q @ (Q.T @ y)

        def hy(y):
            w = np.zeros(len(q))
            w[free] = T @ project(y)
            return project(T.T @ model_hessp(w)[free])

        gy = project(T.T @ pg[free])
        if radius is None:
            radius = options.initial_radius * float(np.linalg.norm(gy))

        deployed_folded = bool(folded_joint(problem.deployed.L))
        while True:  # until a trial is accepted
            s = np.zeros(len(q))
            y = steihaug(hy, gy, radius, min(0.1, np.sqrt(gnorm)) * float(np.linalg.norm(gy)), options.max_cg_iterations)
            s[free] = T @ y
            q_trial = np.maximum(q + s, lb)
            step = q_trial - q
            if not np.any(step) or radius < 1e-12:
                return "no progress possible (the trust region collapsed)", False
            predicted = -(g @ step + 0.5 * step @ model_hessp(step))
            reason = ""
            try:
                with _trial_mode(problem, options):
                    J_trial, f_trial, parts_trial = merit(q_trial)
                plan = problem.planarity(q_trial)
                if plan > options.planarity_tolerance * 1.01:
                    reason = f"flat state left the plane (c = {plan:.2e})"
                elif folded := folded_joint(problem.flat.L):
                    reason = f"flat state: {folded}"
                elif not deployed_folded and (folded := folded_joint(problem.deployed.L)):
                    # a re-solve that carried the deployed state through a fold: not the state the design
                    # deploys to (a joint cannot open past 180°), and the branch is lost from then on. (A
                    # tracked state folded already, where a hold pulled a corner past 180°, is left to the
                    # stage checks, which deploy each design from flat.)
                    reason = f"deployed state: {folded}"
                elif not np.isfinite(f_trial):
                    reason = "minimum angle, flat stability or beam clearance out of bounds"
            except (ArithmeticError, InputError) as exc:
                reason = f"no equilibrium ({exc})"
            actual = f - f_trial if not reason else -np.inf
            rho = actual / predicted if predicted > 0 else -1.0
            _log.debug("trial |y|=%.3g |s|=%.3g radius=%.3g predicted=%.3g actual=%.3g rho=%.3g %s",
                       np.linalg.norm(y), np.linalg.norm(step), radius, predicted, actual, rho, reason)
            if not reason and actual > 0 and rho > 1e-4:
                break
            if reason:
                failures.append(reason)
            radius = 0.25 * min(radius, float(np.linalg.norm(y)))
            _move_to(problem, q, states)
        gJ_new = problem.gradient(q_trial)
        if not exact:
            dg = gJ_new - gJ  # (not ``y``: that is the step in the preconditioned variables)
            sy = float(step @ dg)
            if sy > 1e-12 * float(np.linalg.norm(step) * np.linalg.norm(dg)):
                if B is None:
                    B = np.eye(len(q)) * float(dg @ dg) / sy
                Bs = B @ step
                B = B - np.outer(Bs, Bs) / float(step @ Bs) + np.outer(dg, dg) / sy
        decrease = (J - J_trial) / max(abs(J), 1e-300)
        interior = np.linalg.norm(y) < 0.8 * radius  # the model's own minimizer, not cut by the trust region
        q, f, J, parts, gJ = q_trial, f_trial, J_trial, parts_trial, gJ_new
        g = merit_gradient(gJ, parts)
        states = tuple(snapshot(eq.L) for eq in _equilibria(problem))
        if rho > 0.75 and np.linalg.norm(y) > 0.8 * radius:
            radius *= 2.0
        elif rho < 0.25:
            radius *= 0.25
        record(q, it)
        small = small + 1 if 0 <= decrease < options.objective_tolerance else 0
        if small and interior or small >= 3:
            return "relative decrease of J below tolerance", True
    return "reached the iteration limit", False


def _equilibria(problem) -> tuple:
    """The equilibria that follow the design (a DesignProblem's ``equilibria``: flat, deployed, planar)."""
    return getattr(problem, "equilibria", (problem.flat, problem.deployed))


def free_end_parameters(problem) -> np.ndarray:
    """Which design parameters (S,) the optimization holds: the rest lengths of segments to a free end."""
    return (np.asarray(problem.flat.L.graph.segment_joints) < 0).any(axis=1)


@contextmanager
def _trial_mode(problem, options):
    """Equilibrium solves of a trial design give up early (see :class:`ConstrainedEquilibrium`)."""
    eqs = _equilibria(problem)
    try:
        problem.flat.stop_on_indefinite = True
        for eq in eqs:
            eq.trial_iterations = options.trial_newton_iterations
        yield
    finally:
        for eq in eqs:
            eq.stop_on_indefinite, eq.trial_iterations = False, None


def _scipy_trust_constr(problem, q0, options, eps, record, failures):
    """The same problem through scipy's interior-point ``trust-constr`` (exact ``hessp``)."""
    S = len(problem.p0)
    fixed = free_end_parameters(problem)
    q0 = np.asarray(q0, float)
    bounds = Bounds(np.where(fixed, q0, options.min_rest_length_factor), np.where(fixed, q0, np.inf))

    def lin_op(hv, q, v):
        return LinearOperator((S, S), matvec=lambda d: v[0] * hv(q, np.ravel(d)), dtype=float)

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
                                 hess=lambda q, v: lin_op(problem.planarity_hessp, q, v))
    c_angle = NonlinearConstraint(safe(problem.min_angle, -1e6), eps, np.inf, jac=problem.min_angle_gradient,
                                  hess=lambda q, v: lin_op(problem.min_angle_hessp, q, v))
    res = minimize(safe(problem.objective, 1e6), q0, jac=problem.gradient, hessp=problem.hessp, method="trust-constr",
                   bounds=bounds, constraints=[c_plan, c_angle],
                   callback=lambda r: record(np.asarray(r.x, float), r.nit),
                   options=dict(maxiter=options.max_iterations, initial_tr_radius=0.08 * options.initial_radius,
                                gtol=options.gradient_tolerance, xtol=1e-10, verbose=0))
    return str(res.message), bool(res.success)


def _move_to(problem, q, states) -> None:
    """Put the problem back at design ``q`` with the equilibria stored for it."""
    p = q * problem.p0
    for eq, st in zip(_equilibria(problem), states):
        restore(eq.L, st)
        eq.L.set_rest_lengths(p)
        eq.factorize()
    problem._q = np.array(q, float)
    problem._cache = {}
