"""Jitted automatic derivatives of the stencil energies (the reference method).

Shapes are padded up to a few bucket sizes so that rods of many sizes share
compiled code; padded stencils carry zero stiffness and contribute nothing.
These functions are exact for any source frame. The analytic kernels in
:mod:`.analytic` are faster and are tested against them.
"""
from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jaxconfig  # noqa: F401
from . import stencils


def bucket(n: int) -> int:
    """Smallest size >= n of the form m·2^k with m in {4, 5, 6, 7} (at most 25% padding)."""
    if n <= 8:
        return 8
    k = int(np.floor(np.log2(n))) - 2
    for m in (4, 5, 6, 7, 8):
        if m * 2**k >= n:
            return m * 2**k
    raise AssertionError


def pad_stencils(q: np.ndarray, prm: np.ndarray, stiffness_rows: slice) -> tuple[np.ndarray, np.ndarray, int]:
    """Pad (k, N) stencil arrays to a bucket size with inert copies of stencil 0."""
    n = q.shape[1]
    m = bucket(n)
    if m == n:
        return q, prm, n
    qp = np.empty((q.shape[0], m))
    qp[:, :n] = q
    qp[:, n:] = q[:, :1]
    pp = np.empty((prm.shape[0], m))
    pp[:, :n] = prm
    pp[:, n:] = prm[:, :1]
    pp[stiffness_rows, n:] = 0.0
    return qp, pp, n


# Rows of the vertex parameters holding stiffnesses (zeroed on padding).
VERTEX_STIFFNESS = slice(12, 17)


@partial(jax.jit, static_argnames="variant")
def _vertex_energies(q, prm, variant):
    return jnp.stack(stencils.vertex_energies(tuple(q), tuple(prm), variant))


def _grad_tuple(qt, pt, variant):
    return jax.grad(lambda qq: stencils.vertex_energy(qq, pt, variant))(qt)


@partial(jax.jit, static_argnames="variant")
def _vertex_gradient(q, prm, variant):
    return jnp.stack(_grad_tuple(tuple(q), tuple(prm), variant))


def _hessian_tuple(qt, pt, variant):
    n, size = len(qt), qt[0].shape[0]
    basis = tuple(jnp.broadcast_to((jnp.arange(n) == k).astype(qt[0].dtype)[:, None], (n, size)) for k in range(n))

    def column(v):
        return jnp.stack(jax.jvp(lambda qq: _grad_tuple(qq, pt, variant), (qt,), (v,))[1])

    return jax.vmap(column)(basis)


@partial(jax.jit, static_argnames="variant")
def _vertex_hessian(q, prm, variant):
    return _hessian_tuple(tuple(q), tuple(prm), variant)


def vertex_energies(q, prm, variant="2008"):
    """Bending and twisting energy per stencil: (2, N) array."""
    qp, pp, n = pad_stencils(q, prm, VERTEX_STIFFNESS)
    return np.asarray(_vertex_energies(qp, pp, variant))[:, :n]


def vertex_gradient(q, prm, variant="2008"):
    """Gradient of each stencil's energy: (13, N) array."""
    qp, pp, n = pad_stencils(q, prm, VERTEX_STIFFNESS)
    return np.asarray(_vertex_gradient(qp, pp, variant))[:, :n]


def vertex_hessian(q, prm, variant="2008"):
    """Hessian of each stencil's energy: (13, 13, N) array."""
    qp, pp, n = pad_stencils(q, prm, VERTEX_STIFFNESS)
    return np.asarray(_vertex_hessian(qp, pp, variant))[:, :, :n]
