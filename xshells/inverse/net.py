"""Beam nets on a target surface: joints on the surface and their flat positions.

:func:`surface_net` lays two beam families along the directions
``cos(α/2) e₁ ± sin(α/2) e₂`` of a scissor map's director (``e₂ = n × e₁``).
It solves two Poisson problems for coordinates ``u``, ``v`` whose gradients
are, face by face, those that make ``u`` constant along the second family
and advance by one per ``spacing`` along the first (and the same with the
roles swapped): the beams are the integer level lines of ``u`` and ``v``,
the joints their crossings, found by point location in the (u, v) plane.
The scissor map then gives each joint's flat position from the same
barycentric coordinates, so the flat and deployed nets share their
segments' lengths to the discretization's accuracy.

:func:`read_net` reads a designer's own quad net instead.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..design.fitting import point_mesh_squared_distance
from ..errors import InputError, check_input_file
from .scissor import PoissonSolver, ScissorMap
from .surface import TargetSurface


@dataclass(frozen=True)
class Net:
    """A two-family beam net.

    Attributes
    ----------
    joints : (k, 3) float
        Joint positions on (or near) the surface.
    flat : (k, 2) float or None
        Their flat, closed positions (None until flattened).
    segments : (s, 2) int64
        Joint pairs; ``segments[i, 0] → segments[i, 1]`` runs along the beam.
    family : (s,) int64
        0 or 1.
    """

    joints: np.ndarray = field(repr=False)
    flat: np.ndarray | None = field(repr=False)
    segments: np.ndarray = field(repr=False)
    family: np.ndarray = field(repr=False)

    @property
    def num_joints(self) -> int:
        return len(self.joints)

    @property
    def num_segments(self) -> int:
        return len(self.segments)

    def segment_lengths(self, flat: bool = False) -> np.ndarray:
        X = np.c_[self.flat, np.zeros(len(self.flat))] if flat else self.joints
        return np.linalg.norm(X[self.segments[:, 1]] - X[self.segments[:, 0]], axis=1)


def estimate_segments(surface: TargetSurface, spacing: float, angle: float) -> float:
    """About how many segments a net of this spacing and crossing angle has on the surface (a float:
    ``inf`` where a tiny spacing overflows it, so the caller's "too many segments" check still applies)."""
    # divide twice rather than by spacing²: below ~1e-154 the square underflows to 0, and int(round(inf))
    # raised OverflowError; a float count compares with the limit whatever its size
    with np.errstate(over="ignore", divide="ignore"):
        n = 2.0 * float(surface.area) / float(np.sin(angle)) / float(spacing) / float(spacing)
    return float(round(n)) if np.isfinite(n) else float(n)


def _beam_directions(smap: ScissorMap, angle: float):
    e1 = smap.director
    e2 = np.c_[-e1[:, 1], e1[:, 0]]
    c, s = np.cos(angle / 2), np.sin(angle / 2)
    return c * e1 + s * e2, c * e1 - s * e2


def net_coordinates(smap: ScissorMap, angle: float, spacing: float) -> np.ndarray:
    """(u, v) at the surface's vertices, shape (n, 2): integer level lines are the beams."""
    dp, dm = _beam_directions(smap, angle)

    def rot(d):
        return np.c_[-d[:, 1], d[:, 0]]

    # ∇u ⊥ d₋ (u constant along the second family), ∇u·d₊ = 1/spacing; likewise v
    gu = rot(dm) / ((rot(dm) * dp).sum(1) * spacing)[:, None]
    gv = rot(dp) / ((rot(dp) * dm).sum(1) * spacing)[:, None]
    solver = PoissonSolver(smap.frames)
    return np.c_[solver.solve(gu), solver.solve(gv)]


def _locate(points2, UV, F):
    """Face index and barycentric coordinates of 2D points in the (u, v) triangulation (−1 outside)."""
    import igl

    UV3 = np.c_[UV, np.zeros(len(UV))]
    Q = np.c_[points2, np.zeros(len(points2))]
    sq, fi, C = point_mesh_squared_distance(Q, UV3, F)
    fi = np.asarray(fi, np.int64)
    bc = igl.barycentric_coordinates(np.asarray(C, float), UV3[F[fi, 0]], UV3[F[fi, 1]], UV3[F[fi, 2]])
    span = float(np.ptp(UV, axis=0).max())
    inside = np.asarray(sq) <= (1e-9 * span) ** 2
    return np.where(inside, fi, -1), np.asarray(bc)


def _tidy(joints, segments, family, flat):
    """Drop what a linkage cannot hold or an optimization cannot steer, repeated until nothing changes:
    points on no segment; dangling segments (a free end's rest length would drift, since nothing in the
    objective depends on it); straight-through points of valence 2 (two segments of one family) are
    merged into one segment."""
    while True:
        n = len(joints)
        deg = np.zeros((n, 2), int)
        np.add.at(deg, (segments[:, 0], family), 1)
        np.add.at(deg, (segments[:, 1], family), 1)
        total = deg.sum(1)
        dangling = (total[segments] == 1).any(axis=1)
        if dangling.any():
            segments, family = segments[~dangling], family[~dangling]
            continue
        through = np.flatnonzero((total == 2) & (deg.max(1) == 2))
        if len(through):
            j = int(through[0])
            s = np.flatnonzero((segments == j).any(1))
            a = segments[s[0]][segments[s[0]] != j][0]
            b = segments[s[1]][segments[s[1]] != j][0]
            # keep the family's direction: the segment that ends at j leads into the one that starts there
            first, second = (s[0], s[1]) if segments[s[0], 1] == j else (s[1], s[0])
            start = segments[first, 0] if segments[first, 1] == j else a
            end = segments[second, 1] if segments[second, 0] == j else b
            keep = np.setdiff1d(np.arange(len(segments)), s)
            segments = np.vstack([segments[keep], [start, end]])
            family = np.concatenate([family[keep], [family[s[0]]]])
            continue
        used = total > 0
        if used.all():
            return joints, segments, family, flat
        remap = -np.ones(n, np.int64)
        remap[used] = np.arange(int(used.sum()))
        joints, segments = joints[used], remap[segments]
        flat = flat[used] if flat is not None else None


def surface_net(surface: TargetSurface, smap: ScissorMap, angle: float, spacing: float) -> Net:
    """The net of beams along the scissor map's directions, ``spacing`` apart along the beams."""
    V, F = surface.V, surface.F
    uv = net_coordinates(smap, angle, spacing)
    uv = uv - np.floor(uv.min(0))  # integer offsets only: the lattice is where u, v are integers
    hi = np.ceil(uv.max(0)).astype(int)
    I, J = np.meshgrid(np.arange(hi[0] + 1), np.arange(hi[1] + 1), indexing="ij")
    fi, bc = _locate(np.c_[I.ravel(), J.ravel()].astype(float), uv, F)
    inside = fi >= 0
    w, f = bc[inside], F[fi[inside]]
    joints = np.einsum("nk,nkd->nd", w, V[f])
    flat = np.einsum("nk,nkd->nd", w, smap.flat[f])
    index = -np.ones(I.size, np.int64)
    index[inside] = np.arange(int(inside.sum()))
    index = index.reshape(I.shape)
    segs, fam = [], []
    for k, (a, b) in enumerate(((index[:-1, :], index[1:, :]), (index[:, :-1], index[:, 1:]))):
        ok = (a >= 0) & (b >= 0)
        segs.append(np.c_[a[ok], b[ok]])
        fam.append(np.full(int(ok.sum()), k))
    segments, family = np.concatenate(segs).astype(np.int64), np.concatenate(fam).astype(np.int64)
    if len(segments) == 0:
        raise InputError(f"{surface.path}: no beam net fits on the surface at spacing {spacing:.4g}: the spacing is "
                         f"too large for it")
    joints, segments, family, flat = _tidy(joints, segments, family, flat)
    _check_connected(segments, len(joints), surface.path, spacing)
    return Net(joints, flat, segments, family)


def _check_connected(segments, n, where, spacing):
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    A = sp.coo_matrix((np.ones(len(segments)), (segments[:, 0], segments[:, 1])), shape=(n, n))
    pieces, labels = connected_components(A, directed=False)
    if pieces > 1:
        sizes = np.bincount(labels)
        raise InputError(f"{where}: the beam net at spacing {spacing:.4g} falls apart into {pieces} pieces "
                         f"(of {', '.join(str(int(s)) for s in sorted(sizes)[::-1][:4])} joints): choose a smaller spacing")


# ------------------------------------------------------------ a designer's net
def read_net(path) -> tuple[np.ndarray, np.ndarray]:
    """A quad net from an OBJ: quad faces (``f``) or beam segments (``l``). Returns vertices (k, 3), segments (s, 2).

    Raises
    ------
    InputError
        A vertex line with fewer than three numbers, a face that is not a
        quad, a vertex where more than four segments meet, three joints
        joined in a triangle, or no segments at all: one line naming the
        file (and line where there is one).
    """
    verts, segs = [], set()
    check_input_file(path, "the net")
    try:
        fh = open(path, encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{path}: cannot read the net ({exc.strerror})") from None
    with fh:
        try:
            lines = fh.readlines()
        except UnicodeDecodeError:
            raise InputError(f"{path}: not a text OBJ file") from None
    seg_line = {}
    for ln, raw in enumerate(lines, 1):
        parts = raw.split()
        if not parts:
            continue
        if parts[0] == "v":
            if len(parts) < 4:  # a 2D vertex would make a ragged array and an internal error below
                raise InputError(f"{path}:{ln}: a vertex needs three numbers (x y z), got {len(parts) - 1}")
            try:
                verts.append([float(x) for x in parts[1:4]])
            except ValueError:
                raise InputError(f"{path}:{ln}: a vertex needs three numbers") from None
            continue
        if parts[0] not in ("f", "l"):
            continue
        try:
            idx = [int(p.split("/")[0]) for p in parts[1:]]
        except ValueError:
            raise InputError(f"{path}:{ln}: cannot read the vertex indices") from None
        idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
        if any(i < 0 or i >= len(verts) for i in idx):
            raise InputError(f"{path}:{ln}: a vertex index is out of range")
        if parts[0] == "f":
            if len(idx) != 4:
                raise InputError(f"{path}:{ln}: a face with {len(idx)} sides: --net must be a quad net "
                                 f"(quad faces or beam lines)")
            pairs = [(idx[k], idx[(k + 1) % 4]) for k in range(4)]
        else:
            pairs = list(zip(idx[:-1], idx[1:]))
        for a, b in pairs:
            if a == b:
                raise InputError(f"{path}:{ln}: a segment from a vertex to itself")
            key = (min(a, b), max(a, b))
            if key not in segs:
                segs.add(key)
                seg_line[key] = ln
    if not segs:
        raise InputError(f"{path}: no quad faces or lines: --net must be a quad net")
    V = np.asarray(verts, float)
    if not np.isfinite(V).all():
        raise InputError(f"{path}: a vertex has a non-finite coordinate")
    S = np.asarray(sorted(segs), np.int64)
    deg = np.bincount(S.ravel(), minlength=len(V))
    if deg.max() > 4:
        v = int(np.argmax(deg))
        raise InputError(f"{path}: vertex {v + 1} has {int(deg[v])} segments: a quad net has at most four at a joint")
    _check_no_triangle(S, path, seg_line)
    used = deg > 0
    remap = -np.ones(len(V), np.int64)
    remap[used] = np.arange(int(used.sum()))
    return V[used], remap[S]


def _check_no_triangle(S, path, seg_line) -> None:
    """A quad net has no 3-cycle: a diagonal across a quad (or any three joints joined in a ring) makes a cell
    the linkage cannot hold, and it surfaced only as a late "stopped" of the design. Faces are already
    checked to be quads (``read_net``); every joint has at most four neighbours, so one set intersection per
    segment is cheap."""
    nbrs = [set() for _ in range(int(S.max()) + 1)]
    for a, b in S:
        nbrs[a].add(int(b))
        nbrs[b].add(int(a))
    for a, b in S:
        common = nbrs[a] & nbrs[b]
        if common:
            c = min(common)
            tri = sorted((int(a), int(b), c))
            ln = max(seg_line[(tri[0], tri[1])], seg_line[(tri[0], tri[2])], seg_line[(tri[1], tri[2])])
            raise InputError(f"{path}:{ln}: vertices {tri[0] + 1}, {tri[1] + 1} and {tri[2] + 1} form a triangle: "
                             f"--net must be a quad net (four segments around each cell, no diagonals)")
