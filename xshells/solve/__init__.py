"""Solvers: sparse Cholesky adapter and the Newton energy minimizer (paper §4)."""
from .cholesky import NotPositiveDefinite, SparseCholesky
from .newton import NewtonOptions, NewtonReport, minimize

__all__ = ["SparseCholesky", "NotPositiveDefinite", "NewtonOptions", "NewtonReport", "minimize"]
