"""Analytic NumPy derivatives of the rod's stencil energies.

Fast replacements for automatic differentiation of :mod:`.stencils` (the
definitions; the tests compare every kernel here with ``jax.grad`` /
``jax.hessian`` of them). Inputs and outputs are structure-of-arrays: ``q``
``(13, N)`` and ``prm`` ``(23, N)`` packed as documented in :mod:`.stencils`.

Derivation in brief (``e0 = x1 − x0``, ``e1 = x2 − x1``, ``ℓ = (L0 + L1)/2``):

* The bending energy depends on the four scalars ``u_j = κb·m1_j`` and
  ``v_j = κb·m2_j`` (``κ^j = (v_j, −u_j)``; the 2010 curvature is the mean of
  the two), quadratically: ``E_b = Σ_i c_i (κ_i − κ̄_i)²`` with ``c_i ∝ 1/ℓ``.
* ``κb = 2 e0×e1 / (|e0||e1| + e0·e1)``; for a fixed vector ``M``,
  ``∇(M·κb) = (2∇f − (M·κb)∇den)/den`` with ``f = M·(e0×e1)``. The chain rule
  only ever needs ``M = Σ_a (∂E/∂p_a) m_a``, one contraction.
* Time-parallel transport moves a director as ``δm = −t (m·δe)/|e|`` at the
  source frame (no rotation about ``t``, and ``κb·t = 0`` kills that term in
  ``∇p``); away from the source frame it also rotates the frame about ``t`` by
  ``w·δe`` with ``w = −(t_src×t)/((1 + t_src·t)|e|)``, which acts on the
  energy exactly like ``δθ``: gradient = source-frame formula
  ``+ (∂E/∂θ_j) w_j``.
* The reference twist has ``∇_{e_j} τ = κb/(2|e_j|) ∓ w_j`` (``−`` for edge
  0) at any state; its Hessian at the source frame adds ``∓∇w_j =
  ±[t_j]×/(2|e_j|²)``.
* Second derivatives of the directors at the source frame (from the second
  derivative of the transport formula): for ``a, b`` in ``{m1, m2}`` of edge
  ``j``, ``a·∂²b[δ, η] = −((a·δ)(b·η) + (a·η)(b·δ)) / (2|e_j|²)``.

The Hessian is assembled in the variables ``(e0, e1, θ0, θ1)`` from outer
products of small ``(3, N)`` vectors, first as at the source frame, then
made exact for any source frame by the change of variables ``δθ_j += w_j·δe_j``
plus ``(∂E/∂θ_j)(∇w_j − ∇w_j|source)`` (:func:`_leave_source_frame`), then
mapped to ``(x0, x1, x2)``.
"""
from __future__ import annotations

import numpy as np

BENDING_VARIANTS = ("2008", "2010")


# --------------------------------------------------------------------------- helpers on (3, N) arrays
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    out = np.empty_like(a)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


def _transport(a, b, v):
    """Parallel transport of ``v`` from unit ``a`` to unit ``b`` (as :func:`.vec.parallel_transport`)."""
    c = _cross(a, b)
    d = _dot(a, b)
    f = _dot(c, v) / (1.0 + d)
    return d * v + _cross(c, v) + f * c


def _outer(a, b):
    return a[:, None, :] * b[None, :, :]


def _sym_outer(a, b):
    o = a[:, None, :] * b[None, :, :]
    return o + o.transpose(1, 0, 2)


def _skew(a):
    """``[a]×`` as (3, 3, N): ``[a]× v = a × v``."""
    z = np.zeros_like(a[0])
    return np.array([[z, -a[2], a[1]], [a[2], z, -a[0]], [-a[1], a[0], z]])


def _check_variant(variant):
    if variant not in BENDING_VARIANTS:
        raise ValueError(f"unknown bending variant {variant!r}; expected one of {BENDING_VARIANTS}")


# --------------------------------------------------------------------------- shared first-order quantities
class _Stencil:
    """Geometry, strains and first derivatives of the energy w.r.t. (p, m, θ, e)."""

    def __init__(self, q, prm, variant):
        _check_variant(variant)
        q = np.asarray(q, dtype=float)
        prm = np.asarray(prm, dtype=float)
        self.variant = variant
        x0, x1, x2 = q[0:3], q[3:6], q[6:9]
        th0, th1, L0, L1 = q[9], q[10], q[11], q[12]
        e0 = x1 - x0
        e1 = x2 - x1
        n0 = np.sqrt(_dot(e0, e0))
        n1 = np.sqrt(_dot(e1, e1))
        t0 = e0 / n0
        t1 = e1 / n1
        ts0, ts1 = prm[0:3], prm[6:9]
        r0 = _transport(ts0, t0, prm[3:6])
        r1 = _transport(ts1, t1, prm[9:12])
        s0 = _cross(t0, r0)
        s1 = _cross(t1, r1)
        c0, sn0, c1, sn1 = np.cos(th0), np.sin(th0), np.cos(th1), np.sin(th1)
        m1_0 = c0 * r0 + sn0 * s0
        m2_0 = c0 * s0 - sn0 * r0
        m1_1 = c1 * r1 + sn1 * s1
        m2_1 = c1 * s1 - sn1 * r1
        den = n0 * n1 + _dot(e0, e1)
        kb = (2.0 / den) * _cross(e0, e1)
        u0, v0, u1, v1 = _dot(kb, m1_0), _dot(kb, m2_0), _dot(kb, m1_1), _dot(kb, m2_1)
        ell = 0.5 * (L0 + L1)

        # reference twist on the branch nearest the stored value
        pt = _transport(t0, t1, r0)
        raw = np.arctan2(_dot(_cross(pt, r1), t1), _dot(pt, r1))
        tau = raw + 2.0 * np.pi * np.round((prm[22] - raw) / (2.0 * np.pi))
        dm = th1 - th0 + tau - prm[21]
        kt = prm[16]
        twist_energy = kt * dm * dm / (2.0 * ell)
        dE_dm = kt * dm / ell

        # bending: energy and ∂E/∂(u_j, v_j)
        if variant == "2008":
            a1_0, a2_0, a1_1, a2_1 = v0 - prm[17], -u0 - prm[18], v1 - prm[19], -u1 - prm[20]
            inv = 1.0 / (4.0 * ell)
            cb = (prm[12] * inv, prm[13] * inv, prm[14] * inv, prm[15] * inv)  # c_i of (κ1^0, κ2^0, κ1^1, κ2^1)
            bend = cb[0] * a1_0**2 + cb[1] * a2_0**2 + cb[2] * a1_1**2 + cb[3] * a2_1**2
            Fv0, Fu0 = 2 * cb[0] * a1_0, -2 * cb[1] * a2_0
            Fv1, Fu1 = 2 * cb[2] * a1_1, -2 * cb[3] * a2_1
        else:
            a1 = 0.5 * (v0 + v1) - prm[17]
            a2 = -0.5 * (u0 + u1) - prm[18]
            inv = 1.0 / (2.0 * ell)
            cb = (0.5 * (prm[12] + prm[14]) * inv, 0.5 * (prm[13] + prm[15]) * inv)
            bend = cb[0] * a1**2 + cb[1] * a2**2
            Fv0 = Fv1 = cb[0] * a1
            Fu0 = Fu1 = -cb[1] * a2
        self.cb = cb

        # frame-rotation gradients (zero at the source frame)
        w0 = _cross(ts0, t0) * (-1.0 / ((1.0 + _dot(ts0, t0)) * n0))
        w1 = _cross(ts1, t1) * (-1.0 / ((1.0 + _dot(ts1, t1)) * n1))

        # gradient w.r.t. (e0, e1, θ0, θ1)
        M0 = Fu0 * m1_0 + Fv0 * m2_0
        M1 = Fu1 * m1_1 + Fv1 * m2_1
        M = M0 + M1
        kbM = _dot(kb, M)
        g0 = n1 * t0 + e1  # ∇_{e0} den
        g1 = n0 * t1 + e0
        dth0 = Fu0 * v0 - Fv0 * u0 - dE_dm
        dth1 = Fu1 * v1 - Fv1 * u1 + dE_dm
        inv_den = 1.0 / den
        ge0 = (2.0 * _cross(e1, M) - kbM * g0) * inv_den + (0.5 * dE_dm / n0) * kb + dth0 * w0
        ge1 = (2.0 * _cross(M, e0) - kbM * g1) * inv_den + (0.5 * dE_dm / n1) * kb + dth1 * w1

        self.__dict__.update(
            e0=e0, e1=e1, n0=n0, n1=n1, t0=t0, t1=t1, m1_0=m1_0, m2_0=m2_0, m1_1=m1_1, m2_1=m2_1,
            den=den, inv_den=inv_den, kb=kb, u0=u0, v0=v0, u1=u1, v1=v1, ell=ell, dE_dm=dE_dm, kt=kt,
            Fu0=Fu0, Fv0=Fv0, Fu1=Fu1, Fv1=Fv1, M=M, M0=M0, M1=M1, kbM=kbM, g0=g0, g1=g1,
            dth0=dth0, dth1=dth1, ts0=ts0, ts1=ts1, ge0=ge0, ge1=ge1, bend=bend, twist=twist_energy,
        )

    def gradient(self):
        n = self.e0.shape[1]
        g = np.empty((13, n))
        g[0:3] = -self.ge0
        g[3:6] = self.ge0 - self.ge1
        g[6:9] = self.ge1
        g[9] = self.dth0
        g[10] = self.dth1
        g[11] = g[12] = -(self.bend + self.twist) / (2.0 * self.ell)
        return g


# --------------------------------------------------------------------------- public API
def vertex_energy_and_gradient(q, prm, variant="2008"):
    """Bending energy (N,), twisting energy (N,) and gradient (13, N) of each vertex stencil.

    The gradient is exact for any source frame.
    """
    s = _Stencil(q, prm, variant)
    return s.bend, s.twist, s.gradient()


def vertex_gradient(q, prm, variant="2008"):
    """Gradient (13, N) of each vertex stencil's bending + twisting energy; exact for any source frame."""
    return _Stencil(q, prm, variant).gradient()


# --------------------------------------------------------------------------- Hessian
def _grad_dot_kb(s, m):
    """``(∇_{e0}, ∇_{e1})`` of ``κb·m`` with ``m`` held fixed: two (3, N) arrays."""
    h = _dot(s.kb, m)
    return (2.0 * _cross(s.e1, m) - h * s.g0) * s.inv_den, (2.0 * _cross(m, s.e0) - h * s.g1) * s.inv_den


def _hessian_e(s):
    """Hessian (8, 8, N) in the variables (e0, e1, θ0, θ1), at the source frame."""
    n = s.e0.shape[1]
    H = np.zeros((8, 8, n))
    kb, n0, n1 = s.kb, s.n0, s.n1

    # Gauss-Newton-like terms: Σ 2 c_i ∇κ_i ∇κ_iᵀ + (kt/ℓ) ∇m ∇mᵀ
    G = []
    if s.variant == "2008":
        for coef, m, th, j in ((s.cb[0], s.m2_0, -s.u0, 0), (s.cb[1], s.m1_0, s.v0, 0),
                               (s.cb[2], s.m2_1, -s.u1, 1), (s.cb[3], s.m1_1, s.v1, 1)):
            a0, a1 = _grad_dot_kb(s, m)
            g = np.zeros((8, n))
            g[0:3], g[3:6], g[6 + j] = a0, a1, th
            G.append((2.0 * coef, g))
    else:
        for coef, m, th0, th1 in ((s.cb[0], 0.5 * (s.m2_0 + s.m2_1), -0.5 * s.u0, -0.5 * s.u1),
                                  (s.cb[1], 0.5 * (s.m1_0 + s.m1_1), 0.5 * s.v0, 0.5 * s.v1)):
            a0, a1 = _grad_dot_kb(s, m)
            g = np.empty((8, n))
            g[0:3], g[3:6], g[6], g[7] = a0, a1, th0, th1
            G.append((2.0 * coef, g))
    g = np.empty((8, n))
    g[0:3], g[3:6], g[6], g[7] = (0.5 / n0) * kb, (0.5 / n1) * kb, -1.0, 1.0
    G.append((s.kt / s.ell, g))
    for coef, g in G:
        H += coef * _outer(g, g)

    # Σ_a F_a m_a·∇²κb = M·∇²κb = (2∇²f − g∇hᵀ − ∇h gᵀ − h∇²den)/den, f = M·(e0×e1), h = M·κb
    M, h, inv_den = s.M, s.kbM, s.inv_den
    gb0, gb1 = _grad_dot_kb(s, M)
    g0, g1 = s.g0, s.g1
    t0, t1 = s.t0, s.t1
    eye = np.eye(3)[:, :, None]
    P0 = eye - _outer(t0, t0)
    P1 = eye - _outer(t1, t1)
    H[0:3, 0:3] -= (_sym_outer(g0, gb0) + (h * n1 / n0) * P0) * inv_den
    H[3:6, 3:6] -= (_sym_outer(g1, gb1) + (h * n0 / n1) * P1) * inv_den
    B01 = (-2.0 * _skew(M) - _outer(g0, gb1) - _outer(gb0, g1) - h * (eye + _outer(t0, t1))) * inv_den
    H[0:3, 3:6] += B01
    H[3:6, 0:3] += B01.transpose(1, 0, 2)

    # second derivatives of the directors (per edge)
    for j, (sl, m1, m2, Fu, Fv, u, v, nj, Mj) in enumerate((
            (slice(0, 3), s.m1_0, s.m2_0, s.Fu0, s.Fv0, s.u0, s.v0, n0, s.M0),
            (slice(3, 6), s.m1_1, s.m2_1, s.Fu1, s.Fv1, s.u1, s.v1, n1, s.M1))):
        inv2 = 1.0 / (nj * nj)
        H[sl, sl] += (_sym_outer(kb, Mj) - (Fu * u) * _outer(m1, m1) - (Fv * v) * _outer(m2, m2)
                      - (0.5 * (Fu * v + Fv * u)) * _sym_outer(m1, m2)) * inv2
        H[6 + j, 6 + j] -= Fu * u + Fv * v
        a0, a1 = _grad_dot_kb(s, Fu * m2 - Fv * m1)
        H[0:3, 6 + j] += a0
        H[3:6, 6 + j] += a1
        H[6 + j, 0:3] += a0
        H[6 + j, 3:6] += a1

    # twist: (∂E/∂m) ∇²τ, ∇_{e_j}τ = κb/(2|e_j|) ∓ w_j
    dm = s.dE_dm
    J0 = (-2.0 * _skew(s.e1) - _outer(kb, g0)) * inv_den  # ∂κb/∂e0
    J1 = (2.0 * _skew(s.e0) - _outer(kb, g1)) * inv_den
    H[0:3, 0:3] += dm * ((0.5 / n0) * J0 - (0.5 / n0**2) * (_outer(kb, t0) - _skew(t0)))
    H[3:6, 3:6] += dm * ((0.5 / n1) * J1 - (0.5 / n1**2) * (_outer(kb, t1) + _skew(t1)))
    H[0:3, 3:6] += dm * (0.5 / n0) * J1
    H[3:6, 0:3] += dm * (0.5 / n1) * J0
    _leave_source_frame(s, H)
    return H


def _leave_source_frame(s, H):
    """Make the Hessian exact away from the source frame (in place).

    Any frame-dependent quantity ``X`` varies as ``dX = D̃X + (∂X/∂θ_j) w_j·de_j``
    with ``D̃`` the derivative along time-parallel transport from the current
    state, so ``H = Tᵀ H̃ T + Σ_j (∂E/∂θ_j) ∇w_j`` with ``T: δθ_j += w_j·δe_j``
    and ``H̃`` the source-frame Hessian less ``Σ_j (∂E/∂θ_j) ∇w_j`` at the source.
    At the source frame ``w_j = 0`` and this changes nothing.
    """
    blocks = []
    for j, (ts, t, nj, gth) in enumerate(((s.ts0, s.t0, s.n0, s.dth0), (s.ts1, s.t1, s.n1, s.dth1))):
        c = _cross(ts, t)
        d = _dot(ts, t)
        k = 1.0 / ((1.0 + d) * nj * nj)
        w = (-k * nj) * c
        # ∇w_j = −k[t_src]× + 2k c tᵀ + k/(1+d) c (t_src − d t)ᵀ, less its source value −[t]×/(2|e|²)
        corr = (2.0 * k) * _outer(c, t) + (k / (1.0 + d)) * _outer(c, ts - d * t) - k * _skew(ts) + (0.5 / (nj * nj)) * _skew(t)
        blocks.append((slice(3 * j, 3 * j + 3), 6 + j, w, gth * corr))
    Hee = H[0:6, 0:6].copy()
    for a, ta, wa, corr in blocks:
        for b, tb, wb, _ in blocks:
            Hee[a, b] += (_outer(H[a, tb], wb) + _outer(wa, H[ta, b]) + H[ta, tb] * _outer(wa, wb))
        Hee[a, a] += corr
    for a, ta, wa, _ in blocks:
        for tb in (6, 7):
            H[a, tb] += wa * H[ta, tb]
            H[tb, a] += H[tb, ta] * wa
    H[0:6, 0:6] = Hee
    return H


def vertex_hessian(q, prm, variant="2008"):
    """Hessian (13, 13, N) of each vertex stencil's bending + twisting energy.

    Exact for any source frame (``d1_src ⊥ t_src``, ``t_src ≠ −t``); the
    away-from-source correction (:func:`_leave_source_frame`) vanishes when
    the source frame is the current one, as the solver calls it.
    """
    s = _Stencil(q, prm, variant)
    He = _hessian_e(s)
    n = He.shape[2]
    out = np.empty((13, 13, n))
    A, B, C, D = He[0:3, 0:3], He[0:3, 3:6], He[3:6, 0:3], He[3:6, 3:6]
    out[0:3, 0:3] = A
    out[0:3, 3:6] = B - A
    out[0:3, 6:9] = -B
    out[3:6, 0:3] = C - A
    out[3:6, 3:6] = A - B - C + D
    out[3:6, 6:9] = B - D
    out[6:9, 0:3] = -C
    out[6:9, 3:6] = C - D
    out[6:9, 6:9] = D
    a, b = He[0:3, 6:8], He[3:6, 6:8]
    out[0:3, 9:11] = -a
    out[3:6, 9:11] = a - b
    out[6:9, 9:11] = b
    out[9:11, 0:3] = -He[6:8, 0:3]
    out[9:11, 3:6] = He[6:8, 0:3] - He[6:8, 3:6]
    out[9:11, 6:9] = He[6:8, 3:6]
    out[9:11, 9:11] = He[6:8, 6:8]
    g = s.gradient()
    cross = g[0:11] * (-0.5 / s.ell)
    out[0:11, 11] = cross
    out[0:11, 12] = cross
    out[11, 0:11] = cross
    out[12, 0:11] = cross
    out[11:13, 11:13] = (s.bend + s.twist) / (2.0 * s.ell * s.ell)
    return out


# --------------------------------------------------------------------------- stretching
def edge_energy_gradient_hessian(q, ks):
    """Stretching ``ks L (|e|/L − 1)²/2`` of each edge, its gradient and Hessian.

    ``q`` (7, N) packs ``x0, x1, L``; ``ks`` is a scalar or (N,). Returns
    energy (N,), gradient (7, N) and Hessian (7, 7, N).
    """
    q = np.asarray(q, dtype=float)
    e = q[3:6] - q[0:3]
    L = q[6]
    n = np.sqrt(_dot(e, e))
    t = e / n
    r = (n - L) / L
    energy = 0.5 * ks * L * r * r
    dn = ks * r  # ∂E/∂|e|
    size = e.shape[1]
    grad = np.empty((7, size))
    grad[3:6] = dn * t
    grad[0:3] = -grad[3:6]
    grad[6] = 0.5 * ks * (1.0 - (n / L) ** 2)
    eye = np.eye(3)[:, :, None]
    tt = _outer(t, t)
    Hee = (dn / n) * (eye - tt) + (ks / L) * tt
    hess = np.empty((7, 7, size))
    hess[0:3, 0:3] = Hee
    hess[3:6, 3:6] = Hee
    hess[0:3, 3:6] = -Hee
    hess[3:6, 0:3] = -Hee
    eL = (-ks * n / (L * L)) * t  # ∂²E/∂x1∂L
    hess[3:6, 6] = eL
    hess[6, 3:6] = eL
    hess[0:3, 6] = -eL
    hess[6, 0:3] = -eL
    hess[6, 6] = ks * n * n / L**3
    return energy, grad, hess
