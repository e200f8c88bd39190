"""A graded beam net: two families of curves whose crossing angle varies across the surface.

Why graded. A net whose joints are evenly spaced along both families (a
Chebyshev net, as :func:`.net.surface_net` lays) flattens to a nearly
uniform grid, and a uniform grid opens *in the plane* at almost no cost: its
planar deployment is stable all the way and never buckles onto the surface
(on the shared spherical cap: 0.0065 N·mm in the plane against 1.4e4 on the
cap). An X-shell reaches its shape because its layout is incompatible with a
planar opening (paper §4, "the rigid scissor mechanisms of the linkage
become incompatible"). The paper's layouts carry Chebyshev defects (opposite
sides of a quad that differ) of about 7 %.

This net builds that incompatibility in. With ``e₁`` the beams' mean
bisector and ``d = (p − c)·e₁`` the signed distance of a surface point from
the plane through the centre ``c`` normal to ``e₁``, the crossing angle is

    ω(d) = α + Δ (1 − 2 (d / d_max)²)

(``Δ`` the grading, negative: narrower crossings on the middle line, wider
ones toward the sides). The two families are the curves whose tangents make
the angles ``±ω/2`` with ``g``, the unit tangent projection of ``e₁``: they
are traced on the surface from seeds along the middle curve (the curve
through ``c`` along ``n × g``), the joints are their crossings. The seeds are
``2 s sin(ω₀/2)`` apart, so that the joints on the middle line are the
spacing ``s`` apart along each beam. Joint spacings then vary across the net
(on the shared cap, Chebyshev defects of 8 % median) while the layout still
closes: both families advance along ``e₁`` at almost the same rate, which is
what a layout closed to a small angle needs.

The curves are traced by midpoint steps projected back onto the surface
(libigl's closest points), with normals interpolated from the vertices; a
curve ends where a step leaves the surface (its boundary).
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from .surface import TargetSurface

#: a grading Δ of the crossing angle (radians) that works on a dome: on the shared spherical cap,
#: the evenly spaced net reaches a fit of 0.99 % of the diagonal, this one 0.37 %
DOME_GRADING = np.radians(-25.0)


class _Projector:
    """Closest points on a triangle mesh with smooth (vertex-interpolated) normals."""

    def __init__(self, surface: TargetSurface):
        import igl

        self.V, self.F = surface.V, surface.F
        self._igl = igl
        # one tree for every query (building it is most of a query's cost)
        self._tree = igl.AABB()
        self._tree.init(self.V, self.F)
        fn = surface.face_normals
        vn = np.zeros_like(self.V)
        np.add.at(vn, self.F.ravel(), np.repeat(fn * surface.face_areas[:, None], 3, axis=0))
        self.vn = vn / np.maximum(np.linalg.norm(vn, axis=1), 1e-300)[:, None]

    def __call__(self, P: np.ndarray):
        """Closest points (k, 3), their unit normals (k, 3) and the distances (k,)."""
        sq, fi, C = self._tree.squared_distance(self.V, self.F, np.ascontiguousarray(P, float))
        fi = np.asarray(fi, np.int64)
        C = np.asarray(C, float)
        f = self.F[fi]
        bc = self._igl.barycentric_coordinates(C, self.V[f[:, 0]], self.V[f[:, 1]], self.V[f[:, 2]])
        n = np.einsum("nk,nkd->nd", np.clip(bc, 0.0, 1.0), self.vn[f])
        n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
        return C, n, np.sqrt(np.maximum(sq, 0.0))


class _Field:
    """The beam directions ``cos(ω/2) g ± sin(ω/2) n × g`` at points of the surface."""

    def __init__(self, axis, centre, d_max, angle, grading):
        self.axis, self.centre, self.d_max = axis, centre, d_max
        self.angle, self.grading = angle, grading

    def omega(self, P):
        u = ((P - self.centre) @ self.axis) / self.d_max
        return self.angle + self.grading * (1.0 - 2.0 * u * u)

    def __call__(self, P, n, sign):
        g = self.axis[None] - n * (n @ self.axis)[:, None]
        g /= np.maximum(np.linalg.norm(g, axis=1), 1e-300)[:, None]
        e2 = np.cross(n, g)
        if sign == 0:  # the middle curve: across the bisector
            return e2
        w = self.omega(P)[:, None]
        return np.cos(w / 2) * g + sign * np.sin(w / 2) * e2


def _trace(project, field, seeds, sign, step, max_steps, straight=False):
    """Curves through each seed, both ways, until they leave the surface: a list of (k_i, 3) arrays
    and, per curve, the index of its seed point in it.

    The curves follow the field (midpoint steps projected back onto the
    surface) or, ``straight``, leave each seed along the field and then run
    straight on the surface (geodesics): the tangent is carried from point
    to point with only its normal part removed, half a step to the midpoint
    and a full step from the start along the tangent there.
    """
    halves = []
    for direction in (1.0, -1.0):
        P = seeds.copy()
        _, n, _ = project(P)
        T = direction * field(P, n, sign)
        alive = np.ones(len(P), bool)
        out = [[p.copy()] for p in P]
        for _ in range(max_steps):
            idx = np.flatnonzero(alive)
            if len(idx) == 0:
                break
            p, t = P[idx], T[idx]
            mid, nm, _ = project(p + 0.5 * step * t)
            t = _tangent(t, nm) if straight else direction * field(mid, nm, sign)
            q, nq, off = project(p + step * t)
            # a step that leaves the surface has met the boundary (inside, the projection moves a point
            # by about κh²/2 only)
            ok = off < 0.2 * step
            for k, i in enumerate(idx):
                if ok[k]:
                    out[i].append(q[k])
            P[idx[ok]] = q[ok]
            T[idx[ok]] = _tangent(t[ok], nq[ok]) if straight else direction * field(q[ok], nq[ok], sign)
            alive[idx[~ok]] = False
        halves.append(out)
    curves, origin = [], []
    for fwd, back in zip(*halves):
        curves.append(np.array(back[:0:-1] + fwd))
        origin.append(len(back) - 1)
    return curves, origin


def _tangent(t, n):
    """``t`` (k, 3) made tangent to the unit normals ``n`` (k, 3), unit."""
    t = t - n * np.einsum("kd,kd->k", n, t)[:, None]
    return t / np.maximum(np.linalg.norm(t, axis=1), 1e-300)[:, None]


def surface_centre(surface: TargetSurface, project) -> np.ndarray:
    """The surface point closest to the area-weighted centroid of its triangles, shape (3,)."""
    V, areas = surface.V, surface.face_areas
    centroid = (V[surface.F].mean(axis=1) * areas[:, None]).sum(0) / areas.sum()
    return project(centroid[None])[0][0]


def _middle_seeds(project, field, centre, spacing_on_middle, step, max_steps):
    """Points along the middle curve through ``centre``, ``spacing_on_middle`` apart by arc length,
    keyed by their signed index (0 at the centre)."""
    (curve,), (k0,) = _trace(project, field, centre[None], 0, step, max_steps)
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))]
    s -= s[k0]
    lo, hi = int(np.ceil(s[0] / spacing_on_middle)), int(np.floor(s[-1] / spacing_on_middle))
    keys = np.arange(lo, hi + 1)
    pts = np.column_stack([np.interp(keys * spacing_on_middle, s, curve[:, d]) for d in range(3)])
    return keys, project(pts)[0]


class _Curve:
    """A traced curve: its points in space and in the chart, and their arc lengths."""

    def __init__(self, points, chart):
        self.points = points
        self.chart = chart(points) if len(points) >= 2 else np.zeros((len(points), 2))
        self.s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))] if len(points) else np.zeros(0)

    def at(self, s):
        """The point at arc length ``s``, or None beyond the ends."""
        if len(self.points) < 2 or not self.s[0] <= s <= self.s[-1]:
            return None
        return np.array([np.interp(s, self.s, self.points[:, d]) for d in range(3)])


def all_crossings(a: "_Curve", b: "_Curve") -> list:
    """Every crossing of two curves in the chart, in the order of a's then b's segments: a list of
    (point (3,), arc length on a, arc length on b)."""
    if len(a.points) < 2 or len(b.points) < 2:
        return []
    lo = np.maximum(a.chart.min(0), b.chart.min(0))
    hi = np.minimum(a.chart.max(0), b.chart.max(0))
    if (lo > hi).any():
        return []
    a0, r = a.chart[:-1], np.diff(a.chart, axis=0)
    b0, s = b.chart[:-1], np.diff(b.chart, axis=0)
    den = r[:, None, 0] * s[None, :, 1] - r[:, None, 1] * s[None, :, 0]
    w = b0[None] - a0[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * s[None, :, 1] - w[..., 1] * s[None, :, 0]) / den
        u = (w[..., 0] * r[:, None, 1] - w[..., 1] * r[:, None, 0]) / den
    out = []
    for i, j in np.argwhere((t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)):
        ti, uj = float(t[i, j]), float(u[i, j])
        p = a.points[i] + ti * (a.points[i + 1] - a.points[i])
        out.append((p, a.s[i] + ti * (a.s[i + 1] - a.s[i]), b.s[j] + uj * (b.s[j + 1] - b.s[j])))
    return out


class _Families:
    """The two families of curves, keyed by their integer labels, and their crossings (the joints)."""

    def __init__(self, trace, chart):
        self.trace, self.chart = trace, chart
        self.curves = ({}, {})
        self._cross = {}
        self.on_curve = None

    def add(self, family, key, seed):
        (pts,), _ = self.trace(seed[None], +1.0 if family == 0 else -1.0)
        self.curves[family][key] = _Curve(pts, self.chart)
        if self.on_curve is not None:
            self.on_curve()

    def crossing(self, i, j):
        """Joint (i, j): (point, arc length along A_i, arc length along B_j) or None."""
        if (i, j) not in self._cross:
            hits = all_crossings(self.curves[0][i], self.curves[1][j])
            self._cross[i, j] = hits[0] if hits else None
        return self._cross[i, j]

    def grow(self, family, step_sign) -> bool:
        """Seeds one more curve beyond the family's last (``step_sign`` +1: above the largest label, −1:
        below the smallest) on a curve of the other family, one joint spacing past its last joint there.
        Returns whether a curve was added."""
        own, other = self.curves[family], self.curves[1 - family]
        last = max(own) if step_sign > 0 else min(own)
        new = last + step_sign
        candidates = []
        for j in sorted(other):
            pair = [(last, j), (last - step_sign, j)] if family == 0 else [(j, last), (j, last - step_sign)]
            hits = [self.crossing(*p) for p in pair]
            if any(h is None for h in hits):
                continue
            along = [h[2] if family == 0 else h[1] for h in hits]  # arc lengths on the other family's curve
            seed = other[j].at(2 * along[0] - along[1])
            if seed is not None:
                candidates.append(seed)
        if not candidates:
            return False
        self.add(family, new, candidates[len(candidates) // 2])
        return True


def graded_net_quads(surface: TargetSurface, chart, axis: np.ndarray, angle: float, spacing: float,
                     grading: float = DOME_GRADING, on_curve=None):
    """The graded net's joints and quads.

    Parameters
    ----------
    surface : TargetSurface
    chart : callable
        Maps surface points (k, 3) to a planar chart (k, 2) of the surface
        (the scissor map does); crossings are found there.
    axis : (3,) float
        The beams' mean bisector ``e₁`` (unit).
    angle, spacing : float
        Mean crossing angle (radians) and the joint spacing on the middle line.
    grading : float
        Δ (radians).
    on_curve : callable, optional
        Called with no arguments after each curve is traced (progress).

    Returns
    -------
    joints : (k, 3) float
    segments : (s, 2) int64
        Joint pairs of the two families, quads only (no dangling segments).

    The curves seeded on the middle curve reach only the part of the
    surface that their crossings span (a diamond around it); the families
    then grow outward, each new curve seeded on a curve of the other family
    one joint spacing past its last joint, until no new curve finds room.
    """
    project = _Projector(surface)
    V = surface.V
    centre = surface_centre(surface, project)
    d = (V - centre) @ axis
    d_max = float(np.abs(d).max())
    omega0 = angle + grading
    if not 0.0 < omega0 < np.pi or not 0.0 < angle - grading < np.pi:
        raise InputError(f"the crossing angle would leave (0°, 180°) across the net (mean {np.degrees(angle):g}°, "
                         f"grading {np.degrees(grading):g}°)")
    field = _Field(axis, centre, d_max, angle, grading)
    step = spacing / 8.0
    max_steps = int(4.0 * surface.diagonal / step) + 10
    keys, seeds = _middle_seeds(project, field, centre, 2.0 * spacing * np.sin(omega0 / 2.0), step, max_steps)
    fams = _Families(lambda P, sign: _trace(project, field, P, sign, step, max_steps), chart)
    fams.on_curve = on_curve
    for k, p in zip(keys, seeds):
        fams.add(0, int(k), p)
        fams.add(1, int(k), p)
    limit = int(4.0 * surface.diagonal / spacing) + 4
    for family in (0, 1):
        for sign in (1, -1):
            for _ in range(limit):
                if not fams.grow(family, sign):
                    break
    joints = {}
    for i in fams.curves[0]:
        for j in fams.curves[1]:
            hit = fams.crossing(i, j)
            if hit is not None:
                joints[(i, j)] = hit[0]
    ids = {key: n for n, key in enumerate(joints)}
    segs = set()
    for (i, j) in joints:
        quad = [(i, j), (i, j + 1), (i + 1, j + 1), (i + 1, j)]
        if all(q in ids for q in quad):
            for a, b in zip(quad, quad[1:] + quad[:1]):
                segs.add((min(ids[a], ids[b]), max(ids[a], ids[b])))
    if not segs:
        raise InputError(f"{surface.path}: no beam net fits on the surface at spacing {spacing:.4g}: the spacing is "
                         f"too large for it")
    used = sorted({v for s in segs for v in s})
    remap = {v: n for n, v in enumerate(used)}
    X = np.array(list(joints.values()))[used]
    X = project(X)[0]
    S = np.array(sorted((remap[a], remap[b]) for a, b in segs), np.int64)
    return X, S
