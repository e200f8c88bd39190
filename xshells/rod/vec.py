"""Component-wise 3-vector algebra on structure-of-arrays tuples.

A vector is a tuple ``(x, y, z)`` of arrays of shape ``(N,)``: one entry per
stencil. Written this way, JAX fuses whole stencil kernels into a few long
loops; a ``(N, 3)`` layout differentiated in reverse mode ran 20x slower
here (benchmarked in ``benchmarks/rod_kernels.py``). The functions accept
NumPy or JAX arrays.
"""
from __future__ import annotations

import sys

import numpy as np


def array_module(x):
    """The array module of ``x``: JAX when differentiated, NumPy for the solver's own state updates.

    The solver evaluates the stencil definitions (reference twist, strains,
    joint frames) on NumPy arrays at every state; run eagerly through
    ``jax.numpy``, each elementwise operation compiled once per design size
    (51 compilations, 2 s before a sweep task's first solve and 1 s more for
    each new design).
    """
    jax = sys.modules.get("jax")  # not imported: x cannot be a JAX array (and JAX need not load)
    if jax is not None and isinstance(x, jax.Array):
        return jax.numpy
    return np


def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def scale(s, a):
    return (s * a[0], s * a[1], s * a[2])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    )


def combine(s, a, t, b):
    """``s * a + t * b``."""
    return (s * a[0] + t * b[0], s * a[1] + t * b[1], s * a[2] + t * b[2])


def parallel_transport(a, b, v):
    """Transport ``v`` from unit tangent ``a`` to unit tangent ``b``.

    The rotation about ``a × b`` taking ``a`` to ``b``, written without
    normalising the axis so that it stays smooth as ``b → a``:
    ``P(v) = (a·b) v + (a×b)×v + ((a×b)·v)/(1 + a·b) (a×b)``.
    Undefined for ``b = -a``.
    """
    c = cross(a, b)
    d = dot(a, b)
    cv = cross(c, v)
    f = dot(c, v) / (1.0 + d)
    return (d * v[0] + cv[0] + f * c[0], d * v[1] + cv[1] + f * c[1], d * v[2] + cv[2] + f * c[2])
