"""Assembly of per-stencil vectors (xshells.sparse.VectorAssembler)."""
import numpy as np

from xshells.sparse import VectorAssembler


def test_vector_assembly_by_hand():
    # two stencils of two variables and one of one; index 5 is outside size 4 and dropped
    asm = VectorAssembler([np.array([[0, 1], [1, 2]]), np.array([[3, 5]])], 4)
    got = asm.assemble([np.array([[1.0, 2.0], [3.0, 4.0]]), np.array([[5.0, 6.0]])])
    assert np.array_equal(got, [1.0, 2.0 + 3.0, 4.0, 5.0])


def test_assemble_many_equals_one_at_a_time():
    rng = np.random.default_rng(0)
    idx = [rng.integers(0, 30, (13, 40)), rng.integers(0, 35, (7, 20))]
    asm = VectorAssembler(idx, 30)
    sets = [[rng.standard_normal((13, 40)), rng.standard_normal((7, 20))] for _ in range(3)]
    many = asm.assemble_many(sets)
    assert many.shape == (3, 30)
    for row, values in zip(many, sets):
        assert np.allclose(row, asm.assemble(values), rtol=1e-14, atol=1e-14)
    assert np.allclose(asm.assemble_many(sets[:2]), many[:2], rtol=1e-14, atol=1e-14)  # another count


def _random_csr(rng, n, density):
    import scipy.sparse as sp

    A = sp.random(n, n, density=density, random_state=rng, format="csr")
    A.sum_duplicates()
    return A


def test_pattern_sum_equals_the_sparse_sum_bit_for_bit():
    """``A + c B`` on the union pattern, with B inside A's pattern (the Hessian plus the mass matrix:
    A's values copied, B's added in place) and with patterns that only overlap (scattered)."""
    import scipy.sparse as sp

    from xshells.sparse import PatternSum

    rng = np.random.default_rng(4)
    A = _random_csr(rng, 40, 0.2)
    inside = A.copy()
    inside.data = rng.standard_normal(inside.nnz)
    inside = inside[:, :]  # the same pattern, other arrays
    inside.data[::3] = 0.0  # explicit zeros stay in the pattern
    other = _random_csr(rng, 40, 0.1)
    for B in (inside, other):
        for c in (1.0, 0.37):
            ps = PatternSum(A, B)
            S = ps([A, B], [1.0, c])
            ref = (A.toarray() + c * B.toarray())
            assert np.array_equal(S.toarray(), ref)
            assert S.nnz == (abs(A) + abs(sp.csr_matrix((np.ones(B.nnz), B.indices, B.indptr), shape=B.shape))).nnz
    ps = PatternSum(A, inside)
    assert ps.whole == [True, True]
    assert PatternSum(A, other).whole[1] is False
