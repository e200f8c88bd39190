"""The one adapter around CHOLMOD (through cvxopt) for sparse Cholesky.

The symbolic analysis of each sparsity pattern is kept and reused; a matrix that is not positive definite raises
:class:`NotPositiveDefinite` instead of returning a wrong factor.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from cvxopt import cholmod, matrix, spmatrix

cholmod.options["supernodal"] = 2  # supernodal LLᵀ: fastest here for our sizes
cholmod.options["print"] = 0


# The index structure of each recently analysed pattern, shared by all SparseCholesky objects: a solver
# keeps a second factor of a pattern (the eigen-solves' shift search alternates two), and building an
# spmatrix from triplets (a sort) took twice as long as CHOLMOD's analysis; a copy of one is a memcpy.
_TEMPLATES: dict = {}  # pattern key -> (entries read or None, spmatrix of that structure)
_MAX_TEMPLATES = 8


class NotPositiveDefinite(ArithmeticError):
    """The matrix handed to :meth:`SparseCholesky.factorize` is not positive definite."""


class SparseCholesky:
    """Factorize symmetric positive-definite sparse matrices, keeping the symbolic analysis of each pattern.

    A solver alternates between a few patterns (a Hessian, the same with a
    dense block added for a constraint, a shifted one): each keeps its own
    symbolic analysis (up to ``MAX_PATTERNS``, the least recently used one is
    dropped), so switching back costs a numeric factorization only.
    """

    MAX_PATTERNS = 4

    def __init__(self):
        self._patterns = {}  # key -> [spmatrix holding the values, symbolic (factored in place), entries read or None]
        self._seen = []  # (indptr, indices, key) of recent matrices: the same arrays need no hashing
        self._numeric = None
        self.n = 0

    def _key(self, L):
        for indptr, indices, key in self._seen:
            if L.indptr is indptr and L.indices is indices:
                return key  # the very pattern arrays of a recent call (a linkage's Hessians share them)
        key = (L.shape, len(L.indices), hash(L.indptr.tobytes()), hash(L.indices.tobytes()))
        # a solver alternates a few patterns (plain, augmented, shifted): remember each one's arrays
        self._seen = [(L.indptr, L.indices, key)] + self._seen[: 2 * self.MAX_PATTERNS - 1]
        return key

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
        key = self._key(L)
        entry = self._patterns.pop(key, None)
        if entry is None:
            template = _TEMPLATES.get(key)
            if template is not None:
                take, Am = template[0], +template[1]  # a copy of the structure; the values are set below
                data = L.data if take is None else L.data[take]
                Am.V = matrix(data if data.dtype == np.float64 else data.astype(float))
            else:
                # The spmatrix holds Aᵀ (CSR arrays read as CSC) and only the entries CHOLMOD reads: its upper
                # triangle, the lower one of A (CHOLMOD copies that triangle out on every factorization, so
                # the same values in the same order: the same factor as from the whole matrix, in half the copying).
                cols = np.repeat(np.arange(L.shape[1], dtype=np.int64), np.diff(L.indptr))
                lower = np.flatnonzero(L.indices <= cols)
                take = None if len(lower) == len(cols) else lower
                rows = L.indices.astype(np.int64)
                data = L.data.astype(float)
                if take is not None:
                    rows, cols, data = rows[take], cols[take], data[take]
                Am = spmatrix(matrix(data), matrix(rows), matrix(cols), L.shape)
                try:  # the oldest goes (threads may share the table: a lost race only costs a rebuild)
                    while len(_TEMPLATES) >= _MAX_TEMPLATES:
                        _TEMPLATES.pop(next(iter(_TEMPLATES)), None)
                except (StopIteration, RuntimeError):
                    pass
                _TEMPLATES[key] = (take, +Am)
            entry = [Am, cholmod.symbolic(Am, uplo="U"), take]
            if len(self._patterns) >= self.MAX_PATTERNS:
                self._patterns.pop(next(iter(self._patterns)))
        else:
            data = L.data if entry[2] is None else L.data[entry[2]]
            entry[0].V = matrix(data if data.dtype == np.float64 else data.astype(float))
        self._patterns[key] = entry  # most recently used last
        self.n = L.shape[0]
        self._numeric = None
        try:
            cholmod.numeric(entry[0], entry[1])  # cvxopt factors in place on the symbolic object
        except ArithmeticError as exc:
            raise NotPositiveDefinite(str(exc)) from None
        self._numeric = entry[1]

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve ``A x = b`` for ``b`` of shape (n,) or (n, k)."""
        if self._numeric is None:
            raise RuntimeError("no successful factorization to solve with")
        B = np.asarray(b, dtype=float)
        one = B.ndim == 1
        # cvxopt copies B (any strides) into a column-major matrix that the solve overwrites; the
        # solution is then read in place through the buffer protocol (np.array copied it element by
        # element: 46 ms for 8,000 × 340, a dense state Jacobian of the design optimization)
        M = matrix(B if one else B.reshape(self.n, -1))
        cholmod.solve(self._numeric, M)
        out = np.asarray(M)
        return out[:, 0] if one else out
