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
        key = r[self._take] * self.size + c[self._take]
        uniq, self._slot = np.unique(key, return_inverse=True)
        self.nnz = len(uniq)
        self.indices = (uniq % self.size).astype(np.int32)
        row_of = uniq // self.size
        self.indptr = np.searchsorted(row_of, np.arange(self.size + 1)).astype(np.int32)

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

    def assemble(self, values: Sequence[np.ndarray]) -> np.ndarray:
        """Global vector (size,) from per-stencil values (each (k_i, N_i))."""
        flat = np.concatenate([np.ascontiguousarray(v).ravel() for v in values])
        return np.bincount(self._index, weights=flat[self._take], minlength=self.size)
