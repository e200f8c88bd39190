"""The scissor map: the flat, closed layout of a target surface, as a metric problem.

A small patch of an X-shell whose two beam families cross at angle α and
bisect a unit direction ``e₁`` deforms, when it opens from α₀ to α with
inextensible beams, by the stretch

    λ₁ = cos(α/2) / cos(α₀/2)   along e₁,    λ₂ = sin(α/2) / sin(α₀/2)   across it,

since the beam directions (cos α₀/2, ±sin α₀/2) go to (cos α/2, ±sin α/2).
Closing a deployed surface patch therefore maps it to the plane with the
singular values ``1/λ₁`` (along e₁) and ``1/λ₂`` (across). A flat layout of
the whole surface with joints closed uniformly to α₀ exists exactly when a
direction field ``e₁`` on the surface makes this anisotropic metric flat.

:func:`scissor_map` finds one: a map ψ from the surface to the plane whose
Jacobian has, triangle by triangle, exactly those singular values, by
alternating projections as in as-rigid-as-possible parameterization (Liu et
al. 2008), with the fixed singular values ``(1/λ₁, 1/λ₂)`` in place of
``(1, 1)``. The local step is an SVD per triangle (its right singular vector
is the director), the global step one prefactored Poisson solve per
coordinate. The residual says how far the surface is from having such a
layout at all.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from .surface import TargetSurface


def stretches(deployed_angle: float, flat_angle: float) -> tuple[float, float]:
    """(λ₁, λ₂): the opening's stretch along and across the beams' bisector (angles in radians)."""
    return (float(np.cos(deployed_angle / 2) / np.cos(flat_angle / 2)),
            float(np.sin(deployed_angle / 2) / np.sin(flat_angle / 2)))


@dataclass(frozen=True)
class FaceFrames:
    """Per-triangle orthonormal frames and the P1 gradient operator in them.

    Attributes
    ----------
    ex, ey, normal : (m, 3) float
    area : (m,) float
    edges : (m, 2, 2) float
        Columns: the edges v₁−v₀ and v₂−v₀ in the frame.
    grad : (2m, n) sparse
        Rows 2f, 2f+1: the gradient of a P1 function in triangle f's frame.
    faces : (m, 3) int
    edges_inv : (m, 2, 2) float
        The inverses of ``edges`` (every Jacobian needs them; 12 ms per call on 80k faces).
    """

    ex: np.ndarray = field(repr=False)
    ey: np.ndarray = field(repr=False)
    normal: np.ndarray = field(repr=False)
    area: np.ndarray = field(repr=False)
    edges: np.ndarray = field(repr=False)
    grad: sp.csr_matrix = field(repr=False)
    faces: np.ndarray = field(repr=False)
    edges_inv: np.ndarray = field(repr=False, default=None)

    def to_3d(self, d2: np.ndarray) -> np.ndarray:
        """Per-face 2D frame vectors (m, 2) as 3D vectors (m, 3)."""
        return d2[:, :1] * self.ex + d2[:, 1:] * self.ey

    def jacobians(self, values: np.ndarray) -> np.ndarray:
        """Per-face Jacobians (m, k, 2) of a P1 map with vertex values (n, k)."""
        F = self.faces
        d = np.stack([values[F[:, 1]] - values[F[:, 0]], values[F[:, 2]] - values[F[:, 0]]], axis=2)
        return d @ (np.linalg.inv(self.edges) if self.edges_inv is None else self.edges_inv)


def _det2(A: np.ndarray) -> np.ndarray:
    """Determinants of a stack of 2 × 2 matrices (m, 2, 2), in closed form (LAPACK's per-matrix call
    took 6 ms on 80k faces)."""
    return A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]


def face_frames(V: np.ndarray, F: np.ndarray) -> FaceFrames:
    e1 = V[F[:, 1]] - V[F[:, 0]]
    e2 = V[F[:, 2]] - V[F[:, 0]]
    n = np.cross(e1, e2)
    twice = np.linalg.norm(n, axis=1)
    n = n / twice[:, None]
    ex = e1 / np.linalg.norm(e1, axis=1)[:, None]
    ey = np.cross(n, ex)
    M = np.stack([np.c_[(e1 * ex).sum(1), (e1 * ey).sum(1)], np.c_[(e2 * ex).sum(1), (e2 * ey).sum(1)]], axis=2)
    C = np.linalg.inv(M)
    m = len(F)
    rows, cols, vals = [], [], []
    for k in range(2):  # ∂f/∂x_k = Σ_i (f_i − f_0) C[i−1, k]
        r = 2 * np.arange(m) + k
        rows += [r, r, r]
        cols += [F[:, 0], F[:, 1], F[:, 2]]
        vals += [-(C[:, 0, k] + C[:, 1, k]), C[:, 0, k], C[:, 1, k]]
    G = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(2 * m, len(V)))
    return FaceFrames(ex, ey, n, 0.5 * twice, M, G, F, C)


class PoissonSolver:
    """argmin_f Σ_faces area·|∇f − g|² with f pinned at one vertex (prefactored)."""

    def __init__(self, frames: FaceFrames, pin: int = 0):
        self.G = frames.grad
        self.W = sp.diags(np.repeat(frames.area, 2))
        K = (self.G.T @ self.W @ self.G).tolil()
        K[pin, :] = 0
        K[pin, pin] = 1.0
        self.pin = pin
        self.lu = splu(K.tocsc())

    def solve(self, g: np.ndarray, pin_value: float = 0.0, weights: np.ndarray | None = None) -> np.ndarray:
        """``g``: target gradients (m, 2) in the face frames."""
        w = self.W if weights is None else sp.diags(np.repeat(weights, 2))
        b = self.G.T @ (w @ g.reshape(-1))
        b[self.pin] = pin_value
        return self.lu.solve(b)


@dataclass(frozen=True)
class ScissorMap:
    """The closed layout of a surface.

    Attributes
    ----------
    flat : (n, 2) float
        ψ at the surface's vertices.
    director : (m, 2) float
        e₁ per face, unit, in the face frames (signs made consistent).
    residual : float
        RMS over the area of ``|Dψ − T|`` relative to ``|T|``: 0 when the
        surface has an exact layout closed uniformly to α₀.
    stretch : (λ₁, λ₂)
    frames : FaceFrames
    """

    flat: np.ndarray = field(repr=False)
    director: np.ndarray = field(repr=False)
    residual: float
    stretch: tuple
    frames: FaceFrames = field(repr=False)

    def mean_director_3d(self) -> np.ndarray:
        """The area-weighted mean of the director e₁ in space, unit, shape (3,)."""
        e = (self.frames.to_3d(self.director) * self.frames.area[:, None]).sum(0)
        return e / np.linalg.norm(e)


def _initial_director_uv(V, uv, orientation: float, axis=None) -> np.ndarray:
    """The direction in the LSCM plane of ``axis`` (3,), or by default of the surface's longest principal
    axis (the file's x axis where two axes are within 5 %), turned by ``orientation``."""
    A = np.c_[uv - uv.mean(0), np.ones(len(uv))]
    coef, *_ = np.linalg.lstsq(A, V - V.mean(0), rcond=None)  # V ≈ uv @ coef[:2] + c
    _, sv, vt = np.linalg.svd(V - V.mean(0), full_matrices=False)
    if axis is not None:
        axis = np.asarray(axis, float) / np.linalg.norm(axis)
    elif sv[1] <= 0.95 * sv[0]:
        axis = vt[0]
    else:
        # no clear longest axis (a square or round surface): the file's x axis in the mean plane, so that the
        # choice does not hang on round-off
        n = vt[2]
        x = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        axis = x - (x @ n) * n
        axis /= np.linalg.norm(axis)
    d = np.linalg.lstsq(coef[:2].T, axis, rcond=None)[0]
    d /= np.linalg.norm(d)
    c, s = np.cos(orientation), np.sin(orientation)
    return np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])


def scissor_map(surface: TargetSurface, deployed_angle: float, flat_angle: float, orientation: float = 0.0,
                iterations: int = 200, tolerance: float = 1e-7, axis=None) -> ScissorMap:
    """Flatten ``surface`` as an X-shell closed from ``deployed_angle`` to ``flat_angle`` (radians).

    ``orientation`` (radians) turns the beams' bisector away from ``axis``
    (3,), by default the surface's longest principal axis. Iterates until the
    relative change of the residual falls below ``tolerance``.
    """
    import igl

    V, F = surface.V, surface.F
    frames = face_frames(V, F)
    lam1, lam2 = stretches(deployed_angle, flat_angle)
    a, b = 1.0 / lam1, 1.0 / lam2
    loop = igl.boundary_loop(F)
    i0 = int(loop[0])
    i1 = int(loop[np.argmax(np.linalg.norm(V[loop] - V[i0], axis=1))])
    uv, _ = igl.lscm(V, F, np.array([i0, i1]), np.array([[0.0, 0.0], [1.0, 0.0]]))
    J = frames.jacobians(uv)
    uv = uv / np.sqrt(np.abs(np.linalg.det(J)) @ frames.area / frames.area.sum())
    d = _initial_director_uv(V, uv, orientation, axis)
    R = np.array([[d[0], -d[1]], [d[1], d[0]]])  # e₁ of the uv plane along d
    psi = (uv @ R) @ np.diag([a, b])
    solver = PoissonSolver(frames, pin=i0)
    D = np.diag([a, b])
    prev = np.inf
    scale = np.hypot(a, b)
    for _ in range(iterations):
        J = frames.jacobians(psi)
        U, S, Vt = np.linalg.svd(J)
        flip = _det2(U) * _det2(Vt) < 0  # ±1 each (orthogonal): the sign of the product is exact
        U[flip, :, 1] *= -1
        T = U @ D[None] @ Vt
        res = float(np.sqrt((((J - T) ** 2).sum((1, 2)) * frames.area).sum() / frames.area.sum())) / scale
        psi = np.c_[solver.solve(T[:, 0, :], psi[i0, 0]), solver.solve(T[:, 1, :], psi[i0, 1])]
        if abs(prev - res) <= tolerance * max(res, 1e-12) or res < 1e-12:
            break
        prev = res
    J = frames.jacobians(psi)
    U, S, Vt = np.linalg.svd(J)
    e1 = Vt[:, 0, :].copy()  # the direction Dψ shortens least, i.e. 1/λ₁ > 1/λ₂: the bisector
    # the SVD's signs are arbitrary per face: align every e₁ with the mean director (a field, not a line field)
    e13 = frames.to_3d(e1)
    ref = np.linalg.svd(e13 * np.where(e13 @ e13[0] < 0, -1.0, 1.0)[:, None], full_matrices=False)[2][0]
    e1 *= np.where(e13 @ ref < 0, -1.0, 1.0)[:, None]
    T = U @ D[None] @ Vt
    res = float(np.sqrt((((J - T) ** 2).sum((1, 2)) * frames.area).sum() / frames.area.sum())) / scale
    return ScissorMap(psi, e1, res, (lam1, lam2), frames)
