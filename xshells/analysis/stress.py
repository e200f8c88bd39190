"""Beam stresses at every rod vertex, for the true cross-section (docs/analysis.md).

At a rod vertex with axial strain ε, bending curvature changes κ₁, κ₂ (in
the principal material frame d₁, d₂) and twist rate change θ′:

* **normal stress**: a fibre at (x, y) of the section (x along d₁) strains by
  ``ε − κ₁ x − κ₂ y`` (the centerline bends toward the curvature vector
  ``κb × t``), so ``σ = E · max over the section's outline vertices of
  |ε − κ₁ x − κ₂ y|``: a linear function peaks at a vertex of the convex
  hull, so this is exact for any polygonal section (the extreme fibres about
  both principal axes at once);
* **shear stress** from torsion (Saint-Venant): ``τ = G |θ′| k_τ`` with
  ``k_τ = max |∇ψ + (−y, x)|`` from the section's warping function
  (:attr:`xshells.section.Material.shear_stress_factor`);
* **von Mises**: ``√(σ² + 3τ²)``. σ and τ are each the section's largest, which
  need not occur at the same point: the combination is an upper bound.

Units follow the input: MPa for millimetres and a modulus in MPa.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError


@dataclass(frozen=True)
class Stresses:
    """Per-rod-vertex stresses of a linkage state, each (V,).

    Attributes
    ----------
    normal, shear, von_mises : (V,) float
    utilization : (V,) float or None
        ``von_mises / strength`` where a strength is known.
    strength : float or None
    """

    normal: np.ndarray = field(repr=False)
    shear: np.ndarray = field(repr=False)
    von_mises: np.ndarray = field(repr=False)
    utilization: np.ndarray | None = field(repr=False, default=None)
    strength: float | None = None

    @property
    def max_von_mises(self) -> float:
        return float(self.von_mises.max()) if len(self.von_mises) else 0.0

    @property
    def max_utilization(self) -> float | None:
        return None if self.utilization is None else float(self.utilization.max())


def check_strength(strength, where: str = "strength") -> float | None:
    """A strength (allowable stress) as a positive float, or None; one-line error otherwise."""
    if strength is None:
        return None
    s = float(strength)
    if not (np.isfinite(s) and s > 0):
        raise InputError(f"{where} must be a positive stress (MPa for a design in mm), got {strength!r}")
    return s


def rod_stresses(linkage, strength: float | None = None) -> Stresses:
    """Stresses at every rod vertex of ``linkage`` in its current state (one material for all rods)."""
    if len({id(m) for m in linkage.materials}) > 1:
        raise InputError("stresses: the linkage has several materials; stresses assume one")
    return stresses_of(linkage.rods, linkage.materials[0], strength)


def stresses_of(rods, m, strength: float | None = None) -> Stresses:
    """Stresses at every vertex of ``rods`` (an :class:`~xshells.rod.rods.ElasticRods`) of material ``m``."""
    strength = check_strength(strength)
    s = rods.strain_fields()
    outline = np.concatenate(m.outline)  # (k, 2) in (d1, d2), about the centroid
    fibre = s["axial"][:, None] - s["kappa1"][:, None] * outline[None, :, 0] - s["kappa2"][:, None] * outline[None, :, 1]
    normal = m.E * np.abs(fibre).max(axis=1)
    shear = m.G * np.abs(s["twist"]) * m.shear_stress_factor
    vm = np.sqrt(normal**2 + 3.0 * shear**2)
    return Stresses(normal, shear, vm, None if strength is None else vm / strength, strength)


def beam_report(linkage, stresses: Stresses) -> list[dict]:
    """Per beam: the largest von Mises stress (and utilization), the rod vertex and the nearest joint."""
    g = linkage.graph
    rods = linkage.rods
    seg_of_vertex = np.repeat(np.arange(rods.num_rods), np.diff(rods.vertex_offsets))  # one rod per segment
    beam_of_vertex = np.asarray(g.beam_of_segment)[seg_of_vertex]
    P = linkage.joint_positions()
    rows = []
    for b in range(g.num_beams):
        idx = np.flatnonzero(beam_of_vertex == b)
        if not len(idx):
            continue
        k = idx[np.argmax(stresses.von_mises[idx])]
        where = rods.points[k]
        j = int(np.argmin(np.linalg.norm(P - where, axis=1)))
        rows.append({"beam": b, "max_von_mises": float(stresses.von_mises[k]),
                     "max_utilization": None if stresses.utilization is None else float(stresses.utilization[k]),
                     "rod_vertex": int(k), "segment": int(seg_of_vertex[k]), "nearest_joint": j,
                     "position": where.tolist()})
    return rows
