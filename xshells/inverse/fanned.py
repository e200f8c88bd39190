"""Fanned nets: straight flat beams whose angle varies across each family, laid onto the surface by their lengths.

Why. An evenly spaced net flattens to a uniform grid of parallel lines, and
such a grid is a mechanism in the plane: it opens without bending any beam,
so its deployment stays flat (docs/inverse.md). The paper's designs are not
uniform grids. The pointy wings' flat layout, for one, is two families of
nearly straight lines whose angle to the layout's axis varies from line to
line, from 7° at the ends to 14° in the middle. Lines that are not parallel
cannot open in the plane without bending, so the layout buckles out of it.

Construction (all in the scissor map's closed chart, :mod:`.scissor`):

1. The evenly spaced lattice of :func:`.net.net_coordinates` is fitted by an
   affine grid ``o + i a + j b``: the family-0 beams are the lines
   ``j = const`` (direction ``a``), the family-1 beams ``i = const``.
2. Each line is turned about the point where it crosses the layout's axis
   ``e`` (the bisector of ``a`` and ``b`` through the footprint's centre), to
   the angle ``φ (1 + κ (1 − 2 t²))`` from ``e``, where ``φ`` is its family's
   half opening angle and ``t`` the crossing's position along ``e``,
   −1 … 1 over the surface's footprint. The joints are the new lines'
   crossings: a flat layout of straight beams whose opening angle runs
   from ``α₀ (1 + κ)`` on the middle lines to ``α₀ (1 − κ)`` at the ends.
   ``κ = 0`` is the evenly spaced net.
3. The joints are placed on the surface with the flat segment lengths, by
   least squares over their chart positions (each segment's chord against
   its flat length, plus a weak second difference along the beams that
   fixes what lengths leave free). The net grows from the lattice inside
   the surface: a joint outside is added where its neighbours predict it
   inside, until none is.

:func:`screen_fans` deploys the flat layout of each of a few ``κ`` (and
both bisectors) freely, as a first guess, and ranks them by how close that
deployment comes to the surface: the fan that the surface asks for is the
one whose flat layout already buckles towards it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..design.fitting import point_mesh_squared_distance
from ..errors import InputError
from .net import Net, _check_connected, _locate, _tidy, net_coordinates
from .scissor import ScissorMap
from .surface import TargetSurface

#: how far (in spacings) a joint may lie beyond the surface's boundary (:meth:`ChartLift.outside`) and still be kept
OUTSIDE = 0.35
#: how far (in spacings) beyond the surface's boundary a new joint may be predicted and still join the net.
#: Joints up to 0.2 spacings beyond cover the boundary band fully (the wings: 100 % against 94 %), but that
#: net ended with overlapping beams (2.45 %) where this one reaches 0.50 % / 1.46 %, coverage 89.6 %; at 0.1,
#: 0.39 % / 1.47 %, coverage 96.2 %, but two beams of a family 11.6 apart in the flat state (12 wide)
GROW = 1e-3
#: rings of lattice points beyond the surface's own into which the net may grow
MARGIN = 6
#: the second-difference weight that fixes what the segment lengths leave free
SMOOTH = 0.1
#: the shortest flat segment kept, in spacings: shorter ones are where a strong fan's lines meet
MIN_STEP = 0.4
#: the fans screened. The paper's designs open their middle lines more than their ends (K > 0); stronger
#: fans (0.25-0.33) bring a family's lines together over a footprint that is not a lens, and their first
#: layouts inverted or stalled on the wings and the manta ray. Fans that open their ends more (K < 0) buckle
#: closer to domes and vaults (first deployments, 2026-12-06: the spherical cap 0.65 % of the diagonal at
#: -0.25 against 2.26 % at best with K > 0, Darth Vader's target 0.96 % against 4.53 %, the barrel vault
#: 3.07 % against 4.38 %)
FAN_KAPPAS = (-0.25, -0.2, -0.15, -0.1, 0.1, 0.15, 0.2)
#: a weak pull of each joint to where it started: the lengths leave the net free to slide along the surface
ANCHOR = 0.02


def _barycentric(P, A, B, C):
    """Barycentric coordinates (k, 3) of 2D points ``P`` in triangles ``ABC`` (each (k, 2)), extrapolated outside."""
    v0, v1, v2 = B - A, C - A, P - A
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.c_[1.0 - v - w, v, w]


class ChartLift:
    """Points of the scissor map's chart (k, 2) to the surface (k, 3), through the nearest chart triangle.

    Also returns each point's distance outside the chart (0 inside), in the chart's units.
    """

    def __init__(self, surface: TargetSurface, smap: ScissorMap):
        self.V, self.F, self.U = surface.V, surface.F, smap.flat
        self._U3 = np.c_[smap.flat, np.zeros(len(smap.flat))]
        self._span = float(np.ptp(smap.flat, axis=0).max())

    def faces(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nearest chart triangle (k,) of each point and the distance (k,) outside the chart."""
        sq, fi, _ = point_mesh_squared_distance(np.c_[u, np.zeros(len(u))], self._U3, self.F)
        return np.asarray(fi, np.int64), np.sqrt(np.maximum(np.asarray(sq, float), 0.0))

    def _lift(self, u: np.ndarray):
        fi, d = self.faces(u)
        f = self.F[fi]
        bc = _barycentric(u, self.U[f[:, 0]], self.U[f[:, 1]], self.U[f[:, 2]])
        return np.einsum("nk,nkd->nd", bc, self.V[f]), d, f

    def __call__(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        X, d, _ = self._lift(u)
        return X, d

    def jacobian(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The lifted points (k, 3) and their derivatives (k, 3, 2): each chart triangle maps affinely."""
        X, _, f = self._lift(u)
        E3 = np.stack([self.V[f[:, 1]] - self.V[f[:, 0]], self.V[f[:, 2]] - self.V[f[:, 0]]], axis=2)
        E2 = np.stack([self.U[f[:, 1]] - self.U[f[:, 0]], self.U[f[:, 2]] - self.U[f[:, 0]]], axis=2)
        return X, E3 @ np.linalg.inv(E2)

    def outside(self, u: np.ndarray) -> np.ndarray:
        """How far (k,) the lifted points lie from the surface, in its units: 0 inside the chart; outside,
        the chart triangle's plane continued beyond the boundary (the chart itself is closed, so its own
        distances across the beams are shorter than on the surface by the opening's stretch)."""
        X, d = self(u)
        out = np.zeros(len(u))
        far = d > 1e-9 * self._span
        if far.any():
            sq, _, _ = point_mesh_squared_distance(X[far], self.V, self.F)
            out[far] = np.sqrt(np.maximum(np.asarray(sq, float), 0.0))
        return out


@dataclass(frozen=True)
class FanLines:
    """The flat lines of a fanned net: family 0 beam ``j`` and family 1 beam ``i`` of the lattice.

    A line is a point on the layout's axis and a unit direction. ``point(i, j)`` is their crossing.
    """

    origin: np.ndarray      # (2,) the lattice's affine origin o
    a: np.ndarray           # (2,) lattice step along family 0
    b: np.ndarray           # (2,) lattice step along family 1
    axis: np.ndarray        # (2,) unit e, the bisector
    centre: np.ndarray      # (2,) a point of the axis (the footprint's centre)
    half: float             # half the footprint's extent along e
    mid: float              # the footprint's middle along e (from centre)
    kappa: float

    def _line(self, base: np.ndarray, d: np.ndarray):
        """The axis crossing (k, 2) and new unit direction (k, 2) of lines through ``base`` (k, 2) along ``d`` (2,)."""
        e, n = self.axis, np.array([-self.axis[1], self.axis[0]])
        c = base - self.centre
        s = -(c @ n) / (d @ n)
        x = (c + s[:, None] * d) @ e
        t = np.clip((x - self.mid) / self.half, -1.0, 1.0)  # lines crossing the axis beyond the footprint keep the end angle
        phi = np.arctan2(d @ n, d @ e) * (1.0 + self.kappa * (1.0 - 2.0 * t * t))
        return self.centre + x[:, None] * e, np.cos(phi)[:, None] * e + np.sin(phi)[:, None] * n

    def points(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Flat joint positions (k, 2) of lattice indices ``i``, ``j`` (k,)."""
        i, j = np.asarray(i, float), np.asarray(j, float)
        p0, d0 = self._line(self.origin + j[:, None] * self.b, self.a)   # family 0: j const
        p1, d1 = self._line(self.origin + i[:, None] * self.a, self.b)   # family 1: i const
        # p0 + s d0 = p1 + r d1
        rhs = p1 - p0
        det = d0[:, 0] * (-d1[:, 1]) - d0[:, 1] * (-d1[:, 0])
        s = (rhs[:, 0] * (-d1[:, 1]) - rhs[:, 1] * (-d1[:, 0])) / det
        return p0 + s[:, None] * d0


def fan_lines(smap: ScissorMap, chart_points: np.ndarray, I: np.ndarray, J: np.ndarray, kappa: float) -> FanLines:
    """Fit the affine lattice to the lattice points' chart positions (k, 2) at indices ``I``, ``J`` (k,)."""
    A = np.c_[np.ones(len(I)), I, J]
    coef, *_ = np.linalg.lstsq(A, chart_points, rcond=None)
    o, a, b = coef
    ua, ub = a / np.linalg.norm(a), b / np.linalg.norm(b)
    e = ua + ub
    if np.linalg.norm(e) < 1e-9:
        raise InputError("the lattice's two families are antiparallel: no layout axis")
    e = e / np.linalg.norm(e)
    centre = smap.flat.mean(axis=0)
    xs = (smap.flat - centre) @ e
    return FanLines(o, a, b, e, centre, float(0.5 * np.ptp(xs)), float(0.5 * (xs.max() + xs.min())), float(kappa))


def _index(active: np.ndarray) -> np.ndarray:
    """Node numbers of the active lattice points, −1 elsewhere (same shape)."""
    G = -np.ones(active.shape, np.int64)
    G[active] = np.arange(int(active.sum()))
    return G


def _grid_pairs(G: np.ndarray):
    """Segments (family 0 along the first index, family 1 along the second) and beam triples of a node grid."""
    segs, fam, trip = [], [], []
    for k, (a, c) in enumerate(((G[:-1, :], G[1:, :]), (G[:, :-1], G[:, 1:]))):
        m = (a >= 0) & (c >= 0)
        segs.append(np.c_[a[m], c[m]])
        fam.append(np.full(int(m.sum()), k))
    for A, B, C in ((G[:-2, :], G[1:-1, :], G[2:, :]), (G[:, :-2], G[:, 1:-1], G[:, 2:])):
        m = (A >= 0) & (B >= 0) & (C >= 0)
        trip.append(np.c_[A[m], B[m], C[m]])
    return (np.concatenate(segs).astype(np.int64), np.concatenate(fam).astype(np.int64),
            np.concatenate(trip).astype(np.int64))


def _place_on_surface(lift: ChartLift, u0: np.ndarray, flat: np.ndarray, segs: np.ndarray, trip: np.ndarray,
                      spacing: float) -> np.ndarray:
    """Chart positions (k, 2) whose surface points keep the flat segment lengths (least squares from ``u0``)."""
    import scipy.sparse as sp
    from scipy.optimize import least_squares

    ell = np.linalg.norm(flat[segs[:, 1]] - flat[segs[:, 0]], axis=1)
    n, ns, nt = len(u0), len(segs), len(trip)
    z0 = u0.ravel().copy()
    # the constant rows: second differences along the beams, and the anchor
    rows = np.repeat(np.arange(2 * nt), 3)
    cols = (2 * trip[:, None, :] + np.arange(2)[None, :, None]).reshape(2 * nt, 3).ravel()
    vals = np.tile([1.0, -2.0, 1.0], 2 * nt)
    D2 = sp.csr_matrix((vals * SMOOTH / spacing, (rows, cols)), shape=(2 * nt, 2 * n))
    A = sp.identity(2 * n, format="csr") * (ANCHOR / spacing)
    seg_rows = np.repeat(np.arange(ns), 4)
    seg_cols = (2 * segs[:, :, None] + np.arange(2)).reshape(ns, 4).ravel()

    def residual(z):
        X, _ = lift(z.reshape(-1, 2))
        r1 = (np.linalg.norm(X[segs[:, 1]] - X[segs[:, 0]], axis=1) - ell) / spacing
        return np.r_[r1, D2 @ z, A @ (z - z0)]

    def jacobian(z):
        X, M = lift.jacobian(z.reshape(-1, 2))
        d = X[segs[:, 1]] - X[segs[:, 0]]
        d = d / np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]
        ga = -np.einsum("sd,sdk->sk", d, M[segs[:, 0]])  # d r / d u_a, (s, 2)
        gb = np.einsum("sd,sdk->sk", d, M[segs[:, 1]])
        J1 = sp.csr_matrix((np.c_[ga, gb].ravel() / spacing, (seg_rows, seg_cols)), shape=(ns, 2 * n))
        return sp.vstack([J1, D2, A], format="csr")

    sol = least_squares(residual, z0, jac=jacobian, x_scale=spacing, max_nfev=100, xtol=1e-8)
    return sol.x.reshape(-1, 2)


def fanned_net(surface: TargetSurface, smap: ScissorMap, angle: float, spacing: float, kappa: float,
               max_rounds: int = 8) -> Net:
    """The fanned net of fan ``kappa`` (see the module): joints on the surface, their flat positions, segments.

    ``angle`` (radians) and ``spacing`` as for :func:`.net.surface_net`; ``kappa = 0`` lays the evenly
    spaced lattice's own affine grid.
    """
    if not -0.5 < kappa < 0.5:
        raise InputError(f"a fan of {kappa:g} would close the flat layout's end lines: keep it within (-0.5, 0.5)")
    F = surface.F
    uv = net_coordinates(smap, angle, spacing)
    uv = uv - np.floor(uv.min(0))
    hi = np.ceil(uv.max(0)).astype(int)
    I, J = np.meshgrid(np.arange(-MARGIN, hi[0] + 1 + MARGIN), np.arange(-MARGIN, hi[1] + 1 + MARGIN), indexing="ij")
    fi, bc = _locate(np.c_[I.ravel(), J.ravel()].astype(float), uv, F)
    inside = (fi >= 0).reshape(I.shape)
    if inside.sum() < 4:
        raise InputError(f"{surface.path}: no beam net fits on the surface at spacing {spacing:.4g}: the spacing is "
                         f"too large for it")
    chart = np.zeros(I.shape + (2,))
    chart[inside] = np.einsum("nk,nkd->nd", bc[fi >= 0], smap.flat[F[fi[fi >= 0]]])
    lines = fan_lines(smap, chart[inside], I[inside], J[inside], kappa)
    flat = lines.points(I.ravel(), J.ravel()).reshape(I.shape + (2,))
    lift = ChartLift(surface, smap)
    active, blocked = inside.copy(), np.zeros_like(inside)
    U = chart.copy()
    for rnd in range(max_rounds + 1):
        segs, _, trip = _grid_pairs(_index(active))
        U[active] = _place_on_surface(lift, U[active], flat[active], segs, trip, spacing)
        out = lift.outside(U[active])
        far = np.zeros_like(active)
        far[active] = out > OUTSIDE * spacing
        active &= ~far
        blocked |= far
        if rnd == max_rounds or not _grow(active, blocked, U, lift, spacing):
            break
    segs, fam, _ = _grid_pairs(_index(active))
    # where neighbouring lines of a family come close or cross (a strong fan, far from the axis), the net ends
    step = flat[active][segs[:, 1]] - flat[active][segs[:, 0]]
    along = np.einsum("sd,sd->s", step, np.where(fam[:, None] == 0, lines.a, lines.b))
    along = along / np.where(fam == 0, np.linalg.norm(lines.a), np.linalg.norm(lines.b))
    pinched = along < MIN_STEP * spacing
    if pinched.any():
        n_before = int(active.sum())
        idx = np.argwhere(active)
        active[tuple(idx[np.unique(segs[pinched])].T)] = False
        if active.sum() < 0.5 * n_before:
            raise InputError(f"{surface.path}: with a fan of {kappa:g}, neighbouring beams of one family cross "
                             f"inside the flat layout: the fan is too strong for this surface")
        segs, fam, _ = _grid_pairs(_index(active))
    X, _ = lift(U[active])
    joints, segments, family, fl = _largest_piece(*_tidy(X, segs, fam, flat[active]))
    if len(segments) == 0:
        raise InputError(f"{surface.path}: no fanned net (fan {kappa:g}) fits on the surface at spacing {spacing:.4g}")
    _check_connected(segments, len(joints), surface.path, spacing)
    return Net(joints, fl, segments, family)


def _largest_piece(joints, segments, family, flat):
    """The net's largest connected piece (a fanned net can pinch off a corner of the surface)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    n = len(joints)
    if len(segments) == 0:
        return joints, segments, family, flat
    adj = sp.coo_matrix((np.ones(len(segments)), (segments[:, 0], segments[:, 1])), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    big = np.bincount(label[segments[:, 0]]).argmax()
    keep = label[segments[:, 0]] == big
    if keep.all():
        return joints, segments, family, flat
    return _tidy(joints, segments[keep], family[keep], flat)


def _grow(active: np.ndarray, blocked: np.ndarray, U: np.ndarray, lift: ChartLift, spacing: float) -> int:
    """Activate the lattice points next to the net that its neighbours predict inside the surface; how many."""
    n0, n1 = active.shape
    guess = np.full(U.shape, np.nan)
    A = np.pad(active, 2)
    P = np.pad(U, ((2, 2), (2, 2), (0, 0)))
    for di in (-1, 1):
        for dj in (-1, 1):  # a parallelogram with an active corner
            ok = A[2 + di:2 + di + n0, 2:2 + n1] & A[2:2 + n0, 2 + dj:2 + dj + n1] & A[2 + di:2 + di + n0, 2 + dj:2 + dj + n1]
            g = P[2 + di:2 + di + n0, 2:2 + n1] + P[2:2 + n0, 2 + dj:2 + dj + n1] - P[2 + di:2 + di + n0, 2 + dj:2 + dj + n1]
            take = ok & np.isnan(guess[..., 0])
            guess[take] = g[take]
    for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):  # or a straight continuation along a beam
        ok = A[2 + di:2 + di + n0, 2 + dj:2 + dj + n1] & A[2 + 2 * di:2 + 2 * di + n0, 2 + 2 * dj:2 + 2 * dj + n1]
        g = 2 * P[2 + di:2 + di + n0, 2 + dj:2 + dj + n1] - P[2 + 2 * di:2 + 2 * di + n0, 2 + 2 * dj:2 + 2 * dj + n1]
        take = ok & np.isnan(guess[..., 0])
        guess[take] = g[take]
    cand = ~active & ~blocked & ~np.isnan(guess[..., 0])
    if not cand.any():
        return 0
    ok = lift.outside(guess[cand]) <= GROW * spacing
    idx = np.argwhere(cand)[ok]
    blocked[tuple(np.argwhere(cand)[~ok].T)] = True
    active[tuple(idx.T)] = True
    U[tuple(idx.T)] = guess[cand][ok]
    return int(ok.sum())


@dataclass(frozen=True)
class FanCandidate:
    """One screened fan: its settings, and how its flat layout's own first deployment fits the surface.

    ``first_fit`` is the mean joint distance to the surface over its diagonal (the better of the
    deployment and its mirror image, after a rigid placement); ``None`` with a ``message`` when the
    net or its deployment failed.
    """

    kappa: float
    orientation: float
    segments: int = 0
    first_fit: float | None = None
    height: float = 0.0
    message: str = ""


def first_deployment_fit(surface: TargetSurface, net: Net, material, angle: float, steps: int, subdivision: int,
                         direction: str = "up") -> tuple[float, float]:
    """Deploy the net's flat layout freely (rest lengths from the flat state) and fit it onto the surface.

    Returns (mean distance over the diagonal, the deployment's height off its layout plane); raises
    ArithmeticError when the deployment does not reach ``angle``.
    """
    from ..deploy.simulate import DeployOptions, deploy, rest_length_solve
    from ..io.design import design_from_arrays
    from ..linkage.linkage import Linkage
    from .metrics import apply, mirror_image, place, surface_distances

    L = Linkage(design_from_arrays(np.c_[net.flat, np.zeros(len(net.flat))], net.segments), material,
                subdivision=subdivision)
    rest_length_solve(L)
    res = deploy(L, angle, DeployOptions(steps=steps, direction=direction))
    if not res.converged:
        raise ArithmeticError(res.message)
    jv = np.asarray(L.graph.joint_vertex)
    Y, n = L.joint_positions(), np.asarray(L.graph.layout_normal, float)
    fits = []
    for Yc in (Y, mirror_image(Y, n)):  # the mirrored layout deploys to the mirror image
        T = place(surface, Yc, net.joints[jv])
        fits.append(float(np.mean(surface_distances(surface, apply(T, Yc)))) / surface.diagonal)
    return min(fits), float(np.ptp(Y @ n))


def screen_fans(surface: TargetSurface, material, angle_deg: float, flat_angle_deg: float, spacing: float,
                orientation: float = 0.0, kappas=None, steps: int = 30, subdivision: int = 8,
                direction: str = "up", on_candidate=None, workers: int = 1) -> list[FanCandidate]:
    """Every fan ``kappas`` (default :data:`FAN_KAPPAS`) about both bisectors (``orientation`` and ``orientation + 90``), each laid on the
    surface and deployed freely from its flat layout; sorted best first (failed ones last).

    ``on_candidate(FanCandidate)`` is called after each. With ``workers`` of 2 the two bisectors are
    screened side by side in two processes (the same figures; on two cores about half the time).
    """
    kappas = FAN_KAPPAS if kappas is None else tuple(kappas)
    jobs = [(surface, material, angle_deg, flat_angle_deg, spacing, o, kappas, steps, subdivision, direction)
            for o in (orientation, orientation + 90.0)]
    found = {}
    if workers > 1:
        from .processes import in_processes

        for i, cands in in_processes(_screen_bisector, jobs, workers):
            found[i] = cands
            for c in cands if on_candidate is not None else ():
                on_candidate(c)
    else:
        for i, job in enumerate(jobs):
            found[i] = _screen_bisector(*job, on_candidate=on_candidate)
    out = [c for i in range(len(jobs)) for c in found[i]]  # in the jobs' order, however they finished
    return sorted(out, key=screen_rank(surface))


#: a first deployment that rises less than this share of the diagonal off its plane stayed flat
#: (a planar deployment misses a curved target; see ``run.judge``)
FLAT_RISE = 0.01


def screen_rank(surface: TargetSurface):
    """The screen's sort key: failed fans last; on a surface further than :data:`FLAT_RISE` of its diagonal
    from its plane, a fan whose first deployment stayed flat after every one that buckled; then the first fit.

    A first deployment in the plane fits a gently curved target closely (the saddle over a disc: 1.51 % flat
    against 1.96 % buckled), but its layout's planar opening is stable, and the design that follows tends to
    stay in the plane, which misses the target whatever its fit (the wings' fan of -0.1: 1.78 % flat)."""
    from .surface import plane_deviation

    curved = plane_deviation(surface) > FLAT_RISE

    def key(c: FanCandidate):
        if c.first_fit is None:
            return (2, 0.0)
        return (int(curved and c.height <= FLAT_RISE * surface.diagonal), c.first_fit)

    return key


def _screen_bisector(surface, material, angle_deg, flat_angle_deg, spacing, o, kappas, steps, subdivision, direction,
                     on_candidate=None) -> list[FanCandidate]:
    """The fans of one bisector (see :func:`screen_fans`)."""
    from .scissor import scissor_map

    theta, alpha0 = np.radians(angle_deg), np.radians(flat_angle_deg)
    smap = scissor_map(surface, theta, alpha0, np.radians(o))
    out = []
    for k in kappas:
        try:
            net = fanned_net(surface, smap, theta, spacing, float(k))
            fit, h = first_deployment_fit(surface, net, material, theta, steps, subdivision, direction)
            c = FanCandidate(float(k), float(o), net.num_segments, fit, h)
        except (InputError, ArithmeticError) as exc:
            c = FanCandidate(float(k), float(o), message=str(exc).splitlines()[0][:200])
        out.append(c)
        if on_candidate is not None:
            on_candidate(c)
    return out
