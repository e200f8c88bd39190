"""The target surface of inverse design: a checked triangle mesh, in design units.

Every defect a mesh can have for this purpose is reported as one line that
names the file: unreadable, empty, non-finite coordinates, non-manifold
edges or vertices, several pieces, a closed surface (no boundary) or one
with handles. Faces are re-oriented consistently (a mixed orientation is a
property of how the mesh was exported, not of the surface).
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
    """

    V: np.ndarray = field(repr=False)
    F: np.ndarray = field(repr=False)
    path: str = ""
    diagonal: float = 0.0
    area: float = 0.0
    boundary_loops: int = 1
    note: str | None = None

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


def load_target(path) -> TargetSurface:
    """Read and check a target surface (OBJ, PLY, STL or gmsh ``.msh``, quads and polygons split into
    triangles; see :func:`check_target`)."""
    from dataclasses import replace

    from ..design.fitting import read_surface_noted

    V, F, face, note = read_surface_noted(path)
    return replace(check_target(V, F, str(path), face=face), note=note)


def _edges(F: np.ndarray):
    """Undirected edges (k, 2) and, per edge, how many faces use it."""
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(E, axis=0, return_counts=True)
    return uniq, count


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
    if not np.isfinite(V).all():
        bad = int(np.flatnonzero(~np.isfinite(V).all(axis=1))[0])
        raise InputError(f"{where}: vertex {bad + 1} has a non-finite coordinate")
    used = np.unique(F)
    remap = -np.ones(len(V), np.int64)
    remap[used] = np.arange(len(used))
    V, F = V[used], remap[F]
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
    E, count = _edges(F)
    if (count > 2).any():
        a, b = E[np.flatnonzero(count > 2)[0]]
        raise InputError(f"{where}: the mesh is not manifold: the edge between vertices {used[a] + 1} and {used[b] + 1} "
                         f"has {int(count[count > 2][0])} triangles")
    adj = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(len(V), len(V)))
    pieces, _ = connected_components(adj, directed=False)
    if pieces > 1:
        raise InputError(f"{where}: the mesh has {pieces} separate pieces; give one connected surface")
    manifold_vertex = np.asarray(igl.is_vertex_manifold(F)).ravel().astype(bool)
    if not manifold_vertex.all():
        v = int(np.flatnonzero(~manifold_vertex)[0])
        raise InputError(f"{where}: the mesh is not manifold at vertex {used[v] + 1} (two sheets meet there)")
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
    always exists at the same opening angle: an X-shell deploys off such a surface (docs/inverse.md,
    Limits). A nearly flat one is still within the bar of a plane.
    """
    k = total_curvature(surface) if curvature is None else curvature
    dev = plane_deviation(surface)
    if k >= DEVELOPABLE_CURVATURE or dev <= fit_bar:
        return ""
    return (f"the surface is developable (total Gaussian curvature {k:.2g} rad) and curved "
            f"({100 * dev:.1f}% of its diagonal off its plane, on average): an X-shell deploys off such a surface "
            f"(it has a flat state of lower energy); expect a miss, and see docs/inverse.md, Limits")
