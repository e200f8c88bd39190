"""Geometric properties of a cross-section: area, centroid, inertia, torsion constant.

Area, centroid and second moments are exact polygon integrals (Green's
theorem over each boundary edge), or closed forms for curved profiles.
The torsion constant comes from :mod:`.torsion`.

Two tensors appear and are easy to mix up:

* ``second_moments`` ``M = ∫ r rᵀ dA = [[∫x², ∫xy], [∫xy, ∫y²]]`` about the
  centroid. For a unit vector u, ``uᵀ M u = ∫ (u·r)² dA`` is the second
  moment of the fibres' distance along u; placing u along the rod's d1
  axis gives ``B1 = E uᵀ M u``.
* ``inertia`` ``I = ∫ [[y², -xy], [-xy, x²]] dA = tr(M)·Id - M`` (the paper's
  §3 tensor), which acts on rotation axes rather than on fibre offsets.

Both have the same eigenvectors; the eigenvalues swap.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from . import store
from .profiles import Profile

if TYPE_CHECKING:  # .torsion imports scikit-fem (0.07 s): only a solve loads it
    from .torsion import TorsionResult

#: relative change of J between refinement levels at which the torsion solve stops
DEFAULT_RTOL = 1e-5

# relative size of an off-diagonal term that still counts as "axes are principal"
PRINCIPAL_TOL = 1e-9


def polygon_moments(loops: list[np.ndarray]) -> tuple[float, float, float, float, float, float]:
    """Exact moments of a polygon with holes about the origin.

    Parameters
    ----------
    loops : list of ndarray, each shape (n_k, 2)
        Outer loop counter-clockwise, holes clockwise (as in :class:`Profile`).

    Returns
    -------
    (A, Sx, Sy, Ixx, Iyy, Ixy) : floats
        ``∫1, ∫x, ∫y, ∫x², ∫y², ∫xy`` over the region.
    """
    total = np.zeros(6)
    for loop in loops:
        x0, y0 = loop[:, 0], loop[:, 1]
        x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
        c = x0 * y1 - x1 * y0  # twice the signed area of (origin, p0, p1)
        total += [
            c.sum() / 2,
            ((x0 + x1) * c).sum() / 6,
            ((y0 + y1) * c).sum() / 6,
            ((x0 * x0 + x0 * x1 + x1 * x1) * c).sum() / 12,
            ((y0 * y0 + y0 * y1 + y1 * y1) * c).sum() / 12,
            ((x0 * y1 + 2 * x0 * y0 + 2 * x1 * y1 + x1 * y0) * c).sum() / 24,
        ]
    return tuple(float(v) for v in total)


def centroidal_moments(moments: tuple) -> tuple[float, np.ndarray, np.ndarray]:
    """Area, centroid (2,) and centroidal second moments M (2, 2) from origin moments."""
    A, Sx, Sy, Ixx, Iyy, Ixy = moments
    centroid = np.array([Sx / A, Sy / A])
    cx, cy = centroid
    M = np.array([[Ixx - A * cx * cx, Ixy - A * cx * cy],
                  [Ixy - A * cx * cy, Iyy - A * cy * cy]])
    return A, centroid, M


def principal_axes(second_moments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal second moments and directions of M (2, 2).

    Returns
    -------
    moments : ndarray, shape (2,)
        ``∫(u_k·r)² dA``, largest first.
    directions : ndarray, shape (2, 2)
        Row k is the unit vector u_k; rows form a right-handed frame, and
        u_0 points into the half-plane x ≥ 0 so that the frame is the
        smallest rotation of the profile axes.
    """
    values, vectors = np.linalg.eigh(second_moments)
    order = np.argsort(values)[::-1]
    values, vectors = values[order], vectors[:, order].T
    if vectors[0, 0] < 0 or (vectors[0, 0] == 0 and vectors[0, 1] < 0):
        vectors[0] *= -1
    if np.linalg.det(vectors) < 0:
        vectors[1] *= -1
    return values, vectors


def rotation(angle: float) -> np.ndarray:
    """Matrix R (2, 2) taking profile coordinates to frame coordinates when d1 is at ``angle`` from x."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, s], [-s, c]])


def frame_rotation(second_moments: np.ndarray, stiff_axis=None) -> np.ndarray:
    """Rotation R (2, 2) from centroidal profile coordinates to the rod's (d1, d2) coordinates.

    Parameters
    ----------
    second_moments : ndarray, shape (2, 2)
        Centroidal ``∫ r rᵀ dA``.
    stiff_axis : None, 'D1', 'D2' or float
        ``None`` keeps the profile's x along d1 when its axes are principal,
        else rotates by the smallest angle that makes them principal.
        ``'D1'`` puts the principal direction with the larger second moment
        along d1 (so B1 ≥ B2); ``'D2'`` puts it along d2 (B2 ≥ B1).
        A number is the angle (radians) of d1 from the profile's x axis, used as is.
    """
    if stiff_axis is not None and not isinstance(stiff_axis, str):
        return rotation(float(stiff_axis))
    scale = np.trace(second_moments)
    axes_principal = abs(second_moments[0, 1]) <= PRINCIPAL_TOL * scale
    if axes_principal:
        larger_on_x = second_moments[0, 0] >= second_moments[1, 1]
        isotropic = abs(second_moments[0, 0] - second_moments[1, 1]) <= PRINCIPAL_TOL * scale
        if stiff_axis is None or isotropic or larger_on_x == (stiff_axis == "D1"):
            return np.eye(2)
        return rotation(np.pi / 2)
    _, directions = principal_axes(second_moments)
    if stiff_axis is None:
        # the principal direction closest to x goes to d1
        # ties (e.g. an equal-leg L at 45°) go to the major axis, so B1 >= B2
        closest = 1 if abs(directions[1, 0]) > abs(directions[0, 0]) + PRINCIPAL_TOL else 0
        u = directions[closest] * np.sign(directions[closest, 0])
    else:
        u = directions[0] if stiff_axis == "D1" else np.array([directions[0, 1], -directions[0, 0]])
        u = u if u[0] >= 0 else -u
    return rotation(np.arctan2(u[1], u[0]))


@dataclass(frozen=True, eq=False)
class SectionProperties:
    """Geometry of one cross-section, independent of the material.

    Attributes
    ----------
    profile : Profile
    area : float
    centroid : ndarray, shape (2,)
        In the profile's coordinates.
    second_moments : ndarray, shape (2, 2)
        Centroidal ``∫ r rᵀ dA`` in the profile's axes.
    torsion : TorsionResult or StoredTorsion
        The converged warping solve (centroid-centred coordinates), or its
        results read from the disk cache (:mod:`.store`).
    """

    profile: Profile
    area: float
    centroid: np.ndarray
    second_moments: np.ndarray
    torsion: "TorsionResult | StoredTorsion"

    @property
    def inertia(self) -> np.ndarray:
        """The paper's tensor ``∫[[y², -xy], [-xy, x²]] dA`` about the centroid, shape (2, 2)."""
        M = self.second_moments
        return np.trace(M) * np.eye(2) - M

    @property
    def polar_moment(self) -> float:
        """``∫ |r|² dA`` about the centroid (J of a circle, an upper bound for any shape)."""
        return float(np.trace(self.second_moments))

    @property
    def torsion_constant(self) -> float:
        """Saint-Venant torsion constant J."""
        return self.torsion.torsion_constant

    def principal_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """See :func:`principal_axes`: moments (2,), directions (2, 2)."""
        return principal_axes(self.second_moments)


def profile_moments(profile: Profile) -> tuple:
    """(A, Sx, Sy, Ixx, Iyy, Ixy) about the origin, exact for the profile's shape."""
    if profile.exact_moments is not None:
        return profile.exact_moments
    return polygon_moments(profile.loops)


_CACHE: dict = {}
_CACHE_SIZE = 64


def analyse(profile: Profile, rtol: float = DEFAULT_RTOL) -> SectionProperties:
    """All geometric properties of ``profile``; repeated calls reuse the solve.

    Parameters
    ----------
    profile : Profile
    rtol : float
        Stop refining when J changes by less than this, relative.
    """
    key = (profile.cache_key(), rtol)
    if key not in _CACHE:
        area, centroid, M = centroidal_moments(profile_moments(profile))
        torsion = _torsion(profile, centroid, rtol)
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = SectionProperties(profile, area, centroid, M, torsion)
    return _CACHE[key]


@dataclass(frozen=True)
class StoredTorsion:
    """A torsion solve's results read from the disk cache (:mod:`.store`): J, its refinement history and
    whether it converged, as :class:`.torsion.TorsionResult` has them; the warping solution itself is
    solved again on first use (the section command's plots, the mesh sizes of its summary)."""

    torsion_constant: float
    history: list
    converged: bool
    profile: Profile = field(repr=False)
    centroid: np.ndarray = field(repr=False)
    rtol: float
    _solved: list = field(default_factory=list, repr=False, compare=False)

    @property
    def relative_change(self) -> float:
        return store.relative_change(self.history)

    @property
    def solution(self):
        if not self._solved:
            from .torsion import torsion_constant

            self._solved.append(torsion_constant(self.profile, self.centroid, rtol=self.rtol).solution)
        return self._solved[0]


def _torsion(profile: Profile, centroid: np.ndarray, rtol: float):
    """The torsion solve of ``profile`` about ``centroid``, from the disk cache where it holds it."""
    parts = (*profile.cache_key(), np.asarray(centroid, float).tobytes(), float(rtol))
    hit = store.load("torsion", parts)
    try:
        if hit is not None:
            J = float(hit["torsion_constant"])
            history = [(int(n), float(j)) for n, j in hit["history"]]
            if np.isfinite(J) and J > 0 and history and history[-1][1] == J:
                return StoredTorsion(J, history, bool(hit["converged"]), profile, np.asarray(centroid, float).copy(),
                                     float(rtol))
    except (KeyError, TypeError, ValueError):
        pass  # an entry of another shape or a damaged one: solve again, and overwrite it
    from .torsion import torsion_constant

    result = torsion_constant(profile, centroid, rtol=rtol)
    store.save("torsion", parts, {"torsion_constant": result.torsion_constant,
                                  "history": [[int(n), float(j)] for n, j in result.history],
                                  "converged": bool(result.converged)})
    return result


def outline_in_frame(profile: Profile, centroid: np.ndarray, R: np.ndarray) -> list[np.ndarray]:
    """Boundary loops in (d1, d2) coordinates: ``R (p - centroid)``; each shape (n, 2)."""
    return [(loop - centroid) @ R.T for loop in profile.loops]


def fibre_extents(outline: list[np.ndarray]) -> np.ndarray:
    """``[[min d1, max d1], [min d2, max d2]]`` over the outline, shape (2, 2)."""
    points = np.concatenate(outline)
    return np.column_stack((points.min(axis=0), points.max(axis=0)))
