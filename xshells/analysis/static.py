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
    """The load factor at which the loaded equilibrium loses stability.

    Attributes
    ----------
    factor : float or None
        None when the structure is stable up to ``searched_to``.
    bracket : (float, float)
        Stable below, unstable (or no equilibrium) above.
    method : str
    searched_to : float
    samples : list of (factor, smallest eigenvalue or nan)
    kind : {"bifurcation", "limit point"} or None
        How stability ends: an eigenvalue through zero on the branch (it buckles), or a load beyond which
        the branch has no equilibrium (a limit point: it snaps through).
    """

    factor: float | None
    bracket: tuple
    method: str
    searched_to: float
    samples: list = field(default_factory=list)
    kind: str | None = None


#: Newton iterations per load step in the critical-load search: from a nearby equilibrium a step converges in
#: far fewer; past a limit point Newton walks to the far branch (a jump, or no equilibrium: either way the
#: bracket's upper end) and the walk's hundreds of iterations were most of the search's time.
SEARCH_NEWTON_ITERATIONS = 40


def critical_load_factor(linkage, f, held, options: StaticOptions = StaticOptions(), base_force=None,
                         start: float = 1.0) -> CriticalFactor:
    """Continuation in the load factor from the unloaded state (``linkage`` is left unchanged).

    The smallest eigenvalue μ(λ) of the loaded Hessian is followed along the
    loaded branch (Newton without saddle escapes, so a symmetric state that
    passes its critical load stays on its branch, as a saddle), from
    ``start``/2 (a snap below the requested load is looked for too) up to
    ``options.max_factor`` × ``start``, that factor itself sampled last. Steps
    grow by secant extrapolation of μ toward 0 (at most ×2, a little past the
    predicted zero). The first sign change, the first load without an
    equilibrium, or the first step whose equilibrium *jumped* (the joints
    moved more than three times as far as the tangent dx/dλ = H⁻¹f predicts:
    Newton converged past a limit point, onto the branch after a
    snap-through, where μ > 0 again) is bracketed to ``factor_tolerance``
    (:func:`_bracketed`). A jump where μ had not fallen toward 0 is tried
    again from just below it: one that then steps smoothly was a strongly
    nonlinear path, not a limit point, and the continuation goes on.
    """
    import copy

    from ..linkage.state import restore, snapshot

    work = copy.deepcopy(linkage)
    base_state = snapshot(work)
    samples = []
    free = np.setdiff1d(np.arange(work.num_vars), held)
    joints = 9 * np.arange(work.num_joints)[:, None] + np.arange(3)[None, :]
    on_free = np.isin(free, joints.ravel())  # the joints' positions among the free variables: lengths

    def positions():
        return np.asarray(work.get_vars(), float)[joints.ravel()]

    def tangent_step():
        """max |dx/dλ| of the joints' positions at the current (stable) state: H⁻¹f on the free variables."""
        from ..solve.cholesky import NotPositiveDefinite, SparseCholesky

        chol = SparseCholesky()
        try:
            chol.factorize(work.hessian()[free][:, free].tocsr())
        except NotPositiveDefinite:
            return np.inf
        u = chol.solve(np.asarray(f, float)[free])
        return float(np.abs(u[on_free]).max()) if on_free.any() else 0.0

    def mu_at(lam, from_state, from_lam, rate):
        """(μ, state, rate, jumped) at ``lam`` solved from ``from_state`` at ``from_lam``; μ None where there is
        no equilibrium on the branch (no convergence, a failed eigen-solve, or a jump)."""
        restore(work, from_state)
        x0 = positions()
        # from the stable state at from_lam in two load steps (it is near: the steps at most double the
        # factor), without the final polish that only the reactions need
        st = solve_loaded(work, f, held, lam, StaticOptions(joints=options.joints, load_steps=max(1, options.load_steps // 5),
                                                            gravity=options.gravity), base_force=base_force, escape=False,
                          start_factor=from_lam, polish=False, max_iterations=SEARCH_NEWTON_ITERATIONS)
        if not st.converged:
            samples.append((lam, float("nan")))
            return None, None, None, False
        moved = float(np.abs(positions() - x0).max())
        if rate is not None and moved > 3.0 * rate * (lam - from_lam) + 1e-9 * (1.0 + float(np.abs(x0).max())):
            samples.append((lam, float("nan")))  # past a limit point (a snap-through), or a step too long
            return None, None, None, True
        try:
            mu = smallest_eigenvalue(work, held)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError, RuntimeError):  # ARPACK on a state gone bad
            samples.append((lam, float("nan")))
            return None, None, None, False
        samples.append((lam, mu))
        return mu, snapshot(work), (tangent_step() if mu >= 0 else None), False

    mu0 = smallest_eigenvalue(work, held)
    samples.append((0.0, mu0))
    lo, mu_lo, state_lo = 0.0, mu0, base_state
    rate_lo = tangent_step() if mu0 >= 0 else None
    prev = (None, None)  # the sample before lo: (factor, μ), for the secant
    limit = options.max_factor * max(start, 1e-300)
    tol = options.factor_tolerance
    lam = min(start / 2.0, limit)
    while True:
        mu, st, rate, jumped = mu_at(lam, state_lo, lo, rate_lo)
        if mu is None or mu < 0:
            kind = "bifurcation" if mu is not None else "limit point"
            lo2, mu_lo2, state2, rate2, prev2, hi, kind = _bracketed(mu_at, lo, mu_lo, state_lo, rate_lo, prev, lam, mu, kind, tol)
            if jumped and kind == "limit point" and mu_lo2 > 0.1 * mu0:
                # μ has not fallen toward 0 on the way: no fold in sight. Stepped from just below, is the jump
                # still there? Where it is not, the path was only strongly nonlinear: go on from there.
                mu3, st3, rate3, jumped3 = mu_at(hi, state2, lo2, rate2)
                if mu3 is not None and mu3 >= 0:
                    prev, lo, mu_lo, state_lo, rate_lo = (lo2, mu_lo2), hi, mu3, st3, rate3
                    if lo >= limit:
                        break
                    lam = min(2.0 * lo, limit)
                    continue
            return CriticalFactor(0.5 * (lo2 + hi), (lo2, hi), "continuation in the load factor, bracketed", limit,
                                  samples, kind)
        # the secant toward μ = 0 (a bifurcation, or a limit point ahead), at most doubling: stepping a little
        # past the predicted zero brackets it closely
        slope = (mu - mu_lo) / (lam - lo) if lam > lo else 0.0
        nxt = lam - mu / slope if slope < 0 else 2.0 * lam
        prev, lo, mu_lo, state_lo, rate_lo = (lo, mu_lo), lam, mu, st, rate
        if lam >= limit:
            break
        lam = min(float(np.clip(nxt * 1.02, lam * (1.0 + 2.0 * tol), 2.0 * lam)), limit)
    return CriticalFactor(None, (lo, float("inf")), "continuation in the load factor", limit, samples)


def _bracketed(mu_at, lo, mu_lo, state_lo, rate_lo, prev, hi, mu_hi, kind, tol):
    """Narrow the bracket (lo stable, hi not) to ``tol`` (relative): regula falsi on μ where both ends have one
    (a bifurcation), else the secant through the last two stable samples (a limit point, where μ → 0), each
    kept inside the bracket and alternated with halving once an end stops moving (Illinois' safeguard).
    Returns (lo, μ(lo), its state, its rate, the sample before lo, hi, the kind of what ends stability at hi)."""
    same_end = 0
    last_end = None
    while hi - lo > tol * hi:
        w = hi - lo
        guess = None
        if mu_hi is not None and mu_hi < 0 < mu_lo:
            guess = lo + w * mu_lo / (mu_lo - mu_hi)
        elif prev[0] is not None and prev[1] > mu_lo > 0:
            guess = lo + mu_lo * (lo - prev[0]) / (prev[1] - mu_lo)
        if guess is None or not np.isfinite(guess) or same_end >= 1 or not lo + 0.1 * w < guess < hi - 0.1 * w:
            x = lo + 0.5 * w  # halving: no prediction inside the bracket, or one end has just moved twice
        else:
            x = guess
        mu, st, rate, _ = mu_at(x, state_lo, lo, rate_lo)
        if mu is None or mu < 0:
            hi, mu_hi, kind, end = x, mu, ("bifurcation" if mu is not None else "limit point"), "hi"
        else:
            prev, lo, mu_lo, state_lo, rate_lo, end = (lo, mu_lo), x, mu, st, rate, "lo"
        same_end = same_end + 1 if end == last_end else 0
        last_end = end
    return lo, mu_lo, state_lo, rate_lo, prev, hi, kind


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
