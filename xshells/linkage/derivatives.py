"""Directional derivatives of the linkage Hessian (third derivatives of E).

Design optimization (paper Appendix B) and sparse actuation (§6) need, for a
direction ``(δx, δp)``, the matrix

    dH[δx, δp] = d/dt ∇²E(x + t δx, p + t δp) |_{t=0},

and mostly only its product with one vector. Here it is computed from the
*exact* Hessian by differencing along the direction:

* ``scheme="central"`` (default): ``(H(+h) − H(−h)) / 2h``, two Hessians,
  relative error about 3e-7 (Frobenius norm, manta ray at k = 10 in a
  randomly perturbed 3D state: truncation ``h²`` balanced against round-off
  ``ε‖H‖/h``, and ``‖H‖`` is dominated by the stretching terms, about 1e5
  times ``‖dH‖``);
* ``scheme="forward"``: ``(H(+h) − H(0)) / h`` reusing a Hessian the caller
  already has at the current state, one Hessian, relative error 5e-6 to
  6e-5 depending on the state (the truncation and round-off errors are both
  large, so the step is a compromise); prefer ``"central"`` where accuracy
  matters.

Why not automatic differentiation: JAX third derivatives of the vertex
stencil (a Hessian of a directional derivative) were measured here at about
100 s to compile and 2 s to run for 300 stencils, four orders of magnitude
above the analytic Hessian (3 ms). Exact analytic third-derivative kernels
are future work; the differencing here is accurate enough for the
Newton-CG Hessian-vector products that use it, whose tolerances are far
looser than 1e-8.

The step is scaled per kind of variable: positions and lengths move by about
``1e-5`` (central) of the shortest segment, angles by about ``1e-5`` rad.
The linkage's state is restored exactly afterwards (the rods' frames are a
function of the variables and the stored source frame).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import InputError

_RELATIVE_STEP = {"central": 1e-5, "forward": 1e-7}


def _angle_mask(linkage) -> np.ndarray:
    """True for the reduced variables that are angles (joint ω, α and the rods' material angles)."""
    mask = np.zeros(linkage.num_vars, bool)
    nj = linkage.num_joint_vars
    joint = np.zeros(9, bool)
    joint[3:7] = True
    mask[:nj] = np.tile(joint, nj // 9)
    nrv = linkage.rods.num_vars
    rod_is_angle = np.zeros(nrv, bool)
    rod_is_angle[3 * linkage.rods.num_vertices:] = True
    mask[linkage._free_reduced] = rod_is_angle[linkage._free_rod]
    return mask


def _step(linkage, dx, dp, scheme) -> float:
    length = linkage.min_arc_length()
    ang = _angle_mask(linkage)
    size = max(
        np.abs(dx[ang]).max(initial=0.0),
        np.abs(dx[~ang]).max(initial=0.0) / length,
        np.abs(dp).max(initial=0.0) / length if dp is not None else 0.0,
    )
    if size == 0.0:
        return 0.0
    return _RELATIVE_STEP[scheme] / size


def _hessian_at(linkage, x, p, with_rest_lengths):
    linkage.set_vars(x)
    if p is not None:
        linkage.set_rest_lengths(p)
    return linkage.hessian(with_rest_lengths)


def hessian_derivative(linkage, dx, dp=None, *, with_rest_lengths: bool = False, scheme: str = "central",
                       hessian=None) -> sp.csr_matrix:
    """Derivative of the Hessian along ``(δx, δp)``.

    Parameters
    ----------
    linkage : Linkage
        Evaluated at its current state; left exactly as it was.
    dx : (num_vars,) array
        Direction in the reduced variables.
    dp : (num_segments,) array, optional
        Direction in the per-segment rest lengths (default zero).
    with_rest_lengths : bool
        Return the derivative of the joint Hessian in ``(x, p)``,
        ``(num_vars + S, num_vars + S)``; otherwise of ``∂²E/∂x²`` only.
    scheme : {"central", "forward"}
        See the module notes; ``"forward"`` costs one Hessian when
        ``hessian`` (the Hessian at the current state, with the same
        ``with_rest_lengths``) is given.
    hessian : sparse matrix, optional
        ``H`` at the current state, reused by ``"forward"``.

    Returns
    -------
    scipy.sparse.csr_matrix
        Symmetric, same shape as the Hessian.
    """
    if scheme not in _RELATIVE_STEP:
        raise InputError(f"scheme must be 'central' or 'forward', got {scheme!r}")
    dx = np.asarray(dx, float)
    if dx.shape != (linkage.num_vars,):
        raise InputError(f"dx: expected {linkage.num_vars} values, got shape {dx.shape}")
    if dp is not None:
        dp = np.asarray(dp, float)
        if dp.shape != (linkage.num_segments,):
            raise InputError(f"dp: expected {linkage.num_segments} values, got shape {dp.shape}")
        if not dp.any():
            dp = None
    size = linkage.num_vars + (linkage.num_segments if with_rest_lengths else 0)
    h = _step(linkage, dx, dp, scheme)
    if h == 0.0:
        return sp.csr_matrix((size, size))
    if scheme == "forward" and hessian is None:
        hessian = linkage.hessian(with_rest_lengths)
    x0, p0 = linkage.get_vars(), linkage.rest_lengths
    saved = linkage.move_checkpoint()
    try:
        Hp = _hessian_at(linkage, x0 + h * dx, None if dp is None else p0 + h * dp, with_rest_lengths)
        if scheme == "central":
            Hm = _hessian_at(linkage, x0 - h * dx, None if dp is None else p0 - h * dp, with_rest_lengths)
            return _difference(Hp, Hm, 0.5 / h)
    finally:
        linkage.move_rollback(saved)
    return _difference(Hp, hessian, 1.0 / h)


def _difference(A, B, scale) -> sp.csr_matrix:
    """``(A − B)·scale``; on the reduced Hessian's fixed pattern, a difference of the value arrays."""
    if (isinstance(A, sp.csr_matrix) and isinstance(B, sp.csr_matrix) and A.shape == B.shape
            and A.indptr is B.indptr and A.indices is B.indices):
        return sp.csr_matrix(((A.data - B.data) * scale, A.indices, A.indptr), shape=A.shape)
    return ((A - B) * scale).tocsr()


def hessian_derivative_product(linkage, dx, dp, u, **kwargs) -> np.ndarray:
    """``dH[δx, δp] · u``: the third derivative contracted with two vectors.

    ``u`` has the Hessian's size (``num_vars``, or ``num_vars + S`` with
    ``with_rest_lengths=True``).
    """
    return hessian_derivative(linkage, dx, dp, **kwargs) @ np.asarray(u, float)


def third_derivative_product(linkage, dx, u) -> np.ndarray:
    """``dH[δx] · u = ∂³E[δx, u, ·]`` in the state variables, from four gradients.

    The mixed central difference ``∂²/∂s∂r ∇E(x + s δx + r u)`` costs four
    gradients (about one Hessian, see ``benchmarks/linkage.py``) instead of
    the two Hessians of :func:`hessian_derivative`; steps of about ``2e-4`` of
    the variables' scales balance truncation against the round-off of the
    stretching gradients: relative error 4e-5 (banana, k = 4) to 6e-5 (manta
    ray, k = 10), measured in perturbed 3D states, enough for Newton-CG Hessian-vector products.
    """
    dx = np.asarray(dx, float)
    u = np.asarray(u, float)
    hs = _step(linkage, dx, None, "central") * 20.0
    hr = _step(linkage, u, None, "central") * 20.0
    if hs == 0.0 or hr == 0.0:
        return np.zeros(linkage.num_vars)
    x0 = linkage.get_vars()
    out = np.zeros(linkage.num_vars)
    saved = linkage.move_checkpoint()
    try:
        for s, r, sign in ((1, 1, 1.0), (1, -1, -1.0), (-1, 1, -1.0), (-1, -1, 1.0)):
            linkage.set_vars(x0 + s * hs * dx + r * hr * u)
            out += sign * linkage.gradient()
    finally:
        linkage.move_rollback(saved)
    return out / (4.0 * hs * hr)
