"""Newton's method for elastic equilibria (paper §4, "Numerical Solver").

Minimizes ``E(x) − f·x`` over the free variables of a *problem*: any object
with ``get_vars()``, ``set_vars(x)``, ``energy()``, ``gradient()``,
``hessian()`` (sparse, symmetric), ``mass_matrix()`` and, optionally,
``update_source_frame()`` (called after every accepted step).

Indefinite Hessians are modified to ``H + σM`` with ``M`` the mass matrix,
so a modified step is the step of fixed kinetic energy that lowers the
energy most; ``σ`` starts at ``sigma_factor · λmax(H)/λmax(M)``, is
multiplied by 4 until the factorization succeeds and divided by
``shift_decay`` after each success. Near a saddle (indefinite ``H``, small
gradient) the step adds the most negative generalized eigenvector of
``H d = λ M d``.
"""
from __future__ import annotations

import time
import weakref
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import InvalidState
from ..sparse import PatternSum, PrincipalSubmatrix
from .cholesky import NotPositiveDefinite, SparseCholesky


@dataclass(frozen=True)
class NewtonOptions:
    """Settings of :func:`minimize`.

    Attributes
    ----------
    max_iterations : int
    gradient_tolerance : float
        Stop when the free gradient's Euclidean norm falls below this (or
        below 4× this after a step too small to change the state: the
        gradient's round-off can be above the tolerance's estimate of it).
    sigma_factor : float
        First Hessian shift as a multiple of ``λmax(H)/λmax(M)``.
    saddle_gradient_factor : float
        Escape along negative curvature when ``H`` is indefinite and
        ``|g|`` is below this multiple of ``gradient_tolerance``.
    saddle_step : float
        Largest displacement of the negative-curvature step, in length units
        (``None``: 1/100 of the shortest rod's arc length when the problem
        reports ``min_arc_length()``, else 1e-3).
    armijo : float
    max_backtracks : int
    require_minimum : bool
        At a point with a small gradient, also require a positive-definite
        Hessian (one extra factorization); a saddle is escaped, not accepted.
    shift_decay : float
        After an indefinite spell the shift σ is divided by this after every
        accepted step, until it is below 1e-8 of its first value. Pure
        Newton steps right after the spell (no decay) head back to the
        saddle. Deployments use 100 (:class:`~xshells.deploy.DeployOptions`):
        halving kept them shifted for up to 27 damped iterations (manta ray
        at 10 steps: 137 Newton iterations with 2, 104 with 10, 98 with 100,
        the same equilibria to 4e-9 of the span). The default stays 2 for free
        equilibria (torque control, loads, design optimization's inner
        solves): 10 and 100 have not been measured there (docs/design-notes.md).
    minimum_from_last_step : float
        With ``require_minimum``: a point below the tolerance that a full,
        unshifted Newton step reached, on a positive-definite factor, cutting
        ``|g|`` at least by this factor, counts as a minimum without a new
        Hessian and factorization: that is Newton's quadratic convergence, so
        the point lies well inside the last Hessian's region of validity (its
        step was about ``|g|``/stiffness long). That factor is then left for
        the caller (:func:`_constrained_tangent` with ``reuse``). Default 0:
        every minimum is checked at its own point. Deployments use 0.01
        (:class:`~xshells.deploy.DeployOptions`).
    keep_shift_scale : bool
        Measure ``λmax(H)/λmax(M)`` (the scale of the first shift) once per
        problem, free set and constraint, and keep it for later calls, instead
        of measuring it in every call that meets an indefinite Hessian. Two
        Lanczos solves, 20 ms on the manta ray, four times in a 10-step
        deployment; ``λmax`` is a stretching stiffness, which a deployment
        hardly changes. Deployments use True
        (:class:`~xshells.deploy.DeployOptions`).
    """

    max_iterations: int = 200
    gradient_tolerance: float = 1e-8
    sigma_factor: float = 1e-3
    saddle_gradient_factor: float = 1e3
    saddle_step: float | None = None
    armijo: float = 1e-4
    max_backtracks: int = 40
    require_minimum: bool = True
    shift_decay: float = 2.0
    minimum_from_last_step: float = 0.0
    keep_shift_scale: bool = False


@dataclass
class NewtonReport:
    """What happened in one :func:`minimize` call."""

    converged: bool = False
    iterations: int = 0
    energy: list = field(default_factory=list)
    gradient_norm: list = field(default_factory=list)
    sigma: list = field(default_factory=list)
    indefinite_events: int = 0
    saddle_escapes: int = 0
    time_s: float = 0.0
    message: str = ""
    multiplier: float = 0.0


class _ReusableCholesky:
    """A :class:`SparseCholesky` that skips the numeric factorization when asked
    for the very matrix it factored last (consecutive deployment steps start
    where the previous one's positive-definiteness check ended)."""

    def __init__(self):
        self.chol = SparseCholesky()
        self._last = None
        self.tag = None  # the free indices, where the factor is of an unshifted (plain or augmented) free Hessian

    def factorize(self, A: sp.csr_matrix) -> None:
        last = self._last
        if (last is not None and A.shape == last[3] and len(A.data) == len(last[2])
                and (A.indptr is last[0] or np.array_equal(A.indptr, last[0]))
                and (A.indices is last[1] or np.array_equal(A.indices, last[1])) and np.array_equal(A.data, last[2])):
            return
        self._last = None
        self.tag = None
        self.chol.factorize(A)
        self._last = (A.indptr, A.indices, A.data.copy(), A.shape)

    def solve(self, b):
        return self.chol.solve(b)

    def forget(self) -> None:
        """Before ``self.chol`` is used directly: its factor no longer matches the cached matrix."""
        self._last = None
        self.tag = None


class _Workspace:
    """What one problem's successive :func:`minimize` calls can share: the
    free-variable gather map, the union pattern of the augmented Hessian, the
    Cholesky factor (symbolic analysis and, for an unchanged matrix, the numeric
    one) and the augmentation weight of a repeated constraint."""

    def __init__(self):
        self.chol = _ReusableCholesky()
        self.sub = {}  # pattern kind ("lower" or "full") -> (free index key, PrincipalSubmatrix)
        self.sums = {}
        self.aug = None  # (a copy, ρ)
        self.skip_plain = 0  # factorizations left before the plain (unaugmented) Hessian is tried again
        self.eig_chol = None  # a second factor, of H + sM with the eigen-solve's shift s
        self.shift_scale = None  # (free indices, constraint vector or None, λmax(H)/λmax(M)), see keep_shift_scale
        self.a_outer = None  # (free constraint vector a, a aᵀ, its lower triangle): rebuilt only for another a

    def free_part(self, H, free_idx, n, kind="full"):
        if H.format != "csr":
            H = H.tocsr()
        if len(free_idx) == n:
            return H
        sub = self.sub.get(kind)
        if sub is None or not np.array_equal(sub[0], free_idx) or not sub[1].matches(H):
            if not H.has_canonical_format:
                H = H.copy()
                H.sum_duplicates()
            sub = self.sub[kind] = (free_idx.copy(), PrincipalSubmatrix(H, free_idx))
        return sub[1](H)

    def combine(self, name, mats, coefficients):
        """``Σ c_i mats_i`` on a cached union pattern."""
        mats = [M if (M.format == "csr" and M.has_canonical_format) else sp.csr_matrix(M, copy=True) for M in mats]
        for M in mats:
            if not M.has_canonical_format:
                M.sum_duplicates()
        ps = self.sums.get(name)
        if ps is None or not ps.matches(*mats):
            ps = self.sums[name] = PatternSum(*mats)
        return ps(mats, coefficients)


_workspaces: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _outer_product(ws: "_Workspace", a: np.ndarray):
    """``a aᵀ`` as a sparse matrix on the support of ``a`` (a dense block there) and its lower triangle,
    kept in the workspace for the next call with the same ``a`` (a deployment's steps: 1.3 ms each)."""
    kept = ws.a_outer
    if kept is None or kept[0].shape != a.shape or not np.array_equal(kept[0], a):
        nz = np.flatnonzero(a)
        outer = sp.csr_matrix((np.outer(a[nz], a[nz]).ravel(), np.tile(nz, len(nz)), len(nz) * np.searchsorted(nz, np.arange(len(a) + 1))),
                              shape=(len(a), len(a)))
        kept = ws.a_outer = (a.copy(), outer, sp.tril(outer, format="csr"))
    return kept[1], kept[2]


def free_indices(n: int, fixed=None) -> np.ndarray:
    """The variables (of ``n``) not in ``fixed``, increasing."""
    free = np.ones(n, bool)
    if fixed is not None:
        free[np.asarray(fixed, dtype=int)] = False
    return np.flatnonzero(free)


def _workspace(problem) -> _Workspace:
    try:
        ws = _workspaces.get(problem)
        if ws is None:
            ws = _workspaces[problem] = _Workspace()
        return ws
    except TypeError:  # not weak-referenceable or not hashable: nothing shared
        return _Workspace()


SLOPE_ROUND_OFF = 1e-10
"""A Newton step whose predicted decrease ``−g·d`` is below this fraction of ``|E|``
may be judged by the gradient instead of the energy (see :func:`minimize`)."""

CONSTRAINT_ROUND_OFF = 1e-12
"""A linear constraint ``a·x = target`` holds when its residual is below this fraction of ``Σ|a_i x_i|``
(the size of the terms it sums), or of ``|target|`` or 1, whichever is largest."""

ROUND_OFF_CURVATURE = 1e3 * np.finfo(float).eps

STOPPED_BY_CALLBACK = "stopped by callback"
"""The report's message when the callback asked :func:`minimize` to stop."""
"""Generalized eigenvalues of ``H d = λ M d`` above ``−ROUND_OFF_CURVATURE·λmax``
are indistinguishable from zero in a Hessian assembled in double precision."""


def _largest_eigenvalue(A: sp.spmatrix) -> float:
    try:
        return float(spla.eigsh(A, k=1, which="LA", tol=1e-2, return_eigenvectors=False, maxiter=200, v0=np.ones(A.shape[0]))[0])
    except (spla.ArpackError, ValueError):
        return float(np.max(np.abs(A).sum(axis=1)))  # Gershgorin bound


def uses_lower_triangle(problem) -> bool:
    """Whether ``problem``'s ``hessian_lower()`` is the lower triangle of its own ``hessian()``.

    Only where the class that defines ``hessian`` defines ``hessian_lower`` too: a wrapper that adds terms
    to a linkage's Hessian and hands every other attribute to the linkage (``__getattr__``), or a
    subclass that overrides ``hessian``, would otherwise be solved with the linkage's Hessian alone (the
    design optimization's tethered equilibria were, and the graded cap could no longer be held).
    """
    for klass in type(problem).__mro__:
        if "hessian" in vars(klass):
            return "hessian_lower" in vars(klass)
    return False


def minimize(problem, *, fixed=None, force=None, constraint=None, options: NewtonOptions = NewtonOptions(),
             callback=None, saddle_hint=None) -> NewtonReport:
    """Minimize ``problem.energy() − force·x`` over the variables not in ``fixed``.

    With ``constraint = (a, target)`` the minimization is subject to
    ``a·x = target``, solved by block elimination of the KKT system (paper
    eq. 4); a step that has to restore the constraint is taken in full, and
    the report's ``multiplier`` is λ in ``∇E + λ a = 0``.

    Parameters
    ----------
    problem : object with the methods listed in the module docstring
    fixed : (k,) int array, optional
        Indices of variables held at their current values.
    force : (n,) array, optional
        A constant generalized force (dead load).
    constraint : (a, target), optional
        One linear equality constraint; ``a`` has shape (n,).
    options : NewtonOptions
    callback : callable(iteration, report), optional
        Called after each accepted step; return True to stop early.
    saddle_hint : (n,) array, optional
        Orients a negative-curvature step so that ``saddle_hint · d ≥ 0``
        (e.g. "buckle up"); by default it is oriented downhill.

    Returns
    -------
    NewtonReport
    """
    start = time.perf_counter()
    report = NewtonReport()
    x = problem.get_vars()
    n = len(x)
    free_idx = free_indices(n, fixed)
    f = np.zeros(n) if force is None else np.asarray(force, float)
    ws = _workspace(problem)
    chol = ws.chol
    sigma, sigma0 = 0.0, None
    _mass = []
    # A problem with hessian_lower() hands over the lower triangle of its Hessian: all that the
    # factorizations read. The sums below (free part, augmentation, shift) then run on that
    # triangle, entry for entry the same values; eigen-solves take the whole matrix.
    lower = uses_lower_triangle(problem)
    kind = "lower" if lower else "full"

    def mass():
        """The free-variable mass matrix (only needed for indefinite Hessians)."""
        if not _mass:
            _mass.append(sp.csr_matrix(sp.csr_matrix(problem.mass_matrix())[free_idx][:, free_idx]))
            _mass.append(sp.tril(_mass[0], format="csr") if lower else _mass[0])
        return _mass[0]

    def mass_part():
        """:func:`mass` as the Hessians are held (its lower triangle with ``lower``)."""
        mass()
        return _mass[1]

    def objective() -> float:
        return problem.energy() - f @ problem.get_vars()

    if constraint is not None:
        a_full = np.asarray(constraint[0], float)
        target = float(constraint[1])
        a = a_full[free_idx]
        aa = float(a @ a)
        # The constraint's residual in its own unit (a deployment's: radians), to round-off: a Newton step
        # restores it exactly. (It was the gradient tolerance times |a|, a force: where stiff, tiny
        # segments swamped the gradient's scale, a step 20° off its angle counted as feasible.)
        constraint_tolerance = CONSTRAINT_ROUND_OFF * max(1.0, abs(target), float(np.abs(a_full) @ np.abs(problem.get_vars())))
        a_outer, a_outer_tril = _outer_product(ws, a)
        a_outer_part = a_outer_tril if lower else a_outer
        aug = None  # ρ of the augmented Hessian H + ρ a aᵀ, set from the first Hessian
        if ws.aug is not None and ws.aug[0].shape == a.shape and np.array_equal(ws.aug[0], a):
            aug = ws.aug[1]  # the same constraint as the previous call: the same ρ (and a reusable factor)

    def hessian():
        """The free-variable Hessian (without the augmentation)."""
        nonlocal aug
        H = ws.free_part(problem.hessian_lower() if lower else problem.hessian(), free_idx, n, kind)
        if constraint is not None and aug is None:
            aug = float(np.abs(H.diagonal()).max()) / aa
            ws.aug = (a.copy(), aug)
        return H

    def augmented(H):
        """With a constraint, ``H + ρ a aᵀ``.

        The augmentation leaves the constrained Newton step unchanged (only
        the multiplier shifts) but makes positive definiteness mean
        stability on the constraint surface, so curvature along the
        actuated direction is not mistaken for a saddle.
        """
        if constraint is None:
            return H
        return ws.combine("aug", [H, a_outer_part], [1.0, aug])

    def whole_augmented():
        """The whole (not only lower) augmented free Hessian at the current state, for eigen-solves."""
        H = ws.free_part(problem.hessian(), free_idx, n, "full")
        if constraint is None:
            return H
        return ws.combine("aug_whole" if lower else "aug", [H, a_outer], [1.0, aug])

    def factor_unshifted(H) -> float:
        """Factorize ``H`` if it is positive definite, else its augmented form; returns the ρ used.

        The plain Hessian is sparser (``a aᵀ`` is a dense block over the
        actuated angles) and positive definite in most states; where it is
        not, the augmented one decides stability. Raises NotPositiveDefinite.
        """
        plain_failed = False
        if constraint is not None and ws.skip_plain <= 0:
            try:
                chol.factorize(H)
                chol.tag = free_idx
                return 0.0
            except NotPositiveDefinite:
                plain_failed = True
        ws.skip_plain -= 1
        chol.factorize(augmented(H))
        chol.tag = free_idx
        if plain_failed:
            # indefinite along the actuated direction alone (past the torque's limit point): go
            # straight to the augmented form for the next few factorizations (where both fail,
            # the state is indefinite and the shifted factorizations try the plain form first)
            ws.skip_plain = 4
        return aug if constraint is not None else 0.0

    def shifted(H, sigma, name="shift"):
        return ws.combine(name, [H, mass_part()], [1.0, sigma])

    def factor_shifted(H, sigma) -> float:
        """Factorize the plain ``H + σM`` if it is positive definite, else ``H + ρ a aᵀ + σM``; returns the ρ used.

        Both give the same constrained step (a term ρ a aᵀ changes only the
        multiplier), and the plain one factors about a third faster: ``a aᵀ`` is a
        dense block over the actuated angles (manta ray: 4.6 against 3.0 ms).
        Where the plain one is not positive definite the augmented one decides,
        with the same σ, so the shifts are those of the augmented form alone.
        Raises NotPositiveDefinite (of the augmented form).
        """
        if constraint is None:
            chol.factorize(shifted(H, sigma))
            return 0.0
        try:
            chol.factorize(shifted(H, sigma, "shift_plain"))
            return 0.0
        except NotPositiveDefinite:
            pass
        chol.factorize(shifted(augmented(H), sigma))
        return aug

    def first_shift() -> float:
        """σ0 = sigma_factor·λmax(H)/λmax(M) of the augmented Hessian, computed once per call
        (or once per free set and constraint, with ``options.keep_shift_scale``)."""
        nonlocal sigma0
        if sigma0 is None:
            kept = ws.shift_scale if options.keep_shift_scale else None
            a_key = None if constraint is None else a
            if (kept is None or not np.array_equal(kept[0], free_idx) or (kept[1] is None) != (a_key is None)
                    or (a_key is not None and not np.array_equal(kept[1], a_key))):
                scale = _largest_eigenvalue(whole_augmented()) / _largest_eigenvalue(mass())
                kept = (free_idx.copy(), None if a_key is None else a_key.copy(), scale)
                if options.keep_shift_scale:
                    ws.shift_scale = kept
            sigma0 = options.sigma_factor * kept[2]
        return sigma0

    def free_gradient():
        """The free gradient, its norm (projected onto the constraint surface, if any) and the multiplier."""
        g = (problem.gradient() - f)[free_idx]
        if constraint is None:
            return g, float(np.linalg.norm(g)), 0.0
        lam = -float(a @ g) / aa
        return g, float(np.linalg.norm(g + lam * a)), lam

    stalled = False  # the last step was below round-off: accept a gradient up to 4× the tolerance
    quadratic_step = False  # see options.minimum_from_last_step
    for it in range(options.max_iterations + 1):
        tolerance = options.gradient_tolerance * (4.0 if stalled else 1.0)
        g, gnorm, lam = free_gradient()
        if constraint is not None:
            residual = target - float(a_full @ problem.get_vars())
            report.multiplier = lam
            feasible = abs(residual) <= constraint_tolerance
        else:
            residual, feasible = 0.0, True
        report.energy.append(objective())
        report.gradient_norm.append(gnorm)
        H = None
        rho = 0.0
        if gnorm < tolerance and feasible:
            below = "gradient below tolerance" if gnorm < options.gradient_tolerance else \
                f"gradient at its rounding floor (|g| = {gnorm:.3e}, under 4x the tolerance)"
            if not options.require_minimum:
                report.converged, report.message = True, below
                break
            if quadratic_step:  # the last step's factor stands for this point's (and stays for the caller)
                report.converged, report.message = True, below + " at a minimum (the last Newton step's Hessian)"
                break
            H = hessian()
            try:
                factor_unshifted(H)
                report.converged, report.message = True, below + " at a minimum"
                break
            except NotPositiveDefinite:
                pass
            # A Hessian that is positive semidefinite (e.g. the flat state's free rest
            # lengths) need not factor: its zero eigenvalues come out of the rounding as
            # ±ε·λmax. Curvature that small is not a saddle to escape (the uniform grid's
            # rest-length solve spent 92 escapes on eigenvalues of −2e-16·λmax).
            s_round = ROUND_OFF_CURVATURE / options.sigma_factor * first_shift()
            try:
                chol.factorize(shifted(augmented(H), s_round))
                report.converged = True
                report.message = below + f" at a minimum up to round-off (H + {s_round:.1e} M positive definite)"
                break
            except NotPositiveDefinite:
                sigma = 0.0  # a saddle: fall through to the negative-curvature step
        if it == options.max_iterations:
            report.message = f"stopped after {options.max_iterations} iterations with |g| = {gnorm:.3e}"
            break
        if H is None:
            H = hessian()
        indefinite = False
        sigma_failed = 0.0
        try:
            if sigma == 0:
                rho = factor_unshifted(H)
            else:
                # the shift decays (options.shift_decay) after an indefinite spell (pure Newton
                # steps right away were tried: near a saddle they head back to it, and each new
                # escape costs an eigen-solve)
                rho = factor_shifted(H, sigma)
        except NotPositiveDefinite:
            indefinite = True
            sigma_failed = sigma  # H + σM is indefinite for every σ up to this one (M is positive definite)
            sigma = first_shift() if sigma == 0 else 4 * sigma
            while True:
                try:
                    rho = factor_shifted(H, sigma)
                    break
                except NotPositiveDefinite:
                    sigma_failed, sigma = sigma, 4 * sigma
        report.sigma.append(sigma)
        if constraint is None:
            d = -chol.solve(g)
        else:
            u, v = chol.solve(np.stack([g, a], axis=1)).T
            dlam = -(residual + a @ u) / (a @ v)
            d = -u - dlam * v
            report.multiplier = float(dlam) + rho * residual
        if sigma > 0:
            # Is H itself indefinite? (the shift may just be decaying)
            report.indefinite_events += int(indefinite)
            if indefinite and gnorm < options.saddle_gradient_factor * options.gradient_tolerance:
                if ws.eig_chol is None:
                    ws.eig_chol = SparseCholesky()
                chol.forget()  # its factor may be overwritten by the shift search
                Ha = augmented(H)  # the escape's eigen-solve judges the augmented form
                v, s_eig = _most_negative_direction(whole_augmented(), mass(), chol.chol, sigma, ws.eig_chol,
                                                    lambda s: shifted(Ha, s), floor=sigma_failed)
                # H + s_eig·M factors too (s_eig is within 100× of |λmin|): the next steps' shift
                # decays from 100·s_eig, not from σ (at σ ≫ |λmin| a step barely moves the soft
                # modes: Darth Vader took 16 such steps after its buckling escape)
                sigma = min(sigma, 100.0 * s_eig)
                if v is not None:
                    step = options.saddle_step or 1e-3
                    if hasattr(problem, "min_arc_length") and options.saddle_step is None:
                        step = 1e-2 * problem.min_arc_length()
                    if constraint is not None:
                        v -= a * (a @ v) / aa
                    v *= step / np.abs(v).max()
                    # At a symmetric saddle the gradient cannot choose a side, so the
                    # hint does; elsewhere the curvature step must go downhill.
                    at_saddle = abs(v @ g) <= 1e-4 * np.linalg.norm(v) * max(gnorm, 1e-300) or gnorm < options.gradient_tolerance
                    if saddle_hint is not None and at_saddle:
                        hint = np.asarray(saddle_hint, float)[free_idx]
                        if hint @ v < 0:
                            v = -v
                    elif v @ g > 0:
                        v = -v
                    if (d + v) @ g < 0 or at_saddle:
                        d = d + v
                        report.saddle_escapes += 1
        full_d = np.zeros(n)
        full_d[free_idx] = d
        e0 = report.energy[-1]
        slope = float(g @ d)
        alpha = 1.0
        x = problem.get_vars()
        # When the predicted decrease is below the energy's round-off, the
        # energy cannot judge the step: take it and let the gradient decide.
        resolvable = -slope > 1e-13 * max(abs(e0), 1e-300)
        if constraint is not None and abs(residual) > constraint_tolerance:
            resolvable = False  # a step restoring the constraint is taken in full
        # A decrease this small is within a few hundred roundings of the energy (its terms'
        # sum carries ~1e-13 relative error: the wiggly banana's full Newton steps measured
        # dE = +3.2e-11 at E = 1.3e3 for a predicted -8e-11, then backtracked to nothing and
        # stalled). There a positive-definite Newton step that lowers |g| is taken.
        near_round_off = sigma == 0 and -slope < SLOPE_ROUND_OFF * max(abs(e0), 1e-300)
        for _ in range(options.max_backtracks):
            try:
                problem.set_vars(x + alpha * full_d)
            except InvalidState:  # the trial point is outside the model's domain (a rest length ≤ 0)
                alpha *= 0.5
                continue
            if not resolvable or objective() <= e0 + options.armijo * alpha * min(slope, 0.0):
                break
            if near_round_off and alpha == 1.0 and free_gradient()[1] < gnorm:
                break
            alpha *= 0.5
        else:
            problem.set_vars(x)
            if sigma == 0 and feasible and gnorm < 4.0 * options.gradient_tolerance:
                # A positive-definite Newton step whose decrease the energy's round-off
                # cannot resolve: the gradient is at its rounding floor (as for a step
                # below round-off below). The wiggly banana deployed from its file's
                # unrelaxed state stopped here at 43° with |g| = 2.9x the tolerance.
                report.converged = True
                report.message = f"gradient at its rounding floor (|g| = {gnorm:.3e}, under 4x the tolerance; the line search cannot resolve the energy)"
                break
            report.message = "line search failed"
            break
        if hasattr(problem, "update_source_frame"):
            problem.update_source_frame()
        report.iterations = it + 1
        # a full, unshifted step on a positive-definite factor that cut |g| as Newton's quadratic convergence
        # does: the new point lies well inside that Hessian's region of validity
        quadratic_step = (options.minimum_from_last_step > 0 and sigma == 0 and not indefinite and alpha == 1.0
                          and chol.tag is free_idx and free_gradient()[1] < options.minimum_from_last_step * gnorm)
        if alpha * np.abs(full_d).max() <= 1e-15 * (1.0 + np.abs(x).max()):
            # The gradient's own round-off can exceed the tolerance's estimate of it
            # (a rounding floor): where nothing moves any more and |g| is within 4× of
            # the tolerance, one more iteration accepts it if the Hessian is positive definite.
            if stalled or gnorm >= 4.0 * options.gradient_tolerance or not feasible:
                report.message = f"step below round-off at |g| = {gnorm:.3e}"
                break
            stalled = True
        sigma = 0.0 if sigma < 1e-8 * (sigma0 or 0.0) else sigma / options.shift_decay
        if callback is not None and callback(it, report):
            report.message = STOPPED_BY_CALLBACK
            break
    report.time_s = time.perf_counter() - start
    return report


def _constrained_tangent(problem, fixed, a_full: np.ndarray, reuse: bool = False):
    """Equilibrium path tangent ``dx/dτ`` under the constraint ``a·x = τ`` (so ``a·t = 1``).

    ``t = H⁻¹a / (aᵀH⁻¹a)`` on the free variables, with the same augmented
    Hessian as :func:`minimize` (so at the end of a deployment step its
    factorization is reused, not redone). Returns None if it does not factor.
    With ``reuse``, the factor that :func:`minimize` last left on these free
    variables serves as it is, if it was of an unshifted Hessian (it may be
    the previous iterate's, see ``NewtonOptions.minimum_from_last_step``):
    good enough for a predictor, not for a stability check.
    """
    ws = _workspace(problem)
    n = len(a_full)
    free_idx = free_indices(n, fixed)
    a = np.asarray(a_full, float)[free_idx]
    lower = uses_lower_triangle(problem)  # as minimize holds it
    if ws.aug is None or ws.aug[0].shape != a.shape or not np.array_equal(ws.aug[0], a):
        return None
    if not (reuse and ws.chol.tag is not None and np.array_equal(ws.chol.tag, free_idx)):
        H = ws.free_part(problem.hessian_lower() if lower else problem.hessian(), free_idx, n, "lower" if lower else "full")
        a_outer = _outer_product(ws, a)[1 if lower else 0]
        # as minimize: the plain Hessian if it factors (then the augmented one would too), else the augmented
        plain = ws.skip_plain <= 0
        if plain:
            try:
                ws.chol.factorize(H)
            except NotPositiveDefinite:
                ws.skip_plain, plain = 4, False
        if not plain:
            try:
                ws.chol.factorize(ws.combine("aug", [H, a_outer], [1.0, ws.aug[1]]))
            except NotPositiveDefinite:
                return None
    v = ws.chol.solve(a)
    t = np.zeros(n)
    t[free_idx] = v / (a @ v)
    return t


LANCZOS_VECTORS = 12
"""Lanczos basis size (ARPACK's ``ncv``) of the shift-invert eigen-solves below, against its default
of 20. Every restart cycle costs that many solves with the factor, and after the shift search the
wanted eigenvalues are well separated: one cycle of 12 converges where 20 did. Measured on the manta
ray at 10 steps: 310 → 276 solves, its eigen-solves about 40 % faster, the same joints to 2e-13 of the
span and the same smallest eigenvalues to 1e-9 relative."""


def _lanczos_vectors(n: int, k: int) -> int:
    return min(n, max(LANCZOS_VECTORS, 2 * k + 1))


DENSE_EIGEN_SIZE = 800
"""Up to this size :func:`smallest_eigenvalues` solves densely (LAPACK, under 0.15 s):
exact, and immune to the clusters of near-zero modes that make ARPACK iterate
thousands of times (a 224-DoF mechanism with a 4-fold zero eigenvalue: 0.35 s)."""


def smallest_eigenvalues(H, M, k: int = 2, shift: float | None = None, dense_size: int = DENSE_EIGEN_SIZE,
                         return_shift: bool = False):
    """The ``k`` smallest eigenvalues of ``H d = λ M d`` (sorted), by shift-invert.

    With ``return_shift``, also the ``s`` used (``H + sM`` positive definite; 0.0 for a dense solve):
    it serves a pencil ``H + A`` with ``A`` positive semidefinite as a given ``shift``, since that
    pencil's eigenvalues are no lower.

    Pencils of at most ``dense_size`` rows are solved densely instead.

    The shift ``−s`` is below every eigenvalue, so the ones nearest to it
    are the smallest. Without a given ``shift``, a positive-definite ``H``
    is factored as it is (``s = 0``: one factorization; a stable deployed
    state's final check took 47 ms with the search below, on the manta ray).
    Otherwise ``s`` starts at 1e-6 of ``λmax(H)/λmax(M)``, grows until
    ``H + sM`` factors, and is then lowered by factors
    of 100 while ``H + sM`` still factors (at most 4 times): the lowest
    eigenvalues of a deployed linkage are 1e-3…1e-6 of the first shift and
    clustered, and seen from a far shift they are not separated (ARPACK took
    4,761 solves on a 2,411-DoF grid; 21 after lowering the shift).
    """
    n = H.shape[0]
    if n <= dense_size:
        import scipy.linalg as sla

        A = H.toarray() if sp.issparse(H) else np.asarray(H)
        B = M.toarray() if sp.issparse(M) else np.asarray(M)
        lam = sla.eigh(A, B, subset_by_index=[0, min(k, n) - 1], eigvals_only=True)
        return (lam, 0.0) if return_shift else lam
    chol = SparseCholesky()
    if shift is None:
        try:  # a positive-definite H is its own best shift-invert operator: every eigenvalue lies above 0
            chol.factorize(H)
            shift = 0.0
        except NotPositiveDefinite:
            pass
    s = shift if shift is not None else 1e-6 * _largest_eigenvalue(H) / _largest_eigenvalue(M)
    while True:
        try:
            if s != 0.0:
                chol.factorize(H + s * M)
            break
        except NotPositiveDefinite:
            s *= 4
    if shift is None:
        chol, s = _lowered_shift(chol, SparseCholesky(), lambda t: H + t * M, s, 4)
    op = spla.LinearOperator((n, n), matvec=chol.solve, dtype=float)
    lam = spla.eigsh(H, k=k, M=M, sigma=-s, which="LM", OPinv=op, tol=1e-8, maxiter=2000, return_eigenvectors=False, v0=np.ones(n),
                     ncv=_lanczos_vectors(n, k))
    return (np.sort(lam), s) if return_shift else np.sort(lam)


def _lowered_shift(solver: SparseCholesky, other: SparseCholesky, shifted, s: float, tries: int, floor: float = 0.0):
    """Lower the shift ``s`` by factors of 100 while ``shifted(s)`` (= ``H + sM``) still factors.

    ``solver`` holds the factor at ``s``; the two Cholesky objects take turns,
    so a failed try never overwrites the last factor that succeeded. Returns
    the one holding that factor and its shift. A shift at or below ``floor``
    (one already known not to factor) is not tried: with ``M`` positive
    definite no lower one factors either.
    """
    for _ in range(tries):
        if s / 100 <= floor:
            break
        try:
            other.factorize(shifted(s / 100))
        except NotPositiveDefinite:
            break
        solver, other, s = other, solver, s / 100
    return solver, s


def _most_negative_direction(H, M, chol: SparseCholesky, sigma: float, spare: SparseCholesky | None = None,
                             shifted=None, floor: float = 0.0):
    """Eigenvector of the most negative eigenvalue of ``H d = λ M d`` (or None), and the smallest shift tried that factors.

    Shift-invert about ``−s``. The step's shift σ (``chol`` holds ``H + σM``)
    is usually far above ``|λmin|`` (1e-3 of ``λmax(H)/λmax(M)`` against a
    λmin just past zero), and the wanted ``1/(λmin + σ)`` is then not
    separated from the near-zero modes' ``1/(λ + σ)``: ARPACK ran to its
    iteration limit. So with ``spare`` (a second Cholesky object) and
    ``shifted(s)`` (returns ``H + sM``), the shift is first lowered by factors
    of 100 while ``H + sM`` still factors, leaving ``s`` within 100× of
    ``|λmin|`` (a few factorizations; the solve then takes one Lanczos cycle).
    ``chol`` and ``spare`` take turns, so a failed try never overwrites the
    last factor that succeeded; ``chol`` may be left holding another matrix.
    ``floor``: a shift known not to factor (the step's last failed one); no
    lower one is tried.
    """
    n = H.shape[0]
    solver, s = chol, sigma
    if spare is not None and shifted is not None:
        solver, s = _lowered_shift(chol, spare, shifted, sigma, 8, floor)
    op = spla.LinearOperator((n, n), matvec=solver.solve, dtype=float)
    try:
        lam, vecs = spla.eigsh(H, k=1, M=M, sigma=-s, which="LM", OPinv=op, tol=1e-6, maxiter=500, v0=np.ones(n),
                               ncv=_lanczos_vectors(n, 1))
    except (spla.ArpackError, ValueError):  # no convergence, or ARPACK's own errors (a zero start vector: -9)
        return None, s
    if lam[0] >= 0:
        return None, s
    return vecs[:, 0], s
