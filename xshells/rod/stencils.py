"""Per-stencil elastic energies of the discrete elastic rod, in JAX.

These are the definitions: every other evaluation (the analytic NumPy
kernels, the assembled gradients and Hessians) is checked against automatic
differentiation of the functions here.

Two stencils make up a rod (Bergou et al. 2008, 2010; paper §3):

* the **edge stencil** (stretching): ``x0, x1`` (the edge's endpoints) and the
  rest length ``L``;
* the **vertex stencil** (bending and twisting) at an interior vertex: the
  points ``x0, x1, x2`` of its two edges ``e0 = x1 - x0``, ``e1 = x2 - x1``, the
  material angles ``θ0, θ1`` of those edges and their rest lengths ``L0, L1``.

Reference frames are carried by parallel transport *in time*: edge ``j``'s
reference director is ``d1 = P(t_src → t)(d1_src)``, with ``(t_src, d1_src)``
the source frame stored at the last accepted step. The material frame is the
reference frame rotated by ``θ`` about the tangent. The reference twist at a
vertex is the signed angle, about ``t1``, from the space-parallel transport of
``d1`` of edge 0 onto edge 1 to ``d1`` of edge 1; the ``2π`` branch is the one
nearest the value stored with the source frame.

Every argument is a tuple of arrays of shape ``(N,)`` (see :mod:`.vec`); the
vertex-stencil variables are packed as

====  =====================================================
0:3   ``x0``
3:6   ``x1``
6:9   ``x2``
9     ``θ0``
10    ``θ1``
11    ``L0`` (rest length of edge 0)
12    ``L1`` (rest length of edge 1)
====  =====================================================

and its parameters as

=====  ====================================================
0:3    ``t_src`` of edge 0
3:6    ``d1_src`` of edge 0
6:9    ``t_src`` of edge 1
9:12   ``d1_src`` of edge 1
12:16  bending stiffnesses ``B1, B2`` of edge 0, then of edge 1
16     twisting stiffness at the vertex
17:21  rest curvatures ``(κ̄1, κ̄2)`` in edge 0's frame, then edge 1's
       (the 2010 variant uses 17:19 only)
21     rest twist ``m̄``
22     reference twist stored with the source frame
=====  ====================================================

Bending energies (``ℓ = (L0 + L1)/2`` is the Voronoi rest length,
``κb = 2 t0×t1/(1 + t0·t1)`` the curvature binormal):

* ``"2008"``: ``1/(2ℓ) · ½ Σ_j (κ^j − κ̄^j)ᵀ diag(B^j) (κ^j − κ̄^j)`` with
  ``κ^j = (κb·m2_j, −κb·m1_j)`` in edge ``j``'s material frame (the paper's
  choice and the default);
* ``"2010"``: ``1/(2ℓ) (κ − κ̄)ᵀ diag(B̄) (κ − κ̄)`` with the curvature taken
  in the vertex-averaged frame ``(m1_0 + m1_1)/2, (m2_0 + m2_1)/2`` and
  ``B̄`` the mean of the two edges' stiffnesses.

Twisting: ``kt (m − m̄)² / (2ℓ)`` with ``m = θ1 − θ0 + reference twist``.
Stretching: ``ks L (|e|/L − 1)² / 2``.
"""
from __future__ import annotations

import numpy as np

from . import vec
from .vec import array_module as _xp

NUM_VERTEX_VARS = 13
NUM_VERTEX_PARAMS = 23
NUM_EDGE_VARS = 7  # x0 (3), x1 (3), L
BENDING_VARIANTS = ("2008", "2010")


def unpack3(q, start):
    return (q[start], q[start + 1], q[start + 2])


def reference_directors(t_src, d1_src, t):
    """Reference frame ``(d1, d2)`` of tangent ``t``, transported in time from the source."""
    d1 = vec.parallel_transport(t_src, t, d1_src)
    return d1, vec.cross(t, d1)


def material_directors(d1, d2, theta):
    xp = _xp(theta)
    c, s = xp.cos(theta), xp.sin(theta)
    return vec.combine(c, d1, s, d2), vec.combine(-s, d1, c, d2)


def curvature_binormal(t0, t1):
    return vec.scale(2.0 / (1.0 + vec.dot(t0, t1)), vec.cross(t0, t1))


def reference_twist(t0, d1_0, t1, d1_1, stored):
    """Signed angle about ``t1`` from ``P(t0 → t1) d1_0`` to ``d1_1``, on the branch nearest ``stored``."""
    u = vec.parallel_transport(t0, t1, d1_0)
    raw = vec.dot(vec.cross(u, d1_1), t1)
    xp = _xp(raw)
    raw = xp.arctan2(raw, vec.dot(u, d1_1))
    return raw + 2.0 * np.pi * xp.round((stored - raw) / (2.0 * np.pi))


def vertex_strains(q, prm, variant="2008"):
    """Material curvatures and twist of a vertex stencil.

    Returns
    -------
    kappa : tuple of 4 arrays (N,)
        ``(κ1, κ2)`` in edge 0's frame then in edge 1's (2008), or
        ``(κ1, κ2)`` in the averaged frame followed by zeros (2010).
    twist : array (N,)
        ``m = θ1 − θ0 + reference twist``.
    voronoi_length : array (N,)
        ``(L0 + L1) / 2``.
    """
    x0, x1, x2 = unpack3(q, 0), unpack3(q, 3), unpack3(q, 6)
    th0, th1, L0, L1 = q[9], q[10], q[11], q[12]
    e0, e1 = vec.sub(x1, x0), vec.sub(x2, x1)
    xp = _xp(e0[0])
    t0 = vec.scale(1.0 / xp.sqrt(vec.dot(e0, e0)), e0)
    t1 = vec.scale(1.0 / xp.sqrt(vec.dot(e1, e1)), e1)
    r0, s0 = reference_directors(unpack3(prm, 0), unpack3(prm, 3), t0)
    r1, s1 = reference_directors(unpack3(prm, 6), unpack3(prm, 9), t1)
    m1_0, m2_0 = material_directors(r0, s0, th0)
    m1_1, m2_1 = material_directors(r1, s1, th1)
    kb = curvature_binormal(t0, t1)
    if variant == "2008":
        kappa = (vec.dot(kb, m2_0), -vec.dot(kb, m1_0), vec.dot(kb, m2_1), -vec.dot(kb, m1_1))
    elif variant == "2010":
        m1 = vec.scale(0.5, vec.add(m1_0, m1_1))
        m2 = vec.scale(0.5, vec.add(m2_0, m2_1))
        zero = xp.zeros_like(th0)
        kappa = (vec.dot(kb, m2), -vec.dot(kb, m1), zero, zero)
    else:
        raise ValueError(f"unknown bending variant {variant!r}; expected one of {BENDING_VARIANTS}")
    twist = th1 - th0 + reference_twist(t0, r0, t1, r1, prm[22])
    return kappa, twist, 0.5 * (L0 + L1)


def vertex_energies(q, prm, variant="2008"):
    """Bending and twisting energy of each vertex stencil: two arrays ``(N,)``."""
    kappa, twist, ell = vertex_strains(q, prm, variant)
    dk = [kappa[i] - prm[17 + i] for i in range(4)]
    if variant == "2008":
        bend = (prm[12] * dk[0] ** 2 + prm[13] * dk[1] ** 2 + prm[14] * dk[2] ** 2 + prm[15] * dk[3] ** 2) / (4.0 * ell)
    else:
        b1 = 0.5 * (prm[12] + prm[14])
        b2 = 0.5 * (prm[13] + prm[15])
        bend = (b1 * dk[0] ** 2 + b2 * dk[1] ** 2) / (2.0 * ell)
    dm = twist - prm[21]
    return bend, prm[16] * dm * dm / (2.0 * ell)


def vertex_energy(q, prm, variant="2008"):
    """Total (bending + twisting) energy of all vertex stencils, a scalar."""
    bend, twist = vertex_energies(q, prm, variant)
    return _xp(bend).sum(bend + twist)


def edge_energies(q, ks):
    """Stretching energy ``ks L (|e|/L − 1)² / 2`` of each edge: array ``(N,)``.

    ``q`` packs ``x0 (0:3), x1 (3:6), L (6)``.
    """
    e = vec.sub(unpack3(q, 3), unpack3(q, 0))
    n = _xp(e[0]).sqrt(vec.dot(e, e))
    L = q[6]
    return 0.5 * ks * (n - L) ** 2 / L
