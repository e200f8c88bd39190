"""Analytic NumPy derivatives of the joint map (:mod:`xshells.linkage.joints`).

Same inputs as ``joints``: structure-of-arrays ``q (9, N)`` and ``prm (16, N)``.
Automatic differentiation of the joint map is exact but launch-bound on CPU;
these closed forms are vectorised over instances with plain NumPy.

Derivation (all vectors are the current ones: ``b = R(ω) b0``, ``n = R(ω) n0``,
``u = n × b``, rod edge tangent ``te = σ t_X``, ``ta = ∂te/∂α``).

*Rotation.* Write ``R(ω + δ) = exp([ε(δ)]×) R(ω)``. To first order
``ε = J δ`` with the left Jacobian ``J = I + B [ω]× + C [ω]×²``,
``B = (1 − cos θ)/θ²``, ``C = (θ − sin θ)/θ³``, so every rotated vector moves as
``∂v/∂ω_j = J_j × v``. The second-order part of ``ε`` is
``Γ_jk = ½(∂_k J_j + ∂_j J_k)``; contracted with a vector ``g`` it is
``ω vᵀ + v ωᵀ + C (g·ω) I`` with ``v = B' (g × ω) + C' ((g·ω) ω − |ω|² g) − ½ C g``
(primes: derivatives with respect to ``|ω|²``). Hence for any function ``f``
of the rotated frame, with ``g_ε`` and ``H_ε`` its gradient and Hessian in a
world rotation ``ε`` at the current frame,
``∂²f/∂ω² = Jᵀ H_ε J + g_ε·Γ`` and ``∂²f/∂ω∂x = Jᵀ ∂²f/∂ε∂x``. At ``ω = 0``,
``J = I`` and ``Γ = 0``.

*Positions.* ``start/end = p ∓ ½ ℓ te``; only ``W = ½(w_end − w_start)``
weights the ``te`` part: ``∂²(ℓ W·te)`` has ``εε: ℓ[sym(W ⊗ te) − (W·te) I]``,
``εα: ℓ ta × W``, ``εℓ: te × W``, ``αα: −¼ ℓ W·te``, ``αℓ: W·ta``.

*Material angle.* With ``k = (t_src × te)/(1 + t_src·te)``, the rate of the
time-parallel-transported director about ``te`` is ``−k·δte`` and that of
``m1`` is ``−(n × te)·δn``, so ``δθ = −(n × te)·δn + k·δte``: ``∂θ/∂ε = te + te × k``,
``∂θ/∂α = k·ta``. Differentiating ``G·δg`` once more (``G`` extended off the
constraint manifold by the same formula) and symmetrising, with
``D = 1 + t_src·te``, ``x = te × k``, ``y = te × t_src``:
``εε: sym(te ⊗ k) − sym(x ⊗ y)/D``,
``εα: ta × k + ½ ta − (x (t_src·ta) + y (k·ta))/(2D)``,
``αα: −(k·ta)(t_src·ta)/D``.

Both :func:`outputs_and_jacobian` and :func:`weighted_hessian` are exact for any
``ω`` (checked against ``jax.jacfwd``/``jax.hessian`` of ``joints.instance_outputs``
in ``tests/test_joint_kernels.py``); ``ω = 0`` exactly takes a cheaper path.
"""
from __future__ import annotations

import numpy as np

_I1 = np.array([1, 2, 0])
_I2 = np.array([2, 0, 1])
_EYE3 = np.eye(3)[:, :, None]


def _cross(a, b):
    """Cross product over axis 0 (length 3), broadcasting the other axes."""
    return a[_I1] * b[_I2] - a[_I2] * b[_I1]


def _dot(a, b):
    return np.einsum("i...,i...->...", a, b)


def is_at_source(q: np.ndarray) -> bool:
    """Whether every instance has ``ω = 0`` exactly (the cheaper path applies)."""
    return not np.any(q[3:6])


def _rodrigues_coefficients(s):
    """``sin θ/θ`` and ``(1 − cos θ)/θ²`` exactly as ``joints.rotate`` computes them."""
    small = s < 1e-8
    safe = np.where(small, 1.0, s)
    th = np.sqrt(safe)
    a = np.where(small, 1.0 - s / 6.0 + s * s / 120.0, np.sin(th) / th)
    b = np.where(small, 0.5 - s / 24.0 + s * s / 720.0, (1.0 - np.cos(th)) / safe)
    return a, b


def _jacobian_coefficients(s, derivatives=False):
    """``B = (1 − cos θ)/θ²``, ``C = (θ − sin θ)/θ³`` and, optionally, ``dB/ds, dC/ds`` (``s = θ²``).

    Taylor series below ``s = 1e-2`` (truncation below 1e-18), where the closed
    forms lose digits to cancellation.
    """
    small = s < 1e-2
    safe = np.where(small, 1.0, s)
    th = np.sqrt(safe)
    sn, cs = np.sin(th), np.cos(th)
    big_b = np.where(small, 0.5 + s * (-1 / 24 + s * (1 / 720 + s * (-1 / 40320 + s / 3628800))), (1.0 - cs) / safe)
    big_c = np.where(small, 1 / 6 + s * (-1 / 120 + s * (1 / 5040 + s * (-1 / 362880 + s / 39916800))), (th - sn) / (safe * th))
    if not derivatives:
        return big_b, big_c
    th4 = safe * safe
    db = np.where(
        small,
        -1 / 24 + s * (1 / 360 + s * (-1 / 13440 + s * (1 / 907200 - s * 5 / 479001600))),
        (th * sn - 2.0 * (1.0 - cs)) / (2.0 * th4),
    )
    dc = np.where(
        small,
        -1 / 120 + s * (1 / 2520 + s * (-1 / 120960 + s * (1 / 9979200 - s * 5 / 6227020800))),
        (th * (1.0 - cs) - 3.0 * (th - sn)) / (2.0 * th4 * th),
    )
    return big_b, big_c, db, dc


def _left_jacobian(w, s, big_b, big_c):
    """``J = (1 − C s) I + B [ω]× + C ω ωᵀ``, (3, 3, N)."""
    jl = big_c * w[:, None] * w[None, :]
    jl += (1.0 - big_c * s) * _EYE3
    bw = big_b * w
    jl[1, 2] -= bw[0]
    jl[2, 1] += bw[0]
    jl[2, 0] -= bw[1]
    jl[0, 2] += bw[1]
    jl[0, 1] -= bw[2]
    jl[1, 0] += bw[2]
    return jl


class _Geometry:
    """Everything the outputs and their derivatives share."""

    def __init__(self, q, prm):
        n_inst = q.shape[1]
        w = q[3:6]
        self.at_source = is_at_source(q)
        v0 = prm[0:6].reshape(2, 3, n_inst).transpose(1, 0, 2)  # (3, 2, N): b0, n0
        if self.at_source:
            self.s = None
            frame = v0
        else:
            self.s = _dot(w, w)
            a, bb = _rodrigues_coefficients(self.s)
            wv = _cross(w[:, None], v0)
            frame = v0 + a * wv + bb * _cross(w[:, None], wv)
        b, n = frame[:, 0], frame[:, 1]
        u = _cross(n, b)
        beam, sigma = prm[6], prm[7]
        half_alpha = 0.5 * q[6]
        c, sn = np.cos(half_alpha), np.sin(half_alpha)
        sx_sn = (2.0 * beam - 1.0) * sn  # −sin for beam A, +sin for beam B
        sx_c = (2.0 * beam - 1.0) * c
        self.te = sigma * (c * b + sx_sn * u)
        self.ta = (0.5 * sigma) * (sx_c * u - sn * b)
        self.n = n
        self.beam = beam
        self.length = (1.0 - beam) * q[7] + beam * q[8]
        self.w = w
        ts = prm[8:11]
        self.ts = ts
        te = self.te
        ct = _cross(ts, te)
        self.denom = 1.0 + _dot(ts, te)
        self.k = ct / self.denom
        self._ct = ct

    def outputs(self, q, prm):
        te, n = self.te, self.n
        half = (0.5 * self.length) * te
        out = np.empty((7, q.shape[1]))
        out[0:3] = q[0:3] - half
        out[3:6] = q[0:3] + half
        d1s = prm[11:14]
        ct = self._ct
        d1 = _dot(self.ts, te) * d1s + _cross(ct, d1s) + (_dot(ct, d1s) / self.denom) * ct
        d2 = _cross(te, d1)
        phi = prm[15]
        m1 = np.cos(phi) * _cross(n, te) - np.sin(phi) * n
        raw = np.arctan2(_dot(m1, d2), _dot(m1, d1))
        out[6] = raw + 2.0 * np.pi * np.round((prm[14] - raw) / (2.0 * np.pi))
        return out


def outputs(q: np.ndarray, prm: np.ndarray) -> np.ndarray:
    """Instance outputs, (7, N): start point, end point, θ."""
    return _Geometry(q, prm).outputs(q, prm)


def outputs_and_jacobian(q: np.ndarray, prm: np.ndarray):
    """Instance outputs (7, N) and their Jacobian (7, 9, N), exact for any ``ω``."""
    g = _Geometry(q, prm)
    out = g.outputs(q, prm)
    te, ta, k, length, beam = g.te, g.ta, g.k, g.length, g.beam
    n_inst = q.shape[1]
    jac = np.zeros((7, 9, n_inst))
    jac[0:3, 0:3] = _EYE3
    jac[3:6, 0:3] = _EYE3
    grad_theta = te + _cross(te, k)  # ∂θ/∂ε
    half_l = 0.5 * length
    if g.at_source:
        # ∂te/∂ε_j = e_j × te
        dte = np.zeros((3, 3, n_inst))
        dte[1, 0], dte[2, 0] = -te[2], te[1]
        dte[0, 1], dte[2, 1] = te[2], -te[0]
        dte[0, 2], dte[1, 2] = -te[1], te[0]
        jac[6, 3:6] = grad_theta
    else:
        big_b, big_c = _jacobian_coefficients(g.s)
        jl = _left_jacobian(g.w, g.s, big_b, big_c)
        dte = -_cross(te[:, None], jl)  # column j: J_j × te
        jac[6, 3:6] = _dot(grad_theta[:, None], jl)
    jac[3:6, 3:6] = half_l * dte
    jac[0:3, 3:6] = -jac[3:6, 3:6]
    jac[3:6, 6] = half_l * ta
    jac[0:3, 6] = -jac[3:6, 6]
    jac[6, 6] = _dot(k, ta)
    half_te = 0.5 * te
    jac[3:6, 7] = (1.0 - beam) * half_te
    jac[3:6, 8] = beam * half_te
    jac[0:3, 7:9] = -jac[3:6, 7:9]
    return out, jac


def weighted_hessian(q: np.ndarray, prm: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Hessian of ``Σ_i w_i · output_i`` per instance, (9, 9, N), exact for any ``ω``; ``w`` is (7, N)."""
    g = _Geometry(q, prm)
    te, ta, k, ts, length, beam, denom = g.te, g.ta, g.k, g.ts, g.length, g.beam, g.denom
    n_inst = q.shape[1]
    wt = w[6]
    ww = 0.5 * (w[3:6] - w[0:3])  # weight of ℓ te
    x = _cross(te, k)
    y = _cross(te, ts)
    ts_ta = _dot(ts, ta)
    k_ta = _dot(k, ta)
    w_te = _dot(ww, te)
    lw = length * ww
    wt_d = wt / denom
    # ε-ε block: sym(M) − λ I
    m = lw[:, None] * te[None] + (wt * te)[:, None] * k[None] - (wt_d * x)[:, None] * y[None]
    h_ee = m + m.transpose(1, 0, 2)
    h_ee *= 0.5
    h_ee -= (length * w_te) * _EYE3
    h_ea = _cross(ta, lw + wt * k) + (0.5 * wt) * ta - (0.5 * wt_d) * (x * ts_ta + y * k_ta)
    h_el = _cross(te, ww)
    h_aa = -0.25 * length * w_te - wt_d * k_ta * ts_ta
    h_al = _dot(ww, ta)

    hess = np.zeros((9, 9, n_inst))
    if g.at_source:
        hess[3:6, 3:6] = h_ee
    else:
        big_b, big_c, db, dc = _jacobian_coefficients(g.s, derivatives=True)
        omega, s = g.w, g.s
        jl = _left_jacobian(omega, s, big_b, big_c)
        h_ee = np.einsum("ajn,abn,bkn->jkn", jl, h_ee, jl)
        grad = wt * (te + x) + _cross(te, lw)  # ∂/∂ε of the weighted outputs
        g_w = _dot(grad, omega)
        v = db * _cross(grad, omega) + dc * (g_w * omega - s * grad) - (0.5 * big_c) * grad
        h_ee += omega[:, None] * v[None] + v[:, None] * omega[None]
        h_ee += (big_c * g_w) * _EYE3
        hess[3:6, 3:6] = 0.5 * (h_ee + h_ee.transpose(1, 0, 2))  # exactly symmetric
        h_ea = _dot(h_ea[:, None], jl)
        h_el = _dot(h_el[:, None], jl)
    hess[3:6, 6] = h_ea
    hess[6, 3:6] = h_ea
    hess[3:6, 7] = (1.0 - beam) * h_el
    hess[3:6, 8] = beam * h_el
    hess[7:9, 3:6] = hess[3:6, 7:9].transpose(1, 0, 2)
    hess[6, 6] = h_aa
    hess[6, 7] = (1.0 - beam) * h_al
    hess[6, 8] = beam * h_al
    hess[7:9, 6] = hess[6, 7:9]
    return hess
