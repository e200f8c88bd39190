"""Sparse actuation: where to put the motors (paper §6)."""
from .selection import SelectionOptions, SelectionResult, select_actuators
from .sparsify import SparsifyOptions, SparsifyResult, TorqueFit, sparsify

__all__ = ["SelectionOptions", "SelectionResult", "SparsifyOptions", "SparsifyResult", "TorqueFit", "select_actuators",
           "sparsify"]
