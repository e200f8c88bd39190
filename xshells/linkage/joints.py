"""The joint map: from a joint's 9 variables to the terminal edges of its rods.

A joint (paper §3, Fig. 3) has a position ``p``, an infinitesimal rotation
``ω`` about its source frame ``(b0, n0)`` (reset after every accepted step),
an opening angle ``α`` and the lengths ``ℓA, ℓB`` of its two edges. With
``b = R(ω) b0`` (the bisector of the two beams), ``n = R(ω) n0`` (the
normal) and ``u = n × b``::

    t_A = cos(α/2) b − sin(α/2) u        t_B = cos(α/2) b + sin(α/2) u

so that ``angle(t_A, t_B) = α`` and ``t_A × t_B = sin(α) n``. Each beam's
terminal edge ``ℓ t`` is centred on the joint. A rod that meets the joint
on beam X with orientation ``σ = ±1`` (its edge runs along ``σ t_X``) has
that edge from ``p − σℓt_X/2`` to ``p + σℓt_X/2``; its material frame there
is ``m2 = n`` rotated by the cross-section angle ``φ`` about the edge, and
``θ`` is the angle from the rod's reference director (transported in time
from the rod's source frame) to ``m1``.

One *instance* is one rod end at a joint. Instance variables are packed
``[p (3), ω (3), α, ℓA, ℓB]``; instance parameters are

=====  ===================================================
0:3    ``b0``
3:6    ``n0``
6      beam: 0 for A, 1 for B
7      ``σ``
8:11   the rod edge's source tangent
11:14  the rod edge's source director ``d1``
14     ``θ`` at the last source update (picks the 2π branch)
15     cross-section angle ``φ``
=====  ===================================================

Outputs per instance: the edge's start point (3), end point (3) and ``θ``.
"""
from __future__ import annotations

import functools

import numpy as np

from ..rod import vec

NUM_JOINT_VARS = 9
NUM_INSTANCE_PARAMS = 16
NUM_OUTPUTS = 7


def rotate(w, v):
    """``exp([ω]×) v`` by Rodrigues' formula, smooth (and Taylor-expanded) at ``ω = 0``."""
    th2 = vec.dot(w, w)
    xp = vec.array_module(th2)
    small = th2 < 1e-8
    safe = xp.where(small, 1.0, th2)
    th = xp.sqrt(safe)
    a = xp.where(small, 1.0 - th2 / 6.0 + th2 * th2 / 120.0, xp.sin(th) / th)
    b = xp.where(small, 0.5 - th2 / 24.0 + th2 * th2 / 720.0, (1.0 - xp.cos(th)) / safe)
    wv = vec.cross(w, v)
    wwv = vec.cross(w, wv)
    return tuple(v[i] + a * wv[i] + b * wwv[i] for i in range(3))


def joint_frame(q, b0, n0):
    """Unit tangents ``t_A, t_B`` and normal ``n`` of joints with variables ``q``."""
    w = (q[3], q[4], q[5])
    b = rotate(w, b0)
    n = rotate(w, n0)
    u = vec.cross(n, b)
    xp = vec.array_module(q[6])
    c, s = xp.cos(0.5 * q[6]), xp.sin(0.5 * q[6])
    return vec.combine(c, b, -s, u), vec.combine(c, b, s, u), n


def instance_outputs(q, prm):
    """Terminal edge endpoints and material angle of each instance: tuple of 7 arrays (N,)."""
    b0, n0 = (prm[0], prm[1], prm[2]), (prm[3], prm[4], prm[5])
    beam, sigma = prm[6], prm[7]
    tA, tB, n = joint_frame(q, b0, n0)
    t = vec.combine(1.0 - beam, tA, beam, tB)
    length = (1.0 - beam) * q[7] + beam * q[8]
    te = vec.scale(sigma, t)
    half = vec.scale(0.5 * length, te)
    p = (q[0], q[1], q[2])
    start, end = vec.sub(p, half), vec.add(p, half)
    d1 = vec.parallel_transport((prm[8], prm[9], prm[10]), te, (prm[11], prm[12], prm[13]))
    d2 = vec.cross(te, d1)
    phi = prm[15]
    xp = vec.array_module(te[0])
    m1 = vec.combine(xp.cos(phi), vec.cross(n, te), -xp.sin(phi), n)
    raw = xp.arctan2(vec.dot(m1, d2), vec.dot(m1, d1))
    theta = raw + 2.0 * np.pi * xp.round((prm[14] - raw) / (2.0 * np.pi))
    return (*start, *end, theta)


@functools.cache
def _evaluate():
    """The jitted map (JAX loads on first use: the solver uses the NumPy twin in :mod:`.joint_kernels`)."""
    from .. import _jaxconfig  # noqa: F401

    import jax
    import jax.numpy as jnp

    return jax.jit(lambda q, prm: jnp.stack(instance_outputs(tuple(q), tuple(prm))))


def _pad(arrays, n):
    from ..rod.autodiff import bucket

    m = bucket(n)
    out = []
    for a in arrays:
        p = np.empty((a.shape[0], m))
        p[:, :n] = a
        p[:, n:] = a[:, :1]
        out.append(p)
    return out


def outputs(q: np.ndarray, prm: np.ndarray) -> np.ndarray:
    """Instance outputs, (7, N)."""
    n = q.shape[1]
    qp, pp = _pad([q, prm], n)
    return np.asarray(_evaluate()(qp, pp))[:, :n]
