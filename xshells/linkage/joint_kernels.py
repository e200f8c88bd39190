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

from ..rod.analytic import _add_diag, _add_skew

_I1 = np.array([1, 2, 0])
_I2 = np.array([2, 0, 1])
_EYE3 = np.eye(3)[:, :, None]


def _cross(a, b):
    """Cross product over axis 0 (length 3), broadcasting the other axes."""
    return a.take(_I1, 0) * b.take(_I2, 0) - a.take(_I2, 0) * b.take(_I1, 0)


def _dot(a, b):
    return np.einsum("i...,i...->...", a, b)


def is_at_source(q: np.ndarray) -> bool:
    """Whether every instance has ``ω = 0`` exactly (the cheaper path applies)."""
    return not np.any(q[3:6])


def _coefficients(s, derivatives=False):
    """Rotation coefficients of ``s = |ω|²``, closed forms patched by series where they cancel.

    Returns ``a = sin θ/θ`` and ``b = (1 − cos θ)/θ²`` exactly as ``joints.rotate``
    computes them (series below ``s = 1e-8``), then the left-Jacobian
    coefficients ``B = (1 − cos θ)/θ²``, ``C = (θ − sin θ)/θ³`` and, optionally,
    ``dB/ds, dC/ds``, with series below ``s = 1e-2`` (truncation below 1e-18).
    """
    th = np.sqrt(s)
    sn, cs = np.sin(th), np.cos(th)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = sn / th
        b = (1.0 - cs) / s
        big_c = (th - sn) / (s * th)
        if derivatives:
            s2 = s * s
            db = (th * sn - 2.0 * (1.0 - cs)) / (2.0 * s2)
            dc = (th * (1.0 - cs) - 3.0 * (th - sn)) / (2.0 * s2 * th)
    big_b = b.copy()
    i = np.flatnonzero(s < 1e-2)
    if i.size:
        x = s[i]
        big_b[i] = 0.5 + x * (-1 / 24 + x * (1 / 720 + x * (-1 / 40320 + x / 3628800)))
        big_c[i] = 1 / 6 + x * (-1 / 120 + x * (1 / 5040 + x * (-1 / 362880 + x / 39916800)))
        if derivatives:
            db[i] = -1 / 24 + x * (1 / 360 + x * (-1 / 13440 + x * (1 / 907200 - x * 5 / 479001600)))
            dc[i] = -1 / 120 + x * (1 / 2520 + x * (-1 / 120960 + x * (1 / 9979200 - x * 5 / 6227020800)))
        j = np.flatnonzero(x < 1e-8)
        if j.size:
            x, i = x[j], i[j]
            a[i] = 1.0 - x / 6.0 + x * x / 120.0
            b[i] = 0.5 - x / 24.0 + x * x / 720.0
    if derivatives:
        return a, b, big_b, big_c, db, dc
    return a, b, big_b, big_c


def _left_jacobian(w, s, big_b, big_c):
    """``J = (1 − C s) I + B [ω]× + C ω ωᵀ``, (3, 3, N)."""
    jl = big_c * w[:, None] * w[None, :]
    jl += (1.0 - big_c * s) * _EYE3
    _add_skew(jl, big_b * w)
    return jl


class _Geometry:
    """Everything the outputs and their derivatives share."""

    def __init__(self, q, prm, derivatives=False):
        n_inst = q.shape[1]
        w = q[3:6]
        self.at_source = is_at_source(q)
        v0 = prm[0:6].reshape(2, 3, n_inst).transpose(1, 0, 2)  # (3, 2, N): b0, n0
        if self.at_source:
            self.s = None
            frame = v0
        else:
            self.s = _dot(w, w)
            self.coefficients = _coefficients(self.s, derivatives)
            a, bb = self.coefficients[:2]
            wv = _cross(w[:, None], v0)
            frame = v0 + a * wv + bb * _cross(w[:, None], wv)
        b, n = frame[:, 0], frame[:, 1]
        u = _cross(n, b)
        beam, sigma = prm[6], prm[7]
        half_alpha = 0.5 * q[6]
        c, sn = np.cos(half_alpha), np.sin(half_alpha)
        self.sx = sx = 2.0 * beam - 1.0  # −1 for beam A, +1 for beam B
        self.te = sigma * (c * b + (sx * sn) * u)
        self.ta = (0.5 * sigma) * ((sx * c) * u - sn * b)  # = ½ sx (n × te)
        self.n = n
        self.beam = beam
        self.length = (1.0 - beam) * q[7] + beam * q[8]
        self.w = w
        ts = prm[8:11]
        self.ts = ts
        te = self.te
        ct = _cross(ts, te)
        self.ts_te = _dot(ts, te)
        self.denom = 1.0 + self.ts_te
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
        d1 = self.ts_te * d1s + _cross(ct, d1s) + (_dot(ct, d1s) / self.denom) * ct
        d2 = _cross(te, d1)
        phi = prm[15]
        m1 = (2.0 * np.cos(phi) * self.sx) * self.ta - np.sin(phi) * n  # n × te = 2 sx ta
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
        # (∂/∂ε) J with J = (1 − C s) I + B [ω]× + C ω ωᵀ:
        # −[te]× J = −[te − C (te·ω) ω]× + B (te·ω) I − ω ⊗ (B te + C te × ω)
        # gᵀ J = (1 − C s) g + B g × ω + C (g·ω) ω
        omega, s = g.w, g.s
        big_b, big_c = g.coefficients[2:4]
        te_w = _dot(te, omega)
        v = te - (big_c * te_w) * omega
        row = big_b * te + big_c * _cross(te, omega)
        dte = -omega[:, None] * row[None]
        _add_diag(dte, big_b * te_w)
        _add_skew(dte, -v)
        jac[6, 3:6] = (1.0 - big_c * s) * grad_theta + big_b * _cross(grad_theta, omega) + (big_c * _dot(grad_theta, omega)) * omega
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
    g = _Geometry(q, prm, derivatives=True)
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
        big_b, big_c, db, dc = g.coefficients[2:]
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
