"""Rod materials: a cross-section profile made of an isotropic elastic solid.

Frame convention (discrete elastic rods, Bergou et al. 2008). Each edge has
an orthonormal material frame (t, d1, d2). The cross-section coordinate x
runs along d1 and y along d2. The curvature binormal κb gives the material
curvatures ``κ1 = κb·d2`` and ``κ2 = -κb·d1`` and the bending energy density
``½ (B1 κ1² + B2 κ2²)``.

``κ1`` is a rotation of the cross-section about d2: the centreline bends
towards ±d1 and a fibre at (x, y) is stretched by ``-κ1 x``. Hence

    B1 = E ∫ x² dA     (bending in the t–d1 plane),
    B2 = E ∫ y² dA     (bending in the t–d2 plane).

For a rectangle ``[width, height]`` with the width along d1, B1 = E w³h/12
is the stiff, in-plane bending. The same convention is used by ElasticRods
(``setEllipse``: a along d1 gives B1 = E A a²/4).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..errors import InputError
from . import store
from .profiles import Profile, make_profile
from .properties import (SectionProperties, analyse, fibre_extents,
                         frame_rotation, outline_in_frame)

PER_EDGE_KEYS = ("ks", "B1", "B2", "kt", "area", "density")


def check_elastic_constants(E: float, nu: float, where: str = "material") -> tuple[float, float]:
    """Validate Young's modulus and Poisson's ratio; returns them as floats."""
    try:
        E, nu = float(E), float(nu)
    except (TypeError, ValueError):
        raise InputError(f"{where}: Young's modulus and Poisson's ratio must be numbers") from None
    if not np.isfinite(E) or E <= 0:
        raise InputError(f"{where}: Young's modulus must be positive, got {E:g}")
    if not (-1.0 < nu < 0.5):
        raise InputError(f"{where}: Poisson's ratio must lie in (-1, 0.5), got {nu:g}")
    return E, nu


def _check_stiff_axis(stiff_axis, where: str):
    if stiff_axis is None:
        return None
    if isinstance(stiff_axis, str):
        key = stiff_axis.strip().upper()
        if key not in ("D1", "D2"):
            raise InputError(f"{where}: stiff_axis must be 'D1', 'D2' or an angle in radians, got {stiff_axis!r}")
        return key
    try:
        angle = float(stiff_axis)
    except (TypeError, ValueError):
        raise InputError(f"{where}: stiff_axis must be 'D1', 'D2' or an angle in radians, got {stiff_axis!r}") from None
    if not np.isfinite(angle):
        raise InputError(f"{where}: stiff_axis angle must be finite")
    return angle


_SHEAR_FACTORS: dict = {}


@dataclass(frozen=True, eq=False)
class Material:
    """A homogeneous isotropic beam with a given cross-section.

    Parameters
    ----------
    profile : Profile
    E : float
        Young's modulus (> 0).
    nu : float
        Poisson's ratio, in (-1, 0.5).
    density : float
        Mass per unit volume, in the units of the model (default 1).
    stiff_axis : None, 'D1', 'D2' or float
        How the profile sits in the rod's (d1, d2) frame; see
        :func:`xshells.section.properties.frame_rotation`. ``None`` keeps
        the profile's own x axis along d1 when it is principal.
    rtol : float
        Relative J change at which mesh refinement stops.

    Notes
    -----
    The torsion solve runs once per distinct profile and is cached, so one
    Material shared by many rods costs one solve.
    """

    profile: Profile
    E: float
    nu: float
    density: float = 1.0
    stiff_axis: object = None
    rtol: float = 1e-5
    section: SectionProperties = field(init=False, repr=False)
    frame: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        where = self.profile.name
        E, nu = check_elastic_constants(self.E, self.nu, where)
        density = float(self.density)
        if not np.isfinite(density) or density <= 0:  # the rods' masses must be positive (their mass matrix)
            raise InputError(f"{where}: density must be positive, got {self.density!r}")
        axis = _check_stiff_axis(self.stiff_axis, where)
        section = analyse(self.profile, rtol=self.rtol)
        for name, value in (("E", E), ("nu", nu), ("density", density), ("stiff_axis", axis),
                            ("section", section), ("frame", frame_rotation(section.second_moments, axis))):
            object.__setattr__(self, name, value)

    # ---- constructors ----------------------------------------------------
    @classmethod
    def uniform(cls, kind: str, params: Sequence[float], E: float, nu: float, density: float = 1.0,
                stiff_axis=None) -> "Material":
        """One material from a parametric type, e.g. ``Material.uniform('rectangle', [10, 7], E=..., nu=...)``.

        Pass the result wherever one material serves the whole structure.
        """
        return cls(make_profile(kind, params), E, nu, density=density, stiff_axis=stiff_axis)

    @classmethod
    def from_file(cls, path, density: float = 1.0, stiff_axis=None, young=None, poisson=None) -> "Material":
        """Load a cross-section JSON (or contour file with ``young``/``poisson``); see :mod:`.io`."""
        from .io import load_section
        profile, E, nu = load_section(path, young=young, poisson=poisson)
        return cls(profile, E, nu, density=density, stiff_axis=stiff_axis)

    # ---- moduli ----------------------------------------------------------
    @property
    def G(self) -> float:
        """Shear modulus E / (2 (1 + ν))."""
        return self.E / (2.0 * (1.0 + self.nu))

    @property
    def area(self) -> float:
        return self.section.area

    @property
    def second_moments(self) -> np.ndarray:
        """``∫ r rᵀ dA`` in (d1, d2) coordinates, shape (2, 2)."""
        return self.frame @ self.section.second_moments @ self.frame.T

    @property
    def stretching_stiffness(self) -> float:
        """ks = E A."""
        return self.E * self.section.area

    @property
    def bending_stiffness(self) -> tuple[float, float]:
        """(B1, B2) = (E ∫x² dA, E ∫y² dA), x along d1, y along d2."""
        M = self.second_moments
        return float(self.E * M[0, 0]), float(self.E * M[1, 1])

    @property
    def bending_coupling(self) -> float:
        """E ∫xy dA in the frame: zero unless ``stiff_axis`` is an angle off the principal axes."""
        return float(self.E * self.second_moments[0, 1])

    @property
    def torsion_constant(self) -> float:
        return self.section.torsion_constant

    @property
    def twisting_stiffness(self) -> float:
        """kt = G J."""
        return self.G * self.section.torsion_constant

    @property
    def mass_per_length(self) -> float:
        return self.density * self.section.area

    # ---- geometry in the material frame ---------------------------------
    @property
    def outline(self) -> list[np.ndarray]:
        """Boundary loops in (d1, d2) coordinates about the centroid, outer first; each (n, 2)."""
        return outline_in_frame(self.profile, self.section.centroid, self.frame)

    @property
    def fibre_extents(self) -> np.ndarray:
        """``[[min x, max x], [min y, max y]]`` of the outline in (d1, d2) coordinates, shape (2, 2)."""
        return fibre_extents(self.outline)

    @property
    def shear_stress_factor(self) -> float:
        """``k_τ`` (a length): the largest Saint-Venant torsion shear stress is ``G θ′ k_τ`` at twist rate θ′.

        ``max |∇ψ + (−y, x)|`` over the section (on its boundary), from its
        own P2 warping solves refined to 0.1 % (cached per profile, and on disk: :mod:`.store`). At
        re-entrant corners the exact value is infinite; there the finest
        mesh's value is returned (see :func:`.torsion.shear_stress_factor`).
        """
        key = self.profile.cache_key()
        if key not in _SHEAR_FACTORS:
            parts = (*key, np.asarray(self.section.centroid, float).tobytes())
            hit = store.load("shear_stress_factor", parts)
            if hit is not None and isinstance(hit.get("value"), float) and np.isfinite(hit["value"]) and hit["value"] > 0:
                _SHEAR_FACTORS[key] = hit["value"]
            else:
                from .torsion import shear_stress_factor

                _SHEAR_FACTORS[key] = float(shear_stress_factor(self.profile, self.section.centroid)[0])
                store.save("shear_stress_factor", parts, {"value": _SHEAR_FACTORS[key]})
        return _SHEAR_FACTORS[key]

    @property
    def extreme_fibre_distances(self) -> np.ndarray:
        """Largest |x| and |y| over the section, shape (2,): the stress at the outermost
        fibre under bending curvature κ1 is ``E κ1 c[0]`` (``E κ2 c[1]`` for κ2)."""
        return np.abs(self.fibre_extents).max(axis=1)

    def per_edge(self, n_edges: int) -> dict[str, np.ndarray]:
        """This material's values repeated for ``n_edges`` edges; keys :data:`PER_EDGE_KEYS`, each (n_edges,)."""
        B1, B2 = self.bending_stiffness
        values = {"ks": self.stretching_stiffness, "B1": B1, "B2": B2, "kt": self.twisting_stiffness,
                  "area": self.area, "density": self.density}
        return {key: np.full(n_edges, values[key], dtype=float) for key in PER_EDGE_KEYS}

    def summary(self) -> dict:
        """JSON-ready dict of the properties printed by ``xshells section``."""
        moments, directions = self.section.principal_axes()
        B1, B2 = self.bending_stiffness
        return {
            "area": self.area,
            "centroid": self.section.centroid.tolist(),
            "inertia": self.section.inertia.tolist(),
            "second_moments": self.section.second_moments.tolist(),
            "principal_axes": {"directions": directions.tolist(), "second_moments": moments.tolist()},
            "frame_rotation": self.frame.tolist(),
            "stretching_stiffness": self.stretching_stiffness,
            "bending_stiffness": [B1, B2],
            "torsion_constant": self.torsion_constant,
            "twisting_stiffness": self.twisting_stiffness,
            "extreme_fibre_distances": self.extreme_fibre_distances.tolist(),
            "E": self.E,
            "nu": self.nu,
            "G": self.G,
            "density": self.density,
            "mass_per_length": self.mass_per_length,
            "mesh": {"triangles": self.section.torsion.solution.n_triangles,
                     "dofs": self.section.torsion.solution.n_dofs,
                     "levels": len(self.section.torsion.history),
                     "relative_change": self.section.torsion.relative_change},
        }


def _edge_counts(edges_per_rod) -> np.ndarray:
    counts = np.atleast_1d(np.asarray(edges_per_rod))
    if counts.ndim != 1 or not np.issubdtype(counts.dtype, np.integer) or np.any(counts < 1):
        raise InputError(f"edges_per_rod must be positive integers, got {edges_per_rod!r}")
    return counts


def expand_materials(materials, edges_per_rod) -> dict[str, np.ndarray]:
    """Per-edge stiffness arrays from one material, one per rod, or one per edge.

    Parameters
    ----------
    materials : Material or sequence of Material
        A single Material (uniform), one per rod (length n_rods), or one per
        edge (length n_edges, concatenated rod by rod).
    edges_per_rod : int or sequence of int
        Edge count of each rod (an int for a single rod).

    Returns
    -------
    dict
        Keys ``ks, B1, B2, kt, area, density``; each an array (n_edges,).
    """
    counts = _edge_counts(edges_per_rod)
    n_edges = int(counts.sum())
    if isinstance(materials, Material):
        return materials.per_edge(n_edges)
    materials = list(materials)
    if not all(isinstance(m, Material) for m in materials):
        raise InputError("materials must be Material objects")
    if len(materials) == len(counts):
        per_edge = [m for m, n in zip(materials, counts) for _ in range(int(n))]
    elif len(materials) == n_edges:
        per_edge = materials
    else:
        raise InputError(f"got {len(materials)} materials for {len(counts)} rods with {n_edges} edges; "
                         "give one, one per rod or one per edge")
    # distinct materials are few; evaluate each once
    rows = {id(m): m.per_edge(1) for m in per_edge}
    return {key: np.concatenate([rows[id(m)][key] for m in per_edge]) for key in PER_EDGE_KEYS}
