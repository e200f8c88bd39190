"""The deployed shell under loads: supports, loads, the nonlinear equilibrium, reactions, stability.

Supports hold design vertices (joints or free ends):

* **pinned**: the vertex's position (3 variables);
* **clamped**: its position and rotation — at a joint the rotation ω of its
  frame (3 more), at a free end the next rod vertex and the end edge's
  material angle as well.

``joints="locked"`` holds every joint's opening angle α at its deployed
value (riveted and braced as built); ``"free"`` lets the joints turn while
the deployment's actuation torque stays applied (``τ S_α`` as a dead load).

Loads are dead loads: self-weight (lumped gravity on the rods, density ×
area × length), point forces at vertices, and a vertical load per unit of
horizontal projected area distributed to the joints by tributary area (a
third of each triangle of the deployed joint quads). The equilibrium
``∇E(x) = λ f`` is solved by Newton with load stepping, from the unloaded
deployed state, with large displacements. Units follow the input (N, mm,
MPa for the bundled data).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import InputError

GRAVITY = (0.0, 0.0, -9810.0)  # mm/s²: with densities in t/mm³, forces in N


@dataclass(frozen=True)
class Support:
    """A support at design vertex ``vertex`` (0-based, the input file's order)."""

    vertex: int
    kind: str = "pinned"

    def __post_init__(self):
        if self.kind not in ("pinned", "clamped"):
            raise InputError(f"support type must be pinned or clamped, got {self.kind!r}")


@dataclass(frozen=True)
class Load:
    """A load: ``kind`` "self-weight", "point" (``vertex``, ``vector``) or "area" (``q``, per projected area)."""

    kind: str
    vertex: int | None = None
    vector: tuple | None = None
    q: float | None = None


@dataclass(frozen=True)
class StaticOptions:
    """Settings of :func:`solve_loaded` and :func:`critical_load_factor`.

    Attributes
    ----------
    joints : {"locked", "free"}
    load_steps : int
        Increments of the load factor up to the requested one.
    gravity : (3,) float
    max_factor : float
        The critical load factor is searched up to this multiple of the load.
    factor_tolerance : float
        Relative bracket width of the critical factor.
    """

    joints: str = "locked"
    load_steps: int = 10
    gravity: tuple = GRAVITY
    max_factor: float = 50.0
    factor_tolerance: float = 1e-3

    def __post_init__(self):
        if self.joints not in ("locked", "free"):
            raise InputError(f"--joints must be locked or free, got {self.joints!r}")
        if self.load_steps < 1:
            raise InputError(f"load steps must be at least 1, got {self.load_steps}")


# ------------------------------------------------------------------- supports
def _reduced_of_rod_vars(linkage, rod_vars: np.ndarray) -> np.ndarray:
    lookup = dict(zip(linkage._free_rod.tolist(), linkage._free_reduced.tolist()))
    missing = [r for r in rod_vars.tolist() if r not in lookup]
    if missing:
        raise InputError("internal: a free end's variables are not reduced variables")
    return np.array([lookup[r] for r in rod_vars.tolist()], np.int64)


def support_rows(linkage, support: Support) -> tuple[np.ndarray, np.ndarray]:
    """(position rows (3,), all held rows) of one support in the reduced variables."""
    g = linkage.graph
    n = g.design.num_vertices
    v = int(support.vertex)
    if not (0 <= v < n):
        raise InputError(f"support at vertex {v}: the design has vertices 0 to {n - 1}")
    j = int(g.vertex_joint[v])
    if j >= 0:
        pos = 9 * j + np.arange(3)
        held = pos if support.kind == "pinned" else 9 * j + np.arange(6)
        return pos, held
    if v not in set(np.asarray(g.free_end_vertex).tolist()):
        raise InputError(f"support at vertex {v}: no segment uses that vertex")
    rv, nb, edge = linkage.free_end_rod_vertex(v)
    V = linkage.rods.num_vertices
    pos = _reduced_of_rod_vars(linkage, 3 * rv + np.arange(3))
    if support.kind == "pinned":
        return pos, pos
    more = _reduced_of_rod_vars(linkage, np.r_[3 * nb + np.arange(3), 3 * V + edge])
    return pos, np.r_[pos, more]


def held_variables(linkage, supports, joints: str = "locked") -> np.ndarray:
    """Every held reduced variable: the supports', and the joint angles when ``joints == "locked"``."""
    rows = [support_rows(linkage, s)[1] for s in supports]
    if joints == "locked":
        rows.append(linkage.angle_indices())
    return np.unique(np.concatenate(rows)) if rows else np.zeros(0, np.int64)


def free_rigid_modes(linkage, supports) -> int:
    """How many rigid motions (of 6) the supports leave free."""
    P = linkage.vertex_positions()
    rows = []
    for s in supports:
        p = P[s.vertex]
        # δp = t + r × p for a rigid motion (t, r): the support fixes δp, and r as well when clamped
        skew = np.array([[0, p[2], -p[1]], [-p[2], 0, p[0]], [p[1], -p[0], 0]])
        rows.append(np.c_[np.eye(3), skew])
        if s.kind == "clamped":
            rows.append(np.c_[np.zeros((3, 3)), np.eye(3)])
    if not rows:
        return 6
    A = np.vstack(rows)
    scale = max(1.0, float(np.abs(P).max()))
    A[:, 3:] /= scale
    return int(6 - np.linalg.matrix_rank(A, tol=1e-9))


def lowest_supports(linkage, count: int) -> list[int]:
    """The ``count`` design vertices lowest along z (joints and free ends), lowest first."""
    P = linkage.vertex_positions()
    used = np.flatnonzero(np.asarray(linkage.graph.valence) > 0)
    if not (1 <= count <= len(used)):
        raise InputError(f"--supports lowest:{count}: choose between 1 and {len(used)} vertices")
    return [int(v) for v in used[np.argsort(P[used, 2], kind="stable")[:count]]]


# ---------------------------------------------------------------------- loads
def load_vector(linkage, loads, gravity=GRAVITY) -> tuple[np.ndarray, np.ndarray]:
    """The generalized force (num_vars,) of ``loads`` at the current state, and its resultant force (3,)."""
    f = np.zeros(linkage.num_vars)
    total = np.zeros(3)
    n = linkage.graph.design.num_vertices
    for load in loads:
        if load.kind == "self-weight":  # the materials' densities as they are (the command line checks one was given)
            f += linkage.gravity_force(gravity)
            total += linkage.rods.gravity_force(gravity)[: 3 * linkage.rods.num_vertices].reshape(-1, 3).sum(axis=0)
        elif load.kind == "point":
            v = int(load.vertex)
            if not (0 <= v < n) or linkage.graph.valence[v] == 0:
                raise InputError(f"point load at vertex {v}: no such vertex in the design (0 to {n - 1})")
            F = np.asarray(load.vector, float)
            rows = support_rows(linkage, Support(v))[0]
            f[rows] += F
            total += F
        elif load.kind == "area":
            f_j, tot = area_load(linkage, float(load.q))
            f += f_j
            total += tot
        else:
            raise InputError(f"unknown load {load.kind!r}: use self-weight, point:VERTEX:FX,FY,FZ or area:Q")
    return f, total


def area_load(linkage, q: float):
    """A vertical load ``q`` per unit of horizontal projected area, on the joints by tributary area."""
    from ..design.fitting import joint_faces, triangulate_faces

    P = linkage.joint_positions()
    T = triangulate_faces(P, joint_faces(linkage))
    A = 0.5 * np.abs(np.cross(P[T[:, 1], :2] - P[T[:, 0], :2], P[T[:, 2], :2] - P[T[:, 0], :2]))
    share = np.zeros(len(P))
    np.add.at(share, T.ravel(), np.repeat(A / 3.0, 3))
    F = np.zeros((len(P), 3))
    F[:, 2] = -q * share
    return linkage.joint_force(F), F.sum(axis=0)


# ------------------------------------------------------------------ equilibria
@dataclass
class LoadedState:
    """The result of :func:`solve_loaded`.

    Attributes
    ----------
    load_factor : float
        The factor reached (the requested one when ``converged``).
    converged : bool
    message : str
    displacement : (n, 3) float
        Of every design vertex, from the unloaded state.
    reactions : list of dict
        Per support: ``vertex``, ``kind``, ``force`` (3,) (and ``moment`` info for clamped).
    reactions_total : (3,) float
    total_load : (3,) float
        λ times the loads' resultant.
    min_eigenvalue : float
        Smallest eigenvalue of the loaded Hessian on the free variables (mass metric).
    iterations : int
    """

    load_factor: float
    converged: bool
    message: str
    displacement: np.ndarray = field(repr=False)
    reactions: list = field(default_factory=list)
    reactions_total: np.ndarray = field(default_factory=lambda: np.zeros(3))
    total_load: np.ndarray = field(default_factory=lambda: np.zeros(3))
    min_eigenvalue: float = float("nan")
    iterations: int = 0


def _newton_options(linkage):
    from ..deploy.simulate import _gradient_scale, _noise_floor
    from ..solve import NewtonOptions

    scale = _gradient_scale(linkage) * np.sqrt(linkage.num_vars)
    return NewtonOptions(gradient_tolerance=max(1e-12 * scale, _noise_floor(linkage)), max_iterations=200,
                         saddle_gradient_factor=float("inf"))


def smallest_eigenvalue(linkage, held) -> float:
    """Smallest eigenvalue of the Hessian on the free variables, in the mass metric (< 0: unstable)."""
    from ..solve.newton import smallest_eigenvalues

    free = np.setdiff1d(np.arange(linkage.num_vars), held)
    H = linkage.hessian()[free][:, free]
    M = linkage.mass_matrix()[free][:, free]
    return float(smallest_eigenvalues(H.tocsr(), M.tocsr(), k=1)[0])


def solve_loaded(linkage, f, held, load_factor: float = 1.0, options: StaticOptions = StaticOptions(),
                 base_force=None, callback=None, escape: bool = True, start_factor: float = 0.0,
                 polish: bool = True, max_iterations: int | None = None) -> LoadedState:
    """Equilibrium of ``linkage`` (in place) under ``load_factor · f`` (+ ``base_force``), ``held`` variables fixed.

    Load stepping in ``options.load_steps`` equal increments; ``callback(step,
    factor)`` after each (return True to stop). ``base_force``: a force always
    present (the actuation torque when the joints are free). ``start_factor``:
    the factor ``linkage`` is already in equilibrium under (the steps run from
    it). A step that does not converge leaves the linkage at the last
    equilibrium, whose factor the result gives. ``polish``: take the last equilibrium below the solver's
    round-off estimate (up to four Newton steps), for the reactions' balance. ``max_iterations``: Newton's per
    load step (default 200).
    """
    from ..solve import minimize

    base = np.zeros(linkage.num_vars) if base_force is None else np.asarray(base_force, float)
    P0 = linkage.vertex_positions()
    opts = _newton_options(linkage)
    if not escape:  # stay on the branch (a symmetric state past its critical load is kept, as a saddle)
        opts = replace(opts, saddle_gradient_factor=0.0)
    if max_iterations is not None:
        opts = replace(opts, max_iterations=max_iterations)
    from ..linkage.state import restore, snapshot

    reached, its, message, ok = start_factor, 0, "", True
    for k in range(1, options.load_steps + 1):
        lam = start_factor + (load_factor - start_factor) * k / options.load_steps
        last = snapshot(linkage)
        rep = minimize(linkage, fixed=held, force=base + lam * f, options=opts)
        linkage.update_source_frame()
        its += rep.iterations
        if not rep.converged or not np.all(np.isfinite(linkage.get_vars())):
            # the last equilibrium is what is reported, not the iterate that failed (its displacement and
            # stresses were those of no equilibrium, beside the reactions of another load)
            restore(linkage, last)
            ok, message = False, f"the equilibrium at load factor {lam:.4g} did not converge ({rep.message})"
            break
        reached = lam
        if callback is not None and callback(k, lam):
            ok, message = False, "stopped by request"
            break
    if ok and polish:  # the last equilibrium below the round-off estimate: the reactions' balance is what it leaves
        before = snapshot(linkage)
        free = np.setdiff1d(np.arange(linkage.num_vars), held)
        force = base + reached * f
        g0 = float(np.linalg.norm((linkage.gradient() - force)[free]))
        rep = minimize(linkage, fixed=held, force=force, options=replace(opts, gradient_tolerance=1e-3 * opts.gradient_tolerance,
                                                                       max_iterations=4))
        g1 = float(np.linalg.norm((linkage.gradient() - force)[free]))
        if not g1 < g0:
            restore(linkage, before)
        else:
            linkage.update_source_frame()
            its += rep.iterations
    state = LoadedState(reached, ok, message or "converged", linkage.vertex_positions() - P0, iterations=its)
    return state


def reactions(linkage, supports, f_total, held) -> tuple[list, np.ndarray]:
    """Support reactions from the equilibrium's residual at the held variables: ``r = ∇E − f`` there."""
    g = np.asarray(linkage.gradient(), float) - f_total
    out, total = [], np.zeros(3)
    for s in supports:
        pos, rows = support_rows(linkage, s)
        force = g[pos]  # ∇E = f + R at a held variable: the support's reaction is R = ∇E − f
        moment = None
        j = int(linkage.graph.vertex_joint[s.vertex])
        if s.kind == "clamped" and j >= 0:
            # ω is a rotation vector about the joint's current frame (reset to 0 after every solve), so its
            # energy gradient is the moment the clamp applies
            moment = g[9 * j + 3: 9 * j + 6]
        elif s.kind == "clamped":
            # a clamped free end holds its end vertex, the next rod vertex and the end edge's twist: the
            # reaction is all of theirs (the end vertex's alone left out most of it: 30x off on a test)
            nb_rows, twist_row = rows[3:6], rows[6]
            rv, nb, edge = linkage.free_end_rod_vertex(int(s.vertex))
            P = linkage.rods.points
            a, b = linkage.rods.edges[edge]
            t = (P[b] - P[a]) / np.linalg.norm(P[b] - P[a])
            force = force + g[nb_rows]
            moment = np.cross(P[nb] - P[rv], g[nb_rows]) + g[twist_row] * t
        out.append({"vertex": int(s.vertex), "kind": s.kind, "force": force.tolist(),
                    "moment": None if moment is None else moment.tolist()})
        total += force
    return out, total


@dataclass
class CriticalFactor:
    """The load factor at which the loaded equilibrium loses stability, and the path followed to it.

    Attributes
    ----------
    factor : float or None
        None when the structure is stable up to ``searched_to``.
    bracket : (float, float)
        Stable below, unstable (or no equilibrium on the path) above.
    method : str
    searched_to : float
        How far the path was followed: ``options.max_factor`` × the target, or less where it stopped.
    samples : list of (factor, 0 where the state is stable, -1 where not)
        The equilibria accepted along the path.
    kind : {"bifurcation", "limit point"} or None
        How stability ends: the path goes on through the critical factor, an eigenvalue of its Hessian
        turning negative (a bifurcation: the shell buckles sideways off it), or the path ends at a load
        maximum, past which the nearest equilibrium is far away (a limit point: it snaps through).
    target_state : dict or None
        The equilibrium on the path at the target factor (a :func:`~xshells.linkage.state.snapshot`), where
        the path reached it before losing stability.
    last_stable : dict or None
        The equilibrium at ``bracket[0]``.
    interrupted : bool
        The search was stopped (Ctrl-C, or the callback): what was found so far.
    """

    factor: float | None
    bracket: tuple
    method: str
    searched_to: float
    samples: list = field(default_factory=list)
    kind: str | None = None
    target_state: dict | None = field(default=None, repr=False)
    last_stable: dict | None = field(default=None, repr=False)
    interrupted: bool = False


#: Newton iterations per path step: from the predictor a step converges in a few; past a limit point Newton
#: walks to the far branch (or nowhere) and the walk's hundreds of iterations were most of the search's time.
SEARCH_NEWTON_ITERATIONS = 40
#: A step is accepted when its equilibrium lies within this fraction of the predicted motion from the
#: prediction along the path's tangent. A smooth path misses it by O(dλ²), a fold approached by
#: √(λc − λ) only for steps within ~10 % of the fold, a snap by its whole jump however small the step.
PATH_DEVIATION = 0.5
#: The predicted motion of one step, at most, as a fraction of the shell's span: a snap that moves the shell
#: by more than half of it (1 % of the span) cannot hide inside a long step.
PATH_STEP_SPAN = 0.02
#: Steps of the path at most (the search stops there, saying how far it got).
PATH_MAX_STEPS = 400


def _plain_newton(linkage, free, force, tolerance, iterations: int = 12) -> bool:
    """Newton's method without line search or shifts on ``∇E(x) = force`` (the free variables), from the current
    state: it converges to a saddle as to a minimum, near one. True where ``|g| ≤ tolerance``."""
    import scipy.sparse.linalg as spla

    with np.errstate(all="ignore"):  # a diverging try passes through degenerate joints: it is refused, not reported
        return _plain_newton_steps(linkage, free, force, tolerance, iterations, spla)


def _plain_newton_steps(linkage, free, force, tolerance, iterations, spla) -> bool:
    for _ in range(iterations):
        g = (linkage.gradient() - force)[free]
        if not np.all(np.isfinite(g)):
            return False
        if float(np.linalg.norm(g)) <= tolerance:
            return True
        try:
            d = spla.splu(linkage.hessian()[free][:, free].tocsc()).solve(-g)
        except RuntimeError:  # exactly singular
            return False
        x = linkage.get_vars()
        x[free] += d
        if not np.all(np.isfinite(x)):
            return False
        linkage.set_vars(x)
        linkage.update_source_frame()
    return float(np.linalg.norm((linkage.gradient() - force)[free])) <= tolerance


def critical_load_factor(linkage, f, held, options: StaticOptions = StaticOptions(), base_force=None,
                         start: float = 1.0, search: bool = True, callback=None) -> CriticalFactor:
    """Follow the equilibrium path ``∇E(x) = λ f`` from the unloaded state (``linkage`` is left unchanged).

    The path always starts at λ = 0 (whatever the split of a load between
    ``f`` and ``start``, the same path is followed) and goes, in steps
    controlled along it, through ``start`` (the target, where its state is
    kept) and on to ``options.max_factor`` × ``start`` (only to ``start``
    without ``search``). Each step predicts the state along the path's
    tangent dx/dλ = H⁻¹f (held variables fixed), corrects by Newton without
    saddle escapes (so a symmetric state past its critical load stays on
    its branch, as a saddle), and is accepted when the equilibrium lies
    within :data:`PATH_DEVIATION` of the predicted motion from the
    prediction, the motion itself at most :data:`PATH_STEP_SPAN` of the
    span. Stability ends

    * where the Hessian on the free variables stops being positive definite
      on a path that goes on smoothly: a bifurcation, bracketed by halving;
    * where the path ends: steps down to ``factor_tolerance`` that still
      jump (the state moves far from the prediction: a snap to another
      branch), or find no equilibrium: a limit point.

    The bracket is narrowed to ``factor_tolerance`` (relative); a bound set by
    a long step that failed is confirmed by a short one. ``callback(factor)``
    after each accepted step: True stops the search (``interrupted``), as
    does KeyboardInterrupt; what is found so far is returned.
    """
    import copy

    from ..linkage.state import restore, snapshot
    from ..solve import minimize
    from ..solve.cholesky import NotPositiveDefinite, SparseCholesky

    work = copy.deepcopy(linkage)
    f = np.asarray(f, float)
    base = np.zeros(work.num_vars) if base_force is None else np.asarray(base_force, float)
    free = np.setdiff1d(np.arange(work.num_vars), held)
    V = work.rods.num_vertices
    span = float(np.ptp(work.rods.points, axis=0).max())
    floor = 1e-9 * (span + float(np.abs(work.rods.points).max()))  # motions at round-off
    opts = replace(_newton_options(work), saddle_gradient_factor=0.0, max_iterations=SEARCH_NEWTON_ITERATIONS)
    tol = options.factor_tolerance
    target = float(start)
    limit = options.max_factor * target if search else target
    chol = SparseCholesky()

    def analyse():
        """(stable, tangent (num_vars,) or None, rod points' motion per unit λ (V, 3) or None) at the state."""
        try:
            chol.factorize(work.hessian()[free][:, free].tocsr())
        except NotPositiveDefinite:
            return False, None, None
        t = np.zeros(work.num_vars)
        t[free] = chol.solve(f[free])
        return True, t, (work.rod_jacobian() @ t)[: 3 * V].reshape(-1, 3)

    def step(lam_from, state, t, rate, lam, newton_first=False):
        """Predict from ``state`` (at ``lam_from``) to ``lam`` and correct: the new state, or None where the
        equilibrium is not the path's (no convergence, or far from the prediction). ``newton_first``: correct
        by plain Newton first (the minimizer only where it fails)."""
        restore(work, state)
        dl = lam - lam_from
        P_pred = work.rods.points + dl * rate
        work.set_vars(work.get_vars() + dl * t)
        force = base + lam * f
        x_pred = snapshot(work)
        plain_tol = max(opts.gradient_tolerance, 1e-9 * float(np.linalg.norm(force[free])))
        if newton_first and _plain_newton(work, free, force, plain_tol):
            # halving a bifurcation's bracket, steps land on the saddle branch past it, where the minimizer
            # spent its 40 iterations in vain before plain Newton converged (the manta ray: 6 of them, 2.9 s of
            # the search's 7): from a prediction this close Newton converges to the same equilibrium
            return _on_path(P_pred, dl, rate)
        restore(work, x_pred)
        rep = minimize(work, fixed=held, force=force, options=opts)
        # a saddle on a symmetric branch past its bifurcation stalls at the gradient's round-off, a little above
        # the tolerance set for minima: at 1e-8 of the load it is an equilibrium all the same
        stalled = ("round-off" in rep.message and rep.gradient_norm
                   and rep.gradient_norm[-1] <= 1e-8 * float(np.linalg.norm(force[free])))
        if not (rep.converged or stalled) or not np.all(np.isfinite(work.get_vars())):
            # the minimizer shifts an indefinite Hessian and does not converge to a saddle (the deployed plus's
            # arm under an in-plane load past its lateral buckling load: |g| stuck at 1e-8 to 1e-6): plain Newton
            # from the prediction converges to the branch's saddle where there is one nearby
            restore(work, x_pred)
            if not _plain_newton(work, free, force, plain_tol):
                return None
        return _on_path(P_pred, dl, rate)

    def _on_path(P_pred, dl, rate):
        """The corrected state, or None where it lies far from the prediction ``P_pred`` (not the path's)."""
        work.update_source_frame()
        off = float(np.abs(work.rods.points - P_pred).max())
        if off > PATH_DEVIATION * dl * float(np.abs(rate).max()) + floor:
            return None
        return snapshot(work)

    lo, state_lo = 0.0, snapshot(work)
    stable, t_lo, rate_lo = analyse()
    samples = [(0.0, 0.0 if stable else -1.0)]
    target_state = state_lo if target == 0 else None
    if not stable:  # unstable unloaded: nothing to follow
        return CriticalFactor(0.0, (0.0, 0.0), "continuation in the load factor from zero", 0.0, samples, "bifurcation",
                              None, state_lo)
    hi, kind, hi_confirmed = None, None, False
    u = float(np.abs(rate_lo).max())
    dl = min(limit, PATH_STEP_SPAN * span / u) if u > 0 else limit
    interrupted = False
    try:
        for _ in range(PATH_MAX_STEPS):
            if hi is not None and hi - lo <= tol * hi:
                if hi_confirmed:
                    break
                lam = hi  # a long step's failure set this bound: is it one at a short step too?
            elif hi is not None:
                lam = 0.5 * (lo + hi)
            else:
                if lo >= limit:
                    break
                lam = lo + min(dl, PATH_STEP_SPAN * span / max(float(np.abs(rate_lo).max()), 1e-300))
                if lo < target:
                    lam = min(lam, target)  # the path passes through the target itself
                lam = min(lam, limit)
            new = step(lo, state_lo, t_lo, rate_lo, lam, newton_first=kind == "bifurcation")
            # a failure confirms a bound only from a step as short as the bracket asked for: the hourglass's step
            # of 0.14 % failed the deviation test (the path turning ever faster toward its fold) and was kept
            # as the bound, 0.17 % below the fold
            short = lam - lo <= tol * lam
            if new is None:  # off the path: a limit point beyond lo (or the step was too long)
                hi, kind, hi_confirmed = lam, "limit point", short
                dl = 0.5 * (lam - lo)
                continue
            ok, t, rate = analyse()
            samples.append((lam, 0.0 if ok else -1.0))
            if not ok:  # the path goes on, through the loss of stability: a bifurcation
                hi, kind, hi_confirmed = lam, "bifurcation", True
                continue
            if hi is not None and lam >= hi:  # the bound was a long step's failure only: follow on
                hi, kind = None, None
            if hi is None:  # accepted: the next step twice as long (the span's share caps it)
                dl = 2.0 * (lam - lo)
            lo, state_lo, t_lo, rate_lo = lam, new, t, rate
            if kind == "limit point":  # a failure from an earlier, farther state: confirmed again from this one
                hi_confirmed = False
            if lo == target:
                target_state = new
            if callback is not None and callback(lo):
                interrupted = True
                break
    except KeyboardInterrupt:
        interrupted = True
    if hi is not None and hi - lo <= tol * hi and hi_confirmed:
        return CriticalFactor(0.5 * (lo + hi), (lo, hi), "continuation in the load factor from zero, bracketed",
                              limit, samples, kind, target_state, state_lo, interrupted)
    return CriticalFactor(None, (lo, float("inf")), "continuation in the load factor from zero", lo, samples, None,
                          target_state, state_lo, interrupted)


def translate(linkage, shift) -> None:
    """Move ``linkage`` (in place) rigidly by ``shift`` (3,): joint positions and the free rod vertices.

    The analysis works about the origin: designs drawn far from it (the
    paper's sit 10⁴ mm away) carry round-off in the gradient proportional to
    their coordinates, which the reactions' balance would show.
    """
    x = np.array(linkage.get_vars(), float)
    shift = np.asarray(shift, float)
    nj = linkage.num_joints
    x[: 9 * nj].reshape(-1, 9)[:, 0:3] += shift
    rod_vars = np.asarray(linkage._free_rod)
    points = rod_vars < 3 * linkage.rods.num_vertices
    x[np.asarray(linkage._free_reduced)[points]] += shift[rod_vars[points] % 3]
    linkage.set_vars(x)
    linkage.update_source_frame()
