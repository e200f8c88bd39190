"""Generated layouts: regular and warped rhombic grids."""
from __future__ import annotations

import numpy as np

from ..io.design import Design, design_from_arrays


def rhombic_grid(nx: int, ny: int, spacing: float = 1.0, angle: float = np.pi / 2, warp=None) -> Design:
    """A grid of two families of straight beams crossing at ``angle``.

    Parameters
    ----------
    nx, ny : int
        Segments along each beam family (so ``(nx + 1)(ny + 1)`` joints).
    spacing : float
        Joint spacing along the beams.
    angle : float
        Opening angle between the two beam families, radians.
    warp : callable, optional
        Maps the (n, 2) joint positions of the regular grid to new (n, 2)
        positions, e.g. to make an incompatible layout.

    Returns
    -------
    Design
        Joints in the plane ``z = 0``; vertex ``i (ny + 1) + j`` is grid point ``(i, j)``.
    """
    a = spacing * np.array([np.cos(angle / 2), np.sin(angle / 2)])
    b = spacing * np.array([np.cos(angle / 2), -np.sin(angle / 2)])
    i, j = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), indexing="ij")
    pts = i.ravel()[:, None] * a + j.ravel()[:, None] * b
    pts -= pts.mean(axis=0)
    if warp is not None:
        pts = np.asarray(warp(pts), float)
    vid = lambda ii, jj: ii * (ny + 1) + jj  # noqa: E731
    edges = [(vid(ii, jj), vid(ii + 1, jj)) for ii in range(nx) for jj in range(ny + 1)]
    edges += [(vid(ii, jj), vid(ii, jj + 1)) for ii in range(nx + 1) for jj in range(ny)]
    return design_from_arrays(np.c_[pts, np.zeros(len(pts))], np.array(edges))
