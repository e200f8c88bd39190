"""The CHOLMOD adapter."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from xshells.solve import NotPositiveDefinite, SparseCholesky


def spd(n, seed):
    A = sp.random(n, n, 0.05, random_state=seed)
    return (A @ A.T + sp.eye(n)).tocsr()


def test_solves_match_scipy_and_reuse_the_pattern():
    A = spd(200, 0)
    b = np.random.default_rng(1).standard_normal(200)
    chol = SparseCholesky()
    chol.factorize(A)
    assert np.allclose(chol.solve(b), spla.spsolve(A.tocsc(), b), rtol=1e-10, atol=1e-12)
    B = (2 * A).tocsr()  # same pattern, new values
    chol.factorize(B)
    assert np.allclose(B @ chol.solve(b), b, atol=1e-10)
    X = chol.solve(np.stack([b, 2 * b], axis=1))
    assert np.allclose(B @ X, np.stack([b, 2 * b], axis=1), atol=1e-10)
    chol.factorize(sp.tril(A).tocsr())  # a lower triangle gives the same factor
    assert np.allclose(A @ chol.solve(b), b, atol=1e-10)


def test_indefinite_matrix_raises():
    A = spd(50, 2) - 100 * sp.eye(50)
    with pytest.raises(NotPositiveDefinite):
        SparseCholesky().factorize(A.tocsr())
