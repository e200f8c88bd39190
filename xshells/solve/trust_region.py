"""Trust-region subproblem: Steihaug–Toint conjugate gradients.

Shared by the outer optimizations (design optimization, actuation
sparsification), whose Hessians are only available as products.
"""
from __future__ import annotations

import numpy as np


def steihaug(hessp, g: np.ndarray, radius: float, tol: float, max_iter: int) -> np.ndarray:
    """Approximate minimizer of ``gᵀs + ½ sᵀHs`` subject to ``‖s‖ ≤ radius``.

    Parameters
    ----------
    hessp : callable, (n,) -> (n,)
        ``v ↦ H v``.
    g : (n,) array
    radius : float
    tol : float
        Stop when the model's gradient norm falls below this.
    max_iter : int

    Returns
    -------
    (n,) array
        The step; it lies on the boundary when CG meets negative curvature
        or leaves the region.
    """
    s = np.zeros_like(g)
    r = -g
    d = r.copy()
    rr = r @ r
    if np.sqrt(rr) <= tol:
        return s
    for _ in range(max_iter):
        Hd = hessp(d)
        dHd = d @ Hd
        if dHd <= 0:
            return s + to_boundary(s, d, radius) * d
        a = rr / dHd
        if np.linalg.norm(s + a * d) >= radius:
            return s + to_boundary(s, d, radius) * d
        s = s + a * d
        r = r - a * Hd
        rr_new = r @ r
        if np.sqrt(rr_new) <= tol:
            return s
        d = r + (rr_new / rr) * d
        rr = rr_new
    return s


def to_boundary(s: np.ndarray, d: np.ndarray, radius: float) -> float:
    """The ``τ ≥ 0`` with ``‖s + τ d‖ = radius``."""
    a, b, c = d @ d, 2 * s @ d, s @ s - radius**2
    return (-b + np.sqrt(max(b * b - 4 * a * c, 0.0))) / (2 * a)
