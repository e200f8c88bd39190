"""How well a deployment fits its target surface: placement, distances, coverage, overlaps."""
from __future__ import annotations

import numpy as np

from ..design.fitting import point_mesh_squared_distance
from .surface import TargetSurface


def kabsch(P: np.ndarray, Q: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """The proper rigid 4×4 transform T minimizing Σ w |T P − Q|² (rows are points)."""
    w = np.ones(len(P)) if w is None else np.asarray(w, float)
    w = w / w.sum()
    pc, qc = w @ P, w @ Q
    H = (P - pc).T @ ((Q - qc) * w[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, qc - R @ pc
    return T


def apply(T: np.ndarray, P: np.ndarray) -> np.ndarray:
    return P @ T[:3, :3].T + T[:3, 3]


def mirror_image(P: np.ndarray, normal) -> np.ndarray:
    """Points (k, 3) reflected through the plane through the origin normal to ``normal`` (a unit 3-vector): where a
    flat layout of that normal deploys, the other ``direction`` deploys to this image (up to a rigid motion)."""
    n = np.asarray(normal, float)
    return P - 2.0 * np.outer(P @ n, n)


def surface_distances(surface: TargetSurface, P: np.ndarray) -> np.ndarray:
    """Unsigned distances (k,) of points to the surface."""
    sq, _, _ = point_mesh_squared_distance(np.asarray(P, float), surface.V, surface.F)
    return np.sqrt(np.maximum(np.asarray(sq, float), 0.0))


def place(surface: TargetSurface, joints: np.ndarray, guess: np.ndarray, target_weight: float = 0.1,
          iterations: int = 30) -> np.ndarray:
    """The rigid placement of ``joints`` (k, 3) on the surface.

    Starts from the Kabsch fit onto ``guess`` (k, 3) (where the joints are
    meant to go), then alternates closest points and Kabsch, each joint
    pulled to its closest surface point with weight 1 − ``target_weight``
    and to its guess with ``target_weight`` (the split of the fitting term,
    eq. 6: the shell may slide along the surface, a little).
    """
    T = kabsch(joints, guess)
    for _ in range(iterations):
        X = apply(T, joints)
        _, _, C = point_mesh_squared_distance(X, surface.V, surface.F)
        goal = (1.0 - target_weight) * np.asarray(C) + target_weight * guess
        T_new = kabsch(joints, goal)
        if np.abs(T_new - T).max() <= 1e-12 * max(1.0, surface.diagonal):
            T = T_new
            break
        T = T_new
    return T


def coverage(surface: TargetSurface, beam_points: np.ndarray, beam_edges: np.ndarray, radius: float,
             refinements: int = 2) -> float:
    """Share of the surface's area within ``radius`` of a beam (rod centerline polylines, placed).

    The surface is sampled at the centroids of its triangles after
    ``refinements`` midpoint subdivisions, weighted by area; the beams are
    resampled every ``radius / 8`` so that the nearest sample is within
    ``radius / 16`` of the nearest centerline point.
    """
    import igl
    from scipy.spatial import cKDTree

    V, F = surface.V, surface.F
    for _ in range(refinements):
        V, F = igl.upsample(V, F)
    C = V[F].mean(axis=1)
    A = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    a, b = beam_points[beam_edges[:, 0]], beam_points[beam_edges[:, 1]]
    n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / (radius / 8.0)).astype(int))
    t = np.concatenate([np.arange(k + 1) / k for k in n])
    i = np.repeat(np.arange(len(a)), n + 1)
    samples = a[i] + t[:, None] * (b[i] - a[i])
    d, _ = cKDTree(samples).query(C)
    return float(A[d <= radius].sum() / A.sum())
