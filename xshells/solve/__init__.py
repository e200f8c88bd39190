"""Solvers: sparse Cholesky adapter and the Newton energy minimizer (paper §4)."""
from .cholesky import NotPositiveDefinite, SparseCholesky
from .newton import NewtonOptions, NewtonReport, minimize, smallest_eigenvalues

__all__ = ["SparseCholesky", "NotPositiveDefinite", "NewtonOptions", "NewtonReport", "minimize", "smallest_eigenvalues"]
