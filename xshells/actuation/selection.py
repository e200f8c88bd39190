"""Choosing the actuators: backward elimination from dense actuation, with a Gauss–Newton re-fit after each cut.

Eq. 8 of the paper (:mod:`.sparsify`) trades the fit against an ℓp penalty
whose weight ``η`` means something different on every design: on large
designs the fit's curvature in the thousands of torques is so uneven that
the trust region makes no progress, and no ``η`` gives few actuators. This
module answers the designer's question directly:

* ``max_fit``: the fewest actuators whose equilibrium stays within a mean
  joint deviation ``F`` (relative to the span ``l₀``) of the dense
  deployment;
* ``actuators``: the best ``N`` actuators.

Method (all quantities dimensionless; torques as ``t = τ/τ_ref``):

1. Start from dense actuation (``t = 1`` everywhere, fit exact).
2. At the current equilibrium, the linear response of the joint positions
   to the active torques is ``J = S_P H⁻¹ S_αᵀ τ_ref`` (one back-solve per
   active joint with the equilibrium's Cholesky factor).
3. **Cut.** In the linearized least-squares problem
   ``min |r + J δ|²`` the cost of dropping actuator ``i`` and re-fitting
   the others is ``xᵢ² / (G⁻¹)ᵢᵢ`` (``G = JᵀJ``, ``x`` the LS torques):
   the cheapest ones are removed one at a time, with rank-one downdates of
   ``G⁻¹``; a round removes a fraction of the active set while the fit is
   far below the limit, one actuator near it.
4. **Re-fit.** The remaining torques are re-fitted on the nonlinear model
   by bound-constrained Levenberg–Marquardt (``0 ≤ t ≤ t_max``), each step
   a small dense bounded least-squares problem, each trial a full
   equilibrium solve. A fold residual ``√2 · e`` on each joint angle's
   excess ``e`` beyond the window of :mod:`.sparsify` keeps joints from
   opening through themselves.
5. A cut whose re-fit misses the limit, folds a joint or loses the
   equilibrium is undone; it is retried with a smaller batch, then with
   the next few candidates, and the elimination ends when none passes.

Every accepted cut is one point of the trade-off curve (actuator count
against deviation, paper Fig. 9), so the curve comes out of the same run.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import lsq_linear

from ..deploy.simulate import folded_joint
from ..errors import InputError
from ..linkage.state import restore, snapshot
from .sparsify import TorqueFit, _number, _whole, answer_report

log = logging.getLogger(__name__)

FOLD_LS_WEIGHT = 1.0
"""``c`` in the fold term ``c Σ e²`` of the least-squares objective (``e`` in radians): 5° of
excess costs 7.6e-3, about 150 times the fit term at a 1 % mean deviation."""

UNHOLDABLE = "the dense torques do not hold the deployed shape"
TRIAL_NEWTON_ITERATIONS = 100
"""Newton iterations an equilibrium under a trial cut's torques may take before the cut counts as lost."""
RESTRICTED = "the joints allowed to carry an actuator cannot hold the deployed shape"


@dataclass(frozen=True)
class SelectionOptions:
    """Settings of :func:`select_actuators`.

    Attributes
    ----------
    max_fit : float
        Largest mean joint deviation, relative to the span (bounding-box
        diagonal), that an answer may have (0.01: 1 %).
    actuators : int or None
        Stop at exactly this many actuators instead (``max_fit`` is then
        only reported against).
    tau_max : float or None
        Largest torque of one actuator, in the energy's units; None: no limit.
    full_curve : bool
        Go on eliminating past the answer, down to one actuator, for the
        whole trade-off curve; the answer stays the one that meets the limit.
    cut_fraction : float
        Share of the active actuators removed in one round while the fit is
        far below the limit.
    refit_iterations : int
        Levenberg–Marquardt iterations of one re-fit.
    candidates : int
        Single cuts tried, in the linear model's order, before the
        elimination gives up.
    """

    max_fit: float = 0.01
    actuators: int | None = None
    tau_max: float | None = None
    full_curve: bool = False
    cut_fraction: float = 0.2
    refit_iterations: int = 12
    candidates: int = 4

    def __post_init__(self):
        _number("max_fit", self.max_fit, positive=True)
        if not self.max_fit < 1:
            raise InputError(f"max_fit must be a fraction of the span below 1 (0.01 is 1 %), got {self.max_fit}")
        if self.actuators is not None:
            _number("actuators", self.actuators)
            if not (int(self.actuators) == self.actuators and self.actuators >= 1):
                raise InputError(f"actuators must be a whole number of at least 1, got {self.actuators}")
            object.__setattr__(self, "actuators", int(self.actuators))  # 6.0 from a spec file counts as 6
        if self.tau_max is not None:
            _number("tau_max", self.tau_max, positive=True, finite=False)
            if self.tau_max == np.inf:
                object.__setattr__(self, "tau_max", None)  # no limit
        if not isinstance(self.full_curve, (bool, np.bool_)):
            raise InputError(f"full_curve must be true or false, got {self.full_curve!r}")
        _number("cut_fraction", self.cut_fraction)
        if not (0 < self.cut_fraction < 1):
            raise InputError(f"cut_fraction must lie in (0, 1), got {self.cut_fraction}")
        _whole("refit_iterations", self.refit_iterations)
        _whole("candidates", self.candidates)


@dataclass
class CurvePoint:
    """One accepted cut: the trade-off curve's point at ``num_actuators``."""

    num_actuators: int
    fit_mean: float
    fit_max: float
    work: float
    actuated: np.ndarray
    torques: np.ndarray
    time_s: float


@dataclass
class SelectionResult:
    """The answer of :func:`select_actuators`; the fields as in :class:`.sparsify.SparsifyResult`
    (``actuated``: joint numbers, ``actuated_vertices``: input vertex indices, ``state``: the answer's
    equilibrium; the linkage is back at the state the call started from)."""

    torques: np.ndarray
    actuated: np.ndarray
    fit_mean: float
    fit_max: float
    work: float
    converged: bool
    message: str
    time_s: float
    curve: list = field(default_factory=list)
    rounds: int = 0
    equilibrium_solves: int = 0
    actuated_vertices: np.ndarray = None
    free_end_fit_mean: float = float("nan")
    free_end_fit_max: float = float("nan")
    state: dict = None


class _Refit:
    """The nonlinear least-squares problem over the active torques, on a :class:`TorqueFit` (p = 1, η = 0)."""

    def __init__(self, fit: TorqueFit, ub: np.ndarray):
        self.fit = fit
        self.ub = ub
        self.sw = np.sqrt(fit.weights)[:, None] / fit.l0
        self.solves = 0

    def evaluate(self, t) -> tuple[np.ndarray, float]:
        """Residual ``r`` (3n + n,) and the mean deviation at the equilibrium under ``t``; raises ArithmeticError."""
        self.fit.evaluate(t)
        self.solves += 1
        _, dev = self.fit.fit_terms()
        excess = self.fit.fold_excess()
        r = np.concatenate([(self.sw * dev).ravel(), np.sqrt(2.0 * FOLD_LS_WEIGHT) * excess])
        return r, float(np.linalg.norm(dev, axis=1).mean() / self.fit.l0)

    def _mean(self, r) -> float:
        n = self.fit.L.num_joints
        return float(np.linalg.norm(r[: 3 * n].reshape(n, 3) / self.sw, axis=1).mean() / self.fit.l0)

    def jacobian(self, active) -> np.ndarray:
        """``∂r/∂t`` on the active joints (3n + n, k), from the factorization of the last evaluation."""
        fit, L = self.fit, self.fit.L
        n, k = L.num_joints, len(active)
        rhs = np.zeros((len(fit.free), k))
        # S_αᵀ e_i restricted to the free variables (no angle is pinned)
        pos_in_free = np.searchsorted(fit.free, fit.angle_rows[active])
        rhs[pos_in_free, np.arange(k)] = fit.tau_ref
        X = np.zeros((L.num_vars, k))
        X[fit.free] = fit.chol.solve(rhs)
        Jp = (self.sw[:, :, None] * X[fit.pos_rows]).reshape(3 * n, k)
        active_fold = (fit.fold_excess() != 0.0)
        Ja = np.sqrt(2.0 * FOLD_LS_WEIGHT) * X[fit.angle_rows] * active_fold[:, None]
        return np.vstack([Jp, Ja])

    def run(self, t, active, iterations, r=None, *, good_enough=0.0, give_up_above=np.inf):
        """Levenberg–Marquardt on ``t[active]`` within ``[0, ub]``; returns (t, r, fit_mean) at the best point.

        ``t`` must be the state last evaluated when ``r`` is given. It stops
        early once ``½|r|² ≤ good_enough`` (a fit far inside the limit needs
        no polish), or when the mean deviation is still above
        ``give_up_above`` after two iterations, or 4/3 of it after one (a
        cut that will not pass).
        """
        t = np.array(t, float)
        if r is None:
            r, fit_mean = self.evaluate(t)
        else:
            fit_mean = self._mean(r)
        F = 0.5 * float(r @ r)
        best_state = snapshot(self.fit.L)
        mu = None
        radius = 0.5
        for it in range(iterations):
            if F <= good_enough or (it >= 2 and fit_mean > give_up_above) or (it >= 1 and fit_mean > 4 / 3 * give_up_above):
                break
            J = self.jacobian(active)
            JtJ = J.T @ J
            if mu is None:
                mu = 1e-6 * float(np.trace(JtJ)) / max(len(active), 1)
            g = J.T @ r
            improved = False
            ta = t[active]
            for _attempt in range(6):
                A = np.vstack([J, np.sqrt(mu) * np.eye(len(active))])
                b = np.concatenate([-r, np.zeros(len(active))])
                # a box trust region relative to the torques: the equilibrium (and Newton) stays on its branch
                reach = radius * np.maximum(ta, ta.mean())
                lo, hi = np.maximum(-ta, -reach), np.minimum(self.ub[active] - ta, reach)
                step = lsq_linear(A, b, bounds=(lo, hi), method="bvls" if len(active) <= 60 else "trf",
                                  lsmr_tol="auto").x
                step = np.clip(step, lo, hi)
                predicted = -(g @ step + 0.5 * step @ (JtJ @ step))
                trial = t.copy()
                trial[active] += step
                newton0 = self.fit.equilibrium_iterations
                try:
                    # (measured: accepted trials take 3–10 Newton iterations, rejected ones 30–100, but
                    # capping Newton at 20 made more steps fail and cost more in all)
                    r_trial, fm_trial = self.evaluate(trial)
                    F_trial = 0.5 * float(r_trial @ r_trial)
                except ArithmeticError:
                    F_trial = np.inf
                log.debug("    trial |step| %.3g radius %.3g: F %.3e (%d Newton)", float(np.abs(step).max()), radius, F_trial,
                          self.fit.equilibrium_iterations - newton0)
                if F_trial < F:
                    rho = (F - F_trial) / predicted if predicted > 0 else 0.0
                    small = F - F_trial < 1e-2 * F  # measured: later iterations gain < 1% each and cost the most
                    t, r, F, fit_mean = trial, r_trial, F_trial, fm_trial
                    best_state = snapshot(self.fit.L)
                    if rho > 0.5:
                        mu *= 0.3
                        radius = min(2.0 * radius, 2.0)
                    improved = True
                    break
                if F_trial > 2.0 * F and radius < 1.0 / 64:
                    # even a tiny step snaps to another branch: the fit sits at a limit point, polish no further
                    break
                mu *= 10.0
                radius *= 0.25
                restore(self.fit.L, best_state)
                self.fit._t = None
                self.evaluate(t)  # the factorization for the next trial's predictor
            log.debug("  re-fit %d: F %.3e, mean %.4f%%, %d trial(s), %s", it, F, 100 * fit_mean, _attempt + 1,
                      "accepted" if improved else "no decrease")
            if not improved or small:
                break
        restore(self.fit.L, best_state)
        self.fit._t = None
        r, fit_mean = self.evaluate(t)
        return t, r, fit_mean


def _least_squares(J, r, t_active):
    """The linear model's least-squares torques ``x`` (for the residual ``r + J (x − t)``) and ``G⁻¹ = (JᵀJ)⁻¹``."""
    k = J.shape[1]
    G = J.T @ J
    G += (1e-10 * np.trace(G) / k + 1e-300) * np.eye(k)  # a ridge at round-off level: nearby joints' columns are alike
    Ginv = np.linalg.inv(G)
    return t_active - Ginv @ (J.T @ r), Ginv


def _cut_costs(x, ginv_diag):
    """The residual's rise ``xᵢ² / (G⁻¹)ᵢᵢ`` when actuator ``i`` is dropped and the others re-fitted.

    A negative least-squares torque helps nothing that a motor can do: its cost is −1, first to go.
    """
    cost = x**2 / ginv_diag
    cost[x <= 0] = -1.0
    return cost


def _drop(x, Ginv, i):
    """``x`` re-fitted without actuator ``i`` (rank-one downdate; ``x[i]`` becomes 0)."""
    out = x - Ginv[:, i] * (x[i] / Ginv[i, i])
    out[i] = 0.0
    return out


def _linear_cuts(J, r, t_active, count, ub_active):
    """Indices (into the active set) of ``count`` actuators to drop, cheapest first, and the re-fitted torques.

    One at a time: after each cut the others are re-fitted and ``G⁻¹`` downdated.
    """
    x, Ginv = _least_squares(J, r, t_active)
    keep = list(range(J.shape[1]))
    dropped = []
    for _ in range(count):
        kk = np.array(keep)
        i = int(kk[np.argmin(_cut_costs(x[kk], np.diag(Ginv)[kk]))])
        x = _drop(x, Ginv, i)
        Ginv = Ginv - np.outer(Ginv[:, i], Ginv[:, i]) / Ginv[i, i]
        keep.remove(i)
        dropped.append(i)
    x[dropped] = 0.0  # exactly: the downdates of later cuts leave round-off on the earlier ones
    return dropped, np.clip(x, 0.0, ub_active)


def _ranked_single_cuts(J, r, t_active):
    """All active actuators, cheapest single cut first (linear model), with ``x`` and ``G⁻¹``."""
    x, Ginv = _least_squares(J, r, t_active)
    return np.argsort(_cut_costs(x, np.diag(Ginv)), kind="stable"), x, Ginv


def _proposals(J, r, t_active, ub_active, batch: int, candidates: int):
    """Cuts to try, best first: (indices into the active set to drop, the other torques re-fitted linearly).

    A batch, then a third of it, … down to single cuts; then the next
    ``candidates − 1`` single cuts of the linear ranking.
    """
    while batch > 1:
        yield _linear_cuts(J, r, t_active, batch, ub_active)
        batch = max(1, batch // 3)
    order, x0, Ginv = _ranked_single_cuts(J, r, t_active)
    for i in order[:candidates]:
        yield [int(i)], np.clip(_drop(x0, Ginv, i), 0.0, ub_active)


def _restriction(allowed, tau_max, tau_ref) -> str:
    """How the actuators are restricted, in words for a message ('' where they are not)."""
    parts = []
    if allowed is not None and not allowed.all():
        parts.append(f"with only {int(allowed.sum())} of {len(allowed)} joints allowed (--candidates)")
    if tau_max is not None and tau_max < tau_ref:
        parts.append(f"with torques capped at {tau_max:g} (--tau-max; the dense torque is {tau_ref:.4g})")
    return " and ".join(parts)


def _set_fits(G, c, sets, ridge):
    """Linear-model torques and fit gains of actuator sets.

    With ``b`` the linearized residual at zero torque, the set ``S`` fits
    ``x = G_SS⁻¹ c_S`` (``G = JᵀJ``, ``c = −Jᵀb``) and lowers ``|b|²`` by
    ``c_Sᵀ x``. ``sets`` (m, s) indices into the columns; returns ``x``
    (m, s) and the gains (m,); a set that needs a negative torque (which no
    motor gives) gains ``−inf``.
    """
    Gs = G[sets[:, :, None], sets[:, None, :]] + ridge * np.eye(sets.shape[1])
    x = np.linalg.solve(Gs, c[sets][..., None])[..., 0]
    gain = (c[sets] * x).sum(axis=1)
    return x, np.where((x > 0).all(axis=1), gain, -np.inf)


def _exchange_sets(J, b, active, count, sweeps: int = 20):
    """The linear model's best sets of one actuator fewer than ``active``, reached by dropping and exchanging.

    Greedy elimination never revisits a cut; where it stalls, a smaller set
    that keeps the fit may still exist with a joint cut earlier back in it.
    From each ``active`` less one of its actuators, a local search swaps one
    actuator of the set for one outside it while that raises the fit's gain. ``J`` (rows, n) holds
    the columns of every joint that may carry an actuator; ``active`` and
    the returned sets index into them. Returns up to ``count`` distinct sets
    (best first) with their linear-model torques.
    """
    n = J.shape[1]
    G = J.T @ J
    c = -(J.T @ b)
    ridge = 1e-10 * np.trace(G) / n + 1e-300
    starts = [np.delete(active, i) for i in range(len(active))]
    found = {}
    for S in starts:
        x, gain = _set_fits(G, c, S[None, :], ridge)
        best_gain = gain[0]
        x = x[0]
        for _ in range(sweeps):
            outside = np.setdiff1d(np.arange(n), S)
            if not len(outside):
                break
            # every swap of one member for one outsider: (members × outsiders) sets
            swaps = np.repeat(S[None, :], len(S) * len(outside), axis=0)
            swaps[np.arange(len(swaps)), np.repeat(np.arange(len(S)), len(outside))] = np.tile(outside, len(S))
            sx, sg = _set_fits(G, c, swaps, ridge)
            k = int(np.argmax(sg))
            if not sg[k] > best_gain + 1e-12 * abs(best_gain):
                break
            S, x, best_gain = swaps[k], sx[k], sg[k]
        if np.isfinite(best_gain):
            order = np.argsort(S)
            found[tuple(S[order])] = (best_gain, x[order])
    ranked = sorted(found.items(), key=lambda kv: -kv[1][0])[:count]
    return [(np.array(S), xs) for S, (_, xs) in ranked]


def _cuts_to_try(refit: _Refit, r, t, active, ub, batch: int, candidates: int, give_up_above: float):
    """Trial sets, best first: ``(active joints, torques (n,), give-up level of the re-fit)``.

    First the linear model's cuts of :func:`_proposals`; where none of those
    passes, ``candidates`` sets one smaller found by :func:`_exchange_sets`
    over every joint that may carry an actuator, re-fitted without giving up
    early (the last resort before the elimination stops). Lazy: each set is
    made at the state the previous trial was undone to.
    """
    n, k = len(t), len(active)
    J = refit.jacobian(active)
    fully_refitted = set()  # sets whose re-fit could not give up early: no second try
    for dropped, x in _proposals(J, r, t[active], ub[active], batch, candidates):
        trial_active = np.delete(active, dropped)
        trial = np.zeros(n)
        trial[trial_active] = x[np.setdiff1d(np.arange(k), dropped)]
        if give_up_above == np.inf:
            fully_refitted.add(tuple(trial_active))
        yield trial_active, trial, give_up_above
    if k < 2:
        return
    allowed = np.flatnonzero(ub > 0)
    J_all = refit.jacobian(allowed)
    b = r - J_all[:, np.searchsorted(allowed, active)] @ t[active]
    for S, x in _exchange_sets(J_all, b, np.searchsorted(allowed, active), candidates):
        if tuple(allowed[S]) in fully_refitted:
            continue
        trial = np.zeros(n)
        trial[allowed[S]] = np.clip(x, 0.0, ub[allowed[S]])
        yield allowed[S], trial, np.inf


EXCHANGE_MAX_ACTUATORS = 12
"""``--actuators N`` up to this N ends with the exchange search of :func:`_exchange_refine`."""
EXCHANGE_TRIES = 6
"""Swaps re-fitted on the nonlinear model per round of the exchange search (the linear model's best first)."""
EXCHANGE_ROUNDS = 10


def _exchange_refine(refit: _Refit, t, r, fit_mean, active, ub, iterations, good_enough):
    """Improve a set of N actuators by swapping one member for one joint outside it.

    Elimination is greedy: on a grid, ``--actuators 1`` ended at a joint
    with 0.80 % mean deviation where another alone gives 0.22 %. Each round
    ranks every swap (member × allowed joint outside) by the linear model's
    fit at the current equilibrium and re-fits the best
    :data:`EXCHANGE_TRIES` on the nonlinear model; the first that lowers the
    mean deviation by more than 0.1 % of itself is taken. Yields ``(t, r,
    fit_mean, active, trials)`` after each improvement, then ``(…, None,
    trials)`` when a round finds none (the linkage back at the last set).
    """
    fit, L = refit.fit, refit.fit.L
    allowed = np.flatnonzero(ub > 0)
    for _round in range(EXCHANGE_ROUNDS):
        pos = np.searchsorted(allowed, active)
        outside = np.setdiff1d(np.arange(len(allowed)), pos)
        if not len(outside):
            break
        J_all = refit.jacobian(allowed)
        b = r - J_all[:, pos] @ t[active]
        G = J_all.T @ J_all
        c = -(J_all.T @ b)
        ridge = 1e-10 * np.trace(G) / len(allowed) + 1e-300
        k = len(pos)
        swaps = np.repeat(pos[None, :], k * len(outside), axis=0)
        swaps[np.arange(len(swaps)), np.repeat(np.arange(k), len(outside))] = np.tile(outside, k)
        sx, sg = _set_fits(G, c, swaps, ridge)
        order = [i for i in np.argsort(-sg, kind="stable")[:EXCHANGE_TRIES] if np.isfinite(sg[i])]
        state = snapshot(L)
        tried, found = 0, None
        for i in order:
            S = allowed[swaps[i]]
            trial = np.zeros(len(t))
            trial[S] = np.clip(sx[i], 0.0, ub[S])
            tried += 1
            ok, t_new, r_new, fm_new = _refit_cut(refit, trial, S, iterations, good_enough, np.inf)
            S_new = np.sort(S[t_new[S] > 0])
            if ok and len(S_new) == k and not folded_joint(L) and fm_new < fit_mean * (1 - 1e-3):
                found = (t_new, r_new, fm_new, S_new)
                break
            restore(L, state)
            fit._t = None
            refit.evaluate(t)
        if found is None:
            yield t, r, fit_mean, None, tried
            return
        t, r, fit_mean, active = found
        yield t, r, fit_mean, active, tried
    yield t, r, fit_mean, None, 0


def _refit_cut(refit: _Refit, trial, trial_active, iterations, good_enough, give_up_above):
    """Equilibrium and nonlinear re-fit after a cut: (ok, t, r, fit_mean); ok is False where the equilibrium is lost."""
    start = time.perf_counter()
    try:
        r, first = refit.evaluate(trial)
        t, r, fit_mean = refit.run(trial, trial_active, iterations, r, good_enough=good_enough,
                                   give_up_above=give_up_above)
    except ArithmeticError:
        log.debug("cut to %d: equilibrium lost, %.1f s", len(trial_active), time.perf_counter() - start)
        return False, trial, None, np.inf
    log.debug("cut to %d: mean %.4f%% (first %.4f%%), %.1f s", len(trial_active), 100 * fit_mean, 100 * first,
              time.perf_counter() - start)
    return True, t, r, fit_mean


def select_actuators(linkage, tau_ref: float, options: SelectionOptions = SelectionOptions(), *, allowed=None,
                     flat_energy: float | None = None, targets=None, callback=None) -> SelectionResult:
    """Few actuators that deploy ``linkage`` to its current (densely actuated) shape.

    Parameters
    ----------
    linkage : Linkage
        At the densely actuated deployed equilibrium: its joint positions are
        the targets unless ``targets`` is given. It is back at that state when
        the call returns (so a second call measures against the same targets);
        the answer's equilibrium is ``result.state``.
    tau_ref : float
        The dense torque per joint (``DeploymentResult.torque``).
    options : SelectionOptions
    allowed : (n,) bool array, optional
        Joints that may carry an actuator (default all).
    flat_energy : float, optional
        Energy of the flat assembly state (``DenseDeployment.flat_energy``):
        the reported work is the energy stored from there; without it, NaN.
    targets : (n, 3) array, optional
        Target joint positions (default: the linkage's current ones).
    callback : callable(CurvePoint) -> bool, optional
        Called at every accepted cut; return True to stop (the answer is
        then the best one found so far).

    Returns
    -------
    SelectionResult
    """
    start = time.perf_counter()
    start_state = snapshot(linkage)
    try:
        return _select(linkage, tau_ref, options, allowed, flat_energy, targets, callback, start)
    finally:
        restore(linkage, start_state)


def _select(linkage, tau_ref, options, allowed, flat_energy, targets, callback, start) -> SelectionResult:
    o = options
    n = linkage.num_joints
    fit = TorqueFit(linkage, tau_ref, p=1.0, eta=0.0, targets=targets)
    ub = np.full(n, np.inf if o.tau_max is None else o.tau_max / tau_ref)
    t = np.ones(n)
    if allowed is not None:
        allowed = np.asarray(allowed, bool)
        if allowed.shape != (n,) or not allowed.any():
            raise InputError(f"allowed: expected {n} flags (one per joint), at least one set")
        ub[~allowed] = 0.0
    t = np.minimum(t, ub)
    target_count = o.actuators
    if target_count is not None and target_count > int(np.count_nonzero(ub > 0)):
        raise InputError(f"--actuators {target_count}: only {int(np.count_nonzero(ub > 0))} joints may carry one")
    fit.predictor_limit = 0.2
    refit = _Refit(fit, ub)
    restricted = _restriction(allowed, o.tau_max, tau_ref)
    try:
        r, fit_mean = refit.evaluate(np.ones(n))
    except ArithmeticError as exc:
        raise InputError(f"{exc} at the dense torques themselves: the deployed shape is not a stable equilibrium "
                         f"under torque control, so no set of torques holds it; try another --angle") from None
    dense_holds = fit_mean <= o.max_fit
    if restricted:
        try:
            r, fit_mean = refit.evaluate(t)
        except ArithmeticError as exc:
            raise InputError(f"{exc} under the dense torques {restricted}: {RESTRICTED}; allow more joints "
                             f"(--candidates) or a larger --tau-max") from None
    active = np.flatnonzero(ub > 0)
    # Fit first where the dense torques are not all available, or where they do not hold the dense shape
    # (a deployment unstable under torque control snaps to another equilibrium: the boat at 62°).
    if len(active) < n or o.tau_max is not None or fit_mean > 0.1 * o.max_fit:
        t, r, fit_mean = refit.run(t, active, o.refit_iterations, r)
    curve = []

    def record():
        _, dev = fit.fit_terms()
        dist = np.linalg.norm(dev, axis=1) / fit.l0
        act = np.flatnonzero(t > 0)
        work = float(linkage.energy()) - flat_energy if flat_energy is not None else float("nan")
        p = CurvePoint(len(act), float(dist.mean()), float(dist.max()), work,
                       act, fit.torques(t)[act], time.perf_counter() - start)
        curve.append(p)
        return p

    def meets(fm):
        return fm <= o.max_fit if target_count is None else True

    # a re-fit far inside the limit needs no polish; one still far outside after two iterations will not pass
    good_enough = 0.5 * (0.02 * o.max_fit) ** 2
    # While it can, every mode cuts within the limit (with exchanges where plain cuts fail): --actuators N
    # and --sweep then follow the default's path down to its answer. Past that point they take the
    # first valid cut, re-fitted in full.
    strict = True
    point = record()
    # A cut's equilibrium settles within about 40 Newton iterations where it holds (measured on the wiggly
    # banana: every accepted trial took ≤ 40); one that will not settle used the whole 300 of the dense
    # solve, and those were half the run's time.
    fit.newton = replace(fit.newton, max_iterations=TRIAL_NEWTON_ITERATIONS)
    best = (t.copy(), snapshot(linkage), point) if meets(fit_mean) and not folded_joint(linkage) else None
    state = snapshot(linkage)
    message, converged, rounds = "", False, 0
    stopped = False
    # Where even every joint, re-fitted, misses the limit, the shape cannot be held by torques: say why.
    unholdable = target_count is None and fit_mean > o.max_fit
    try:
        while not unholdable and len(active) > (target_count or 1):
            rounds += 1
            k = len(active)
            far = fit_mean < 0.3 * o.max_fit
            batch = max(1, int(o.cut_fraction * k)) if far else max(1, int(0.05 * k)) if fit_mean < 0.7 * o.max_fit else 1
            if target_count is not None:
                batch = min(batch, k - target_count)
            accepted = False
            give_up_above = 1.5 * o.max_fit if strict else np.inf
            for trial_active, trial, give_up in _cuts_to_try(refit, r, t, active, ub, batch, o.candidates, give_up_above):
                ok, trial, r_new, fm_new = _refit_cut(refit, trial, trial_active, o.refit_iterations, good_enough, give_up)
                trial_active = trial_active[trial[trial_active] > 0]  # the re-fit may switch off more actuators
                if ok and not folded_joint(linkage) and (fm_new <= o.max_fit or not strict):
                    accepted = True
                    t, r, fit_mean, active = trial, r_new, fm_new, trial_active
                    state = snapshot(linkage)
                    point = record()
                    if meets(fit_mean):
                        best = (t.copy(), state, point)
                    if callback is not None and callback(point):
                        stopped = True
                    break
                restore(linkage, state)  # undo the cut, with the factorization of the state kept
                fit._t = None
                refit.evaluate(t)
            if stopped:
                message = "stopped by request"
                break
            if not accepted and strict and (o.full_curve or target_count is not None):
                strict = False  # no cut keeps the limit any more: from here on the first valid cut
                continue
            if not accepted:
                if target_count is not None or o.full_curve:  # there a cut needs only a valid equilibrium
                    message = (f"no cut below {len(active)} actuators keeps a valid equilibrium (every one "
                               f"tried loses it or folds a joint)")
                    if o.full_curve:
                        message = f"the curve ends at {len(active)} actuators: {message}"
                else:
                    c = min(o.candidates, len(active))
                    message = (f"neither a single cut of the {c} cheapest actuators nor the {c} best exchanges "
                               f"keep the mean deviation within {100 * o.max_fit:g}% of the span")
                break
            if not o.full_curve and not meets(fit_mean):
                break
        else:
            message = f"reached {len(active)} actuator{'s' if len(active) != 1 else ''}"
            if target_count is not None and len(active) == target_count and target_count <= EXCHANGE_MAX_ACTUATORS:
                swaps_tried, gained = 0, 0
                for t_new, r_new, fm_new, active_new, tried in _exchange_refine(
                        refit, t, r, fit_mean, active, ub, o.refit_iterations, good_enough):
                    swaps_tried += tried
                    if active_new is None:
                        break
                    gained += 1
                    t, r, fit_mean, active = t_new, r_new, fm_new, active_new
                    state = snapshot(linkage)
                    if curve and curve[-1].num_actuators == len(active):
                        curve.pop()  # the same count, a better set: the curve keeps the better one
                    point = record()
                    best = (t.copy(), state, point)
                message += (f"; {gained} exchange{'s' if gained != 1 else ''} of one joint for another improved it "
                            f"({swaps_tried} tried)")
        if o.full_curve and best is not None and len(best[0].nonzero()[0]) != len(active):
            k = int(np.count_nonzero(best[0]))
            message = (f"the curve reached {len(active)} actuator{'s' if len(active) != 1 else ''}; the answer is the "
                       f"fewest within the limit, {k} actuator{'s' if k != 1 else ''}"
                       + (f" ({message})" if not message.startswith("reached") else ""))
        if unholdable and restricted and dense_holds:
            message = (f"{RESTRICTED}: {restricted}, with their torques re-fitted, the mean deviation is "
                       f"{100 * fit_mean:.2f}% (limit {100 * o.max_fit:g}%), while every joint at the dense torque "
                       f"holds it")
        elif unholdable:
            message = (f"{UNHOLDABLE}: under torque control it moves to another equilibrium (mean deviation "
                       f"{100 * fit_mean:.2f}% with all {len(active)} joints actuated and their torques re-fitted), so it is "
                       f"not stable under torque control at this angle (typically where the deployment torque falls as "
                       f"it opens)")
        converged = best is not None and not stopped
        if target_count is not None:
            converged = converged and len(active) == target_count
    except KeyboardInterrupt:
        message = "interrupted by the user"
    if best is None:
        message += "; no answer met the limit"
        restore(linkage, state)
        fit._t = None
        final_t = t
    else:
        final_t, st, _ = best
        restore(linkage, st)
        fit._t = None
    fit.evaluate(final_t)
    tau = fit.torques(final_t)
    folded = folded_joint(linkage)
    if folded:
        converged = False
        message += f"; the final state is not valid: {folded}"
    return SelectionResult(torques=tau, **answer_report(fit, tau, flat_energy), converged=converged,
                           message=message.strip("; "), time_s=time.perf_counter() - start, curve=curve, rounds=rounds,
                           equilibrium_solves=refit.solves)
