"""Continuation of an equilibrium in the rest lengths: the first-order predictor of a design change.

At an equilibrium ``x`` of ``E(x, p)`` (with the free gradient balanced by a
constraint ``a·x = τ`` if one is held), a change of the rest lengths to ``p'``
moves the equilibrium, to first order, by the solution of

    H dx = −(∇ₓE(x, p') − ∇ₓE(x, p)),    a·dx = 0,

with ``H`` the Hessian at the old equilibrium, which is positive definite
there: that is what makes it stable. Newton's method then starts from
``x + dx``, next to the new equilibrium, instead of from ``x`` under the
unbalanced forces of the new rest lengths. From ``x`` itself the new Hessian
is often indefinite, and the shifted steps take tens of iterations. The
right-hand side is the exact force change at ``x``, not its linearization in
``p``.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .cholesky import NotPositiveDefinite
from .newton import _workspace, free_indices


def rest_length_predictor(problem, new_rest_lengths, *, fixed=None, constraint_direction=None) -> bool:
    """Set ``problem``'s rest lengths to ``new_rest_lengths`` and move its state by the first-order predictor.

    Parameters
    ----------
    problem : object
        With ``get_vars``, ``set_vars``, ``gradient``, ``hessian``,
        ``set_rest_lengths`` (e.g. :class:`xshells.linkage.linkage.Linkage`),
        at an equilibrium of its current rest lengths.
    new_rest_lengths : (S,) array
    fixed : (k,) int array, optional
        Variables held (the rigid pins).
    constraint_direction : (n,) array, optional
        ``a`` of a held constraint ``a·x = τ``; the predicted step keeps ``a·dx = 0``.

    Returns
    -------
    bool
        Whether the step was taken. False when the Hessian, augmented on the
        constraint, does not factor (the state is not a stable equilibrium).
        The rest lengths are changed either way.
    """
    x = problem.get_vars()
    n = len(x)
    free_idx = free_indices(n, fixed)
    ws = _workspace(problem)
    g_old = problem.gradient()
    H = ws.free_part(problem.hessian(), free_idx, n)
    problem.set_rest_lengths(new_rest_lengths)
    b = (problem.gradient() - g_old)[free_idx]
    a = None if constraint_direction is None else np.asarray(constraint_direction, float)[free_idx]
    chol = ws.chol
    try:
        chol.factorize(H)
    except NotPositiveDefinite:
        if a is None:
            return False
        # stability on the constraint surface: H + ρ a aᵀ (the step with a·dx = 0 is the same)
        rho = float(np.abs(H.diagonal()).max()) / float(a @ a)
        nz = np.flatnonzero(a)
        outer = sp.csr_matrix((np.outer(a[nz], a[nz]).ravel(), (np.repeat(nz, len(nz)), np.tile(nz, len(nz)))),
                              shape=H.shape)
        try:
            chol.factorize(ws.combine("predictor", [H, outer], [1.0, rho]))
        except NotPositiveDefinite:
            return False
    if a is None:
        dx = -chol.solve(b)
    else:
        u, v = chol.solve(np.stack([b, a], axis=1)).T
        dx = -u + (a @ u) / (a @ v) * v
    x[free_idx] += dx
    problem.set_vars(x)
    if hasattr(problem, "update_source_frame"):
        problem.update_source_frame()
    return True
