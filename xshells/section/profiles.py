"""Beam cross-section shapes as polygons with holes.

A :class:`Profile` is the planar region swept along a beam: one outer
loop (counter-clockwise) and any number of holes (clockwise), in the
profile's own coordinates. The parametric types follow the cross-section
JSON files of ElasticRods (``{type, young, poisson, params}``); their
parameters are described in ``docs/sections.md``.

Every constructor validates its input and raises
:class:`xshells.errors.InputError` with one line naming what is wrong.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from ..errors import InputError

# A curve may replace the straight boundary edges by the exact shape: it maps
# points near the boundary, shape (n, 2), onto it. Used for the ellipse so that
# P2 elements see a curved boundary and keep their O(h^4) accuracy in J.
BoundaryProjector = Callable[[np.ndarray], np.ndarray]

ELLIPSE_OUTLINE_POINTS = 96


@dataclass(frozen=True, eq=False)
class Profile:
    """A cross-section region.

    Attributes
    ----------
    outer : ndarray, shape (n, 2)
        Outer boundary, counter-clockwise, not repeating the first point.
    holes : tuple of ndarray, each shape (m, 2)
        Hole boundaries, clockwise, each strictly inside ``outer``.
    kind : str
        Canonical type name (``rectangle``, ``ellipse``, ``I``, ``L``, ``+``,
        ``polygon``).
    params : tuple of float
        The parameters the profile was built from (empty for polygons).
    name : str
        Where it came from, for messages (a file name or the type).
    projector : callable or None
        Maps points, shape (n, 2), onto the exact curved boundary; ``None``
        when the polygon is the exact shape.
    exact_moments : tuple or None
        ``(area, Sx, Sy, Ixx, Iyy, Ixy)`` about the origin for curved shapes
        (with ``Ixx = ∫x²``, ``Iyy = ∫y²``, ``Ixy = ∫xy``); ``None`` to
        integrate the polygon exactly.
    """

    outer: np.ndarray
    holes: tuple = ()
    kind: str = "polygon"
    params: tuple = ()
    name: str = "polygon"
    projector: BoundaryProjector | None = field(default=None, repr=False)
    exact_moments: tuple | None = None

    @property
    def loops(self) -> list[np.ndarray]:
        """All boundary loops, outer first; each shape (n, 2)."""
        return [self.outer, *self.holes]

    def cache_key(self) -> tuple:
        """A hashable key identifying the geometry (for caching solves)."""
        return (self.kind, self.params,
                tuple(loop.tobytes() for loop in self.loops))


# --------------------------------------------------------------------------
# Geometry predicates
# --------------------------------------------------------------------------

def signed_area(loop: np.ndarray) -> float:
    """Shoelace area of a closed loop, shape (n, 2); positive if counter-clockwise."""
    x, y = loop[:, 0], loop[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def points_in_loop(points: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Even-odd test of points, shape (k, 2), against a loop, shape (n, 2); bool (k,)."""
    px, py = points[:, 0:1], points[:, 1:2]
    x0, y0 = loop[:, 0], loop[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    straddles = (y0 > py) != (y1 > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = x0 + (py - y0) * (x1 - x0) / (y1 - y0)
    return np.count_nonzero(straddles & (px < x_cross), axis=1) % 2 == 1


def _segments(loops: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Segments of all loops: starts (s, 2), ends (s, 2), loop id (s,), index in loop (s,)."""
    starts = np.concatenate(loops)
    ends = np.concatenate([np.roll(loop, -1, axis=0) for loop in loops])
    loop_id = np.concatenate([np.full(len(loop), k) for k, loop in enumerate(loops)])
    index = np.concatenate([np.arange(len(loop)) for loop in loops])
    return starts, ends, loop_id, index


def _orient(p, q, r):
    """Twice the signed area of triangles (p, q, r); arrays broadcast over leading axes."""
    return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])


def _on_segment(p, s0, s1, o, eps, tol):
    """Whether p lies on segment (s0, s1), given its orientation value o against it."""
    d = s1 - s0
    t = np.einsum("...k,...k->...", p - s0, d) / np.maximum(np.einsum("...k,...k->...", d, d), 1e-300)
    return (np.abs(o) <= eps) & (t >= -tol) & (t <= 1 + tol)


def first_crossing(loops: Sequence[np.ndarray], tol: float, block: int = 256) -> tuple[int, int, int, int] | None:
    """First pair of non-adjacent segments that touch or cross.

    Parameters
    ----------
    loops : sequence of ndarray, each shape (n_k, 2)
    tol : float
        Relative tolerance: closer than ``tol`` times the segment length counts as touching.
    block : int
        Rows compared at once; bounds memory to about ``block * n_segments`` floats.

    Returns
    -------
    (loop_a, seg_a, loop_b, seg_b) or None
    """
    a, b, loop_id, index = _segments(loops)
    sizes = np.array([len(loop) for loop in loops])
    length = np.linalg.norm(b - a, axis=1)
    aj, bj = a[None], b[None]
    for start in range(0, len(a), block):
        rows = slice(start, start + block)
        ai, bi = a[rows, None], b[rows, None]
        eps = tol * np.maximum(length[rows, None], length[None]) ** 2
        o1, o2 = _orient(ai, bi, aj), _orient(ai, bi, bj)
        o3, o4 = _orient(aj, bj, ai), _orient(aj, bj, bi)
        proper = (((o1 > eps) & (o2 < -eps)) | ((o1 < -eps) & (o2 > eps))) & \
                 (((o3 > eps) & (o4 < -eps)) | ((o3 < -eps) & (o4 > eps)))
        # touching: an end point of one segment lies on the other
        touching = (_on_segment(aj, ai, bi, o1, eps, tol) | _on_segment(bj, ai, bi, o2, eps, tol)
                    | _on_segment(ai, aj, bj, o3, eps, tol) | _on_segment(bi, aj, bj, o4, eps, tol))
        same = loop_id[rows, None] == loop_id[None]
        gap = np.abs(index[rows, None] - index[None])
        n = sizes[loop_id[rows]][:, None]
        adjacent = same & ((gap <= 1) | (gap == n - 1))
        later = np.arange(len(a))[None] > np.arange(start, min(start + block, len(a)))[:, None]
        pairs = np.argwhere((proper | touching) & ~adjacent & later)
        if len(pairs):
            i, j = pairs[0]
            i += start
            return int(loop_id[i]), int(index[i]), int(loop_id[j]), int(index[j])
    return None


# --------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------

def _as_loop(points, what: str) -> np.ndarray:
    """Points -> float array (n, 2) without a repeated closing point."""
    try:
        loop = np.array(points, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{what}: points must be numbers") from None
    if loop.ndim != 2 or loop.shape[1] not in (2, 3):
        raise InputError(f"{what}: expected a list of (x, y) points, got shape {loop.shape}")
    if not np.all(np.isfinite(loop)):
        raise InputError(f"{what}: points must be finite")
    if loop.shape[1] == 3:  # a contour drawn in a plane z = const (as OBJ writes it) loses only its z
        z = loop[:, 2]
        if np.ptp(z) > 1e-9 * max(1.0, float(np.abs(loop[:, :2]).max())):
            raise InputError(f"{what}: the points leave the section's plane (z from {z.min():g} to {z.max():g}): "
                             "a section is drawn in x, y")
    loop = loop[:, :2]
    if len(loop) > 1 and np.allclose(loop[0], loop[-1], rtol=0, atol=1e-12 * (1 + np.abs(loop).max())):
        loop = loop[:-1]
    # consecutive duplicates would make zero-length edges
    keep = np.any(np.abs(loop - np.roll(loop, 1, axis=0)) > 0, axis=1)
    loop = loop[keep] if keep.any() else loop[:1]
    if len(loop) < 3:
        raise InputError(f"{what}: a contour needs at least 3 distinct points, got {len(loop)}")
    return loop


def _is_flat(loop: np.ndarray, extent: float) -> bool:
    """Whether all points of ``loop`` (n, 2) lie on one line, to round-off relative to ``extent``."""
    centred = loop - loop.mean(axis=0)
    return bool(np.linalg.svd(centred, compute_uv=False)[-1] <= 1e-12 * extent * np.sqrt(len(loop)))


def polygon(outer, holes: Sequence = (), name: str = "polygon") -> Profile:
    """A profile from an outer contour and optional hole contours.

    Parameters
    ----------
    outer : array_like, shape (n, 2)
        Outer contour, either orientation; a repeated closing point is dropped.
    holes : sequence of array_like, each shape (m, 2)
        Hole contours, each strictly inside ``outer``.
    name : str
        Used in error messages.

    Returns
    -------
    Profile
    """
    outer = _as_loop(outer, f"{name}: outer contour")
    holes = [_as_loop(h, f"{name}: hole {k + 1}") for k, h in enumerate(holes)]
    loops = [outer, *holes]
    extent = float(np.ptp(np.concatenate(loops), axis=0).max())
    if extent == 0:
        raise InputError(f"{name}: the profile has zero area (all points coincide)")
    for k, loop in enumerate(loops):
        # a flat loop is "zero area"; a bow-tie also sums to zero but is caught as a crossing below
        if _is_flat(loop, extent):
            what = "outer contour" if k == 0 else f"hole {k}"
            raise InputError(f"{name}: {what} has zero area")
    check_extent(outer, name)
    crossing = first_crossing(loops, tol=1e-9)
    if crossing is not None:
        la, sa, lb, sb = crossing
        label = lambda l: "outer contour" if l == 0 else f"hole {l}"  # noqa: E731
        if la == lb:
            raise InputError(f"{name}: {label(la)} intersects itself (edges {sa + 1} and {sb + 1})")
        raise InputError(f"{name}: {label(la)} edge {sa + 1} crosses {label(lb)} edge {sb + 1}")
    for k, hole in enumerate(holes):
        if not points_in_loop(hole, outer).all():
            raise InputError(f"{name}: hole {k + 1} lies outside the outer boundary")
        for j, other in enumerate(holes):
            if j != k and points_in_loop(hole[:1], other)[0]:
                raise InputError(f"{name}: hole {k + 1} lies inside hole {j + 1}")
    if signed_area(outer) < 0:
        outer = outer[::-1]
    holes = tuple(h[::-1] if signed_area(h) > 0 else h for h in holes)
    return Profile(outer=outer, holes=holes, kind="polygon", name=name)


#: the range of a parametric profile's dimensions, in any units, and the largest ratio between them (the
#: bundled profiles reach 25; thin-walled steel about 200)
MIN_DIMENSION, MAX_DIMENSION, MAX_ASPECT = 1e-6, 1e6, 1e3


def _ratio_text(ratio: float) -> str:
    """``ratio`` with enough digits to differ from :data:`MAX_ASPECT` (1001, not 1e+03)."""
    for digits in range(4, 16):
        text = f"{ratio:.{digits}g}"
        if float(text) != MAX_ASPECT:
            return text
    return f"{ratio!r}"


def check_extent(loop: np.ndarray, name: str) -> None:
    """Refuse a contour whose width or height lies outside MIN_DIMENSION to MAX_DIMENSION.

    The same range as a parametric profile's dimensions: a contour file or point list at 1e7 was
    accepted where a rectangle 1e7 wide was refused.
    """
    width, height = np.ptp(loop, axis=0)
    for label, value in (("width", width), ("height", height)):
        if not MIN_DIMENSION <= value <= MAX_DIMENSION:
            raise InputError(f"{name}: the contour's {label} {value:g} is outside {MIN_DIMENSION:g} to "
                             f"{MAX_DIMENSION:g}: check the units")


def _check_params(kind: str, params, count: int, name: str) -> tuple:
    """Number and sign checks shared by the parametric types."""
    try:
        values = tuple(float(p) for p in params)
    except (TypeError, ValueError):
        raise InputError(f"{name}: {kind} parameters must be numbers, got {params!r}") from None
    if len(values) != count:
        raise InputError(f"{name}: {kind} takes {count} parameters ({PARAM_NAMES[kind]}), got {len(values)}")
    for label, value in zip(PARAM_NAMES[kind].split(", "), values):
        if not np.isfinite(value) or value <= 0:
            raise InputError(f"{name}: {kind} dimension {label} must be positive, got {value:g}")
        # moments go as size⁴: far outside this range they underflow or overflow (a division by zero,
        # a "singular" torsion solve), whatever the units (mm or m: 1 nm to 1000 km)
        if not MIN_DIMENSION <= value <= MAX_DIMENSION:
            raise InputError(f"{name}: {kind} dimension {label} = {value:g} is outside {MIN_DIMENSION:g} to "
                             f"{MAX_DIMENSION:g}: check the units")
    if max(values) > MAX_ASPECT * min(values):
        # the torsion mesh resolves the thinnest part over the whole profile: at 1e5 it ran out of memory
        raise InputError(f"{name}: {kind} dimensions span {_ratio_text(max(values) / min(values))}x "
                         f"(largest over smallest), more than {MAX_ASPECT:g}x: "
                         "the torsion mesh cannot resolve such a profile")
    return values


def _parametric(kind: str, params: tuple, outer: np.ndarray, name: str, **extra) -> Profile:
    return Profile(outer=np.asarray(outer, dtype=float), kind=kind, params=params, name=name, **extra)


def rectangle(width: float, height: float, name: str = "rectangle") -> Profile:
    """Axis-aligned rectangle centred at the origin; ``width`` along x."""
    w, h = _check_params("rectangle", (width, height), 2, name)
    outer = [(-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2), (-w / 2, h / 2)]
    return _parametric("rectangle", (w, h), outer, name)


def ellipse_points(a: float, b: float, n: int) -> np.ndarray:
    """``n`` points (n, 2) on the ellipse, uniform in the angle parameter, counter-clockwise.

    Uniform parameter spacing puts points closer together at the sharp ends
    of a slender ellipse, where the curvature is high.
    """
    t = 2 * np.pi * np.arange(n) / n
    return np.column_stack((a * np.cos(t), b * np.sin(t)))


def _ellipse_projector(a: float, b: float) -> BoundaryProjector:
    def project(points: np.ndarray) -> np.ndarray:
        t = np.arctan2(points[:, 1] / b, points[:, 0] / a)
        return np.column_stack((a * np.cos(t), b * np.sin(t)))
    return project


def ellipse(a: float, b: float, name: str = "ellipse") -> Profile:
    """Ellipse centred at the origin with semi-axis ``a`` along x and ``b`` along y.

    As in ElasticRods, the two parameters are the semi-axes (radii), not the
    full width and height.
    """
    a, b = _check_params("ellipse", (a, b), 2, name)
    area = np.pi * a * b
    moments = (area, 0.0, 0.0, area * a * a / 4, area * b * b / 4, 0.0)
    return _parametric("ellipse", (a, b), ellipse_points(a, b, ELLIPSE_OUTLINE_POINTS), name,
                       projector=_ellipse_projector(a, b), exact_moments=moments)


def i_beam(w1: float, w2: float, w3: float, h1: float, h2: float, h3: float, name: str = "I") -> Profile:
    """I-beam: flanges of thickness ``h1`` (bottom) and ``h3`` (top), web ``w2`` wide and ``h2`` tall.

    The flanges overhang the web by ``w1`` on the left and ``w3`` on the
    right, so the total width is ``w1 + w2 + w3``.
    """
    w1, w2, w3, h1, h2, h3 = _check_params("I", (w1, w2, w3, h1, h2, h3), 6, name)
    W, H = w1 + w2 + w3, h1 + h2 + h3
    outer = [(0, 0), (W, 0), (W, h1), (w1 + w2, h1), (w1 + w2, h1 + h2), (W, h1 + h2),
             (W, H), (0, H), (0, h1 + h2), (w1, h1 + h2), (w1, h1), (0, h1)]
    return _parametric("I", (w1, w2, w3, h1, h2, h3), outer, name)


def l_angle(a: float, b: float, t1: float, t2: float, name: str = "L") -> Profile:
    """L-angle: horizontal leg ``a`` long and ``t1`` thick, vertical leg ``b`` tall and ``t2`` thick."""
    a, b, t1, t2 = _check_params("L", (a, b, t1, t2), 4, name)
    if t1 >= b or t2 >= a:
        raise InputError(f"{name}: L leg thicknesses ({t1:g}, {t2:g}) must be less than the leg lengths ({b:g}, {a:g})")
    outer = [(0, 0), (a, 0), (a, t1), (t2, t1), (t2, b), (0, b)]
    return _parametric("L", (a, b, t1, t2), outer, name)


def plus(a: float, b: float, t1: float, t2: float, name: str = "+") -> Profile:
    """Plus (cross): horizontal bar ``a`` wide and ``t1`` thick, vertical bar ``b`` tall and ``t2`` thick."""
    a, b, t1, t2 = _check_params("+", (a, b, t1, t2), 4, name)
    if t1 >= b or t2 >= a:
        raise InputError(f"{name}: + bar thicknesses ({t1:g}, {t2:g}) must be less than the bar lengths ({b:g}, {a:g})")
    x, y, u, v = a / 2, b / 2, t2 / 2, t1 / 2
    outer = [(u, -v), (x, -v), (x, v), (u, v), (u, y), (-u, y),
             (-u, v), (-x, v), (-x, -v), (-u, -v), (-u, -y), (u, -y)]
    return _parametric("+", (a, b, t1, t2), outer, name)


PARAM_NAMES = {
    "rectangle": "width, height",
    "ellipse": "a, b",
    "I": "w1, w2, w3, h1, h2, h3",
    "L": "a, b, t1, t2",
    "+": "a, b, t1, t2",
}

_BUILDERS = {"rectangle": (rectangle, 2), "ellipse": (ellipse, 2), "I": (i_beam, 6),
             "L": (l_angle, 4), "+": (plus, 4)}

# names accepted for each type, compared case-insensitively
TYPE_ALIASES = {
    "rectangle": "rectangle", "rect": "rectangle",
    "ellipse": "ellipse",
    "i": "I", "ibeam": "I", "i-beam": "I",
    "l": "L",
    "+": "+", "plus": "+",
}


def canonical_type(kind: str, name: str = "profile") -> str:
    """Canonical type name for ``kind`` (case-insensitive); InputError if unknown."""
    key = str(kind).strip().lower()
    if key not in TYPE_ALIASES:
        known = ", ".join(sorted(set(TYPE_ALIASES.values()), key=str.lower))
        raise InputError(f"{name}: unknown cross-section type {kind!r} (known: {known})")
    return TYPE_ALIASES[key]


def make_profile(kind: str, params: Sequence[float], name: str | None = None) -> Profile:
    """Build a parametric profile from a type name and its parameter list.

    Parameters
    ----------
    kind : str
        ``Rectangle``, ``Ellipse``, ``I``, ``L`` or ``+`` (case-insensitive).
    params : sequence of float
        The type's parameters, in the order of :data:`PARAM_NAMES`.
    name : str, optional
        Used in error messages (defaults to the type).
    """
    canonical = canonical_type(kind, name or "profile")
    builder, count = _BUILDERS[canonical]
    values = _check_params(canonical, params, count, name or canonical)
    return builder(*values, name=name or canonical)
