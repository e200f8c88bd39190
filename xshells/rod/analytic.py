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


# --------------------------------------------------------------------------- helpers on (3, ...) arrays
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    out = np.empty(a.shape if a.shape == b.shape else np.broadcast_shapes(a.shape, b.shape))
    np.multiply(a[1], b[2], out=out[0])
    out[0] -= a[2] * b[1]
    np.multiply(a[2], b[0], out=out[1])
    out[1] -= a[0] * b[2]
    np.multiply(a[0], b[1], out=out[2])
    out[2] -= a[1] * b[0]
    return out


def _transport_perp(a, b, v):
    """Parallel transport of ``v`` from unit ``a`` to unit ``b`` (as :func:`.vec.parallel_transport`).

    Written as ``v − ((a+b)·v)/(1 + a·b) (a+b) + 2(a·v) b``, the same rotation.
    """
    out = np.add(a, b)
    av = _dot(a, v)
    f = (av + _dot(b, v)) / (1.0 + _dot(a, b))
    out *= -f
    out += v
    av *= 2.0
    out += av * b
    return out


def _outer(a, b):
    return a[:, None] * b[None, :]


def _check_variant(variant):
    if variant not in BENDING_VARIANTS:
        raise ValueError(f"unknown bending variant {variant!r}; expected one of {BENDING_VARIANTS}")


# --------------------------------------------------------------------------- shared first-order quantities
class _Stencil:
    """Geometry, strains, energies and first derivatives of N vertex stencils.

    Per-edge quantities are stacked as ``(3, 2, N)`` (or ``(2, N)``): edge 0, edge 1.
    """

    def __init__(self, q, prm, variant, derivatives=True):
        """``derivatives=False`` stops at the energies (a line search's trial point);
        :meth:`first_derivatives` completes the stencils later, with the same values."""
        _check_variant(variant)
        q = np.asarray(q, dtype=float)
        prm = np.asarray(prm, dtype=float)
        self.variant = variant
        n = q.shape[1]
        E = np.empty((3, 2, n))
        np.subtract(q[3:6], q[0:3], out=E[:, 0])
        np.subtract(q[6:9], q[3:6], out=E[:, 1])
        nn = np.sqrt(_dot(E, E))
        T = E / nn
        p4 = prm[0:12].reshape(2, 2, 3, n)
        TS = np.ascontiguousarray(p4[:, 0].transpose(1, 0, 2))
        VS = np.ascontiguousarray(p4[:, 1].transpose(1, 0, 2))
        R = _transport_perp(TS, T, VS)  # reference directors d1
        S = _cross(T, R)  # d2
        C = _cross(TS, T)
        dts = _dot(TS, T)
        e0, e1 = E[:, 0], E[:, 1]
        n0, n1 = nn[0], nn[1]
        cr = _cross(e0, e1)
        d01 = _dot(e0, e1)
        n01 = n0 * n1
        den = n01 + d01
        inv_den = 1.0 / den
        kb = (2.0 * inv_den) * cr
        kbR = _dot(kb[:, None], R)
        kbS = _dot(kb[:, None], S)
        th = q[9:11]
        # cos and sin from one transcendental call (half-angle tangent)
        th2 = np.tan(0.5 * th)
        sn = th2 * th2
        cs = 1.0 / (1.0 + sn)
        sn = 2.0 * th2 * cs
        cs *= 2.0
        cs -= 1.0
        U = cs * kbR + sn * kbS  # κb·m1_j
        V = cs * kbS - sn * kbR  # κb·m2_j
        L0, L1 = q[11], q[12]
        ell = 0.5 * (L0 + L1)

        # reference twist: angle about t1 from P(t0→t1) d1_0 to d1_1, nearest the stored branch
        r0, t0 = R[:, 0], T[:, 0]
        a = _dot(T[:, 1], r0) / (1.0 + d01 / n01)
        ptr = _dot(r0, R[:, 1]) - a * _dot(t0, R[:, 1])
        pts = _dot(r0, S[:, 1]) - a * _dot(t0, S[:, 1])
        raw = np.arctan2(-pts, ptr)
        tau = raw + (2.0 * np.pi) * np.round((prm[22] - raw) * (0.5 / np.pi))
        dm = q[10] - q[9] + tau - prm[21]
        kt = prm[16]
        dE_dm = kt * dm / ell
        twist_energy = 0.5 * dE_dm * dm

        # bending: energy and F = ∂E/∂(u_j, v_j)
        if variant == "2008":
            inv = 0.25 / ell
            cb = prm[12:16] * inv  # c_i of (κ1^0, κ2^0, κ1^1, κ2^1)
            a1 = V - prm[17:21:2]  # κ1^j − κ̄1^j
            a2 = U + prm[18:21:2]  # −(κ2^j − κ̄2^j)
            Fv = 2.0 * cb[0::2] * a1
            Fu = 2.0 * cb[1::2] * a2
            a1 *= Fv
            a2 *= Fu
            a1 += a2
            bend = 0.5 * (a1[0] + a1[1])
        else:
            inv = 1.0 / (2.0 * ell)
            cb = np.array([0.5 * (prm[12] + prm[14]) * inv, 0.5 * (prm[13] + prm[15]) * inv])
            a1 = 0.5 * (V[0] + V[1]) - prm[17]
            a2 = -0.5 * (U[0] + U[1]) - prm[18]
            bend = cb[0] * a1 * a1 + cb[1] * a2 * a2
            Fv = np.broadcast_to(cb[0] * a1, (2, n))
            Fu = np.broadcast_to(-cb[1] * a2, (2, n))
        self.__dict__.update(
            E=E, nn=nn, T=T, TS=TS, R=R, S=S, C=C, dts=dts, cs=cs, sn=sn, e0=e0, e1=e1, n0=n0, n1=n1, cr=cr,
            den=den, inv_den=inv_den, kb=kb, U=U, V=V, ell=ell, dE_dm=dE_dm, kt=kt, cb=cb, Fu=Fu, Fv=Fv,
            bend=bend, twist=twist_energy,
        )
        self.has_derivatives = False
        if derivatives:
            self.first_derivatives()

    def first_derivatives(self):
        """Complete the stencils with the first derivatives (once; the energies are kept)."""
        if self.has_derivatives:
            return self
        R, S, cs, sn, Fu, Fv, U, V = self.R, self.S, self.cs, self.sn, self.Fu, self.Fv, self.U, self.V
        dE_dm, kb, inv_den, nn, dts, C = self.dE_dm, self.kb, self.inv_den, self.nn, self.dts, self.C
        e0, e1, n0, n1, cr = self.e0, self.e1, self.n0, self.n1, self.cr
        # Σ_a F_a m_a per edge, in the reference frame
        MJ = np.multiply(Fu * cs - Fv * sn, R)
        MJ += (Fu * sn + Fv * cs) * S
        M = MJ[:, 0] + MJ[:, 1]
        dth = Fu * V - Fv * U
        dth[0] -= dE_dm
        dth[1] += dE_dm
        kbM = _dot(kb, M)

        # gradient w.r.t. e0, e1 (+ (∂E/∂θ_j) w_j, w_j = −(t_src×t)/((1 + t_src·t)|e|))
        k = kbM * inv_den
        wc = dth * (-1.0 / ((1.0 + dts) * nn))
        ge0 = _cross(e1, M)
        ge0 *= 2.0 * inv_den
        ge0 -= (k * n1 / n0) * e0
        ge0 -= k * e1
        ge0 += (dE_dm * inv_den / n0) * cr
        ge0 += wc[0] * C[:, 0]
        ge1 = _cross(M, e0)
        ge1 *= 2.0 * inv_den
        ge1 -= (k * n0 / n1) * e1
        ge1 -= k * e0
        ge1 += (dE_dm * inv_den / n1) * cr
        ge1 += wc[1] * C[:, 1]

        self.__dict__.update(MJ=MJ, M=M, kbM=kbM, dth=dth, ge0=ge0, ge1=ge1)
        self.has_derivatives = True
        return self

    def gradient(self):
        g = np.empty((13, self.e0.shape[1]))
        np.negative(self.ge0, out=g[0:3])
        np.subtract(self.ge0, self.ge1, out=g[3:6])
        g[6:9] = self.ge1
        g[9:11] = self.dth
        g[11] = (self.bend + self.twist) * (-0.5 / self.ell)
        g[12] = g[11]
        return g


# --------------------------------------------------------------------------- public API
def vertex_energy_and_gradient(q, prm, variant="2008"):
    """Bending energy (N,), twisting energy (N,) and gradient (13, N) of each vertex stencil.

    The gradient is exact for any source frame.
    """
    s = _Stencil(q, prm, variant)
    return s.bend, s.twist, s.gradient()


def vertex_energies(q, prm, variant="2008"):
    """Bending and twisting energy of each vertex stencil, stacked as (2, N)."""
    s = _Stencil(q, prm, variant, derivatives=False)
    return np.stack([s.bend, s.twist])


def vertex_gradient(q, prm, variant="2008"):
    """Gradient (13, N) of each vertex stencil's bending + twisting energy; exact for any source frame."""
    return _Stencil(q, prm, variant).gradient()


# --------------------------------------------------------------------------- Hessian
def _grad_dot_kb(s, m):
    """``(∇_{e0}, ∇_{e1})`` of ``κb·m`` with ``m`` (3, N) held fixed: two (3, N) arrays."""
    h = _dot(s.kb, m) * s.inv_den
    a0 = _cross(s.e1, m)
    a0 *= 2.0 * s.inv_den
    a0 -= h * s.g0
    a1 = _cross(m, s.e0)
    a1 *= 2.0 * s.inv_den
    a1 -= h * s.g1
    return a0, a1


_SCRATCH = {}


def _scratch(n):
    """Reused (2, 30, 3, N) work array for the outer-product factors.

    Fresh large arrays cost page faults on every call (a third of the Hessian's
    time here); not thread-safe, like the rest of the rod's caches.
    """
    buf = _SCRATCH.get(n)
    if buf is None:
        _SCRATCH.clear()
        buf = _SCRATCH[n] = np.empty((2, 30, 3, n))
    return buf


class _Pairs:
    """Accumulates a (3, 3, N) block as a sum of outer products ``Σ_k p_k ⊗ q_k``."""

    def __init__(self, buf, start, count):
        self.P = buf[0, start:start + count]
        self.Q = buf[1, start:start + count]
        self.k = 0

    def add(self, p, q):
        self.P[self.k] = p
        self.Q[self.k] = q
        self.k += 1

    def sum(self):
        k = self.k
        return np.einsum("kin,kjn->ijn", self.P[:k], self.Q[:k])


def _add_diag(B, c):
    for i in range(3):
        B[i, i] += c


def _add_skew(B, v):
    """``B += [v]×``."""
    B[0, 1] -= v[2]
    B[0, 2] += v[1]
    B[1, 0] += v[2]
    B[1, 2] -= v[0]
    B[2, 0] -= v[1]
    B[2, 1] += v[0]


def _hessian_blocks(s):
    """Hessian at the source frame in the variables (e0, e1, θ0, θ1) as blocks.

    Returns ``H00, H01, H11`` (3, 3, N), ``He0θ, He1θ`` (3, 2, N) and ``Hθθ`` (2, 2, N).
    """
    n = s.e0.shape[1]
    e0, e1, n0, n1, kb, inv_den = s.e0, s.e1, s.n0, s.n1, s.kb, s.inv_den
    t0, t1 = s.T[:, 0], s.T[:, 1]
    s.g0 = g0 = n1 * t0 + e1  # ∇_{e0} den
    s.g1 = g1 = n0 * t1 + e0
    m1 = s.cs * s.R + s.sn * s.S
    m2 = s.cs * s.S - s.sn * s.R
    U, V, Fu, Fv = s.U, s.V, s.Fu, s.Fv
    buf = _scratch(n)
    b00, b01, b11 = _Pairs(buf, 0, 11), _Pairs(buf, 11, 8), _Pairs(buf, 19, 11)
    he0 = np.zeros((3, 2, n))
    he1 = np.zeros((3, 2, n))
    hth = np.zeros((2, 2, n))

    # Σ 2 c_i ∇κ_i ∇κ_iᵀ over the curvatures, ∇κ = (a0, a1, θ entries)
    if s.variant == "2008":
        terms = []
        for j in (0, 1):
            terms.append((2.0 * s.cb[2 * j], m2[:, j], {j: -U[j]}))  # κ1^j = v_j
            terms.append((2.0 * s.cb[2 * j + 1], m1[:, j], {j: V[j]}))  # κ2^j = −u_j (sign irrelevant)
    else:
        terms = [(2.0 * s.cb[0], 0.5 * (m2[:, 0] + m2[:, 1]), {0: -0.5 * U[0], 1: -0.5 * U[1]}),
                 (2.0 * s.cb[1], 0.5 * (m1[:, 0] + m1[:, 1]), {0: 0.5 * V[0], 1: 0.5 * V[1]})]
    for c, m, ths in terms:
        a0, a1 = _grad_dot_kb(s, m)
        ca0, ca1 = c * a0, c * a1
        b00.add(ca0, a0)
        b01.add(ca0, a1)
        b11.add(ca1, a1)
        for j, thj in ths.items():
            he0[:, j] += thj * ca0
            he1[:, j] += thj * ca1
            for i, thi in ths.items():
                hth[i, j] += c * thi * thj

    # twist: (kt/ℓ) ∇m ∇mᵀ + (∂E/∂m) ∇²τ, ∇_{e_j} m = κb/(2|e_j|)
    ktl = s.kt / s.ell
    dm = s.dE_dm
    y0 = (0.5 * inv_den / n0) * g0 + (0.5 / (n0 * n0)) * t0
    y1 = (0.5 * inv_den / n1) * g1 + (0.5 / (n1 * n1)) * t1
    hdm = -0.5 * dm
    b00.add(kb, (0.25 * ktl / (n0 * n0)) * kb + hdm * y0)
    b00.add(hdm * y0, kb)
    b11.add(kb, (0.25 * ktl / (n1 * n1)) * kb + hdm * y1)
    b11.add(hdm * y1, kb)
    b01.add(kb, (0.25 * ktl / (n0 * n1)) * kb - (0.5 * dm * inv_den / n0) * g1)
    for j, sgn in ((0, -1.0), (1, 1.0)):
        he0[:, j] += (0.5 * sgn * ktl / n0) * kb
        he1[:, j] += (0.5 * sgn * ktl / n1) * kb
    hth[0, 0] += ktl
    hth[1, 1] += ktl
    hth[0, 1] -= ktl
    hth[1, 0] -= ktl

    # M·∇²κb = (2∇²f − g∇hᵀ − ∇h gᵀ − h∇²den)/den, f = M·(e0×e1), h = M·κb
    gb0, gb1 = _grad_dot_kb(s, s.M)
    h = s.kbM * inv_den
    b00.add(-inv_den * g0, gb0)
    b00.add(-inv_den * gb0, g0)
    b00.add((h * n1 / n0) * t0, t0)
    b11.add(-inv_den * g1, gb1)
    b11.add(-inv_den * gb1, g1)
    b11.add((h * n0 / n1) * t1, t1)
    b01.add(-inv_den * g0, gb1)
    b01.add(-inv_den * gb0, g1)
    b01.add(-h * t0, t1)

    # second derivatives of the directors, in edge j's (m1, m2) plane
    for j, blk in ((0, b00), (1, b11)):
        inv2 = 1.0 / (s.nn[j] * s.nn[j])
        q11, q22 = Fu[j] * U[j] * inv2, Fv[j] * V[j] * inv2
        q12 = 0.5 * (Fu[j] * V[j] + Fv[j] * U[j]) * inv2
        blk.add(m1[:, j], q11 * m1[:, j] + q12 * m2[:, j])
        blk.add(m2[:, j], q12 * m1[:, j] + q22 * m2[:, j])
        hth[j, j] -= Fu[j] * U[j] + Fv[j] * V[j]
        a0, a1 = _grad_dot_kb(s, Fu[j] * m2[:, j] - Fv[j] * m1[:, j])
        he0[:, j] += a0
        he1[:, j] += a1

    H00, H01, H11 = b00.sum(), b01.sum(), b11.sum()
    _add_diag(H00, -h * n1 / n0)
    _add_diag(H11, -h * n0 / n1)
    _add_diag(H01, -h)
    _add_skew(H01, (-2.0 * inv_den) * s.M + (dm * inv_den / n0) * e0)
    return H00, H01, H11, he0, he1, hth


def _skew(a):
    """``[a]×`` as (3, 3, N)."""
    z = np.zeros_like(a[0])
    return np.array([[z, -a[2], a[1]], [a[2], z, -a[0]], [-a[1], a[0], z]])


def _leave_source_frame(s, H00, H01, H11, he0, he1, hth):
    """Make the Hessian blocks exact away from the source frame; returns new ``H00, H01, H10, H11, he0, he1``.

    Any frame-dependent quantity ``X`` varies as ``dX = D̃X + (∂X/∂θ_j) w_j·de_j``
    with ``D̃`` the derivative along time-parallel transport from the current
    state, so ``H = Tᵀ H̃ T + Σ_j (∂E/∂θ_j) ∇w_j`` with ``T: δθ_j += w_j·δe_j``
    and ``H̃`` the source-frame Hessian less ``Σ_j (∂E/∂θ_j) ∇w_j`` at the source.
    At the source frame ``w_j = 0`` and this changes nothing.
    """
    W, corr = [], []
    for j in (0, 1):
        ts, t, c, d, nj = s.TS[:, j], s.T[:, j], s.C[:, j], s.dts[j], s.nn[j]
        k = 1.0 / ((1.0 + d) * nj * nj)
        W.append((-k * nj) * c)
        # ∇w_j = −k[t_src]× + 2k c tᵀ + k/(1+d) c (t_src − d t)ᵀ, less its source value −[t]×/(2|e|²)
        cj = (2.0 * k) * _outer(c, t) + (k / (1.0 + d)) * _outer(c, ts - d * t) - k * _skew(ts) + (0.5 / (nj * nj)) * _skew(t)
        corr.append(s.dth[j] * cj)
    he = (he0, he1)
    Hb = [[H00, H01], [H01.transpose(1, 0, 2), H11]]
    out = [[None, None], [None, None]]
    for a in (0, 1):
        for b in (0, 1):
            blk = Hb[a][b] + _outer(he[a][:, b], W[b]) + _outer(W[a], he[b][:, a]) + hth[a, b] * _outer(W[a], W[b])
            if a == b:
                blk += corr[a]
            out[a][b] = blk
    ne0 = he0 + W[0][:, None] * hth[0][None]
    ne1 = he1 + W[1][:, None] * hth[1][None]
    return out[0][0], out[0][1], out[1][0], out[1][1], ne0, ne1


# Source-frame offsets |t_src × t| below this are treated as zero (relative error of that order).
SOURCE_TOLERANCE = 1e-13


def vertex_hessian(q, prm, variant="2008"):
    """Hessian (13, 13, N) of each vertex stencil's bending + twisting energy.

    Exact for any source frame (``d1_src ⊥ t_src``, ``t_src ≠ −t``); the
    away-from-source correction (:func:`_leave_source_frame`) is skipped when
    every ``|t_src × t| ≤ SOURCE_TOLERANCE``, i.e. at the source frame, as the
    solver calls it.
    """
    return _hessian(_Stencil(q, prm, variant))[0]


def vertex_energy_gradient_hessian(q, prm, variant="2008"):
    """Bending and twisting energies (N,) each, gradient (13, N) and Hessian (13, 13, N) of each vertex stencil.

    One evaluation of the stencils' geometry for all four (what a Newton
    step needs at a new state); the same values as the separate functions.
    """
    s = _Stencil(q, prm, variant)
    H, g = _hessian(s)
    return s.bend, s.twist, g, H


def _hessian(s):
    """Hessian (13, 13, N) and gradient (13, N) of the stencils ``s``."""
    H00, H01, H11, he0, he1, hth = _hessian_blocks(s)
    if np.abs(s.C).max(initial=0.0) > SOURCE_TOLERANCE:
        H00, H01, H10, H11, he0, he1 = _leave_source_frame(s, H00, H01, H11, he0, he1, hth)
    else:
        H10 = H01.transpose(1, 0, 2)
    n = H00.shape[2]
    out = np.empty((13, 13, n))
    out[0:3, 0:3] = H00
    np.subtract(H01, H00, out=out[0:3, 3:6])
    np.negative(H01, out=out[0:3, 6:9])
    np.subtract(H10, H00, out=out[3:6, 0:3])
    x11 = out[3:6, 3:6]
    np.subtract(H00, H01, out=x11)
    x11 -= H10
    x11 += H11
    np.subtract(H01, H11, out=out[3:6, 6:9])
    np.negative(H10, out=out[6:9, 0:3])
    np.subtract(H10, H11, out=out[6:9, 3:6])
    out[6:9, 6:9] = H11
    np.negative(he0, out=out[0:3, 9:11])
    np.subtract(he0, he1, out=out[3:6, 9:11])
    out[6:9, 9:11] = he1
    out[9:11, 0:9] = out[0:9, 9:11].transpose(1, 0, 2)
    out[9:11, 9:11] = hth
    g = s.gradient()
    np.multiply(g[0:11], -0.5 / s.ell, out=out[0:11, 11])
    out[0:11, 12] = out[0:11, 11]
    out[11:13, 0:11] = out[0:11, 11]
    out[11:13, 11:13] = (s.bend + s.twist) / (2.0 * s.ell * s.ell)
    return out, g


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
