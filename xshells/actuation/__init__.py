"""Sparse actuation: where to put the motors (paper §6)."""
from .sparsify import SparsifyOptions, SparsifyResult, TorqueFit, sparsify

__all__ = ["SparsifyOptions", "SparsifyResult", "TorqueFit", "sparsify"]
