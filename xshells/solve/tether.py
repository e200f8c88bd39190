"""Springs on some variables: ``½ k Σ (x_r − t_r)²``, and a problem with them added.

Used to hold a state on a shape: the inverse design's hold on its target
(:mod:`xshells.inverse.guide`), a design's held deployed state
(:mod:`xshells.design.equilibrium`) and a deployment guided into one of
its equilibria (:mod:`xshells.deploy.guide`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp


@dataclass(frozen=True)
class Tether:
    """Springs ``½ k Σ (x_r − t_r)²`` pulling the variables ``rows`` toward ``targets``.

    Attributes
    ----------
    k : float
        Stiffness (force per length for position variables).
    rows : (r,) int
    targets : (r,) float
    """

    k: float
    rows: np.ndarray
    targets: np.ndarray

    def energy(self, x) -> float:
        d = x[self.rows] - self.targets
        return 0.5 * self.k * float(d @ d)

    def gradient(self, x) -> np.ndarray:
        g = np.zeros(len(x))
        g[self.rows] = self.k * (x[self.rows] - self.targets)
        return g

    def diagonal(self, n: int) -> sp.csr_matrix:
        """``k`` on the tethered rows of an (n, n) matrix."""
        return sp.csr_matrix((np.full(len(self.rows), self.k), (self.rows, self.rows)), shape=(n, n))


class Tethered:
    """A linkage plus a tether, as a Newton problem (the rest is the linkage's)."""

    def __init__(self, linkage, tether: Tether):
        self._L, self._t = linkage, tether

    def __getattr__(self, name):
        return getattr(self._L, name)

    def energy(self):
        return self._L.energy() + self._t.energy(self._L.get_vars())

    def gradient(self):
        return np.asarray(self._L.gradient(), float) + self._t.gradient(self._L.get_vars())

    def hessian(self):
        H = self._L.hessian()
        return (H + self._t.diagonal(H.shape[0])).tocsr()
