"""Fast assembly of stencil blocks into one sparse symmetric matrix.

Every energy here is a sum over small stencils; its Hessian is a sum of
dense ``k × k`` blocks scattered into a large sparse matrix with a pattern
that never changes. :class:`BlockAssembler` analyses that pattern once
(sorting, deduplication) so that each later assembly is a single gather and
``np.bincount`` over the block entries.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp


class BlockAssembler:
    """Scatter stencil blocks into a fixed sparse pattern.

    Parameters
    ----------
    index_sets : sequence of (k_i, N_i) int arrays
        For each stencil type, the global index of each of a stencil's ``k_i``
        variables. Entries outside ``[0, size)`` are dropped (use them for
        variables that are held fixed or live in another block).
    size : int
        Matrix dimension.
    triangle : {"full", "lower"}
        Which entries to keep. ``"lower"`` keeps ``row >= col``: the input a
        sparse Cholesky factorization wants, at half the cost.
    """

    def __init__(self, index_sets: Sequence[np.ndarray], size: int, triangle: str = "full"):
        if triangle not in ("full", "lower"):
            raise ValueError("triangle must be 'full' or 'lower'")
        self.size = int(size)
        self.triangle = triangle
        self.block_shapes = [idx.shape for idx in index_sets]
        rows, cols = [], []
        for idx in index_sets:
            k, n = idx.shape
            rows.append(np.broadcast_to(idx[:, None, :], (k, k, n)).ravel())
            cols.append(np.broadcast_to(idx[None, :, :], (k, k, n)).ravel())
        r = np.concatenate(rows).astype(np.int64)
        c = np.concatenate(cols).astype(np.int64)
        keep = (r >= 0) & (c >= 0) & (r < size) & (c < size)
        if triangle == "lower":
            keep &= r >= c
        self._take = np.flatnonzero(keep)
        r, c = r[self._take], c[self._take]
        # The pattern by SciPy's COO -> CSR conversion (a counting sort by row), then each entry's slot by a
        # binary search of its key in it: the same as np.unique(key, return_inverse=True), in half the time
        # (627,432 entries of the manta ray's rods: 19 against 43 ms, on the path of every rest-length solve).
        P = sp.csr_matrix((np.ones(len(r), dtype=np.int32), (r, c)), shape=(self.size, self.size))
        P.sum_duplicates()
        uniq = np.repeat(np.arange(self.size, dtype=np.int64), np.diff(P.indptr)) * self.size + P.indices
        self._slot = np.searchsorted(uniq, r * self.size + c)
        self.nnz = len(uniq)
        self.indices = P.indices.astype(np.int32)
        self.indptr = P.indptr.astype(np.int32)

    def assemble_data(self, blocks: Sequence[np.ndarray]) -> np.ndarray:
        """CSR data array (nnz,) for the given blocks (each (k_i, k_i, N_i))."""
        flat = np.concatenate([np.ascontiguousarray(b).ravel() for b in blocks])
        return np.bincount(self._slot, weights=flat[self._take], minlength=self.nnz)

    def assemble(self, blocks: Sequence[np.ndarray]) -> sp.csr_matrix:
        """Assemble into a CSR matrix of shape ``(size, size)``."""
        data = self.assemble_data(blocks)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))


class VectorAssembler:
    """Sum per-stencil vectors into a global vector (the gradient's :class:`BlockAssembler`).

    Parameters
    ----------
    index_sets : sequence of (k_i, N_i) int arrays
        Global index of each stencil variable; entries outside ``[0, size)`` are dropped.
    size : int
    """

    def __init__(self, index_sets: Sequence[np.ndarray], size: int):
        idx = np.concatenate([np.asarray(i).ravel() for i in index_sets]).astype(np.int64)
        self.size = int(size)
        self._take = np.flatnonzero((idx >= 0) & (idx < size))
        self._index = idx[self._take]
        self._index_many = {}  # count of vectors -> their stacked indices (assemble_many)

    def assemble(self, values: Sequence[np.ndarray]) -> np.ndarray:
        """Global vector (size,) from per-stencil values (each (k_i, N_i))."""
        flat = np.concatenate([np.ascontiguousarray(v).ravel() for v in values])
        return np.bincount(self._index, weights=flat[self._take], minlength=self.size)

    def assemble_many(self, value_sets: Sequence[Sequence[np.ndarray]]) -> np.ndarray:
        """Several global vectors at once, ``(len(value_sets), size)``: one pass instead of one per vector."""
        m = len(value_sets)
        if m not in self._index_many:
            self._index_many[m] = (self._index[None, :] + self.size * np.arange(m)[:, None]).ravel()
        flat = np.concatenate([np.concatenate([np.ascontiguousarray(v).ravel() for v in values])[self._take]
                               for values in value_sets])
        return np.bincount(self._index_many[m], weights=flat, minlength=m * self.size).reshape(m, self.size)


def _canonical(A: sp.spmatrix) -> sp.csr_matrix:
    A = A.tocsr() if A.format != "csr" else A
    if not A.has_canonical_format:
        A = A.copy()
        A.sum_duplicates()
    return A


def _same_pattern(A: sp.csr_matrix, indptr: np.ndarray, indices: np.ndarray) -> bool:
    if A.shape[0] + 1 != len(indptr) or len(A.indices) != len(indices):
        return False
    return (A.indptr is indptr or np.array_equal(A.indptr, indptr)) and (A.indices is indices or np.array_equal(A.indices, indices))


class PrincipalSubmatrix:
    """``A[idx][:, idx]`` for CSR matrices of one sparsity pattern, by a gather map computed once.

    Call :meth:`matches` to check that a matrix has the pattern the map was
    built for (cheap: identity of the index arrays, else one comparison).
    """

    def __init__(self, A: sp.spmatrix, idx: np.ndarray):
        A = _canonical(A)
        self.src_indptr, self.src_indices, self.src_shape = A.indptr, A.indices, A.shape
        marker = sp.csr_matrix((np.arange(1, A.nnz + 1, dtype=float), A.indices, A.indptr), shape=A.shape)
        sub = marker[idx][:, idx].tocsr()
        sub.sort_indices()
        self.take = sub.data.astype(np.int64) - 1
        self.indices, self.indptr, self.shape = sub.indices, sub.indptr, sub.shape

    def matches(self, A: sp.spmatrix) -> bool:
        return A.format == "csr" and A.shape == self.src_shape and A.has_canonical_format and _same_pattern(A, self.src_indptr, self.src_indices)

    def __call__(self, A: sp.csr_matrix) -> sp.csr_matrix:
        S = sp.csr_matrix((A.data[self.take], self.indices, self.indptr), shape=self.shape)
        S.has_canonical_format = True
        return S


class PatternSum:
    """``A + Σ c_i B_i`` for matrices of fixed patterns, into the union pattern computed once."""

    def __init__(self, A: sp.spmatrix, *others: sp.spmatrix):
        mats = [_canonical(A)] + [_canonical(B) for B in others]
        self.patterns = [(M.indptr, M.indices, M.shape) for M in mats]
        ones = [sp.csr_matrix((np.ones(M.nnz), M.indices, M.indptr), shape=M.shape) for M in mats]
        U = ones[0]
        for O in ones[1:]:
            U = U + O
        U = _canonical(U.tocsr())
        U.sort_indices()
        n = U.shape[1]
        rows_u = np.repeat(np.arange(U.shape[0]), np.diff(U.indptr))
        key_u = rows_u.astype(np.int64) * n + U.indices
        self.positions = []
        # whether a matrix has the union pattern itself (a Hessian with the mass matrix's pattern inside its
        # own): its values are then copied, not scattered (0.03 against 0.21 ms at 100k entries)
        self.whole = []
        for M in mats:
            whole = M.nnz == U.nnz and np.array_equal(M.indptr, U.indptr) and np.array_equal(M.indices, U.indices)
            if whole:
                self.positions.append(np.arange(U.nnz))
            else:
                rows = np.repeat(np.arange(M.shape[0]), np.diff(M.indptr))
                self.positions.append(np.searchsorted(key_u, rows.astype(np.int64) * n + M.indices))
            self.whole.append(whole)
        self.indices, self.indptr, self.shape, self.nnz = U.indices, U.indptr, U.shape, U.nnz

    def matches(self, *mats) -> bool:
        return len(mats) == len(self.patterns) and all(
            M.format == "csr" and M.shape == shp and M.has_canonical_format and _same_pattern(M, ip, ix)
            for M, (ip, ix, shp) in zip(mats, self.patterns))

    def __call__(self, mats, coefficients) -> sp.csr_matrix:
        if self.whole[0] and coefficients[0] == 1.0:
            data = np.array(mats[0].data, dtype=float)
        else:
            data = np.zeros(self.nnz)
        for i, (M, pos, c) in enumerate(zip(mats, self.positions, coefficients)):
            if i == 0 and c == 1.0:
                if not self.whole[0]:
                    data[pos] = M.data  # onto zeros: the same values, without reading them back (a third faster)
            elif self.whole[i] and c == 1.0:
                data += M.data
            elif self.whole[i] and c != 0.0:
                data += c * M.data
            elif c == 1.0:
                data[pos] += M.data
            elif c != 0.0:
                data[pos] += c * M.data
        S = sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)
        S.has_canonical_format = True
        return S
