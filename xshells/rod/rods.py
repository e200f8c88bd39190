"""A set of discrete elastic rods: state, frames, energy and derivatives.

:class:`ElasticRods` stores any number of independent rods flat, so that a
single rod and the hundreds of rod segments of a linkage share one code
path. The variables of the set are

``[x_0, y_0, z_0, x_1, ..., z_{V-1}, θ_0, ..., θ_{E-1}]``

(all vertex positions, then one material angle per edge). Rest lengths, one
per edge, are the design parameters; every derivative is available with
respect to them too (``with_rest_lengths=True`` appends them after the
variables).

Units follow the input: with millimetres and MPa, stiffnesses are in N·mm²
(bending, twisting) and N (stretching), energies in N·mm.
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..errors import InputError, InvalidState
from ..sparse import BlockAssembler, VectorAssembler
from . import frames, stencils

# The fast analytic kernels; tests set this to None to compare with autodiff.
from . import analytic as _analytic


@dataclass(frozen=True)
class EnergyParts:
    stretch: float
    bend: float
    twist: float

    @property
    def total(self) -> float:
        return self.stretch + self.bend + self.twist

    def as_dict(self) -> dict:
        return {"stretch": self.stretch, "bend": self.bend, "twist": self.twist, "total": self.total}


def _real(name: str, value) -> np.ndarray:
    """``value`` as a float array, or one :class:`InputError` naming ``name``.

    ``np.asarray(value, dtype=float)`` alone drops imaginary parts with only a
    warning, turns ``None`` into NaN, and answers text, ragged lists and huge
    Python ints with NumPy's own messages that name no input.
    """
    try:
        arr = np.asarray(value)
    except ValueError:  # NumPy refuses ragged nesting outright
        raise InputError(f"{name}: expected a rectangular array of real numbers, got rows of different lengths") from None
    except (TypeError, OverflowError) as exc:  # an object NumPy cannot take as an array at all
        raise InputError(f"{name}: expected real numbers ({exc})") from None
    kind = arr.dtype.kind
    if kind == "f" and arr.dtype == np.float64:
        return arr  # the common case: no copy (set_vars runs at every trial state)
    if kind in "biuf":
        return arr.astype(float)
    if kind == "c":
        raise InputError(f"{name}: expected real numbers, got complex values ({arr.dtype})")
    if kind == "O":  # Python objects: None, ints beyond int64, Fractions, or nested lists of different lengths
        for v in arr.flat:
            if isinstance(v, bool) or not isinstance(v, numbers.Real):
                if isinstance(v, (list, tuple, np.ndarray)):
                    raise InputError(f"{name}: expected a rectangular array of real numbers, got rows of different lengths")
                raise InputError(f"{name}: expected real numbers, got {type(v).__name__} {v!r:.40}")
        try:
            return arr.astype(float)
        except OverflowError:
            raise InputError(f"{name}: a value is too large for a float") from None
    raise InputError(f"{name}: expected real numbers, got {'text' if kind in 'US' else arr.dtype}")


# Parallel transport from tangent a to tangent b divides by 1 + a·b; within about 0.008° of b = -a
# (1 + a·b <= 1e-8) its round-off grows past the square root of the machine epsilon and, worse, the
# carried frame swings through a full turn for a tiny change of b: refused there, accepted elsewhere.
_ANTIPARALLEL = 1e-8
# Coordinates past this would overflow squared lengths (3 (2·1e150)² ≈ 1e301 < 1.8e308) in the checks and kernels.
_MAX_COORDINATE = 1e150


def stretch_kernel(q: np.ndarray, ks: np.ndarray, hessian: bool = True, gradient: bool = True):
    """Stretching energy, gradient and Hessian of edge stencils (``gradient=False``: the energy alone, the same values).

    Parameters
    ----------
    q : (7, N) array
        ``x0 (0:3), x1 (3:6)``, rest length ``L`` (6).
    ks : (N,) array

    Returns
    -------
    energy : (N,), gradient : (7, N), hessian : (7, 7, N)
    """
    e = q[3:6] - q[0:3]
    n = np.sqrt(np.einsum("in,in->n", e, e))
    L = q[6]
    t = e / n
    strain = n / L - 1.0
    energy = 0.5 * ks * L * strain**2
    if not gradient:
        return energy, None, None
    grad = np.empty((7, q.shape[1]))
    ge = ks * strain * t
    grad[0:3], grad[3:6] = -ge, ge
    grad[6] = 0.5 * ks * (1.0 - (n / L) ** 2)
    if not hessian:
        return energy, grad, None
    a = ks / L
    b = ks * (1.0 / L - 1.0 / n)
    hee = (a - b) * t[:, None, :] * t[None, :, :] + b * np.eye(3)[:, :, None]
    hess = np.empty((7, 7, q.shape[1]))
    hess[0:3, 0:3], hess[3:6, 3:6] = hee, hee
    hess[0:3, 3:6], hess[3:6, 0:3] = -hee, -hee
    heL = -ks * n / L**2 * t
    hess[3:6, 6], hess[6, 3:6] = heL, heL
    hess[0:3, 6], hess[6, 0:3] = -heL, -heL
    hess[6, 6] = ks * n**2 / L**3
    return energy, grad, hess


class ElasticRods:
    """Independent discrete elastic rods with shared storage.

    Parameters
    ----------
    rods : sequence of (n_r + 1, 3) arrays
        The centerline points of each rod (its current, deformed state):
        real, finite numbers; no edge of zero length, no 180° fold back.
    stretching : float or (E,) array
        Stretching stiffness ``EA`` per edge (E = total edges of all rods,
        in rod order).
    bending : (2,) or (E, 2) array
        Bending stiffnesses ``(B1, B2)`` per edge: ``B1`` resists curvature
        ``κ1 = κb·m2`` (bending about ``m2``, which moves the centreline
        along ``m1``), so ``B1 = E∫x² dA`` with ``x`` the cross-section
        coordinate along ``m1``; ``B2 = E∫y² dA`` resists ``κ2 = −κb·m1``.
        Either may be the larger.
    twisting : float or (E,) array
        Twisting stiffness ``GJ`` per edge; a vertex uses the mean of its two edges.
    density, area : float or (E,) array
        Mass density and cross-section area (for the mass matrix and gravity).
    polar_moment : float or (E,) array, optional
        ``∫ r² dA`` of the cross-section, the rotational inertia of ``θ``;
        defaults to that of a disc of the given area.
    rest_lengths : float or (E,) array, optional
        Defaults to the edge lengths of the rest shape.
    rest_shape : sequence of (n_r + 1, 3) arrays, optional
        A curved rest configuration. Its curvature and twist (with
        ``rest_thetas`` and the directors) become the rest curvature and
        twist. Default: each rod straight, so only lengths come from ``rods``.
        The current frames are the rest frames carried to the current edges
        by parallel transport, edge by edge (each from its rest edge to its
        current edge). A rest shape moved rigidly is therefore *not* an
        unstrained rod with equal ``thetas``: the transport of each edge
        turns its frame about a different axis, so the current reference
        frames differ from the moved rest frames and the rod starts bent
        and twisted in its material frame. To start unstrained elsewhere,
        build the rod in its rest shape (``rods`` = ``rest_shape``) and move
        it (:meth:`set_vars`, a solver). A current edge pointing (within
        about 0.01°) opposite its rest edge is refused: transport is
        undefined there.
    rest_thetas : float or (E,) array, optional
        Material angles of the rest shape (default zero). Without
        ``rest_shape`` they apply to the straight default rest shape: a rest
        twist ``θ̄_{i+1} − θ̄_i`` at each interior vertex and no rest
        curvature, as a straight ``rest_shape`` with these angles gives.
    directors : sequence of (3,) arrays, optional
        Director ``d1`` of each rod's first edge *in the rest shape* (the
        current points when there is no ``rest_shape``): finite, nonzero and
        not along that edge (only its part normal to the edge is used). The
        other rest edges' directors follow by parallel transport along the
        rod, so the rest shape's reference twist is zero; the current frames
        follow from the rest frames as described under ``rest_shape`` (so with
        a ``rest_shape`` the current reference twist is in general not zero).
        Default: a deterministic perpendicular.
    thetas : float or (E,) array, optional
        Initial material angles (default zero).
    bending_energy : {"2008", "2010"}
        "2008" averages the curvature energies computed in each incident
        edge's material frame (the paper's choice); "2010" uses the
        vertex-averaged frame.
    """

    def __init__(
        self,
        rods: Sequence[np.ndarray],
        *,
        stretching,
        bending,
        twisting,
        density=1.0,
        area=1.0,
        polar_moment=None,
        rest_lengths=None,
        rest_shape: Sequence[np.ndarray] | None = None,
        rest_thetas=None,
        directors: Sequence[np.ndarray] | None = None,
        thetas=None,
        bending_energy: str = "2008",
    ):
        if bending_energy not in stencils.BENDING_VARIANTS:
            raise InputError(f"bending_energy must be one of {stencils.BENDING_VARIANTS}, got {bending_energy!r}")
        self.bending_energy = bending_energy
        pts = [_real(f"rod {r} points", p) for r, p in enumerate(rods)]
        if not pts:
            raise InputError("no rods given")
        for r, p in enumerate(pts):
            if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2:
                raise InputError(f"rod {r}: points must have shape (n+1, 3) with n >= 1, got {p.shape}")
        nv = np.array([len(p) for p in pts])
        self.vertex_offsets = np.concatenate([[0], np.cumsum(nv)])
        self.edge_offsets = np.concatenate([[0], np.cumsum(nv - 1)])
        V, E = int(self.vertex_offsets[-1]), int(self.edge_offsets[-1])
        self.num_vertices, self.num_edges = V, E
        self.num_rods = len(pts)

        starts = np.concatenate([np.arange(a, b - 1) for a, b in zip(self.vertex_offsets[:-1], self.vertex_offsets[1:])])
        self.edges = np.stack([starts, starts + 1], axis=1)
        # interior vertices: the second edge of the stencil is the edge starting at the vertex
        inner_edges = np.concatenate([np.arange(a + 1, b) for a, b in zip(self.edge_offsets[:-1], self.edge_offsets[1:])])
        self.stencil_edges = np.stack([inner_edges - 1, inner_edges], axis=1)
        self.stencil_vertices = np.stack(
            [self.edges[inner_edges - 1, 0], self.edges[inner_edges, 0], self.edges[inner_edges, 1]], axis=1
        )
        self.num_stencils = len(inner_edges)
        # which pairs of consecutive edges (j, j + 1) meet at a vertex of one rod (set_vars' fold check)
        self._pair_is_stencil = np.zeros(max(E - 1, 0), dtype=bool)
        self._pair_is_stencil[inner_edges - 1] = True

        points = np.concatenate(pts)
        self._check_points(points, "rod points")
        self.points = points
        self.thetas = np.zeros(E) if thetas is None else self._edge_array("thetas", thetas)

        self.ks = self._per_edge("stretching stiffness", stretching)
        self.bending_stiffness = self._per_edge("bending stiffness", bending, 2)
        self.kt_edge = self._per_edge("twisting stiffness", twisting)
        self.density = self._per_edge("density", density)
        self.area = self._per_edge("area", area)
        self.polar_moment = (
            self.area**2 / (2 * np.pi) if polar_moment is None else self._per_edge("polar moment", polar_moment)
        )

        if rest_shape is None:
            rest = pts
        else:
            rest = [_real(f"rest_shape of rod {r}", p) for r, p in enumerate(rest_shape)]
            if len(rest) != len(pts):
                raise InputError(f"rest_shape: expected {len(pts)} rods (as many as rods), got {len(rest)}")
            for r, (q, p) in enumerate(zip(rest, pts)):
                if q.shape != p.shape:
                    raise InputError(f"rest_shape of rod {r}: expected shape {p.shape} (as its points), got {q.shape}")
        rest_points = np.concatenate(rest)
        self._check_points(rest_points, "rest shape")
        t_rest, len_rest = frames.unit_tangents(rest_points, self.edges)
        self._check_folds(t_rest, "rest shape" if rest_shape is not None else "rod points")
        self.rest_lengths = len_rest if rest_lengths is None else self._per_edge("rest length", rest_lengths)

        # Directors: d1 of each rod's first rest edge, carried along the rod by parallel transport.
        first = frames.perpendicular(t_rest[self.edge_offsets[:-1]])
        if directors is not None:
            first = self._check_directors(directors, t_rest[self.edge_offsets[:-1]])
        d1_rest = frames.space_parallel_directors_of_rods(t_rest, self.edge_offsets, first)
        # Rest curvature and twist, measured with straight-rest defaults of zero.
        self.kappa_bar = np.zeros((self.num_stencils, 4))
        self.twist_bar = np.zeros(self.num_stencils)
        self.t_src, self.d1_src = t_rest, d1_rest
        self.ref_twist_src = np.zeros(self.num_stencils)
        rest_th = None if rest_thetas is None else self._edge_array("rest_thetas", rest_thetas)
        if rest_shape is not None and self.num_stencils:
            q = self._vertex_q(rest_points, np.zeros(E) if rest_th is None else rest_th, self.rest_lengths)
            kappa, twist, _ = stencils.vertex_strains(tuple(q), tuple(self._vertex_params()), bending_energy)
            self.kappa_bar = np.stack([np.asarray(k) for k in kappa], axis=1)
            self.twist_bar = np.asarray(twist)
        elif rest_th is not None and self.num_stencils:
            # The straight default rest shape with its directors carried along (zero reference twist):
            # no rest curvature in any frame, and a rest twist of the angles' differences, as a
            # straight rest_shape given with these rest_thetas measures it.
            self.twist_bar = rest_th[self.stencil_edges[:, 1]] - rest_th[self.stencil_edges[:, 0]]
        # The deformed state's source frame: transport the rest directors onto the current tangents.
        t_now, _ = frames.unit_tangents(self.points, self.edges)
        if rest_shape is not None:
            self._check_points_into(t_rest, t_now)
            self._check_folds(t_now, "rod points")
        self.t_src = t_now
        self.d1_src = frames.orthonormalize(frames.transport(t_rest, t_now, d1_rest), t_now)
        self.ref_twist_src = self._reference_twist()

        for arr in (self.ks, self.bending_stiffness, self.kt_edge, self.density, self.area, self.polar_moment):
            arr.flags.writeable = False  # stiffnesses are fixed at construction (cached stencil parameters)
        self._build_indices()

    # ------------------------------------------------------------------ input
    def _edge_name(self, j: int) -> str:
        """``edge k of rod r`` for global edge ``j``: messages number edges within their rod."""
        r = int(np.searchsorted(self.edge_offsets, j, side="right") - 1)
        return f"edge {j - self.edge_offsets[r]} of rod {r}"

    def _vertex_name(self, v: int) -> str:
        """``vertex k of rod r`` for global vertex ``v``."""
        r = int(np.searchsorted(self.vertex_offsets, v, side="right") - 1)
        return f"vertex {v - self.vertex_offsets[r]} of rod {r}"

    def _per_edge(self, name: str, value, columns: int | None = None) -> np.ndarray:
        """A positive, finite value per edge (a scalar, ``columns`` values, or one row per edge) as an array."""
        arr = _real(name, value)
        shape = (self.num_edges,) if columns is None else (self.num_edges, columns)
        try:
            arr = np.broadcast_to(arr, shape).copy()
        except ValueError:
            raise InputError(f"{name}: expected a scalar or an array of shape {shape}, got shape {arr.shape}") from None
        bad = np.flatnonzero(~(np.isfinite(arr) & (arr > 0)).reshape(self.num_edges, -1).all(axis=1))
        if len(bad):
            raise InputError(f"{name} must be positive and finite: {self._edge_name(bad[0])} has {arr[bad[0]]}")
        return arr

    def _check_points(self, points: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
        """Refuse non-finite, huge or coincident points; return the edge vectors and their squared lengths."""
        if not np.isfinite(points).all():
            bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
            raise InvalidState(f"{what}: {self._vertex_name(bad[0])} is not finite: {points[bad[0]]}")
        scale = float(np.abs(points).max(initial=0.0))
        if scale > _MAX_COORDINATE:
            bad = int(np.flatnonzero(np.abs(points).max(axis=1) > _MAX_COORDINATE)[0])
            raise InvalidState(
                f"{what}: {self._vertex_name(bad)} has a coordinate beyond {_MAX_COORDINATE:g} ({points[bad]}): "
                "its squared edge lengths would overflow; use other units or move the origin"
            )
        scale = max(scale, 1.0)
        d = points[self.edges[:, 1]] - points[self.edges[:, 0]]
        # squared lengths: this runs on every move of the state (a third of set_vars with norms)
        sq = np.einsum("ij,ij->i", d, d)
        bad = np.flatnonzero(sq <= (1e-14 * scale) ** 2)
        if len(bad):
            raise InvalidState(f"{what}: {self._edge_name(bad[0])} has zero length")
        return d, sq

    def _check_points_into(self, t_from: np.ndarray, t_to: np.ndarray) -> None:
        """Refuse carrying the rest frames onto current edges that point (nearly) opposite their rest edges."""
        bad = np.flatnonzero(1.0 + np.einsum("ij,ij->i", t_from, t_to) <= _ANTIPARALLEL)
        if len(bad):
            raise InputError(
                f"rod points: {self._edge_name(bad[0])} points (nearly) opposite its rest edge in rest_shape, so its "
                "frame cannot be carried over from the rest shape by parallel transport; build the rod in its rest "
                "shape and move it there, or give a rest shape turned to match"
            )

    def _check_folds(self, t: np.ndarray, what: str) -> None:
        """Refuse a rod that turns back on itself at a vertex: its curvature is infinite and its frame undefined."""
        if not self.num_stencils:
            return
        e0, e1 = self.stencil_edges[:, 0], self.stencil_edges[:, 1]
        bad = np.flatnonzero(1.0 + np.einsum("ij,ij->i", t[e0], t[e1]) <= _ANTIPARALLEL)
        if len(bad):
            v = int(self.stencil_vertices[bad[0], 1])
            raise InputError(f"{what}: the rod folds back at {self._vertex_name(v)} (its two edges point opposite ways)")

    def _check_directors(self, directors, t_first: np.ndarray) -> np.ndarray:
        """Each rod's first director as an (R, 3) array: finite, nonzero and not along its rod's first edge."""
        dirs = _real("directors", directors)
        if self.num_rods == 1 and dirs.size == 3:
            dirs = dirs.reshape(1, 3)  # one rod's director, however nested ((3,), or (1, 3) wrapped by ElasticRod)
        if dirs.shape != (self.num_rods, 3):
            raise InputError(
                f"directors: expected {self.num_rods} vector{'s' if self.num_rods != 1 else ''} (one per rod) of 3 components, got shape {dirs.shape}"
            )
        for r, d in enumerate(dirs):
            if not np.isfinite(d).all():
                raise InputError(f"directors: the director of rod {r} is not finite: {d}")
            norm = float(np.linalg.norm(d))
            if norm == 0.0:
                raise InputError(f"directors: the director of rod {r} is zero")
            # only its part normal to the first edge is used: nothing left (to round-off) gives no direction
            if np.linalg.norm(d - (d @ t_first[r]) * t_first[r]) <= _ANTIPARALLEL * norm:
                raise InputError(f"directors: the director of rod {r} {d} is along the rod's first edge; give one across it")
        return dirs

    def _edge_array(self, name: str, value) -> np.ndarray:
        """A finite value of any sign per edge (a scalar for all edges, or one per edge)."""
        arr = _real(name, value)
        if arr.ndim == 0:
            arr = np.full(self.num_edges, float(arr))
        if arr.shape != (self.num_edges,):
            raise InputError(f"{name}: expected shape ({self.num_edges},) (or a scalar for all edges), got {arr.shape}")
        if not np.isfinite(arr).all():
            j = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise InputError(f"{name}: {self._edge_name(j)} is not finite: {arr[j]}")
        return arr.copy()

    # ------------------------------------------------------------- variables
    @property
    def num_vars(self) -> int:
        """Number of variables: 3 per vertex plus one angle per edge."""
        return 3 * self.num_vertices + self.num_edges

    def get_vars(self) -> np.ndarray:
        return np.concatenate([self.points.ravel(), self.thetas])

    def set_vars(self, x: np.ndarray) -> None:
        """Set positions and angles; the source frame stays until :meth:`update_source_frame`.

        Raises
        ------
        InvalidState
            A coordinate or angle that is not finite, a coordinate too large, an edge of zero
            length, an edge turned (nearly) opposite its direction in the source frame (the
            frame cannot be carried over), or a rod folding back at a vertex (infinite
            curvature): a line search answers it by shortening its step.
        """
        x = _real("state", x)
        if x.shape != (self.num_vars,):
            raise InputError(f"expected {self.num_vars} variables, got shape {x.shape}")
        points = x[: 3 * self.num_vertices].reshape(-1, 3)
        thetas = x[3 * self.num_vertices :]
        d, sq = self._check_points(points, "state")
        if not np.isfinite(thetas).all():
            j = int(np.flatnonzero(~np.isfinite(thetas))[0])
            raise InvalidState(f"state: the material angle of {self._edge_name(j)} is not finite: {thetas[j]}")
        # Time-parallel transport from the source tangent is undefined for a reversed edge, and the curvature
        # of two edges pointing opposite ways is infinite (see _ANTIPARALLEL). Cosines times lengths: the
        # lengths are at most ~3.5e150 (_MAX_COORDINATE), so their products cannot overflow.
        n = np.sqrt(sq)
        c = np.einsum("ij,ij->i", d, self.t_src)
        flipped = c <= -(1.0 - _ANTIPARALLEL) * n
        if flipped.any():
            bad = np.flatnonzero(flipped)
            raise InvalidState(
                f"state: {self._edge_name(bad[0])} points (nearly) opposite its direction at the last source frame "
                "update, so its frame cannot be carried over; move it in smaller steps"
            )
        if self.num_stencils:
            # consecutive edges as views (no gathers); pairs across two rods are masked out
            folded = np.einsum("ij,ij->i", d[:-1], d[1:]) <= -(1.0 - _ANTIPARALLEL) * (n[:-1] * n[1:])
            folded &= self._pair_is_stencil
            if folded.any():
                j = int(np.flatnonzero(folded)[0])
                raise InvalidState(
                    f"state: the rod folds back at {self._vertex_name(int(self.edges[j, 1]))} (its two edges point "
                    "opposite ways: infinite curvature)"
                )
        self.points = points.copy()
        self.thetas = thetas.copy()

    def set_rest_lengths(self, lengths) -> None:
        """Set the rest length of each edge (a scalar for all edges, or one per edge; positive and finite)."""
        self.rest_lengths = self._per_edge("rest length", lengths)

    # ---------------------------------------------------------------- frames
    def reference_directors(self) -> np.ndarray:
        """Current reference director ``d1`` of each edge, (E, 3), by transport in time from the source."""
        t, _ = frames.unit_tangents(self.points, self.edges)
        return frames.transport(self.t_src, t, self.d1_src)

    def material_frames(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tangent, ``m1`` and ``m2`` of each edge, each (E, 3)."""
        t, _ = frames.unit_tangents(self.points, self.edges)
        d1 = frames.transport(self.t_src, t, self.d1_src)
        d2 = np.cross(t, d1)
        c, s = np.cos(self.thetas)[:, None], np.sin(self.thetas)[:, None]
        return t, c * d1 + s * d2, -s * d1 + c * d2

    def _reference_twist(self) -> np.ndarray:
        if not self.num_stencils:
            return np.zeros(0)
        t, _ = frames.unit_tangents(self.points, self.edges)
        d1 = frames.transport(self.t_src, t, self.d1_src)
        e0, e1 = self.stencil_edges[:, 0], self.stencil_edges[:, 1]
        tw = stencils.reference_twist(tuple(t[e0].T), tuple(d1[e0].T), tuple(t[e1].T), tuple(d1[e1].T), self.ref_twist_src)
        return np.asarray(tw)

    def reference_twist(self) -> np.ndarray:
        """Reference twist at each interior vertex (stencil order), (S,)."""
        return self._reference_twist()

    def update_source_frame(self) -> None:
        """Make the current reference frame the new source (call after each accepted step).

        Keeps time-parallel transport short, and makes the analytic Hessian exact.
        """
        t, _ = frames.unit_tangents(self.points, self.edges)
        d1 = frames.transport(self.t_src, t, self.d1_src)
        self.ref_twist_src = self._reference_twist()
        self.t_src, self.d1_src = t, frames.orthonormalize(d1, t)

    # --------------------------------------------------------------- stencils
    def _build_indices(self) -> None:
        V3, nv = 3 * self.num_vertices, self.num_vars
        sv, se = self.stencil_vertices, self.stencil_edges
        coords = np.arange(3)
        self.vertex_index = np.concatenate(
            [
                (3 * sv[:, 0][None, :] + coords[:, None]),
                (3 * sv[:, 1][None, :] + coords[:, None]),
                (3 * sv[:, 2][None, :] + coords[:, None]),
                V3 + se.T,
                nv + se.T,
            ]
        ).astype(np.int64)
        ev = self.edges
        self.edge_index = np.concatenate(
            [3 * ev[:, 0][None, :] + coords[:, None], 3 * ev[:, 1][None, :] + coords[:, None], nv + np.arange(self.num_edges)[None, :]]
        ).astype(np.int64)
        kt = self.kt_edge
        self.kt_vertex = 0.5 * (kt[se[:, 0]] + kt[se[:, 1]]) if self.num_stencils else np.zeros(0)
        self._assemblers: dict = {}

    def _vertex_q(self, points=None, thetas=None, rest_lengths=None) -> np.ndarray:
        points = self.points if points is None else points
        thetas = self.thetas if thetas is None else thetas
        rest_lengths = self.rest_lengths if rest_lengths is None else rest_lengths
        sv, se = self.stencil_vertices, self.stencil_edges
        q = np.empty((13, self.num_stencils))
        q[0:3], q[3:6], q[6:9] = points[sv[:, 0]].T, points[sv[:, 1]].T, points[sv[:, 2]].T
        q[9], q[10] = thetas[se[:, 0]], thetas[se[:, 1]]
        q[11], q[12] = rest_lengths[se[:, 0]], rest_lengths[se[:, 1]]
        return q

    def _vertex_params(self) -> np.ndarray:
        # Cached: it changes only with the source frame, which replaces these arrays.
        key = (self.t_src, self.d1_src, self.ref_twist_src, self.kappa_bar, self.twist_bar)
        old = getattr(self, "_params_key", None)
        if old is None or any(a is not b for a, b in zip(old, key)):
            self._params = self._build_vertex_params()
            self._params_key = key
        return self._params

    def _build_vertex_params(self) -> np.ndarray:
        se = self.stencil_edges
        p = np.empty((stencils.NUM_VERTEX_PARAMS, self.num_stencils))
        p[0:3], p[3:6] = self.t_src[se[:, 0]].T, self.d1_src[se[:, 0]].T
        p[6:9], p[9:12] = self.t_src[se[:, 1]].T, self.d1_src[se[:, 1]].T
        p[12:14], p[14:16] = self.bending_stiffness[se[:, 0]].T, self.bending_stiffness[se[:, 1]].T
        p[16] = getattr(self, "kt_vertex", 0.5 * (self.kt_edge[se[:, 0]] + self.kt_edge[se[:, 1]]))
        p[17:21] = self.kappa_bar.T
        p[21] = self.twist_bar
        p[22] = self.ref_twist_src
        return p

    def _edge_q(self) -> np.ndarray:
        q = np.empty((7, self.num_edges))
        q[0:3] = self.points[self.edges[:, 0]].T
        q[3:6] = self.points[self.edges[:, 1]].T
        q[6] = self.rest_lengths
        return q

    # --------------------------------------------------------------- energies
    def energy_parts(self) -> EnergyParts:
        stretch = float(np.sum(stretch_kernel(self._edge_q(), self.ks, hessian=False)[0])) if self.num_edges else 0.0
        if self.num_stencils:
            eb = self._vertex_energies()
            bend, twist = float(np.sum(eb[0])), float(np.sum(eb[1]))
        else:
            bend = twist = 0.0
        return EnergyParts(stretch, bend, twist)

    def energy(self) -> float:
        return self.energy_parts().total

    def _vertex_energies(self) -> np.ndarray:
        q, p = self._vertex_q(), self._vertex_params()
        if _analytic is not None:
            return _analytic.vertex_energies(q, p, self.bending_energy)
        from . import autodiff  # JAX, loaded only where the analytic kernels are switched off

        return autodiff.vertex_energies(q, p, self.bending_energy)

    def _size(self, with_rest_lengths: bool) -> int:
        return self.num_vars + (self.num_edges if with_rest_lengths else 0)

    def gradient(self, with_rest_lengths: bool = False) -> np.ndarray:
        """Gradient of the energy, (num_vars,) or (num_vars + E,) with rest lengths appended."""
        size = self._size(with_rest_lengths)
        key = ("grad", size)
        if key not in self._assemblers:
            self._assemblers[key] = VectorAssembler([self.vertex_index, self.edge_index], size)
        gv = self._vertex_gradient() if self.num_stencils else np.zeros((13, 0))
        _, ge, _ = stretch_kernel(self._edge_q(), self.ks, hessian=False)
        return self._assemblers[key].assemble([gv, ge])

    def _vertex_gradient(self) -> np.ndarray:
        q, p = self._vertex_q(), self._vertex_params()
        if _analytic is not None:
            return _analytic.vertex_gradient(q, p, self.bending_energy)
        from . import autodiff  # JAX, loaded only where the analytic kernels are switched off

        return autodiff.vertex_gradient(q, p, self.bending_energy)

    def _vertex_hessian(self) -> np.ndarray:
        q, p = self._vertex_q(), self._vertex_params()
        if _analytic is not None:
            return _analytic.vertex_hessian(q, p, self.bending_energy)
        from . import autodiff  # JAX, loaded only where the analytic kernels are switched off

        return autodiff.vertex_hessian(q, p, self.bending_energy)

    def hessian(self, with_rest_lengths: bool = False, triangle: str = "full") -> sp.csr_matrix:
        """Sparse Hessian of the energy.

        Parameters
        ----------
        with_rest_lengths : bool
            Include the rest lengths as variables (appended after the state).
        triangle : {"full", "lower"}
            ``"lower"`` returns only the lower triangle (for Cholesky).

        Exact at any state; fastest right after :meth:`update_source_frame`.
        """
        size = self._size(with_rest_lengths)
        key = ("hess", size, triangle)
        if key not in self._assemblers:
            self._assemblers[key] = BlockAssembler([self.vertex_index, self.edge_index], size, triangle)
        hv = self._vertex_hessian() if self.num_stencils else np.zeros((13, 13, 0))
        _, _, he = stretch_kernel(self._edge_q(), self.ks)
        return self._assemblers[key].assemble([hv, he])

    def hessian_pattern(self, with_rest_lengths: bool = False, triangle: str = "full") -> BlockAssembler:
        size = self._size(with_rest_lengths)
        key = ("hess", size, triangle)
        if key not in self._assemblers:
            self._assemblers[key] = BlockAssembler([self.vertex_index, self.edge_index], size, triangle)
        return self._assemblers[key]

    # ------------------------------------------------------------ mass, loads
    def vertex_masses(self, density=None) -> np.ndarray:
        """Lumped mass of each vertex: half of each incident edge's ``ρ A L̄``, (V,) (``density``: per edge, default the rods')."""
        rho = self.density if density is None else self._per_edge("density", density)
        m_edge = rho * self.area * self.rest_lengths
        return np.bincount(self.edges.ravel(), weights=np.repeat(0.5 * m_edge, 2), minlength=self.num_vertices)

    def mass_matrix(self, density=None) -> sp.dia_matrix:
        """Lumped (diagonal) mass matrix over the variables.

        Positions get their vertex mass; each angle gets its edge's
        rotational inertia ``ρ ∫r²dA L̄``. ``density`` (a scalar or one per edge, positive and
        finite) replaces the rods' own.
        """
        rho = self.density if density is None else self._per_edge("density", density)
        diag = np.concatenate([np.repeat(self.vertex_masses(rho), 3), rho * self.polar_moment * self.rest_lengths])
        return sp.diags(diag)

    def gravity_force(self, g=(0.0, 0.0, -9.81)) -> np.ndarray:
        """Generalized force of gravity on the variables, (num_vars,).

        ``g`` is in the input's units (for millimetres and seconds,
        ``(0, 0, -9810)``); with density in t/mm³ the force is in N. A ``g`` that is not three
        finite real numbers is refused with a ValueError.
        """
        g = _real("gravity g", g)
        if g.shape != (3,):
            raise InputError(f"gravity g: expected a vector of 3 components (x, y, z), got shape {g.shape}")
        if not np.isfinite(g).all():
            raise InputError(f"gravity g: not finite: {g}")
        f = np.zeros(self.num_vars)
        f[: 3 * self.num_vertices] = (self.vertex_masses()[:, None] * g[None, :]).ravel()
        return f

    # ------------------------------------------------------- visualization
    def strain_fields(self) -> dict:
        """Per-vertex strains of the centerline and its frame, each (V,), relative to the rest state.

        ``axial``: the mean stretch strain ``|e|/ℓ̄ − 1`` of the vertex's edges;
        ``kappa1``, ``kappa2``: bending curvature changes (per length) in the
        material frame, ``κ1 = κb·d2`` and ``κ2 = −κb·d1`` less their rest
        values, the stencil's integrated curvature over its Voronoi length
        (for the per-edge-frame bending energy, the mean of the two edges');
        ``twist``: twist rate change (per length). End vertices of a rod (no
        stencil) have zero bending and twist.
        """
        V = self.num_vertices
        n = np.linalg.norm(self.points[self.edges[:, 1]] - self.points[self.edges[:, 0]], axis=1)
        cnt = np.bincount(self.edges.ravel(), minlength=V)
        out = {"axial": np.bincount(self.edges.ravel(), weights=np.repeat(n / self.rest_lengths - 1.0, 2), minlength=V) / cnt}
        k1, k2, tw = np.zeros(V), np.zeros(V), np.zeros(V)
        if self.num_stencils:
            sv = self.stencil_vertices[:, 1]
            ell = 0.5 * (self.rest_lengths[self.stencil_edges[:, 0]] + self.rest_lengths[self.stencil_edges[:, 1]])
            kappa, twist, _ = stencils.vertex_strains(tuple(self._vertex_q()), tuple(self._vertex_params()), self.bending_energy)
            dk = np.stack([np.asarray(k) for k in kappa]) - self.kappa_bar.T
            if self.bending_energy == "2008":
                c1, c2 = 0.5 * (dk[0] + dk[2]), 0.5 * (dk[1] + dk[3])
            else:
                c1, c2 = dk[0], dk[1]
            k1[sv], k2[sv] = c1 / ell, c2 / ell
            tw[sv] = (np.asarray(twist) - self.twist_bar) / ell
        out.update(kappa1=k1, kappa2=k2, twist=tw)
        return out

    def stress_measures(self, young=None, shear=None, fibre=None) -> dict:
        """Per-vertex scalar fields for visualization, each (V,).

        Always: ``bending_energy_density``, ``twisting_energy_density`` and
        ``stretching_energy_density`` (energy per unit rest length; a vertex
        takes its stencil's bending and twisting and the mean of its edges'
        stretching). With ``young``, ``shear`` and ``fibre`` (extreme fibre
        distances ``(c1, c2)`` along ``m1`` and ``m2``, per edge or scalar):
        ``bending_stress`` (the largest normal stress, ``E (|Δκ1| c1 + |Δκ2| c2)/ℓ``
        averaged over the incident edges' frames), ``twisting_stress``
        (``G r |Δm| / ℓ`` with ``r = hypot(c1, c2)``) and
        ``stretching_stress`` (``E |strain|``). ``young``, ``shear`` and ``fibre`` must be
        positive and finite (a ValueError names the first edge that is not).
        """
        V = self.num_vertices
        out = {}
        sv = self.stencil_vertices[:, 1] if self.num_stencils else np.zeros(0, int)
        ell = 0.5 * (self.rest_lengths[self.stencil_edges[:, 0]] + self.rest_lengths[self.stencil_edges[:, 1]]) if self.num_stencils else np.zeros(0)
        eb = self._vertex_energies() if self.num_stencils else np.zeros((2, 0))
        out["bending_energy_density"] = np.bincount(sv, weights=eb[0] / ell, minlength=V)
        out["twisting_energy_density"] = np.bincount(sv, weights=eb[1] / ell, minlength=V)
        es = stretch_kernel(self._edge_q(), self.ks)[0] / self.rest_lengths
        cnt = np.bincount(self.edges.ravel(), minlength=V)
        out["stretching_energy_density"] = np.bincount(self.edges.ravel(), weights=np.repeat(es, 2), minlength=V) / cnt
        if young is not None and shear is not None and fibre is not None:
            E = self._per_edge("young", young)
            G = self._per_edge("shear", shear)
            c = self._per_edge("fibre", fibre, 2)
            n = np.linalg.norm(self.points[self.edges[:, 1]] - self.points[self.edges[:, 0]], axis=1)
            strain = np.abs(n / self.rest_lengths - 1.0)
            out["stretching_stress"] = np.bincount(self.edges.ravel(), weights=np.repeat(E * strain, 2), minlength=V) / cnt
            if self.num_stencils:
                kappa, twist, _ = stencils.vertex_strains(tuple(self._vertex_q()), tuple(self._vertex_params()), self.bending_energy)
                dk = np.stack([np.asarray(k) for k in kappa]) - self.kappa_bar.T
                e0, e1 = self.stencil_edges[:, 0], self.stencil_edges[:, 1]
                if self.bending_energy == "2008":
                    s0 = E[e0] * (np.abs(dk[0]) * c[e0, 0] + np.abs(dk[1]) * c[e0, 1])
                    s1 = E[e1] * (np.abs(dk[2]) * c[e1, 0] + np.abs(dk[3]) * c[e1, 1])
                    sb = 0.5 * (s0 + s1) / ell
                else:
                    cm = 0.5 * (c[e0] + c[e1])
                    sb = 0.5 * (E[e0] + E[e1]) * (np.abs(dk[0]) * cm[:, 0] + np.abs(dk[1]) * cm[:, 1]) / ell
                r = 0.5 * (np.hypot(c[e0, 0], c[e0, 1]) + np.hypot(c[e1, 0], c[e1, 1]))
                st = 0.5 * (G[e0] + G[e1]) * r * np.abs(np.asarray(twist) - self.twist_bar) / ell
            else:
                sb = st = np.zeros(0)
            out["bending_stress"] = np.bincount(sv, weights=sb, minlength=V)
            out["twisting_stress"] = np.bincount(sv, weights=st, minlength=V)
        return out


def rods_with_materials(rods: Sequence[np.ndarray], materials, **kwargs) -> ElasticRods:
    """:class:`ElasticRods` whose stiffnesses, area, density and rotational inertia come from
    :class:`xshells.section.Material` objects: one for all rods, one per rod, or one per edge."""
    from ..section import expand_materials

    edges_per_rod = [len(r) - 1 for r in rods]
    props = expand_materials(materials, edges_per_rod)
    mats = materials if isinstance(materials, (list, tuple)) else [materials]
    polar = [float(np.trace(np.asarray(m.second_moments))) for m in mats]
    if len(mats) == 1:
        polar_moment = polar[0]
    elif len(mats) == len(rods):
        polar_moment = np.repeat(polar, edges_per_rod)
    else:
        polar_moment = np.asarray(polar)
    return ElasticRods(
        rods,
        stretching=props["ks"],
        bending=np.stack([props["B1"], props["B2"]], axis=1),
        twisting=props["kt"],
        area=props["area"],
        density=props["density"],
        polar_moment=polar_moment,
        **kwargs,
    )


def ElasticRod(points: np.ndarray, **kwargs) -> ElasticRods:
    """A single discrete elastic rod: :class:`ElasticRods` with one rod.

    ``rest_shape`` and ``directors``, if given, are for this one rod.
    """
    if kwargs.get("rest_shape") is not None:
        kwargs["rest_shape"] = [kwargs["rest_shape"]]
    if kwargs.get("directors") is not None:
        kwargs["directors"] = [kwargs["directors"]]
    return ElasticRods([points], **kwargs)
