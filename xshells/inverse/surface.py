"""The target surface of inverse design: a checked triangle mesh, in design units.

Every defect a mesh can have for this purpose is reported as one line that
names the file: unreadable, empty, non-finite coordinates, non-manifold
edges or vertices, duplicate faces, several pieces (or an unwelded seam), a
one-sided (non-orientable) surface, a closed surface (no boundary) or one
with handles. Unused vertices are dropped before any check. Faces are
re-oriented consistently (a mixed orientation is a property of how the
mesh was exported, not of the surface).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import InputError


@dataclass(frozen=True)
class TargetSurface:
    """A target surface.

    Attributes
    ----------
    V : (n, 3) float
        Vertices (design units).
    F : (m, 3) int64
        Consistently oriented triangles.
    path : str
        Where it came from (for messages).
    diagonal : float
        Length of the bounding-box diagonal.
    area : float
    boundary_loops : int
    note : str or None
        How the file was read where that says more than its name: a ``.3dm``'s layer, its units and their
        conversion to mm (then the lengths here are mm).
    simplified : (int, int, float) or None
        Where the file's mesh was finer than inverse design needs (:func:`simplified`): its triangles, the
        triangles kept, and the largest distance between the two meshes (design units).
    """

    V: np.ndarray = field(repr=False)
    F: np.ndarray = field(repr=False)
    path: str = ""
    diagonal: float = 0.0
    area: float = 0.0
    boundary_loops: int = 1
    note: str | None = None
    simplified: tuple | None = None

    @property
    def unit(self) -> str:
        """The length unit for messages: " mm" for a ``.3dm`` (read in mm), else "" (the file's own units)."""
        return " mm" if self.note else ""

    @property
    def face_normals(self) -> np.ndarray:
        """Unit normals, shape (m, 3), by the face orientation."""
        n = np.cross(self.V[self.F[:, 1]] - self.V[self.F[:, 0]], self.V[self.F[:, 2]] - self.V[self.F[:, 0]])
        return n / np.linalg.norm(n, axis=1)[:, None]

    @property
    def face_areas(self) -> np.ndarray:
        n = np.cross(self.V[self.F[:, 1]] - self.V[self.F[:, 0]], self.V[self.F[:, 2]] - self.V[self.F[:, 0]])
        return 0.5 * np.linalg.norm(n, axis=1)


# A finer mesh than this is simplified before inverse design works on it (:func:`simplified`). The method's
# surface work grows faster than the triangles: the scissor map of the shared spherical cap took 1.25 s at its
# 3,562 triangles and 117 s Loop-subdivided three times (227,968), and the fan screen maps it several times.
# The shared targets have fewer than 5,000, a realizable target about 15 per segment of its design.
MAX_TRIANGLES = 20_000
# How close the simplified mesh must stay to the file's, relative to the diagonal: a fiftieth of the
# realizable bar's mean fit (0.5 %), so that the fit measured on it is the fit to the file's surface
SIMPLIFY_TOLERANCE = 1e-4


def load_target(path, simplify: bool = True) -> TargetSurface:
    """Read and check a target surface (OBJ, PLY, STL or gmsh ``.msh``, quads and polygons split into
    triangles; see :func:`check_target`), simplified where finer than inverse design needs (:func:`simplified`;
    not with ``simplify=False``)."""
    from dataclasses import replace

    from ..design.fitting import read_surface_noted

    V, F, face, note = read_surface_noted(path)  # meshio's exits and noise handled there
    surface = replace(check_target(V, F, str(path), face=face), note=note)
    return simplified(surface) if simplify else surface


def simplified(surface: TargetSurface, max_triangles: int = MAX_TRIANGLES,
               tolerance: float = SIMPLIFY_TOLERANCE) -> TargetSurface:
    """``surface`` with at most ``max_triangles`` triangles where it has more, or as it is.

    The mesh is simplified by quadric edge collapses (libigl's ``qslim``). The result is kept only if it is a
    valid target (:func:`check_target`) with as many boundary loops, and every vertex of either mesh lies
    within ``tolerance`` × the diagonal of the other; otherwise twice as many triangles are tried, up to the
    file's own mesh. ``simplified`` on the result records the triangles before and after and that distance.
    """
    from dataclasses import replace

    import igl

    m0 = len(surface.F)
    m = max_triangles
    V = np.asfortranarray(surface.V, dtype=float)
    F = np.asfortranarray(surface.F, dtype=np.int32)
    while m < m0:
        try:
            U, G, _, _ = igl.qslim(V, F, m)
            s = check_target(U, G, surface.path)
        except (InputError, RuntimeError, ValueError):  # a collapse that broke the mesh: keep more triangles
            s = None
        if s is not None and s.boundary_loops == surface.boundary_loops:
            gap = max(_largest_distance(surface.V, s), _largest_distance(s.V, surface))
            if gap <= tolerance * surface.diagonal:
                return replace(s, note=surface.note, simplified=(m0, len(s.F), gap))
        m *= 2
    return surface


def _largest_distance(P: np.ndarray, surface: TargetSurface) -> float:
    """The largest distance from the points ``P`` (k, 3) to the triangles of ``surface``."""
    import igl

    d2, _, _ = igl.point_mesh_squared_distance(np.ascontiguousarray(P, dtype=float),
                                               np.ascontiguousarray(surface.V, dtype=float),
                                               np.ascontiguousarray(surface.F, dtype=np.int64))
    return float(np.sqrt(max(float(d2.max()), 0.0)))


def _edges(F: np.ndarray):
    """Undirected edges (k, 2) and, per edge, how many faces use it."""
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(E, axis=0, return_counts=True)
    return uniq, count


def _coincident_across(V, labels, diag):
    """A pair of vertices (i, j) in different pieces at the same point (to 1e-9 of the diagonal), or None."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(V).query_pairs(1e-9 * diag, output_type="ndarray")
    across = pairs[labels[pairs[:, 0]] != labels[pairs[:, 1]]] if len(pairs) else pairs
    if len(across) == 0:
        return None
    across = np.sort(across, axis=1)
    first = np.lexsort((across[:, 1], across[:, 0]))[0]  # the lowest-numbered pair: a stable message
    return int(across[first, 0]), int(across[first, 1])


def _orientation_conflict(F):
    """A triangle at which no consistent orientation closes (the surface is non-orientable), or None.

    Two triangles sharing an edge agree when they run along it in opposite directions. On the double cover
    (each triangle as kept, 2t, and flipped, 2t+1) an agreeing pair links kept–kept and flipped–flipped, a
    disagreeing pair kept–flipped: the mesh is orientable iff no triangle's two copies are connected.
    Call on an edge-manifold mesh (at most two triangles per edge)."""
    m = len(F)
    half = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    tri = np.tile(np.arange(m), 3)
    und = np.sort(half, axis=1)
    _, inv, cnt = np.unique(und, axis=0, return_inverse=True, return_counts=True)
    inv = np.asarray(inv).ravel()
    order = np.argsort(inv, kind="stable")
    inner = cnt[inv[order]] == 2
    o = order[inner].reshape(-1, 2)  # the two half-edges of each interior edge
    t, u = tri[o[:, 0]], tri[o[:, 1]]
    same = half[o[:, 0], 0] == half[o[:, 1], 0]  # both run the same way: one of them must flip
    rows = np.r_[2 * t, 2 * t + 1]
    cols = np.r_[2 * u + same, 2 * u + 1 - same]
    A = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(2 * m, 2 * m))
    _, lab = connected_components(A, directed=False)
    bad = np.flatnonzero(lab[0::2] == lab[1::2])
    return int(bad[0]) if len(bad) else None


def check_target(V, F, where: str = "the target surface", face=None) -> TargetSurface:
    """Check a triangle mesh for inverse design and orient it consistently.

    ``face`` (f,), optional: the file face each triangle was split from (messages name that face).

    Raises
    ------
    InputError
        One line naming ``where`` and the first problem found.
    """
    import igl

    V = np.asarray(V, float)
    F = np.asarray(F, np.int64)

    def triangle(i):  # how a message names triangle i: as the file has it
        return f"triangle {i + 1}" if face is None else f"face {int(face[i]) + 1}"

    if len(F) == 0 or len(V) < 3:
        raise InputError(f"{where}: the mesh is empty (no triangles)")
    # unused vertices are dropped first, then only the used ones are checked: an unused NaN was refused
    # while an unused 1e20 was accepted, though neither touches the surface
    used = np.unique(F)
    remap = -np.ones(len(V), np.int64)
    remap[used] = np.arange(len(used))
    V, F = V[used], remap[F]
    if not np.isfinite(V).all():
        bad = int(np.flatnonzero(~np.isfinite(V).all(axis=1))[0])
        raise InputError(f"{where}: vertex {used[bad] + 1} has a non-finite coordinate")
    dup = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    if dup.any():
        raise InputError(f"{where}: {triangle(int(np.flatnonzero(dup)[0]))} repeats a vertex")
    diag = float(np.linalg.norm(np.ptp(V, axis=0)))
    if not diag > 0:
        raise InputError(f"{where}: all vertices coincide")
    areas = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    flat = areas <= 1e-12 * diag**2
    if flat.any():
        n = int(flat.sum())
        raise InputError(f"{where}: {n} triangle{'s have' if n != 1 else ' has'} zero area (the first is "
                         f"{triangle(int(np.flatnonzero(flat)[0]))})")
    # a face given twice (either orientation) makes its edges look non-manifold: name it for what it is
    key, first, inverse = np.unique(np.sort(F, axis=1), axis=0, return_index=True, return_inverse=True)
    if len(key) < len(F):
        inverse = np.asarray(inverse).ravel()
        j = int(np.flatnonzero(first[inverse] != np.arange(len(F)))[0])
        raise InputError(f"{where}: {triangle(j)} duplicates {triangle(int(first[inverse[j]]))} (the same three "
                         f"vertices): remove one")
    E, count = _edges(F)
    if (count > 2).any():
        a, b = E[np.flatnonzero(count > 2)[0]]
        raise InputError(f"{where}: the mesh is not manifold: the edge between vertices {used[a] + 1} and {used[b] + 1} "
                         f"has {int(count[count > 2][0])} triangles")
    adj = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(len(V), len(V)))
    pieces, labels = connected_components(adj, directed=False)
    if pieces > 1:
        seam = _coincident_across(V, labels, diag)
        if seam is not None:  # an unwelded seam: the pieces are one surface whose copies were not merged
            a, b = (int(used[v]) + 1 for v in seam)
            raise InputError(f"{where}: the mesh falls into {pieces} pieces that touch at coincident vertices that "
                             f"are not merged (vertices {a} and {b}): weld them")
        raise InputError(f"{where}: the mesh has {pieces} separate pieces; give one connected surface")
    manifold_vertex = np.asarray(igl.is_vertex_manifold(F)).ravel().astype(bool)
    if not manifold_vertex.all():
        v = int(np.flatnonzero(~manifold_vertex)[0])
        raise InputError(f"{where}: the mesh is not manifold at vertex {used[v] + 1} (two sheets meet there)")
    if _orientation_conflict(F) is not None:  # igl.bfs_orient cannot tell; Euler's formula then gave "-16 handle(s)"
        raise InputError(f"{where}: the surface is one-sided (not orientable, like a Möbius strip): an X-shell is a "
                         f"two-sided sheet")
    F, _ = igl.bfs_orient(F)
    F = np.asarray(F, np.int64)
    loops = (count == 1).any() and len(igl.boundary_loop_all(F)) or 0
    if loops == 0:
        raise InputError(f"{where}: the surface is closed (it has no boundary): an X-shell is a sheet; cut it open")
    euler = len(V) - len(E) + len(F)
    genus = (2 - loops - euler) // 2
    if genus != 0:
        raise InputError(f"{where}: the surface has {genus} handle(s); only sheets with holes are supported")
    # Orient the normals to the side the surface bulges to along +z of its file, so "up" is the
    # designer's up (a vertical sheet keeps the file's orientation).
    normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    if normals[:, 2].sum() < 0:
        F = F[:, ::-1].copy()
    F.setflags(write=False)
    V.setflags(write=False)
    return TargetSurface(V, F, where, diag, float(areas.sum()), int(loops))


#: ∫|K| dA (radians) below which a surface counts as developable: the shared barrel vault has 0 to
#: round-off, the flattest curved target measured (the spherical cap, half-angle 30°) 0.75
DEVELOPABLE_CURVATURE = 0.05


def angle_defects(surface: TargetSurface) -> np.ndarray:
    """Discrete Gaussian curvature ``2π − Σ angles`` (radians) per vertex, shape (n,); 0 on the boundary.

    Summed over a region it is ∫K dA there (Gauss–Bonnet), so on a spherical cap of
    half-angle θ it tends to 2π(1 − cos θ) as the mesh refines (the boundary ring's share aside).
    """
    V, F = surface.V, surface.F
    angles = np.zeros(F.shape)
    for c in range(3):
        a = V[F[:, (c + 1) % 3]] - V[F[:, c]]
        b = V[F[:, (c + 2) % 3]] - V[F[:, c]]
        angles[:, c] = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
    defect = 2.0 * np.pi - np.bincount(F.ravel(), angles.ravel(), minlength=len(V))
    E, count = _edges(F)
    defect[np.unique(E[count == 1])] = 0.0
    return defect


def total_curvature(surface: TargetSurface) -> float:
    """∫|K| dA (radians) over the interior vertices: the total Gaussian curvature an X-shell must make."""
    return float(np.abs(angle_defects(surface)).sum())


def plane_deviation(surface: TargetSurface) -> float:
    """Mean distance of the vertices to their least-squares plane, as a share of the diagonal."""
    C = surface.V - surface.V.mean(axis=0)
    normal = np.linalg.svd(C, full_matrices=False)[2][2]
    return float(np.abs(C @ normal).mean() / surface.diagonal)


def developable_warning(surface: TargetSurface, fit_bar: float, curvature: float | None = None) -> str:
    """'' or one line (without the file's name): the surface is developable but curved beyond the mean-fit bar ``fit_bar``.

    ``curvature``: the surface's :func:`total_curvature`, where the caller has it already.

    A net on a developable surface unrolls into the plane with the same lengths, angles and
    in-plane bending and without the out-of-plane bending, so a planar state of lower energy
    always exists at the same opening angle: the beams of an X-shell cannot lie on such a surface,
    only near it, in a slightly doubly curved shell (docs/inverse.md, Limits). A nearly flat one is
    still within the bar of a plane.
    """
    k = total_curvature(surface) if curvature is None else curvature
    dev = plane_deviation(surface)
    if k >= DEVELOPABLE_CURVATURE or dev <= fit_bar:
        return ""
    return (f"the surface is developable (total Gaussian curvature {k:.2g} rad) and curved "
            f"({100 * dev:.1f}% of its diagonal off its plane, on average): an X-shell's beams cannot lie on it (a "
            f"flat state has less energy), only near it, in a slightly doubly curved shell; see docs/inverse.md, Limits")
