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
