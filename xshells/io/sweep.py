"""Swept beam surfaces: a cross-section outline carried along rod centerlines.

Each rod becomes a closed triangle surface: one ring of outline points per
centerline vertex, quads between consecutive rings split into two triangles,
and both ends closed by a triangulation of the outline polygon (ear clipping,
so non-convex outlines such as I, L and + profiles are capped correctly).
Normals point outward whatever the orientation of the outline or the
handedness of the material frame.

Conventions
-----------
An outline point ``(x, y)`` is placed at ``p + x*m1 + y*m2``: ``x`` along the
first material director, ``y`` along the second, as in :mod:`xshells.section`.
Rod ``r`` owns centerline vertices ``vertex_offsets[r]:vertex_offsets[r+1]``
and edges ``edge_offsets[r]:edge_offsets[r+1]``, where both offsets are the
running sums of ``edges_per_rod`` (a rod of ``n`` edges has ``n + 1``
vertices). Holes of a section (several loops) are ignored: only the loop of
largest area is swept.

Files are written through :func:`xshells.io.export.atomic_write_text`, so a
reader never sees a half-written file.
"""
from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .export import atomic_write_bytes, atomic_write_text

__all__ = ["SweptMesh", "swept_beam_mesh", "outer_loop", "triangulate_polygon",
           "write_obj", "write_ply", "enclosed_volume", "ply_property_names"]


@dataclass(frozen=True)
class SweptMesh:
    """Triangle surface of swept beams.

    Attributes
    ----------
    vertices : (N, 3) float array
    triangles : (T, 3) int array, counter-clockwise seen from outside.
    fields : dict of str -> (N,) float array, per-vertex scalars.
    rod_of_vertex : (N,) int array, the rod each vertex belongs to.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    fields: dict = field(default_factory=dict)
    rod_of_vertex: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


def _signed_area(poly: np.ndarray) -> float:
    """Shoelace area of a (K, 2) polygon; positive when counter-clockwise."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def outer_loop(outline) -> np.ndarray:
    """The outer loop of a section outline, counter-clockwise.

    Parameters
    ----------
    outline : (K, 2) array, or sequence of (K_i, 2) arrays
        A closed polygon (last point not repeated) or several loops, as
        returned by ``Material.outline``. With several loops the one of
        largest area is taken; holes are ignored.

    Returns
    -------
    (K, 2) float array, counter-clockwise.
    """
    if isinstance(outline, np.ndarray) and outline.ndim == 2:
        loops = [outline]
    else:
        loops = [np.asarray(loop, dtype=np.float64) for loop in outline]
    if not loops:
        raise ValueError("swept_beam_mesh: the outline has no loop")
    for loop in loops:
        if loop.ndim != 2 or loop.shape[1] != 2 or loop.shape[0] < 3:
            raise ValueError(f"swept_beam_mesh: an outline loop must be (K>=3, 2), got {loop.shape}")
        if not np.all(np.isfinite(loop)):
            raise ValueError("swept_beam_mesh: the outline has non-finite coordinates")
    areas = [_signed_area(loop) for loop in loops]
    best = int(np.argmax(np.abs(areas)))
    if areas[best] == 0.0:
        raise ValueError("swept_beam_mesh: the outline has zero area")
    loop = np.asarray(loops[best], dtype=np.float64)
    return loop if areas[best] > 0 else loop[::-1].copy()


def _cross2(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def _is_ear(poly: np.ndarray, ring: list, i: int, tol: float) -> bool:
    prev, cur, nxt = ring[i - 1], ring[i], ring[(i + 1) % len(ring)]
    a, b, c = poly[prev], poly[cur], poly[nxt]
    if _cross2(a, b, c) <= tol:
        return False
    # A vertex on the closed triangle (its edges included) would leave a
    # T-junction on the diagonal a-c, so the surface would not be watertight.
    for j in ring:
        if j in (prev, cur, nxt):
            continue
        p = poly[j]
        if (_cross2(a, b, p) >= -tol and _cross2(b, c, p) >= -tol
                and _cross2(c, a, p) >= -tol):
            return False
    return True


def triangulate_polygon(poly: np.ndarray) -> np.ndarray:
    """Triangulate a simple counter-clockwise polygon by ear clipping.

    Parameters
    ----------
    poly : (K, 2) float array, counter-clockwise, last point not repeated.

    Returns
    -------
    (K - 2, 3) int array of indices into ``poly``, each triangle
    counter-clockwise. Every polygon edge belongs to exactly one triangle.
    """
    poly = np.asarray(poly, dtype=np.float64)
    scale = float(np.ptp(poly, axis=0).max())
    tol = 1e-12 * scale * scale
    ring = list(range(len(poly)))
    tris = []
    while len(ring) > 3:
        for i in range(len(ring)):
            if _is_ear(poly, ring, i, tol):
                break
        else:
            # Only collinear (zero-area) corners are left to cut; a flat
            # triangle keeps the cap's edges matched with the side walls.
            i = int(np.argmin([abs(_cross2(poly[ring[k - 1]], poly[ring[k]],
                                           poly[ring[(k + 1) % len(ring)]]))
                               for k in range(len(ring))]))
        tris.append((ring[i - 1], ring[i], ring[(i + 1) % len(ring)]))
        del ring[i]
    tris.append(tuple(ring))
    return np.asarray(tris, dtype=np.int64)


def _normalized(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _vertex_frames(m1: np.ndarray, m2: np.ndarray, counts: np.ndarray):
    """Per-vertex directors: the average of the adjacent edges' directors.

    Parameters
    ----------
    m1, m2 : (E, 3) edge directors.
    counts : (R,) edges per rod.

    Returns
    -------
    d1, d2 : (V, 3) orthonormal vertex directors, V = E + R.
    """
    edge_offsets = np.concatenate([[0], np.cumsum(counts)])
    rod = np.repeat(np.arange(len(counts)), counts + 1)
    local = np.arange(len(rod)) - np.repeat(edge_offsets[:-1] + np.arange(len(counts)), counts + 1)
    n = counts[rod]
    # End vertices use their single edge: clipping makes both "neighbours" it.
    before = edge_offsets[rod] + np.clip(local - 1, 0, n - 1)
    after = edge_offsets[rod] + np.clip(local, 0, n - 1)
    d1 = m1[before] + m1[after]
    d2 = m2[before] + m2[after]
    # A half-turn of twist over one vertex cancels the sum; fall back to the
    # edge before rather than divide by zero.
    flat = (np.linalg.norm(d1, axis=1) < 1e-8) | (np.linalg.norm(d2, axis=1) < 1e-8)
    d1[flat], d2[flat] = m1[before[flat]], m2[before[flat]]
    d1 = _normalized(d1)
    # Gram-Schmidt keeps the swept cross-section undistorted (averaged
    # directors are not exactly orthogonal).
    d2 = _normalized(d2 - np.sum(d2 * d1, axis=1, keepdims=True) * d1)
    return d1, d2


def _rod_triangles(num_rings: int, cap: np.ndarray, k: int) -> np.ndarray:
    """Triangles of one rod's surface, indices local to its rings.

    The outline is assumed counter-clockwise about the rod's direction of
    travel, so side normals (edge x tangent) point outward.
    """
    i, j = np.meshgrid(np.arange(num_rings - 1), np.arange(k), indexing="ij")
    a = (i * k + j).ravel()
    b = (i * k + (j + 1) % k).ravel()
    c = b + k
    d = a + k
    sides = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    # Counter-clockwise cap triangles face +tangent: right at the far end,
    # reversed at the near end.
    start = cap[:, ::-1]
    end = cap + (num_rings - 1) * k
    return np.concatenate([start, sides, end])


def swept_beam_mesh(points, edges_per_rod, m1, m2, outline,
                    vertex_fields: Mapping[str, np.ndarray] | None = None) -> SweptMesh:
    """Sweep a cross-section outline along rod centerlines.

    Parameters
    ----------
    points : (V, 3) array
        Centerline vertices of all rods, concatenated; rod ``r`` has
        ``edges_per_rod[r] + 1`` consecutive vertices.
    edges_per_rod : (R,) int array
        Number of edges of each rod (each >= 1); ``V = sum + R``.
    m1, m2 : (E, 3) arrays
        Material directors per edge, ``E = sum(edges_per_rod)``; the edges
        of a rod are its consecutive vertex pairs.
    outline : (K, 2) array or sequence of loops
        Cross-section outline in material coordinates (x along m1, y along
        m2), e.g. ``Material.outline``. Only the outer loop is used.
    vertex_fields : dict of str -> (V,) array, optional
        Per-centerline-vertex scalars copied onto every ring vertex.

    Returns
    -------
    SweptMesh
        ``R * (V_r * K)`` vertices in rod, ring, outline order; closed,
        outward-oriented triangles.
    """
    points = np.asarray(points, dtype=np.float64)
    counts = np.asarray(edges_per_rod, dtype=np.int64).reshape(-1)
    m1 = np.asarray(m1, dtype=np.float64)
    m2 = np.asarray(m2, dtype=np.float64)
    _check_inputs(points, counts, m1, m2)
    loop = outer_loop(outline)
    k = len(loop)
    cap = triangulate_polygon(loop)

    d1, d2 = _vertex_frames(m1, m2, counts)
    # The outline is counter-clockwise in (m1, m2); it is counter-clockwise
    # about the rod's direction only if m1 x m2 points along the rod.
    vertex_offsets = np.concatenate([[0], np.cumsum(counts + 1)])
    tris, rods = [], []
    reversed_loop = loop[::-1]
    ring_pts = np.empty((len(points), k, 3))
    for r in range(len(counts)):
        lo, hi = vertex_offsets[r], vertex_offsets[r + 1]
        e_lo = lo - r
        tangent = points[lo + 1:hi] - points[lo:hi - 1]
        handed = np.sum(np.cross(m1[e_lo:e_lo + counts[r]], m2[e_lo:e_lo + counts[r]]) * tangent)
        xy = loop if handed >= 0 else reversed_loop
        ring_pts[lo:hi] = (points[lo:hi, None, :] + xy[None, :, 0, None] * d1[lo:hi, None, :]
                           + xy[None, :, 1, None] * d2[lo:hi, None, :])
        tris.append(_rod_triangles(hi - lo, cap, k) + lo * k)
        rods.append(np.full((hi - lo) * k, r, dtype=np.int64))

    fields = {}
    for name, values in (vertex_fields or {}).items():
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        if values.shape != (len(points),):
            raise ValueError(f"swept_beam_mesh: field {name!r} has shape {values.shape}, "
                             f"expected ({len(points)},)")
        fields[name] = np.repeat(values, k)
    return SweptMesh(vertices=ring_pts.reshape(-1, 3), triangles=np.concatenate(tris),
                     fields=fields, rod_of_vertex=np.concatenate(rods))


def _check_inputs(points, counts, m1, m2) -> None:
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"swept_beam_mesh: points must be (V, 3), got {points.shape}")
    if counts.size == 0 or np.any(counts < 1):
        raise ValueError("swept_beam_mesh: every rod needs at least one edge")
    num_edges = int(counts.sum())
    if points.shape[0] != num_edges + counts.size:
        raise ValueError(f"swept_beam_mesh: {points.shape[0]} points but edges_per_rod "
                         f"implies {num_edges + counts.size}")
    for name, m in (("m1", m1), ("m2", m2)):
        if m.shape != (num_edges, 3):
            raise ValueError(f"swept_beam_mesh: {name} must be ({num_edges}, 3), got {m.shape}")
    for name, a in (("points", points), ("m1", m1), ("m2", m2)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"swept_beam_mesh: {name} has non-finite values")


def enclosed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Volume enclosed by a closed surface (divergence theorem).

    Parameters
    ----------
    vertices : (N, 3) array.
    triangles : (T, 3) int array.

    Returns
    -------
    float, positive when the triangles face outward.
    """
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    return float(np.sum(a * np.cross(b, c)) / 6.0)


def _rows(row: str, table) -> str:
    """``row`` %-formatted with each row of ``table`` (a 2D array), concatenated.

    One formatting of the whole table (``%r`` of a Python float is its repr(),
    which round-trips a double exactly): 2-3x faster than a format per row.
    """
    table = np.asarray(table)
    return (row * len(table)) % tuple(table.ravel().tolist()) if len(table) else ""


def write_obj(path: str | os.PathLike, mesh: SweptMesh) -> None:
    """Write a swept mesh as a Wavefront OBJ file.

    OBJ carries no per-vertex scalars, so only the first field (in dict
    order) is kept, as the texture coordinate ``vt f 0`` of each vertex
    (face corners reference it as ``v/vt``); its name is in a comment.
    Other fields are dropped: use :func:`write_ply` for all of them.
    """
    lines = ["# swept beam surface written by xshells\n", _rows("v %r %r %r\n", mesh.vertices)]
    tri = np.asarray(mesh.triangles, dtype=np.int64) + 1
    if mesh.fields:
        name, values = next(iter(mesh.fields.items()))
        lines.append(f"# vt u = field {name}\n")
        lines.append(_rows("vt %r 0\n", np.asarray(values).reshape(-1, 1)))
        lines.append(_rows("f %d/%d %d/%d %d/%d\n", np.repeat(tri, 2, axis=1)))
    else:
        lines.append(_rows("f %d %d %d\n", tri))
    atomic_write_text(path, "".join(lines))


def ply_property_names(names: Sequence[str]) -> list[str]:
    """PLY-safe, distinct property names for fields.

    Characters outside ``[A-Za-z0-9_]`` become ``_``; names that would clash
    with ``x``, ``y``, ``z`` or each other get a numeric suffix.
    """
    taken = {"x", "y", "z"}
    out = []
    for name in names:
        base = re.sub(r"[^A-Za-z0-9_]", "_", str(name)) or "field"
        candidate, n = base, 1
        while candidate in taken:
            candidate, n = f"{base}_{n}", n + 1
        taken.add(candidate)
        out.append(candidate)
    return out


def write_ply(path: str | os.PathLike, mesh: SweptMesh) -> None:
    """Write a swept mesh as a binary (little-endian) PLY file with every field.

    Each field becomes a vertex property named by
    :func:`ply_property_names`. Properties are ``double`` rather than
    ``float`` so coordinates and fields read back bit for bit. Binary, not
    ASCII: the manta ray's deployed beams (23,000 vertices) took 50 ms to
    format as text, on the path of every ``xshells deploy``, and 2 ms this way.
    """
    names = ply_property_names(list(mesh.fields))
    n = len(mesh.vertices)
    tri = np.asarray(mesh.triangles, dtype=np.int64).reshape(-1, 3)
    header = ["ply\n", "format binary_little_endian 1.0\n", "comment swept beam surface written by xshells\n",
              f"element vertex {n}\n", "property double x\n", "property double y\n",
              "property double z\n"]
    header += [f"property double {name}\n" for name in names]
    header += [f"element face {len(tri)}\n",
               "property list uchar int vertex_indices\n", "end_header\n"]
    columns = np.column_stack([np.asarray(mesh.vertices, dtype=np.float64)] +
                              [np.asarray(v, dtype=np.float64) for v in mesh.fields.values()])
    if len(tri) and (tri.min() < 0 or tri.max() >= 2**31):
        raise ValueError("write_ply: a triangle index outside the int range of PLY")
    faces = np.empty(len(tri), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    faces["n"] = 3
    faces["v"] = tri
    body = columns.astype("<f8").tobytes() + faces.tobytes()
    atomic_write_bytes(path, "".join(header).encode("ascii") + body)
