"""Directional derivatives of the linkage Hessian (third derivatives of E).

Design optimization (paper Appendix B) and sparse actuation (§6) need, for a
direction ``(δx, δp)``, the matrix

    dH[δx, δp] = d/dt ∇²E(x + t δx, p + t δp) |_{t=0},

and mostly only its product with one vector. The product
(:func:`hessian_derivative_product`, what the reference implementation calls
the directional derivative of ``applyHessian``) is computed without
assembling a Hessian, term by term of the chain rule with the stencil kernels
(relative error 2e-8 to 6e-7 at equilibria, 0.72–0.81 of one Hessian's
time, ``benchmarks/linkage.py``). The matrix itself is computed from the *exact*
Hessian by differencing along the direction:

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
from ..rod import rods as _rods_module
from . import joint_kernels as jk

_RELATIVE_STEP = {"central": 1e-5, "forward": 1e-7}
_PRODUCT_STEP = 5e-5  # relative step of the mixed differences of the stencil gradients (per stencil)
_JOINT_STEP = 1e-5  # central differences of the joint map's derivatives


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


def hessian_derivative_product(linkage, dx, dp, w, *, with_rest_lengths: bool = False) -> np.ndarray:
    """``dH[δx, δp] · w``: the Hessian's directional derivative applied to a vector.

    This is what the design optimization (Appendix B) and the sparse
    actuation (§6) consume; the matrix itself (:func:`hessian_derivative`) is
    never needed. It is computed without assembling any Hessian, term by term
    of the chain rule through the reduced-to-rod map ``z = φ(x)`` (rod
    variables) and ``R p`` (edge rest lengths)::

        dH·w = Jᵀ ∇³E[a, b] + Jᵀ ∇²E c + J'ᵀ ∇²E b
               + Σ_o (∇²E a)_o ∇²φ_o w + Σ_o (∇E)_o ∇³φ_o[δx, w]

    with ``a = J(δx, δp)``, ``b = J w``, ``c = ∇²φ[δx, w]`` and ``J' = ∇²φ[δx]``:

    * the bending and twisting stencils from their analytic gradients at a
      few perturbed stencil states, evaluated in one batch: a mixed central
      difference in ``a`` and ``b`` for ``∇³E[a, b]`` (four points, which
      also give ``∇²E a`` and ``∇²E b``, and the gradient itself at a state
      not evaluated yet), and two more points for ``∇²E c`` on the stencils
      next to a joint, the only ones ``c`` touches;
    * the stretching stencils exactly, from their third derivative by hand
      (:func:`_stretch_terms`);
    * the joint map's terms from central differences of its exact Jacobian
      and of its weighted Hessian (small, well-scaled 9-variable kernels).

    Nothing is differenced across the whole assembled linkage, and each
    stencil takes its own step (``_PRODUCT_STEP`` relative to its own
    perturbation and edge length), so the large internal forces of a deployed
    state do not swamp the small stencils. Relative error 2e-8 (manta ray
    deployed) to 6e-7 (wiggly banana at 80°, the design optimization's
    vectors); up to 2e-5 in the tests' strongly twisted random states, where
    the differences' truncation dominates. Cost: 0.72–0.81 of one Hessian
    (``benchmarks/linkage.py``).

    Parameters
    ----------
    linkage : Linkage
        Evaluated at its current state, which is left untouched.
    dx : (num_vars,) array
    dp : (num_segments,) array or None
    w : (num_vars,) or (num_vars + num_segments,) array
        The second size with ``with_rest_lengths=True``.
    with_rest_lengths : bool
        Apply the derivative of the joint Hessian in ``(x, p)``.

    Returns
    -------
    (num_vars,) or (num_vars + num_segments,) array
    """
    L = linkage
    nx, S = L.num_vars, L.num_segments
    dx = np.asarray(dx, float)
    if dx.shape != (nx,):
        raise InputError(f"dx: expected {nx} values, got shape {dx.shape}")
    if dp is not None:
        dp = np.asarray(dp, float)
        if dp.shape != (S,):
            raise InputError(f"dp: expected {S} values, got shape {dp.shape}")
    size = nx + (S if with_rest_lengths else 0)
    w = np.asarray(w, float)
    if w.shape != (size,):
        raise InputError(f"w: expected {size} values, got shape {w.shape}")
    wx, wp = w[:nx], (w[nx:] if with_rest_lengths else None)
    rods = L.rods
    if _rods_module._analytic is None or rods.num_stencils == 0:
        return hessian_derivative(L, dx, dp, with_rest_lengths=with_rest_lengths) @ w
    nv, ne = rods.num_vars, rods.num_edges
    length = L.min_arc_length()
    _, jac = L._instance_jacobian()
    prm_j = L._inst_prm
    n_inst = jac.shape[2]
    nj = L.num_joint_vars

    def per_instance(v):  # joint variables of each instance, (9, N)
        return np.ascontiguousarray(v[:nj].reshape(-1, 9)[L._inst_joint].T)

    def to_rod(J, v, vp):  # (J v, R vp) in rod space (rod variables, then edge rest lengths)
        z = np.zeros(nv + ne)
        z[L._free_rod] = v[L._free_reduced]
        z[L._inst_rows] = np.einsum("oin,in->on", J, per_instance(v))
        if vp is not None:
            z[nv:] = L.rest_length_map @ vp
        return z

    a = to_rod(jac, dx, dp)
    b = to_rod(jac, wx, wp)
    if not a.any() or not b.any():
        return np.zeros(size)

    # joint map: Jacobian and weighted Hessian at x ± h δx (joint variables only)
    di, wi = per_instance(dx), per_instance(wx)
    dscale = max(np.abs(di[3:7]).max(initial=0.0), np.abs(np.r_[di[:3].ravel(), di[7:].ravel()]).max(initial=0.0) / length)
    q0 = L._instance_q(L._x)
    c = np.zeros(nv + ne)
    dJ = None
    if dscale > 0.0:
        hj = _JOINT_STEP / dscale
        qpm = np.concatenate([q0 + hj * di, q0 - hj * di], axis=1)
        _, jpm = jk.outputs_and_jacobian(qpm, np.concatenate([prm_j, prm_j], axis=1))
        dJ = (jpm[:, :, :n_inst] - jpm[:, :, n_inst:]) / (2.0 * hj)
        c[L._inst_rows] = np.einsum("oin,in->on", dJ, wi)

    # rod stencils at perturbed states, one batch: four points for a and b, and two for c, which is
    # nonzero only next to the joints (the stencils it touches)
    vi, ei = rods.vertex_index, rods.edge_index
    Aq, Bq = a[vi], b[vi]
    vq = rods._vertex_q()
    # a step per stencil, relative to its own perturbation and edge lengths: every stencil's
    # difference then balances its own truncation and round-off errors
    s_k, r_k = _stencil_steps(vq, Aq), _stencil_steps(vq, Bq)
    sA, rB = s_k * Aq, r_k * Bq
    points = [vq + sA + rB, vq + sA - rB, vq - sA + rB, vq - sA - rB]
    prm_v = rods._vertex_params()
    n_st = vq.shape[1]
    near = np.flatnonzero(c[vi].any(axis=0))
    if len(near):
        Cq = c[vi[:, near]]
        c_k = _stencil_steps(vq[:, near], Cq)
        points += [vq[:, near] + c_k * Cq, vq[:, near] - c_k * Cq]
        prm_v = np.concatenate([np.tile(prm_v, (1, 4)), prm_v[:, near], prm_v[:, near]], axis=1)
    else:
        prm_v = np.tile(prm_v, (1, 4))
    G = _rods_module._analytic.vertex_gradient(np.concatenate(points, axis=1), prm_v, rods.bending_energy)
    G0 = G[:, : 4 * n_st].reshape(13, 4, n_st)
    y1_v = (G0[:, 0] - G0[:, 1] - G0[:, 2] + G0[:, 3]) / (4.0 * s_k * r_k)
    ba_v = (G0[:, 0] + G0[:, 1] - G0[:, 2] - G0[:, 3]) / (4.0 * s_k)
    bb_v = (G0[:, 0] - G0[:, 1] + G0[:, 2] - G0[:, 3]) / (4.0 * r_k)
    if len(near):
        m = len(near)
        y1_v[:, near] += (G[:, 4 * n_st : 4 * n_st + m] - G[:, 4 * n_st + m :]) / (2.0 * c_k)

    y1_e, ba_e, bb_e = _stretch_terms(rods._edge_q(), rods.ks, a[ei], b[ei], c[ei])

    asm = L._vector_assembler(nv + ne)
    if ("rod_grad", False) in L._cached():
        y1, Ba, Bb = asm.assemble_many([[y1_v, y1_e], [ba_v, ba_e], [bb_v, bb_e]])
        g_rod = L._rod_gradient()
    else:  # a state not evaluated yet: the rods' gradient from the same points (their mean, to O(step²))
        _, ge, _ = _rods_module.stretch_kernel(rods._edge_q(), rods.ks, hessian=False)
        y1, Ba, Bb, g_rod = asm.assemble_many([[y1_v, y1_e], [ba_v, ba_e], [bb_v, bb_e], [G0.mean(axis=1), ge]])

    # back to the reduced variables
    out = np.zeros(size)
    out[L._free_reduced] = y1[L._free_rod]
    rows = L._inst_rows
    joint = np.einsum("oin,on->in", jac, y1[rows])
    g = g_rod[rows]
    if dJ is not None:
        joint += np.einsum("oin,on->in", dJ, Bb[rows])
        # Σ g·∇³φ[δx] (a difference of weighted Hessians at x ± h δx) plus Σ (∇²E a)·∇²φ at x, which
        # the mean of the two points gives to O(h²): the weighted Hessian is linear in its weights
        wpm = np.concatenate([g / (2.0 * hj) + 0.5 * Ba[rows], -g / (2.0 * hj) + 0.5 * Ba[rows]], axis=1)
        wh = jk.weighted_hessian(qpm, np.concatenate([prm_j, prm_j], axis=1), wpm)
        d3 = wh[:, :, :n_inst] + wh[:, :, n_inst:]
    else:
        d3 = jk.weighted_hessian(q0, prm_j, Ba[rows])
    joint += np.einsum("ijn,jn->in", d3, wi)
    out[:nj] = np.bincount(((9 * L._inst_joint)[None, :] + np.arange(9)[:, None]).ravel(), weights=joint.ravel(),
                           minlength=nj)
    if with_rest_lengths:
        out[nx:] = L.rest_length_map.T @ y1[nv:]
    return out


def _stencil_steps(q, A):
    """Step of each vertex stencil along its direction ``A`` (13, N): ``_PRODUCT_STEP`` over the
    largest of its angle changes and its position and rest-length changes over its shorter edge; 1
    where ``A`` is zero (its differences are exactly zero then)."""
    ell = np.minimum(np.abs(q[11]), np.abs(q[12]))
    size_ = np.maximum(np.abs(A[9:11]).max(axis=0), np.maximum(np.abs(A[0:9]).max(axis=0), np.abs(A[11:13]).max(axis=0)) / ell)
    return np.where(size_ > 0.0, _PRODUCT_STEP / np.where(size_ > 0.0, size_, 1.0), 1.0)


def _stretch_terms(q, ks, A, B, C):
    """Per edge stencil: ``∇³E[A, B] + ∇²E C``, ``∇²E A`` and ``∇²E B`` (each (7, N)).

    The stretching energy ``E = ks/(2L) (|e| − L)²`` of an edge ``e = x1 − x0``
    with rest length ``L``, differentiated by hand in ``(e, L)``: with
    ``n = |e|``, ``t = e/n``, its Hessian applied to ``v = (v_e, v_L)`` is::

        (∇²E v)_e = ks [ (t·v_e) t / n + (1/L − 1/n) v_e − n v_L t / L² ]
        (∇²E v)_L = ks [ −n (t·v_e) / L² + n² v_L / L³ ]

    and ``∇³E[A, B]`` is its derivative along ``A`` with ``v = B`` fixed,
    using ``δn = t·A_e`` and ``δt = (A_e − (t·A_e) t)/n``. Checked against
    central differences of the stretch kernel's Hessian in the tests.
    """
    e = q[3:6] - q[0:3]
    n = np.sqrt(np.einsum("in,in->n", e, e))
    t = e / n
    L = q[6]

    def apply(v):
        ve = v[3:6] - v[0:3]
        tv = np.einsum("in,in->n", t, ve)
        he = ks * ((tv / n) * t + (1.0 / L - 1.0 / n) * ve - (n * v[6] / L**2) * t)
        hL = ks * (-n * tv / L**2 + n**2 * v[6] / L**3)
        return ve, tv, he, hL

    def to_nodes(he, hL):
        out = np.empty((7, he.shape[1]))
        np.negative(he, out=out[0:3])
        out[3:6] = he
        out[6] = hL
        return out

    ae, ta, he_a, hL_a = apply(A)
    be, tb, he_b, hL_b = apply(B)
    _, _, he_c, hL_c = apply(C)
    aL, bL = A[6], B[6]
    dt_b = (np.einsum("in,in->n", ae, be) - ta * tb) / n  # δt·B_e
    dt = (ae - ta * t) / n  # δt, (3, N)
    d_he = ks * ((-ta * tb / n**2 + dt_b / n) * t + (tb / n) * dt + (-aL / L**2 + ta / n**2) * be
                 - bL * ((ta / L**2 - 2.0 * n * aL / L**3) * t + (n / L**2) * dt))
    d_hL = ks * (-(ta * tb / L**2 + n * dt_b / L**2 - 2.0 * n * tb * aL / L**3)
                 + bL * (2.0 * n * ta / L**3 - 3.0 * n**2 * aL / L**4))
    return to_nodes(d_he + he_c, d_hL + hL_c), to_nodes(he_a, hL_a), to_nodes(he_b, hL_b)


def third_derivative_product(linkage, dx, u) -> np.ndarray:
    """``dH[δx] · u = ∂³E[δx, u, ·]`` in the state variables (rest lengths fixed).

    :func:`hessian_derivative_product` with ``δp = 0``.
    """
    return hessian_derivative_product(linkage, dx, None, u)
