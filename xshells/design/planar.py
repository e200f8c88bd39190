"""The planar branch: the flat layout opened *in its plane* to an angle, and whether it buckles out of it.

An X-shell reaches its shape because its planar opening becomes unstable on
the way to the deployed angle (paper §1 and §4, "rest-length optimization":
joints off a regular grid make the scissor mechanism incompatible, and the
beams buckle out of plane when the joints are actuated). A design whose planar
state at the deployed angle is still stable deploys flat, whatever curved
equilibria it has besides (``xshells inverse`` found such designs: their
optimization tracked a curved state that a deployment from flat never
reaches).

By mirror symmetry about the layout plane, a planar state is an equilibrium
of the whole problem as soon as it is one of the in-plane problem, and the
Hessian there has no in-plane/out-of-plane coupling. So the planar state is
solved with the out-of-plane variables held (:func:`planar_equilibrium`,
stable in the plane even where it is not out of it), and its out-of-plane
stability is the eigenproblem of the out-of-plane block alone
(:func:`out_of_plane_modes`).

The eigenvalues' derivatives in the rest lengths follow as for the flat
state (:meth:`DesignProblem.flat_stability`): ``dλ/dp = ∂³E[v, v, ·]_p −
H_px w`` with ``K w = ∂³E[v, v, ·]_x``, ``K`` the in-plane problem's KKT
matrix (by symmetry ``∂³E[v, v, ·]_x`` has no out-of-plane part for an
out-of-plane ``v``).
"""
from __future__ import annotations

import copy

import numpy as np
import scipy.sparse.linalg as spla

from ..errors import InputError
from .equilibrium import ConstrainedEquilibrium


def out_of_plane_indices(linkage) -> np.ndarray:
    """The variables that move the linkage out of its layout plane (sorted, int).

    Per joint its height and the two rotations that tilt its normal
    (``x[9j+2]``, ``x[9j+3]``, ``x[9j+4]``); per rod the heights of its free
    vertices and every free material angle. Requires the layout plane to be
    a coordinate plane ``z = const`` (the flat layouts xshells builds).
    """
    n = np.asarray(linkage.graph.layout_normal, float)
    if abs(abs(n[2]) - 1.0) > 1e-12:
        raise InputError(f"the planar branch needs a layout in a plane z = const (its normal is {n.round(6).tolist()})")
    J = 9 * np.arange(linkage.num_joints)
    rod, red = np.asarray(linkage._free_rod), np.asarray(linkage._free_reduced)
    V3 = 3 * linkage.rods.num_vertices
    rods = red[((rod < V3) & (rod % 3 == 2)) | (rod >= V3)]
    return np.sort(np.concatenate([J + 2, J + 3, J + 4, rods]))


def planar_equilibrium(flat_linkage, angle: float, steps: int = 10) -> ConstrainedEquilibrium:
    """The planar state of (a copy of) ``flat_linkage``, opened in its plane to ``angle`` (radians) in ``steps``.

    The out-of-plane variables and the central joint's rigid motion are held;
    the returned equilibrium owns the copy and follows the design parameters
    like the flat and deployed ones.
    """
    L = copy.deepcopy(flat_linkage)
    pins = np.union1d(L.rigid_pin_indices(), out_of_plane_indices(L))
    a0 = L.average_angle()
    eq = ConstrainedEquilibrium(L, a0, pins=pins)
    for a in np.linspace(a0, float(angle), steps + 1)[1:]:
        eq.angle = float(a)
        eq.solve()
    return eq


def buckling_block(eq: ConstrainedEquilibrium) -> np.ndarray:
    """The out-of-plane variables of ``eq``'s linkage less its central joint's rigid ones (height, two tilts)."""
    L = eq.L
    return np.setdiff1d(out_of_plane_indices(L), 9 * L.central_joint() + np.array([2, 3, 4]))


def out_of_plane_modes(eq: ConstrainedEquilibrium, block: np.ndarray, M, modes: int = 4, v0=None):
    """The lowest ``modes`` eigenpairs of ``H v = λ M v`` on the out-of-plane ``block``, ascending.

    ``M`` (len(block), len(block)) is the metric (a mass matrix, held fixed by
    the caller). Eigenvectors are M-normalized, (len(block), modes). Shift-invert
    about 0: the lowest modes of a planar state lie close to it on either side.
    """
    H = eq.L.hessian()[block][:, block].tocsc()
    try:
        lam, vecs = spla.eigsh(H, k=modes, M=M, sigma=0.0, which="LM", tol=1e-10,
                               v0=np.ones(len(block)) if v0 is None else v0)
    except (spla.ArpackError, RuntimeError) as exc:  # no convergence, or a factor exactly singular at the shift
        raise ArithmeticError(f"the planar state's out-of-plane eigenvalues could not be computed ({exc})") from exc
    order = np.argsort(lam)
    lam, vecs = lam[order], vecs[:, order]
    vecs = vecs / np.sqrt(np.einsum("ij,ij->j", vecs, M @ vecs))[None, :]
    return lam, vecs


def eigenvalue_gradients(eq: ConstrainedEquilibrium, block: np.ndarray, vecs: np.ndarray) -> np.ndarray:
    """``dλ_i/dp`` (modes, S) of the eigenpairs (columns of ``vecs`` on ``block``, M-normalized, at the
    equilibrium ``eq``), the metric held fixed: ``∂³E[v, v, ·]`` by second differences of the gradient."""
    from ..linkage.derivatives import _step

    L, nx = eq.L, eq.nx
    saved = L.move_checkpoint()
    x0 = L.get_vars()
    out = np.zeros((vecs.shape[1], len(L.rest_lengths)))
    try:
        G0 = L.gradient(with_rest_lengths=True)
        for i in range(vecs.shape[1]):
            v = np.zeros(nx)
            v[block] = vecs[:, i]
            h = _step(L, v, None, "central") * 100.0
            L.set_vars(x0 + h * v)
            Gp = L.gradient(with_rest_lengths=True)
            L.set_vars(x0 - h * v)
            Gm = L.gradient(with_rest_lengths=True)
            L.move_rollback(saved)
            T = (Gp + Gm - 2.0 * G0) / (h * h)
            w = eq.kkt_solve(T[:nx])
            out[i] = T[nx:] - eq.Hpx @ w
    finally:
        L.move_rollback(saved)
    return out
