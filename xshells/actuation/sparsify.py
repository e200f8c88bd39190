"""Sparse actuation: few joint torques that still deploy to the target (paper §6, eqs. 7–8).

The deployed equilibrium under a vector of joint torques ``τ`` is
``x̃(τ) = argmin E(x) − τ·S_α x`` (one joint's position and rotation held).
Dense actuation (every joint pushing with the deployment's multiplier
``τ_ref``) reproduces the angle-driven deployment exactly, and its joint
positions are the targets. Sparsification solves eq. 8,

    min_{0 ≤ t ≤ (τ_max/τ_ref)^p}  f(t) = T(x̃(τ(t))) / l₀² + η/n Σ t_i,   τ_i = τ_ref t_i^{1/p},

where ``T(x) = ½ Σ_j w_j |P_j(x) − P_j^tgt|²`` (equal weights summing to 1,
no surface term; in the code ``f`` also has the fold penalty
``⅓ Σ e_j³`` on each joint angle's excess ``e_j`` beyond FOLD_MARGIN from 0
or π, zero at valid answers), ``l₀`` is the bounding-box diagonal of the targets and
``n`` the number of joints. Scaling by ``l₀²`` and by ``τ_ref`` makes ``η``
dimensionless: at ``t = 1`` (dense actuation) the regularizer is ``η`` and
the fit is exact.

Derivatives (adjoint method, all with one factorization of the equilibrium
Hessian ``H`` on the free variables):

* ``H λ = ∇T``, ``∂f/∂τ = S_α λ / l₀²``;
* for a direction ``δτ``: ``H δx = S_αᵀ δτ`` and
  ``H δλ = ∇²T δx − dH[δx] λ``; then ``δ(∂f/∂τ) = S_α δλ / l₀²``;
* the chain rule through ``τ(t)`` adds ``(∂f/∂τ) τ''(t) δt``.

``dH[δx] λ`` is the third derivative contracted with two vectors
(:func:`xshells.linkage.derivatives.third_derivative_product`).

The bound-constrained problem is solved by a projected trust-region
Newton-CG (Steihaug CG on the free variables, in the spirit of Lin & Moré's
TRON): components at a bound whose gradient pushes outwards are held, the
others take the Newton-CG step, and the trial point is projected onto the
box. Components that reach zero switch their actuator off exactly.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..deploy.simulate import folded_joint
from ..errors import InputError
from ..linkage.derivatives import third_derivative_product
from ..linkage.state import restore, snapshot
from ..solve import NewtonOptions, NotPositiveDefinite, SparseCholesky, minimize
from ..solve.trust_region import steihaug


FOLD_MARGIN = np.radians(5.0)
"""Joint angles within this of 0 or π (or beyond the dense deployment's own) are penalized."""
FOLD_WEIGHT = 1.0
"""Weight of the fold penalty ``⅓ Σ |excess|³`` (radians) in ``f``: an excess of 5° costs 2.2e-4,
more than the fit term of a typical sparse answer (``T/l₀²`` about 1e-6…1e-5). Cubic, so that
``f`` stays C² (a quadratic penalty's kink collapsed the trust region)."""


@dataclass(frozen=True)
class SparsifyOptions:
    """Settings of :func:`sparsify`.

    Attributes
    ----------
    eta : float
        Weight of the sparsity term (dimensionless, see the module notes).
    p : float
        Power of the ℓp "norm", 0 < p ≤ 1 (eq. 8).
    tau_max : float or None
        Largest torque one actuator may apply, in the energy's units (N·mm
        for designs in mm and MPa); None for no limit.
    max_iterations : int
        Outer trust-region iterations.
    tolerance : float
        Stop when the projected gradient's largest entry falls below this
        (in units of ``f``, which is dimensionless).
    off_threshold : float
        An actuator whose torque is below this fraction of ``τ_ref`` counts
        as off in the reported count.
    initial_radius : float
        First trust radius, in ``t`` units (``t = 1`` is dense actuation).
    max_cg_iterations : int
    """

    eta: float = 1e-4
    p: float = 0.5
    tau_max: float | None = None
    max_iterations: int = 100
    tolerance: float = 1e-9
    off_threshold: float = 1e-3
    initial_radius: float = 1.0
    max_cg_iterations: int = 50

    def __post_init__(self):
        _number("eta", self.eta, minimum=0.0)
        _number("p", self.p)
        if not (0 < self.p <= 1):
            raise InputError(f"p must lie in (0, 1], got {self.p}")
        if self.tau_max is not None:
            _number("tau_max", self.tau_max, positive=True, finite=False)
            if self.tau_max == np.inf:
                object.__setattr__(self, "tau_max", None)  # no limit
        _whole("max_iterations", self.max_iterations)
        _whole("max_cg_iterations", self.max_cg_iterations)
        _number("tolerance", self.tolerance, positive=True)
        _number("off_threshold", self.off_threshold, minimum=0.0)
        if not self.off_threshold < 1:
            raise InputError(f"off_threshold must lie in [0, 1) (a fraction of the dense torque), got {self.off_threshold}")
        _number("initial_radius", self.initial_radius, positive=True)


def _number(name, value, *, minimum=None, positive=False, finite=True) -> None:
    """An option that must be a real number (not a string or a bool), finite unless told, ≥ minimum / > 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if np.isnan(v) or (finite and not np.isfinite(v)):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    if positive and not v > 0:
        raise InputError(f"{name} must be positive, got {value!r}")
    if minimum is not None and not v >= minimum:
        raise InputError(f"{name} must be a non-negative number, got {value!r}")


def _whole(name, value, minimum: int = 1) -> None:
    """An option that must be a whole number of at least ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise InputError(f"{name} must be a whole number of at least {minimum}, got {value!r}")


@dataclass
class IterationRecord:
    iteration: int
    objective: float
    fit: float
    regularizer: float
    num_actuators: int
    radius: float
    projected_gradient: float
    accepted: bool


@dataclass
class SparsifyResult:
    """The answer of :func:`sparsify`.

    ``actuated`` holds joint numbers (indices into ``torques``, the
    linkage's joint order); ``actuated_vertices`` the same joints as input
    vertex indices (what the CLI prints and ``result.json`` calls
    ``actuated_joints``). ``fit_mean``/``fit_max``: the joints' distance to
    the targets relative to the span; ``free_end_fit_mean``/``_max``: the
    free ends' distance to where they were at the call's start (not part of
    the fit; NaN without free ends). ``work``: energy stored from
    ``flat_energy`` (NaN when it was not given). ``state``: a snapshot of the
    sparsely actuated equilibrium (``xshells.linkage.state.restore``); the
    linkage itself is back at the state the call started from.
    """

    torques: np.ndarray
    actuated: np.ndarray
    objective: float
    fit_mean: float
    fit_max: float
    work: float
    iterations: int
    converged: bool
    message: str
    time_s: float
    history: list = field(default_factory=list)
    actuated_vertices: np.ndarray = None
    free_end_fit_mean: float = float("nan")
    free_end_fit_max: float = float("nan")
    state: dict = None


def _equilibrium_options(linkage, tau_ref) -> NewtonOptions:
    # Tight: the adjoint gradient is only as accurate as the equilibrium. The
    # floor is what round-off in the stiff stretching terms leaves. Up to 300
    # iterations: a shape unstable under torque control snaps to another
    # equilibrium, a long walk (the boat at 62°: not settled after 100 on one
    # machine, |g| = 3e2, though it was on another; within 300 there).
    eps = np.finfo(float).eps
    coords = float(np.abs(linkage.rods.points).max())
    floor = 10.0 * eps * float(linkage.rods.ks.max()) * coords / float(linkage.rods.rest_lengths.min()) * np.sqrt(linkage.num_vars)
    return NewtonOptions(gradient_tolerance=max(1e-9 * tau_ref * np.sqrt(linkage.num_joints), floor), max_iterations=300,
                         saddle_gradient_factor=float("inf"))


class TorqueFit:
    """``f(t)`` of eq. 8 with its adjoint gradient and Hessian-vector products.

    Parameters
    ----------
    linkage : Linkage
        At the densely actuated deployed equilibrium; it follows every
        evaluation (warm starts) and is left at the last evaluated state.
    tau_ref : float
        The dense actuation torque (the deployment's multiplier per joint).
    p, eta : float
    targets : (n, 3) array, optional
        Target joint positions (default: the current ones).
    weights : (n,) array, optional
        Fitting weights (default equal, summing to one).
    """

    def __init__(self, linkage, tau_ref: float, p: float = 0.5, eta: float = 1e-4, targets=None, weights=None):
        if not (np.isfinite(tau_ref) and tau_ref > 0):
            raise InputError(f"the dense actuation torque must be positive (an opening deployment), got {tau_ref}")
        self.L = linkage
        self.tau_ref, self.p, self.eta = float(tau_ref), float(p), float(eta)
        n = linkage.num_joints
        self.targets = linkage.joint_positions() if targets is None else np.asarray(targets, float)
        if self.targets.shape != (n, 3) or not np.isfinite(self.targets).all():
            raise InputError(f"targets: expected {n} finite joint positions (shape ({n}, 3)), got shape {self.targets.shape}")
        self.free_end_vertices = np.asarray(linkage.graph.free_end_vertex, int)
        self.free_end_targets = linkage.vertex_positions()[self.free_end_vertices]  # reported, not fitted
        self.weights = np.full(n, 1.0 / n) if weights is None else np.asarray(weights, float)
        self.l0 = float(np.linalg.norm(np.ptp(self.targets, axis=0)))
        self.pins = linkage.rigid_pin_indices()
        self.free = np.setdiff1d(np.arange(linkage.num_vars), self.pins)
        self.angle_rows = linkage.angle_indices()
        self.pos_rows = (9 * np.arange(n))[:, None] + np.arange(3)[None, :]
        self.chol = SparseCholesky()
        self.newton = _equilibrium_options(linkage, self.tau_ref)
        self._t = None
        self.equilibrium_iterations = 0
        self.predictor_limit = None  # largest joint-angle change (radians) of the predictor; None: no limit
        # Joint angles are penalized outside [lo, hi]: FOLD_MARGIN inside (0, π), widened to
        # the dense deployment's own angles, so the penalty is zero wherever that is.
        alpha = linkage.joint_angles()
        self.angle_window = (min(FOLD_MARGIN, float(alpha.min())), max(np.pi - FOLD_MARGIN, float(alpha.max())))

    # ---------------------------------------------------------------- maps
    def torques(self, t) -> np.ndarray:
        return self.tau_ref * np.power(np.maximum(t, 0.0), 1.0 / self.p)

    def _dtau(self, t):
        q = 1.0 / self.p
        return self.tau_ref * q * np.power(np.maximum(t, 0.0), q - 1.0)

    def _d2tau(self, t):
        q = 1.0 / self.p
        if q == 1.0:
            return np.zeros_like(t)
        return self.tau_ref * q * (q - 1.0) * np.power(np.maximum(t, 0.0), q - 2.0)

    def fit_terms(self) -> tuple[float, np.ndarray]:
        """``T(x)`` and the joint deviations ``P − P_tgt`` (n, 3) at the linkage's state."""
        dev = self.L.joint_positions() - self.targets
        return 0.5 * float(np.sum(self.weights[:, None] * dev**2)), dev

    def free_end_distances(self) -> np.ndarray:
        """The free ends' distances to their positions at the start, relative to the span (not part of the fit)."""
        if not len(self.free_end_vertices):
            return np.zeros(0)
        P = self.L.vertex_positions()[self.free_end_vertices]
        return np.linalg.norm(P - self.free_end_targets, axis=1) / self.l0

    def fold_excess(self) -> np.ndarray:
        """How far (radians) each joint angle lies outside the angle window, signed (n,): the fold penalty is ``⅓ FOLD_WEIGHT Σ |excess|³``."""
        alpha = self.L.joint_angles()
        lo, hi = self.angle_window
        return np.where(alpha > hi, alpha - hi, np.where(alpha < lo, alpha - lo, 0.0))

    # ----------------------------------------------------------- evaluation
    def _solve_equilibrium(self, t) -> None:
        tau = self.torques(t)
        force = np.zeros(self.L.num_vars)
        force[self.angle_rows] = tau
        if self._t is not None:  # first-order predictor with the factorization at hand
            dx = np.zeros(self.L.num_vars)
            dx[self.free] = self.chol.solve((force - self._force)[self.free])
            if self.predictor_limit is not None:  # near a buckling load the linear prediction overshoots
                swing = float(np.abs(dx[self.angle_rows]).max())
                if swing > self.predictor_limit:
                    dx *= self.predictor_limit / swing
            self.L.set_vars(self.L.get_vars() + dx)
        report = minimize(self.L, fixed=self.pins, force=force, options=self.newton)
        self.equilibrium_iterations += report.iterations
        if not report.converged:
            raise ArithmeticError(f"equilibrium under the trial torques did not converge ({report.message})")
        self.L.update_source_frame()
        H = self.L.hessian()[self.free][:, self.free]
        try:
            self.chol.factorize(H)
        except NotPositiveDefinite:
            raise ArithmeticError("the equilibrium under the trial torques is unstable (indefinite Hessian)") from None
        self._t = np.array(t, float)
        self._force = force

    def evaluate(self, t) -> float:
        """``f(t)``; moves the linkage to ``x̃(τ(t))`` and factorizes its Hessian."""
        t = np.asarray(t, float)
        if self._t is None or not np.array_equal(t, self._t):
            self._solve_equilibrium(t)
        T, dev = self.fit_terms()
        self._dev = dev
        excess = self._excess = self.fold_excess()
        # the objective's gradient in x, scaled by l₀² (the fit's own scale)
        gT = np.zeros(self.L.num_vars)
        gT[self.pos_rows] = self.weights[:, None] * dev
        gT[self.angle_rows] += FOLD_WEIGHT * self.l0**2 * excess * np.abs(excess)
        self._lam = np.zeros(self.L.num_vars)
        self._lam[self.free] = self.chol.solve(gT[self.free])
        fold = FOLD_WEIGHT / 3.0 * float(np.sum(np.abs(excess) ** 3))
        return T / self.l0**2 + fold + self.eta / len(t) * float(np.sum(t))

    def parts(self, t) -> tuple[float, float]:
        """(fit term ``T/l₀²`` plus the fold penalty, regularizer) at ``t``."""
        f = self.evaluate(t)
        reg = self.eta / len(t) * float(np.sum(t))
        return f - reg, reg

    def gradient(self, t) -> np.ndarray:
        t = np.asarray(t, float)
        self.evaluate(t)
        g_tau = self._lam[self.angle_rows] / self.l0**2
        return g_tau * self._dtau(t) + self.eta / len(t)

    def hessp(self, t, v) -> np.ndarray:
        """Hessian of ``f`` at ``t`` times ``v`` (two back-solves and one Hessian derivative)."""
        t, v = np.asarray(t, float), np.asarray(v, float)
        self.evaluate(t)
        dtau = self._dtau(t) * v
        rhs = np.zeros(self.L.num_vars)
        rhs[self.angle_rows] = dtau
        dx = np.zeros(self.L.num_vars)
        dx[self.free] = self.chol.solve(rhs[self.free])
        r = np.zeros(self.L.num_vars)
        r[self.pos_rows] = self.weights[:, None] * dx[self.pos_rows]
        r[self.angle_rows] += 2.0 * FOLD_WEIGHT * self.l0**2 * np.abs(self._excess) * dx[self.angle_rows]
        if np.any(self._lam) and np.any(dx):
            r -= third_derivative_product(self.L, dx, self._lam)
        dlam = np.zeros(self.L.num_vars)
        dlam[self.free] = self.chol.solve(r[self.free])
        g_tau = self._lam[self.angle_rows] / self.l0**2
        return dlam[self.angle_rows] / self.l0**2 * self._dtau(t) + g_tau * self._d2tau(t) * v


def sparsify(linkage, tau_ref: float, options: SparsifyOptions = SparsifyOptions(), *, targets=None, weights=None,
             t0=None, allowed=None, flat_energy: float | None = None, callback=None) -> SparsifyResult:
    """Sparse joint torques that deploy ``linkage`` to its current (densely actuated) shape.

    Parameters
    ----------
    linkage : Linkage
        At the densely actuated deployed equilibrium (e.g. after
        :func:`xshells.deploy.simulate.deploy`): its joint positions are the
        targets unless ``targets`` is given. It is back at that state when
        the call returns (so a second call measures against the same
        targets); the sparse equilibrium is ``result.state``.
    tau_ref : float
        The dense torque per joint (``DeploymentResult.torque``).
    options : SparsifyOptions
    targets, weights : optional
        See :class:`TorqueFit`.
    t0 : (n,) array, optional
        Starting point in ``t`` (default 1: dense actuation).
    allowed : (n,) bool array, optional
        Joints that may carry an actuator (default all); the others get
        no torque.
    flat_energy : float, optional
        Energy of the flat assembly state (``DenseDeployment.flat_energy``):
        the reported work is the energy stored from there to the sparse
        equilibrium, which is what the actuators do over any quasi-static
        deployment (the loads are conservative). Without it the work is NaN.
    callback : callable(IterationRecord) -> bool, optional
        Progress; return True to stop (the result keeps the last accepted
        iterate).

    Returns
    -------
    SparsifyResult
    """
    start = time.perf_counter()
    start_state = snapshot(linkage)
    try:
        return _sparsify(linkage, tau_ref, options, targets, weights, t0, allowed, flat_energy, callback, start)
    finally:
        restore(linkage, start_state)


def answer_report(fit: TorqueFit, tau, flat_energy) -> dict:
    """What both methods report about the state the linkage is at: fits, free ends, work, vertices, its snapshot."""
    L = fit.L
    _, dev = fit.fit_terms()
    dist = np.linalg.norm(dev, axis=1) / fit.l0
    free = fit.free_end_distances()
    actuated = np.flatnonzero(tau > 0)
    return dict(actuated=actuated, actuated_vertices=np.asarray(L.graph.joint_vertex)[actuated],
                fit_mean=float(dist.mean()), fit_max=float(dist.max()),
                free_end_fit_mean=float(free.mean()) if len(free) else float("nan"),
                free_end_fit_max=float(free.max()) if len(free) else float("nan"),
                work=float(L.energy()) - flat_energy if flat_energy is not None else float("nan"),
                state=snapshot(L))


def _sparsify(linkage, tau_ref, options, targets, weights, t0, allowed, flat_energy, callback, start) -> SparsifyResult:
    o = options
    n = linkage.num_joints
    fit = TorqueFit(linkage, tau_ref, o.p, o.eta, targets, weights)
    ub = np.full(n, np.inf if o.tau_max is None else (o.tau_max / tau_ref) ** o.p)
    if allowed is not None:
        allowed = np.asarray(allowed, bool)
        if allowed.shape != (n,) or not allowed.any():
            raise InputError(f"allowed: expected {n} flags (one per joint), at least one set")
        ub[~allowed] = 0.0
    t = np.ones(n) if t0 is None else np.asarray(t0, float)
    if t.shape != (n,):
        raise InputError(f"t0: expected {n} values (one per joint), got shape {t.shape}")
    t = np.clip(t, 0.0, ub)
    try:
        f = fit.evaluate(t)
    except ArithmeticError as exc:
        raise InputError(f"{exc} at the starting torques: sparse actuation needs a stable equilibrium there "
                         f"(at the dense torques: try another --angle)") from None
    g = fit.gradient(t)
    radius = o.initial_radius
    history, converged, message = [], False, "reached the iteration limit"
    best = snapshot(linkage)
    it = 0
    try:
        for it in range(1, o.max_iterations + 1):
            at_lower = (t <= 0.0) & (g > 0)
            at_upper = (t >= ub) & (g < 0)
            held = at_lower | at_upper
            pg = np.where(held, 0.0, g)
            pg_inf = float(np.abs(np.clip(t - g, 0.0, ub) - t).max())
            if pg_inf <= o.tolerance:
                converged, message = True, "projected gradient below tolerance"
                break
            freeset = ~held

            def hp(v):
                w = np.zeros(n)
                w[freeset] = v
                return fit.hessp(t, w)[freeset]

            s_free = steihaug(hp, pg[freeset], radius, 1e-2 * min(1.0, np.linalg.norm(pg)) * np.linalg.norm(pg), o.max_cg_iterations)
            s = np.zeros(n)
            s[freeset] = s_free
            t_trial = np.clip(t + s, 0.0, ub)
            step = t_trial - t
            if not np.any(step):
                message = "no progress possible (step vanished)"
                break
            predicted = -(g @ step + 0.5 * step @ fit.hessp(t, step))
            try:
                f_trial = fit.evaluate(t_trial)
                ok = True
            except ArithmeticError:
                f_trial, ok = np.inf, False
            actual = f - f_trial
            rho = actual / predicted if predicted > 0 else -1.0
            accepted = ok and actual > 0 and rho > 1e-4
            if accepted:
                t, f = t_trial, f_trial
                g = fit.gradient(t)
                best = snapshot(linkage)
                if rho > 0.75 and np.linalg.norm(step) > 0.8 * radius:
                    radius *= 2.0
                elif rho < 0.25:
                    radius *= 0.25
            else:
                radius = 0.25 * min(radius, np.linalg.norm(step))
                # back to the accepted state (and its factorization)
                restore(linkage, best)
                fit._t = None
                fit.evaluate(t)
            fit_val, reg = f - o.eta / n * np.sum(t), o.eta / n * np.sum(t)
            rec = IterationRecord(it, float(f), float(fit_val), float(reg), int(np.sum(fit.torques(t) > o.off_threshold * tau_ref)),
                                  float(radius), pg_inf, bool(accepted))
            history.append(rec)
            if callback is not None and callback(rec):
                message = "stopped by request"
                break
            if radius < 1e-12:
                message = "trust region collapsed"
                break
    except KeyboardInterrupt:  # keep the last accepted iterate
        message = "interrupted by the user"
        restore(linkage, best)
        fit._t = None
    fit.evaluate(t)
    tau = fit.torques(t)
    tau[tau < o.off_threshold * tau_ref] = 0.0
    # Iterates may pass through folded states (rejecting such trials left the pointy wings
    # with 9 actuators); the fold penalty keeps the answer out of them, and this says so
    # if it did not.
    folded = folded_joint(linkage)
    if folded:
        converged = False
        message += f"; the final state is not valid: {folded}"
    return SparsifyResult(
        torques=tau,
        objective=float(f),
        **answer_report(fit, tau, flat_energy),
        iterations=it,
        converged=converged,
        message=message,
        time_s=time.perf_counter() - start,
        history=history,
    )

