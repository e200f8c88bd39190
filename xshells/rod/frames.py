"""Frames of a discrete rod, in NumPy: tangents, initial directors, transport.

Arrays are ``(N, 3)`` here (one row per edge); the stencil kernels use the
structure-of-arrays layout of :mod:`.vec`, which these functions share.
"""
from __future__ import annotations

import numpy as np

from . import vec


def unit_tangents(points: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents and lengths of edges.

    Parameters
    ----------
    points : (V, 3) array
    edges : (E, 2) int array

    Returns
    -------
    t : (E, 3) array
    length : (E,) array
    """
    e = points[edges[:, 1]] - points[edges[:, 0]]
    length = np.linalg.norm(e, axis=1)
    return e / length[:, None], length


def perpendicular(t: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to each row of ``t`` (E, 3), chosen deterministically."""
    axis = np.zeros_like(t)
    axis[np.arange(len(t)), np.argmin(np.abs(t), axis=1)] = 1.0
    d = np.cross(t, axis)
    return d / np.linalg.norm(d, axis=1)[:, None]


def transport(a: np.ndarray, b: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Parallel transport of rows of ``v`` from unit tangents ``a`` to ``b`` (all (N, 3))."""
    out = vec.parallel_transport(tuple(a.T), tuple(b.T), tuple(v.T))
    return np.stack(out, axis=1)


def orthonormalize(d1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Project ``d1`` (N, 3) onto the plane normal to ``t`` and normalise (removes round-off drift)."""
    d1 = d1 - np.sum(d1 * t, axis=1)[:, None] * t
    return d1 / np.linalg.norm(d1, axis=1)[:, None]


def space_parallel_directors(t: np.ndarray, first_d1: np.ndarray) -> np.ndarray:
    """Directors of one rod's edges by parallel transport along the rod.

    Parameters
    ----------
    t : (n, 3) array
        Unit tangents of the rod's consecutive edges.
    first_d1 : (3,) array
        Director of edge 0 (projected onto the plane normal to ``t[0]``).

    Returns
    -------
    d1 : (n, 3) array, with zero reference twist at every interior vertex.
    """
    return space_parallel_directors_of_rods(t, np.array([0, len(t)]), np.asarray(first_d1, float)[None, :])


def space_parallel_directors_of_rods(t: np.ndarray, offsets: np.ndarray, first_d1: np.ndarray) -> np.ndarray:
    """:func:`space_parallel_directors` of many rods at once: one transport per edge position, all rods together
    (a loop over the rods' edges took 50 of the 130 ms of building the manta ray's linkage).

    Parameters
    ----------
    t : (E, 3) array
        Unit tangents of every rod's consecutive edges, rod after rod.
    offsets : (R + 1,) int array
        Rod r's edges are ``offsets[r]:offsets[r + 1]`` (each rod has at least one).
    first_d1 : (R, 3) array
        Director of each rod's first edge.

    Returns
    -------
    d1 : (E, 3) array, the same numbers as rod by rod (the same operations on each element).
    """
    starts = np.asarray(offsets[:-1], dtype=np.int64)
    lengths = np.diff(offsets)
    d1 = np.empty_like(t)
    if not len(starts):
        return d1
    d1[starts] = orthonormalize(first_d1, t[starts])
    for j in range(1, int(lengths.max())):
        at = starts[lengths > j] + j
        d1[at] = transport(t[at - 1], t[at], d1[at - 1])
    return orthonormalize(d1, t)
