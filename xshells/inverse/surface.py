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
    """

    V: np.ndarray = field(repr=False)
    F: np.ndarray = field(repr=False)
    path: str = ""
    diagonal: float = 0.0
    area: float = 0.0
    boundary_loops: int = 1

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
    """Read and check a target surface (OBJ, PLY, STL or gmsh ``.msh``; see :func:`check_target`)."""
    from ..design.fitting import read_surface

    V, F = read_surface(path)
    return check_target(V, F, str(path))


def _edges(F: np.ndarray):
    """Undirected edges (k, 2) and, per edge, how many faces use it."""
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(E, axis=0, return_counts=True)
    return uniq, count


def check_target(V, F, where: str = "the target surface") -> TargetSurface:
    """Check a triangle mesh for inverse design and orient it consistently.

    Raises
    ------
    InputError
        One line naming ``where`` and the first problem found.
    """
    import igl

    V = np.asarray(V, float)
    F = np.asarray(F, np.int64)
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
        raise InputError(f"{where}: triangle {int(np.flatnonzero(dup)[0]) + 1} repeats a vertex")
    diag = float(np.linalg.norm(np.ptp(V, axis=0)))
    if not diag > 0:
        raise InputError(f"{where}: all vertices coincide")
    areas = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    flat = areas <= 1e-12 * diag**2
    if flat.any():
        raise InputError(f"{where}: {int(flat.sum())} triangles have zero area (the first is triangle "
                         f"{int(np.flatnonzero(flat)[0]) + 1})")
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
