"""The one adapter around CHOLMOD (through cvxopt) for sparse Cholesky.

One symbolic analysis is kept and reused while the sparsity pattern stays
the same; a matrix that is not positive definite raises
:class:`NotPositiveDefinite` instead of returning a wrong factor.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from cvxopt import cholmod, matrix, spmatrix

cholmod.options["supernodal"] = 2  # supernodal LLᵀ: fastest here for our sizes
cholmod.options["print"] = 0


class NotPositiveDefinite(ArithmeticError):
    """The matrix handed to :meth:`SparseCholesky.factorize` is not positive definite."""


class SparseCholesky:
    """Factorize symmetric positive-definite sparse matrices of one pattern."""

    def __init__(self):
        self._pattern = None
        self._A = None
        self._symbolic = None
        self._numeric = None
        self.n = 0

    def factorize(self, A: sp.spmatrix) -> None:
        """Factorize ``A``: a symmetric sparse matrix, full or lower triangle (only the lower triangle is read).

        Raises
        ------
        NotPositiveDefinite
        """
        # Read as CSC, the CSR arrays of A describe Aᵀ; CHOLMOD is told to read
        # its upper triangle, which is A's lower one: no triangle extraction.
        L = A.tocsr() if A.format != "csr" else A
        if not L.has_sorted_indices:
            L = L.copy()
            L.sort_indices()
        key = (L.shape, len(L.indices), hash(L.indptr.tobytes()), hash(L.indices.tobytes()))
        if key != self._pattern:
            self.n = L.shape[0]
            cols = np.repeat(np.arange(L.shape[1]), np.diff(L.indptr))
            self._A = spmatrix(L.data.astype(float), L.indices.astype(int).tolist(), cols.tolist(), L.shape)
            # the spmatrix holds Aᵀ (CSR arrays read as CSC): its upper triangle is the lower one of A
            self._symbolic = cholmod.symbolic(self._A, uplo="U")
            self._pattern = key
        else:
            self._A.V = matrix(L.data.astype(float))
        self._numeric = self._symbolic  # cvxopt factors in place on the symbolic object
        try:
            cholmod.numeric(self._A, self._symbolic)
        except ArithmeticError as exc:
            self._numeric = None
            raise NotPositiveDefinite(str(exc)) from None

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve ``A x = b`` for ``b`` of shape (n,) or (n, k)."""
        if self._numeric is None:
            raise RuntimeError("no successful factorization to solve with")
        B = np.array(b, dtype=float, order="F")
        one = B.ndim == 1
        M = matrix(B.reshape(self.n, -1, order="F"))
        cholmod.solve(self._numeric, M)
        out = np.array(M)
        return out[:, 0] if one else out
