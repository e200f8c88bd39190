"""The fitting term T of the design optimization (paper §5, eq. 6, and Appendix B).

    T(x) = ½ ‖x − P_surf(x)‖²_{W_surf} + ½ ‖x − x_tgt‖²_W

acts on the joint positions ``P`` (n, 3) of the deployed linkage. ``P_surf``
projects each joint onto its closest point on a target triangle mesh; by
default (the paper's "improve an existing design" mode) that mesh is the
linkage's own joint graph faces at the current deployed state, triangulated
and refined by two Loop subdivisions, and ``x_tgt`` are the current joint
positions.

Derivatives: the gradient of ½|p − C(p)|² is ``p − C(p)`` (the projection's
own variation is orthogonal to ``p − C``), and its derivative is ``I − J``
with ``J = ∂C/∂p``: ``I − n nᵀ`` over a triangle's interior, ``e eᵀ`` on an
edge, ``0`` at a vertex. This is exact away from the measure-zero set where
the closest point jumps.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..errors import InputError, check_input_file

__all__ = [
    "joint_edges",
    "planar_faces",
    "joint_faces",
    "triangulate_faces",
    "target_surface",
    "read_surface",
    "read_surface_faces",
    "read_surface_noted",
    "point_mesh_squared_distance",
    "closest_points",
    "FittingTerm",
]

# Barycentric coordinates below this (relative) value count as zero: the
# closest point lies on the opposite edge (or, with two of them, at a vertex).
_BARY_TOL = 1e-9


# ------------------------------------------------------------ joint faces
def _layout_coordinates(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """2D coordinates of points (n, 3) in the plane with unit ``normal`` (3,), right-handed about it; (n, 2)."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    return np.c_[points @ u, points @ v]


def joint_edges(segment_joints: np.ndarray) -> np.ndarray:
    """Unique joint-to-joint edges, (e, 2) int with ``a < b``; segments to free ends (-1) dropped."""
    sj = np.asarray(segment_joints, dtype=np.int64).reshape(-1, 2)
    sj = sj[(sj >= 0).all(axis=1) & (sj[:, 0] != sj[:, 1])]
    if len(sj) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    return np.unique(np.sort(sj, axis=1), axis=0)


def _prune_dangling(num: int, edges: np.ndarray) -> np.ndarray:
    """Drop edges to vertices of degree ≤ 1, repeatedly (they bound no face); (e', 2)."""
    keep = np.ones(len(edges), dtype=bool)
    while True:
        deg = np.bincount(edges[keep].ravel(), minlength=num)
        bad = keep & ((deg[edges[:, 0]] <= 1) | (deg[edges[:, 1]] <= 1))
        if not bad.any():
            return edges[keep]
        keep &= ~bad


def _signed_area(xy: np.ndarray) -> float:
    """Shoelace signed area of a polygon (k, 2), positive counter-clockwise."""
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def planar_faces(xy: np.ndarray, edges: np.ndarray) -> list[list[int]]:
    """Bounded faces of a plane straight-line graph, counter-clockwise.

    Parameters
    ----------
    xy : (n, 2) float
        Vertex positions in the plane.
    edges : (e, 2) int
        Undirected edges (no duplicates).

    Returns
    -------
    list of list of int
        Each bounded face as its vertex cycle. The faces of negative or zero
        signed area (the unbounded face of each connected component, and
        slivers) are dropped.
    """
    xy = np.asarray(xy, float)
    edges = _prune_dangling(len(xy), np.asarray(edges, np.int64).reshape(-1, 2))
    nbrs: dict[int, list[int]] = {}
    for a, b in edges.tolist():
        nbrs.setdefault(a, []).append(b)
        nbrs.setdefault(b, []).append(a)
    # Neighbours of each vertex sorted counter-clockwise, and the position of
    # each in that order.
    order: dict[int, list[int]] = {}
    rank: dict[tuple[int, int], int] = {}
    for v, ns in nbrs.items():
        d = xy[ns] - xy[v]
        ns = [ns[i] for i in np.argsort(np.arctan2(d[:, 1], d[:, 0]), kind="stable")]
        order[v] = ns
        for i, w in enumerate(ns):
            rank[(v, w)] = i
    visited: set[tuple[int, int]] = set()
    faces = []
    for a, b in edges.tolist():
        for start in ((a, b), (b, a)):
            if start in visited:
                continue
            face, (u, v) = [], start
            while (u, v) not in visited:
                visited.add((u, v))
                face.append(u)
                # Turn as far right as possible at v: the neighbour just
                # before u in counter-clockwise order keeps the face on the left.
                ns = order[v]
                w = ns[(rank[(v, u)] - 1) % len(ns)]
                u, v = v, w
            if _signed_area(xy[face]) > 0:
                faces.append(face)
    return faces


def joint_faces(linkage, max_sides: int | None = 6) -> list[list[int]]:
    """Bounded faces of a linkage's planar joint graph in its flat layout.

    Joints are connected where a segment joins them (segments to free ends
    are ignored); the graph is embedded in the plane of the layout (the
    design's vertices projected along ``graph.layout_normal``) and its faces
    are traced; the unbounded face is dropped.

    Parameters
    ----------
    linkage : Linkage
    max_sides : int or None
        Faces with more sides are holes in the X-shell (a beam network's
        faces are quads, with triangles and pentagons at the boundary) and
        are dropped; None keeps every bounded face.

    Returns
    -------
    list of list of int
        Each face (the quads of an X-shell, plus triangles and pentagons at
        the boundary) as joint numbers, counter-clockwise about the layout
        normal.

    Raises
    ------
    InputError
        The segments cross each other in the layout plane (a design that is
        not a flat layout), so the traced faces are not those of a plane
        graph (the Euler characteristic V − E + F is not 1).
    """
    g = linkage.graph
    flat = np.asarray(g.design.vertices, float)[np.asarray(g.joint_vertex)]
    xy = _layout_coordinates(flat, g.layout_normal)
    edges = joint_edges(g.segment_joints)
    faces = planar_faces(xy, edges)
    chi = g.num_joints - len(edges) + len(faces)
    if chi != 1:
        raise InputError(f"{g.design.label()}: segments cross in the layout plane (V - E + F = {chi}, not 1), "
                         "so the joint faces cannot be found; give a target surface instead")
    if max_sides is not None:
        faces = [f for f in faces if len(f) <= max_sides]
    return faces


# --------------------------------------------------------- target surface
def triangulate_faces(P: np.ndarray, faces) -> np.ndarray:
    """Split polygons into triangles: quads along the shorter diagonal, others fanned.

    Parameters
    ----------
    P : (n, 3) float
        Vertex positions (decide the quad diagonals).
    faces : sequence of sequences of int
        Polygons of ≥ 3 vertices.

    Returns
    -------
    (f, 3) int64
        Triangles, oriented like their polygons.
    """
    P = np.asarray(P, float)
    tris = []
    for face in faces:
        f = [int(i) for i in face]
        if len(f) == 4:
            a, b, c, d = f
            if np.linalg.norm(P[a] - P[c]) <= np.linalg.norm(P[b] - P[d]):
                tris += [(a, b, c), (a, c, d)]
            else:
                tris += [(a, b, d), (b, c, d)]
        else:
            tris += [(f[0], f[i], f[i + 1]) for i in range(1, len(f) - 1)]
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


def target_surface(linkage, faces=None, subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The paper's default target surface: the triangulated joint faces, Loop-subdivided.

    Parameters
    ----------
    linkage : Linkage
        Its current (deployed) joint positions are the mesh vertices.
    faces : list of list of int, optional
        Joint faces (default: :func:`joint_faces`).
    subdivisions : int
        Loop subdivision steps (≥ 0).

    Returns
    -------
    V : (m, 3) float
    F : (f, 3) int64
    """
    P = np.asarray(linkage.joint_positions(), float)
    faces = joint_faces(linkage) if faces is None else faces
    F = triangulate_faces(P, faces)
    if len(F) == 0:
        raise InputError("the linkage's joint graph encloses no face: no target surface can be built")
    V = P
    if subdivisions > 0:
        import igl

        used = np.unique(F)
        remap = np.full(len(P), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        V, F = igl.loop(np.ascontiguousarray(P[used]), np.ascontiguousarray(remap[F]), int(subdivisions))
    return np.asarray(V, float), np.asarray(F, np.int64)


def read_surface(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a user-supplied surface mesh (OBJ, PLY, STL, gmsh ``.msh``, ... via meshio; ``.3dm`` via rhino3dm).

    Quads are split along their shorter diagonal and other polygons fanned
    (:func:`read_surface_faces`); lines, points and volume cells are ignored.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    V : (m, 3) float
    F : (f, 3) int64
        The triangles of all the file's surface faces, in file order.

    Raises
    ------
    InputError
        One line naming the file: unreadable, without surface faces, an index
        out of range, a non-finite coordinate or a polygon that is not convex.
    """
    V, F, _ = read_surface_faces(path)
    return V, F


#: meshio's surface cell types, by how many of their first nodes are the corners
_SURFACE_CELLS = {"triangle": 3, "triangle6": 3, "triangle7": 3, "quad": 4, "quad8": 4, "quad9": 4, "polygon": None}


_MAX_COORDINATE = 1e100
"""A surface with a coordinate beyond this cannot be computed with: its areas and distances square it past
double precision (one at 3e300 ended ``xshells optimize`` in an IndexError and was called 'zero area')."""


def read_surface_faces(path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`read_surface`, with the file face each triangle comes from (its coordinates checked for size)."""
    return read_surface_noted(path)[:3]


def read_surface_noted(path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, str | None]:
    """:func:`read_surface_faces`, and how the file was read where that says more than its name (a ``.3dm``'s
    layer, its units and their conversion to mm; else None)."""
    V, F, face, note = _read_surface_faces(path)
    big = np.flatnonzero(np.abs(np.where(np.isfinite(V), V, 0.0)).max(axis=1, initial=0.0) > _MAX_COORDINATE) if len(V) else []
    if len(big):
        v = int(big[0])
        raise InputError(f"{path}: vertex {v + 1} has a coordinate of {np.abs(V[v]).max():.3g}: too large to compute with "
                         f"(is the surface in the design's units?)")
    if len(F):
        T = V[F]
        area = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
        size = float(np.linalg.norm(np.ptp(V[np.unique(F)], axis=0)))
        if not (area > 1e-12 * size**2).any():  # nothing to project onto: every distance would be to a line or point
            raise InputError(f"{path}: the target surface has zero area (all {len(F)} of its triangles are degenerate)")
    return V, F, face, note


def _read_quietly(read, path):
    """``read(path)`` with meshio's console output held back, and its ``sys.exit`` made an InputError.

    meshio prints each failed reader's complaint and then calls ``sys.exit(1)`` when no reader for the
    extension accepts the file (an OBJ named ``.stl``, a corrupt ``.ply``): that printed "Error: Couldn't
    read file ..." without the command's prefix and exited 1, the code for a missed design. Its gmsh reader
    also prints blank lines on success. Exceptions are not touched: they are the real errors, and the
    reader already words them."""
    import contextlib
    import io
    import re

    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            return read(path)
    except SystemExit:
        said = " ".join((out.getvalue() + " " + err.getvalue()).split())
        m = re.search(r"Couldn't read file .* as (?:either of )?(.+)$", said)
        formats = " or ".join(f.strip() for f in m.group(1).split(",")) if m else Path(str(path)).suffix.lstrip(".")
        raise InputError(f"{path}: cannot read the target surface as {formats or 'a mesh'}: the file is not valid "
                         f"{formats or 'mesh'} data (is its extension right?)") from None


def _read_surface_faces(path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, str | None]:
    """:func:`read_surface_faces` before the size check.

    Returns
    -------
    V : (m, 3) float
    F : (f, 3) int64
    face : (f,) int64 or None
        The 0-based index of each triangle's face among the file's surface
        faces, or None where every face is a triangle (then ``face[i] = i``).
    note : str or None
        How a ``.3dm`` was read (its layer and units); None for the other formats.
    """
    import meshio

    path = Path(path)
    check_input_file(path, "the target surface")
    if path.suffix.lower() == ".3dm":  # Rhino: its meshes, or its surfaces' render meshes, in mm
        from ..rhino.read import read_3dm_surface

        V, F, note = read_3dm_surface(path, with_note=True)
        return V, F, None, note
    try:
        with warnings.catch_warnings():  # meshio warns while guessing at malformed files
            warnings.simplefilter("ignore")
            mesh = _read_quietly(meshio.read, str(path))
    except InputError:
        raise
    except Exception as exc:  # meshio raises many kinds for bad files
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"{path}: cannot read the target surface: {msg}") from None
    blocks = [(c.type, np.asarray(c.data, np.int64)) for c in mesh.cells if c.type in _SURFACE_CELLS and len(c.data)]
    if not blocks:
        raise InputError(f"{path}: the target surface has no triangles, quads or polygons")
    V = np.asarray(mesh.points, float)
    if V.ndim != 2 or V.shape[1] not in (2, 3):
        raise InputError(f"{path}: the target surface's points are not 2D or 3D")
    if V.shape[1] == 2:
        V = np.c_[V, np.zeros(len(V))]
    tris, origin, first = [], [], 0
    for kind, data in blocks:
        corners = data[:, : _SURFACE_CELLS[kind] or data.shape[1]]
        if corners.min() < 0 and path.suffix.lower() == ".obj":  # meshio reads OBJ's relative indices as they stand
            row = int(np.flatnonzero((corners < 0).any(axis=1))[0])
            raise InputError(f"{path}: face {first + row + 1} of the target surface uses relative (negative) vertex "
                             "indices, which are not supported: export it with absolute indices")
        if corners.min() < 0 or corners.max() >= len(V):
            row = int(np.flatnonzero((corners < 0).any(axis=1) | (corners >= len(V)).any(axis=1))[0])
            raise InputError(f"{path}: face {first + row + 1} of the target surface has a vertex index out of range")
        if not np.isfinite(V[corners]).all():
            bad = int(corners.ravel()[np.flatnonzero(~np.isfinite(V[corners.ravel()]).all(axis=1))[0]])
            raise InputError(f"{path}: the target surface's vertex {bad + 1} has a non-finite coordinate")
        t, o = _split_polygons(V, corners)
        if o is None:
            bad, why = t
            raise InputError(f"{path}: face {first + bad + 1} of the target surface {why}")
        tris.append(t)
        origin.append(first + o)
        first += len(corners)
    F, origin = np.concatenate(tris), np.concatenate(origin)
    return V, F, (None if len(F) == first else origin), None


_NOT_CONVEX = "is a polygon that is not convex or crosses itself: triangulate it before use"


def _split_polygons(V: np.ndarray, faces: np.ndarray):
    """Triangles of polygons with the same number of corners: quads along the shorter diagonal where that
    split keeps both halves facing the quad's way (else the other), larger polygons fanned from their first
    corner.

    Parameters
    ----------
    V : (n, 3) float
    faces : (k, m) int64, m ≥ 3

    Returns
    -------
    (triangles (t, 3), face (t,)), or ((index of the first bad polygon, what is wrong with it), None).
    """
    k, m = faces.shape
    if m < 3:
        return (0, f"has only {m} corner{'s' * (m != 1)}: a surface face needs at least 3"), None
    if m == 3:
        return faces, np.arange(k)
    P = V[faces]  # (k, m, 3)
    newell = np.cross(P, np.roll(P, -1, axis=1)).sum(axis=1)  # the polygons' area-weighted normals
    span = float(np.ptp(V, axis=0).max()) if len(V) else 0.0
    tiny = 1e-12 * span**2
    # A polygon of no area (its corners on a line) has no way to face: any split will do, and its zero-area
    # triangles are the mesh checks' to report. One whose normal cancels but whose corners span an area (a
    # bow tie) crosses itself: no split faces its way, and it is refused below.
    fan_area = np.linalg.norm(np.cross(P[:, 1:-1] - P[:, :1], P[:, 2:] - P[:, :1]), axis=2).max(axis=1)
    degenerate = (np.linalg.norm(newell, axis=1) <= tiny) & (fan_area <= tiny)

    def facing(tri):  # (k, 3) corner positions in faces' columns -> each triangle faces its polygon's way
        a, b, c = (P[np.arange(k), tri[:, i]] for i in range(3))
        return (np.einsum("ij,ij->i", np.cross(b - a, c - a), newell) > 0) | degenerate

    if m == 4:
        one = (np.array([0, 1, 2]), np.array([0, 2, 3]))  # along the diagonal 0–2
        two = (np.array([0, 1, 3]), np.array([1, 2, 3]))  # along 1–3
        ok1 = facing(np.tile(one[0], (k, 1))) & facing(np.tile(one[1], (k, 1)))
        ok2 = facing(np.tile(two[0], (k, 1))) & facing(np.tile(two[1], (k, 1)))
        shorter = np.linalg.norm(P[:, 0] - P[:, 2], axis=1) <= np.linalg.norm(P[:, 1] - P[:, 3], axis=1)
        use_one = np.where(ok1 & ok2, shorter, ok1 | ~ok2)
        if not (ok1 | ok2).all():
            return (int(np.flatnonzero(~(ok1 | ok2))[0]), _NOT_CONVEX), None
        pick = np.where(use_one[:, None, None], np.stack(one)[None], np.stack(two)[None])  # (k, 2, 3)
        tri = np.take_along_axis(faces[:, None, :], pick.reshape(k, 1, 6), axis=2).reshape(k, 2, 3)
        return tri.reshape(-1, 3), np.repeat(np.arange(k), 2)
    fan = [np.array([0, i, i + 1]) for i in range(1, m - 1)]
    ok = np.logical_and.reduce([facing(np.tile(f, (k, 1))) for f in fan])
    if not ok.all():
        return (int(np.flatnonzero(~ok)[0]), _NOT_CONVEX), None
    tri = np.stack([faces[:, f] for f in fan], axis=1)  # (k, m − 2, 3)
    return tri.reshape(-1, 3), np.repeat(np.arange(k), m - 2)


# ------------------------------------------------------- closest points
# The AABB trees of recently queried meshes: libigl's point_mesh_squared_distance builds one per call
# (47 ms of its 56 ms on an 80k-triangle target, which the design optimization queries about a thousand
# times); the tree's answers are the same to the last bit.
_TREES: dict = {}
_MAX_TREES = 4


def point_mesh_squared_distance(P: np.ndarray, V: np.ndarray, F: np.ndarray):
    """``igl.point_mesh_squared_distance(P, V, F)`` with the mesh's AABB tree kept between calls.

    Parameters
    ----------
    P : (n, 3) float
        Query points.
    V : (m, 3) float
    F : (f, 3) int

    Returns
    -------
    sq : (n,) float
        Squared distances.
    I : (n,) int64
        The closest triangle of each point.
    C : (n, 3) float
        The closest points.
    """
    import igl

    V = np.ascontiguousarray(V, dtype=float)
    F = np.ascontiguousarray(F, dtype=np.int64)
    P = np.ascontiguousarray(P, dtype=float)
    key = (V.shape, F.shape, hash(V.tobytes()), hash(F.tobytes()))
    tree = _TREES.get(key)
    if tree is None:
        tree = igl.AABB()
        tree.init(V, F)
        try:  # the oldest goes (threads may share the table: a lost race only costs a rebuild)
            while len(_TREES) >= _MAX_TREES:
                _TREES.pop(next(iter(_TREES)), None)
        except (StopIteration, RuntimeError):
            pass
        _TREES[key] = tree
    return tree.squared_distance(V, F, P)


def _barycentric(C: np.ndarray, A: np.ndarray, B: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of points C (n, 3) in triangles (A, B, D), each (n, 3); (n, 3)."""
    e0, e1, r = B - A, D - A, C - A
    d00 = np.einsum("ij,ij->i", e0, e0)
    d01 = np.einsum("ij,ij->i", e0, e1)
    d11 = np.einsum("ij,ij->i", e1, e1)
    d20 = np.einsum("ij,ij->i", r, e0)
    d21 = np.einsum("ij,ij->i", r, e1)
    den = d00 * d11 - d01 * d01
    den = np.where(den > 0, den, 1.0)
    b1 = (d11 * d20 - d01 * d21) / den
    b2 = (d00 * d21 - d01 * d20) / den
    return np.c_[1.0 - b1 - b2, b1, b2]


def closest_points(V: np.ndarray, F: np.ndarray, P: np.ndarray, tol: float = _BARY_TOL):
    """Closest points of query points on a triangle mesh, and their Jacobians.

    Parameters
    ----------
    V : (m, 3) float
        Mesh vertices.
    F : (f, 3) int
        Triangles.
    P : (n, 3) float
        Query points.
    tol : float
        A barycentric coordinate ≤ ``tol`` counts as zero.

    Returns
    -------
    C : (n, 3) float
        Closest points.
    J : (n, 3, 3) float
        ``∂C/∂P``: ``I − n nᵀ`` when ``C`` is interior to its triangle (``n``
        the unit normal), ``e eᵀ`` on an edge (``e`` the unit edge vector),
        ``0`` at a vertex.
    """
    V = np.ascontiguousarray(V, dtype=float)
    F = np.ascontiguousarray(F, dtype=np.int64)
    P = np.ascontiguousarray(np.asarray(P, float).reshape(-1, 3))
    if len(P) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3, 3))
    _, I, C = point_mesh_squared_distance(P, V, F)
    T = V[F[I]]  # (n, 3 corners, 3)
    bary = _barycentric(C, T[:, 0], T[:, 1], T[:, 2])
    zero = bary <= tol
    nzero = zero.sum(axis=1)
    J = np.zeros((len(P), 3, 3))

    inner = nzero == 0
    if inner.any():
        nrm = np.cross(T[inner, 1] - T[inner, 0], T[inner, 2] - T[inner, 0])
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        J[inner] = np.eye(3) - nrm[:, :, None] * nrm[:, None, :]

    edge = nzero == 1
    if edge.any():
        k = np.argmax(zero[edge], axis=1)  # the vertex opposite the edge
        rows = np.flatnonzero(edge)
        e = T[rows, (k + 2) % 3] - T[rows, (k + 1) % 3]
        e /= np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-300)
        J[edge] = e[:, :, None] * e[:, None, :]
    return np.asarray(C, float), J


# ------------------------------------------------------------ fitting term
class FittingTerm:
    """T(P) = ½ Σ ws_j |P_j − C_j(P_j)|² + ½ Σ w_j |P_j − tgt_j|² on joint positions.

    Parameters
    ----------
    targets : (n, 3) float
        Target joint positions x_tgt.
    weights : (n,) float
        Point-to-point weights (diagonal of W, per joint).
    surface_weights : (n,) float, optional
        Point-to-surface weights (diagonal of W_surf, per joint); default zero.
    surface : (V (m, 3), F (f, 3)), optional
        Target triangle mesh; required when any surface weight is nonzero.
    """

    def __init__(self, targets, weights, surface_weights=None, surface=None):
        self.targets = np.array(targets, float).reshape(-1, 3)
        n = len(self.targets)
        self.weights = _weights(weights, n, "weights")
        self.surface_weights = _weights(np.zeros(n) if surface_weights is None else surface_weights, n,
                                        "surface_weights")
        if surface is None:
            if np.any(self.surface_weights != 0):
                raise InputError("surface weights are given but no target surface")
            self.surface = None
        else:
            V, F = surface
            V, F = np.array(V, float).reshape(-1, 3), np.array(F, np.int64).reshape(-1, 3)
            if len(F) == 0:
                raise InputError("the target surface has no triangles")
            self.surface = (V, F)
        for a in (self.targets, self.weights, self.surface_weights):
            a.setflags(write=False)

    @classmethod
    def paper_defaults(cls, linkage, surface=None) -> "FittingTerm":
        """The paper's weights for improving an existing design (§5).

        Targets are the current joint positions; the surface is
        :func:`target_surface` of the linkage unless given. W_surf totals 0.9
        spread equally over the joints; W totals 0.1, with joints of valence 2
        (corners) weighted 10× the others. All weights sum to one.
        """
        P = linkage.joint_positions()
        n = len(P)
        surface = target_surface(linkage) if surface is None else surface
        valence = np.asarray(linkage.graph.valence)[np.asarray(linkage.graph.joint_vertex)]
        w = np.where(valence == 2, 10.0, 1.0)
        return cls(P, 0.1 * w / w.sum(), np.full(n, 0.9 / n), surface)

    def _check(self, P) -> np.ndarray:
        P = np.asarray(P, float)
        if P.shape != self.targets.shape:
            raise ValueError(f"joint positions must have shape {self.targets.shape}, got {P.shape}")
        return P

    def _project(self, P):
        """Closest surface points (n, 3) and their Jacobians (n, 3, 3), or None without a surface."""
        if self.surface is None:
            return None
        return closest_points(*self.surface, P)

    def value(self, P) -> float:
        """T at joint positions P (n, 3)."""
        P = self._check(P)
        t = 0.5 * float(np.sum(self.weights * np.sum((P - self.targets) ** 2, axis=1)))
        proj = self._project(P)
        if proj is not None:
            t += 0.5 * float(np.sum(self.surface_weights * np.sum((P - proj[0]) ** 2, axis=1)))
        return t

    def gradient(self, P) -> np.ndarray:
        """∂T/∂P = W_surf (P − C) + W (P − tgt), shape (n, 3)."""
        P = self._check(P)
        g = self.weights[:, None] * (P - self.targets)
        proj = self._project(P)
        if proj is not None:
            g += self.surface_weights[:, None] * (P - proj[0])
        return g

    def hessian_vector(self, P, dP) -> np.ndarray:
        """∂²T/∂P² dP = W_surf (dP − J dP) + W dP (Appendix B), shape (n, 3)."""
        P = self._check(P)
        dP = np.asarray(dP, float).reshape(P.shape)
        h = self.weights[:, None] * dP
        proj = self._project(P)
        if proj is not None:
            h += self.surface_weights[:, None] * (dP - np.einsum("nij,nj->ni", proj[1], dP))
        return h

    def hessian_vectors(self, P, dPs) -> np.ndarray:
        """:meth:`hessian_vector` for a stack of directions ``dPs`` (m, n, 3), one projection for all."""
        P = self._check(P)
        dPs = np.asarray(dPs, float).reshape((-1,) + P.shape)
        h = self.weights[None, :, None] * dPs
        proj = self._project(P)
        if proj is not None:
            h += self.surface_weights[None, :, None] * (dPs - np.einsum("nij,mnj->mni", proj[1], dPs))
        return h

    def __repr__(self) -> str:
        surf = "none" if self.surface is None else f"{len(self.surface[0])} vertices, {len(self.surface[1])} triangles"
        return (f"FittingTerm(joints={len(self.targets)}, sum W={self.weights.sum():.4g}, "
                f"sum W_surf={self.surface_weights.sum():.4g}, surface: {surf})")


def _weights(w, n: int, name: str) -> np.ndarray:
    """Per-joint nonnegative weights as a fresh (n,) float array."""
    w = np.array(w, float)
    if w.ndim == 0:
        w = np.full(n, float(w))
    if w.shape != (n,):
        raise InputError(f"{name} must have one entry per joint ({n}), got shape {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise InputError(f"{name} must be finite and nonnegative")
    return w

