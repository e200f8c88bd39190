"""Triangle meshes of cross-section profiles (Shewchuk's Triangle).

Meshes are quality meshes (minimum angle :data:`MIN_ANGLE` degrees) so that
P2 elements behave; refinement passes a per-triangle area limit back to
Triangle, which keeps the boundary segments and the quality bound.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import triangle

from .profiles import Profile

MIN_ANGLE = 28.0


@dataclass(frozen=True)
class TriMesh:
    """A planar triangle mesh.

    Attributes
    ----------
    points : ndarray, shape (n, 2)
    triangles : ndarray of int, shape (m, 3), counter-clockwise
    segments : ndarray of int, shape (s, 2)
        Boundary edges Triangle must keep (subdivided boundary).
    hole_points : ndarray, shape (h, 2)
        One point inside each hole.
    """

    points: np.ndarray
    triangles: np.ndarray
    segments: np.ndarray
    hole_points: np.ndarray

    def triangle_areas(self) -> np.ndarray:
        """Area of each triangle, shape (m,)."""
        return _areas(self.points[self.triangles])


def _areas(corners: np.ndarray) -> np.ndarray:
    """Unsigned areas (m,) of triangles given by their corners (m, 3, 2)."""
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def _loop_segments(sizes: list[int]) -> np.ndarray:
    """Closed-loop segments (s, 2) for loops of the given sizes stacked in order."""
    segments, offset = [], 0
    for n in sizes:
        i = np.arange(n) + offset
        segments.append(np.column_stack((i, np.roll(i, -1))))
        offset += n
    return np.concatenate(segments)


def hole_point(loop: np.ndarray) -> np.ndarray:
    """A point strictly inside a simple polygon ``loop`` (n, 2), shape (2,).

    The centroid of a triangle of the loop's own constrained triangulation
    is always inside, even for non-convex holes.
    """
    pslg = {"vertices": loop, "segments": _loop_segments([len(loop)])}
    tri = triangle.triangulate(pslg, "pQ")
    corners = tri["vertices"][tri["triangles"]]
    return corners[np.argmax(_areas(corners))].mean(axis=0)


def _as_trimesh(tri: dict, hole_points: np.ndarray) -> TriMesh:
    return TriMesh(points=tri["vertices"], triangles=tri["triangles"].astype(np.int64),
                   segments=tri["segments"], hole_points=hole_points)


def triangulate_loops(loops: list[np.ndarray], max_area: float, min_angle: float = MIN_ANGLE) -> TriMesh:
    """Quality-mesh the region bounded by ``loops`` (outer first, then holes).

    Parameters
    ----------
    loops : list of ndarray, each shape (n_k, 2)
    max_area : float
        Largest triangle area allowed.
    min_angle : float
        Smallest angle allowed, degrees.
    """
    holes = np.array([hole_point(h) for h in loops[1:]]).reshape(-1, 2)
    pslg = {"vertices": np.concatenate(loops), "segments": _loop_segments([len(l) for l in loops])}
    if len(holes):
        pslg["holes"] = holes
    tri = triangle.triangulate(pslg, f"pq{min_angle:g}a{max_area:.17g}Q")
    return _as_trimesh(tri, holes)


def triangulate_profile(profile: Profile, max_area: float, min_angle: float = MIN_ANGLE) -> TriMesh:
    """Quality mesh of a profile's polygon; see :func:`triangulate_loops`."""
    return triangulate_loops(profile.loops, max_area, min_angle)


def refine(mesh: TriMesh, max_areas: np.ndarray, min_angle: float = MIN_ANGLE) -> TriMesh:
    """Refine ``mesh`` so that triangle ``i`` is split below ``max_areas[i]``.

    Parameters
    ----------
    mesh : TriMesh
    max_areas : ndarray, shape (m,)
        Per-triangle area limit; a value <= 0 leaves that triangle unconstrained.
    min_angle : float
        Smallest angle allowed, degrees.
    """
    data = {"vertices": mesh.points, "triangles": mesh.triangles.astype(np.int32),
            "segments": mesh.segments, "triangle_max_area": np.asarray(max_areas, dtype=float)}
    if len(mesh.hole_points):
        data["holes"] = mesh.hole_points
    tri = triangle.triangulate(data, f"rpq{min_angle:g}aQ")
    return _as_trimesh(tri, mesh.hole_points)
