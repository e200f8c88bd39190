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


def test_alternating_patterns_each_keep_their_analysis_and_give_right_solves():
    # A solver alternates a Hessian, its augmented and its shifted forms: every switch must
    # still factor the matrix handed over (not the last pattern's), also past MAX_PATTERNS.
    b = np.random.default_rng(3).standard_normal(120)
    mats = [spd(120, seed) for seed in range(SparseCholesky.MAX_PATTERNS + 2)]
    chol = SparseCholesky()
    for round_ in range(2):
        for k, A in enumerate(mats):
            M = (A * (1.0 + round_ + k)).tocsr()
            chol.factorize(M)
            assert np.allclose(M @ chol.solve(b), b, atol=1e-9), (round_, k)
    assert len(chol._patterns) == SparseCholesky.MAX_PATTERNS


def test_new_values_on_the_very_same_pattern_arrays_are_factored():
    # the pattern key is reused, unhashed, for the same index arrays: the values must still be read
    A = spd(80, 5)
    b = np.ones(80)
    chol = SparseCholesky()
    chol.factorize(A)
    B = sp.csr_matrix((3.0 * A.data, A.indices, A.indptr), shape=A.shape)
    B.indices, B.indptr = A.indices, A.indptr
    chol.factorize(B)
    assert np.allclose(B @ chol.solve(b), b, atol=1e-10)


def test_a_failed_factorization_leaves_nothing_to_solve_with_and_the_pattern_usable():
    A = spd(60, 6)
    chol = SparseCholesky()
    chol.factorize(A)
    bad = sp.csr_matrix((A.data.copy(), A.indices, A.indptr), shape=A.shape)
    bad.data[bad.indices == np.repeat(np.arange(60), np.diff(bad.indptr))] -= 100.0  # the diagonal
    with pytest.raises(NotPositiveDefinite):
        chol.factorize(bad)
    with pytest.raises(RuntimeError):
        chol.solve(np.ones(60))
    chol.factorize(A)  # the same pattern factors again
    assert np.allclose(A @ chol.solve(np.ones(60)), np.ones(60), atol=1e-10)


def test_a_second_object_on_a_known_pattern_gives_the_very_same_solves():
    # a new SparseCholesky copies the structure analysed by another (shared templates): the factor,
    # from the whole matrix or from its lower triangle, must be the same to the last bit
    A = spd(150, 7)
    b = np.random.default_rng(8).standard_normal(150)
    first = SparseCholesky()
    first.factorize(A)
    for M in (A, (A * 1.5).tocsr(), sp.tril(A, format="csr")):
        fresh, again = SparseCholesky(), SparseCholesky()
        fresh.factorize(M)
        again.factorize(M)
        assert np.array_equal(fresh.solve(b), again.solve(b))
    assert np.allclose(A @ first.solve(b), b, atol=1e-10)
    lower = SparseCholesky()
    lower.factorize(sp.tril(A, format="csr"))
    assert np.array_equal(lower.solve(b), first.solve(b))
