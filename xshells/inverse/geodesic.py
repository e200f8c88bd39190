"""A geodesic beam net: two families of geodesics of the target surface.

Why geodesics. A beam's stiff bending is about the surface normal (its width
lies in the surface), so on the deployed shell that bending is the beams'
geodesic curvature. Along geodesics it is zero: the deployed state stores
only the soft bending and the twist, while the same net laid flat has to
bend its beams in their stiff direction wherever geodesics spread or gather
(which is where the surface is curved). The planar opening then costs more
than buckling onto the surface, and the layout rises the way the surface does.
Measured on the shared hyperbolic paraboloid: the evenly spaced net fits to
2.99 % of the diagonal (mean), this one to 0.56 % (``xshells inverse``).

Construction. As in :mod:`.graded` (which this module shares its tracing
with): a middle geodesic through the surface's centre runs across the beams'
bisector ``g``; from seeds on it, ``2 s sin(α/2)`` apart, one geodesic of
each family leaves at ``±α/2`` from ``g`` and runs straight (its tangent is
carried from point to point, only its normal part removed) until it leaves
the surface. The families then grow outward, one joint spacing past their
last joints. Geodesics of one family gather on a dome and may cross or
meet a curve of the other family more than once, so the joints are not
simply all the crossings: they are found by a flood fill from the seeds,
each joint the crossing of its two curves closest (along the shared curve)
to its accepted neighbour, and kept only where the segment it makes lies
between ``MIN_SEGMENT`` and ``MAX_SEGMENT`` spacings. Quads whose four
sides all pass are the net; its largest edge-connected piece is kept.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from ..errors import InputError
from .graded import _Curve, _Field, _Projector, _trace, all_crossings, surface_centre
from .surface import TargetSurface

#: a joint-to-joint segment shorter than this many spacings means curves gather (or meet twice): dropped
MIN_SEGMENT = 0.35
#: and longer than this many spacings, that they spread too far for one beam segment
MAX_SEGMENT = 2.5


def trace_geodesics(project, field, seeds, sign, step, max_steps):
    """Geodesics through each seed, both ways, leaving along the field (``sign`` as in
    :func:`.graded._trace`), until they leave the surface: a list of (k_i, 3) point arrays and,
    per curve, the index of its seed in it."""
    return _trace(project, field, seeds, sign, step, max_steps, straight=True)


class _Net:
    """The two families keyed by integer labels, and their crossings, cached."""

    def __init__(self, trace, chart, on_curve):
        self.trace, self.chart, self.on_curve = trace, chart, on_curve
        self.curves = ({}, {})
        self._cross = {}

    def add(self, family, key, seed):
        (pts,), _ = self.trace(seed[None], +1.0 if family == 0 else -1.0)
        self.curves[family][key] = _Curve(pts, self.chart)
        if self.on_curve is not None:
            self.on_curve()

    def crossings(self, i, j):
        if i not in self.curves[0] or j not in self.curves[1]:
            return []
        if (i, j) not in self._cross:
            self._cross[i, j] = all_crossings(self.curves[0][i], self.curves[1][j])
        return self._cross[i, j]

    def near(self, i, j, family, s_ref):
        """The crossing (i, j) closest to arc length ``s_ref`` on the shared curve (A_i when ``family`` is 0,
        B_j when 1), with that distance; or None."""
        hits = self.crossings(i, j)
        if not hits:
            return None
        d = [abs(h[1 + family] - s_ref) for h in hits]
        k = int(np.argmin(d))
        return hits[k], d[k]


def _flood(net: _Net, seeds: dict, spacing: float) -> dict:
    """Joints reachable from the seed joints through segments of acceptable length: {(i, j): (p, s_a, s_b)}."""
    joints = dict(seeds)
    queue = deque(seeds)
    lo, hi = MIN_SEGMENT * spacing, MAX_SEGMENT * spacing
    while queue:
        i, j = queue.popleft()
        _, sa, sb = joints[i, j]
        for di, dj in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            key = (i + di, j + dj)
            if key in joints:
                continue
            # moving along A_i (j changes) or along B_j (i changes)
            family, s_ref = (0, sa) if di == 0 else (1, sb)
            found = net.near(*key, family, s_ref)
            if found is None or not lo <= found[1] <= hi:
                continue
            joints[key] = found[0]
            queue.append(key)
    return joints


def _segment_ok(a, b, family, spacing):
    d = abs(a[1 + family] - b[1 + family])
    return MIN_SEGMENT * spacing <= d <= MAX_SEGMENT * spacing


def _largest_piece(quads):
    """The quads (list of 4-tuples of keys) edge-connected to the largest group."""
    parent = list(range(len(quads)))

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    owner = {}
    for q, quad in enumerate(quads):
        for a, b in zip(quad, quad[1:] + quad[:1]):
            e = (min(a, b), max(a, b))
            if e in owner:
                parent[find(q)] = find(owner[e])
            else:
                owner[e] = q
    roots = [find(q) for q in range(len(quads))]
    if not roots:
        return []
    best = max(set(roots), key=roots.count)
    return [quad for quad, r in zip(quads, roots) if r == best]


def geodesic_net_quads(surface: TargetSurface, chart, axis: np.ndarray, angle: float, spacing: float,
                       on_curve=None):
    """The geodesic net's joints and quads.

    Parameters
    ----------
    surface : TargetSurface
    chart : callable
        Maps surface points (k, 3) to a planar chart (k, 2) of the surface;
        crossings are found there.
    axis : (3,) float
        The beams' mean bisector ``g`` at the centre (unit).
    angle, spacing : float
        Crossing angle at the middle line (radians) and the joint spacing there.
    on_curve : callable, optional
        Called with no arguments after each curve is traced (progress).

    Returns
    -------
    joints : (k, 3) float
    segments : (s, 2) int64
        Joint pairs of the two families, quads only (no dangling segments).
    """
    project = _Projector(surface)
    centre = surface_centre(surface, project)
    d_max = float(np.abs((surface.V - centre) @ axis).max())
    field = _Field(axis, centre, d_max, angle, 0.0)
    step = spacing / 8.0
    max_steps = int(4.0 * surface.diagonal / step) + 10

    def trace(P, sign):
        return trace_geodesics(project, field, P, sign, step, max_steps)

    # the middle curve: a geodesic across the bisector, seeds on it by arc length
    (middle,), (k0,) = trace(centre[None], 0)
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(middle, axis=0), axis=1))]
    s -= s[k0]
    gap = 2.0 * spacing * np.sin(angle / 2.0)
    keys = np.arange(int(np.ceil(s[0] / gap)), int(np.floor(s[-1] / gap)) + 1)
    seeds = project(np.column_stack([np.interp(keys * gap, s, middle[:, d]) for d in range(3)]))[0]
    net = _Net(trace, chart, on_curve)
    for k, p in zip(keys, seeds):
        net.add(0, int(k), p)
        net.add(1, int(k), p)
    seed_joints = {}
    for k, p in zip(keys, seeds):
        hits = net.crossings(int(k), int(k))
        if hits:
            seed_joints[int(k), int(k)] = min(hits, key=lambda h: np.linalg.norm(h[0] - p))
    _grow(net, seed_joints, spacing, int(4.0 * surface.diagonal / spacing) + 4)
    joints = _flood(net, seed_joints, spacing)
    quads = []
    for (i, j) in joints:
        quad = [(i, j), (i, j + 1), (i + 1, j + 1), (i + 1, j)]
        if all(q in joints for q in quad) and all(
                _segment_ok(joints[a], joints[b], 0 if a[0] == b[0] else 1, spacing)
                for a, b in zip(quad, quad[1:] + quad[:1])):
            quads.append(tuple(quad))
    quads = _largest_piece(quads)
    if not quads:
        raise InputError(f"{surface.path}: no geodesic beam net fits on the surface at spacing {spacing:.4g}: "
                         f"the spacing is too large for it")
    used = sorted({k for q in quads for k in q})
    ids = {k: n for n, k in enumerate(used)}
    segs = sorted({(min(ids[a], ids[b]), max(ids[a], ids[b])) for q in quads for a, b in zip(q, q[1:] + q[:1])})
    X = project(np.array([joints[k][0] for k in used]))[0]
    return X, np.array(segs, np.int64)


def _grow(net: _Net, seed_joints: dict, spacing: float, limit: int) -> None:
    """Adds curves beyond each family's outermost ones, seeded on a curve of the other family one joint
    spacing past the last joint the flood fill reaches on it, until no new curve finds room."""
    for family in (0, 1):
        for sign in (1, -1):
            for _ in range(limit):
                joints = _flood(net, seed_joints, spacing)
                own = net.curves[family]
                last = max(own) if sign > 0 else min(own)
                candidates = []
                for j, curve in net.curves[1 - family].items():
                    pair = [(last, j), (last - sign, j)] if family == 0 else [(j, last), (j, last - sign)]
                    if not all(p in joints for p in pair):
                        continue
                    along = [joints[p][2 if family == 0 else 1] for p in pair]
                    seed = curve.at(2 * along[0] - along[1])
                    if seed is not None:
                        candidates.append((j, seed))
                if not candidates:
                    break
                candidates.sort(key=lambda c: c[0])
                net.add(family, last + sign, candidates[len(candidates) // 2][1])

