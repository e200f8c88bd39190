"""The editable flat layout of the app: immutable layouts, edits, warps, undo/redo and live topology checks.

Everything here is plain NumPy, so it is tested without a browser. A
:class:`Layout` never changes; every edit returns a new one and the
:class:`History` keeps them for undo/redo.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError

# Segments shorter than this fraction of the layout's span count as zero-length
# (the joint frame of a zero-length segment is undefined).
ZERO_LENGTH_RELATIVE = 1e-9


@dataclass(frozen=True, eq=False)
class Layout:
    """A flat beam network: joint positions in the plane and segments between them.

    Attributes
    ----------
    vertices : ndarray, shape (n, 2)
    edges : ndarray of int, shape (m, 2)
    """

    vertices: np.ndarray
    edges: np.ndarray

    def __post_init__(self):
        V = np.array(self.vertices, dtype=float).reshape(-1, 2)
        E = np.array(self.edges, dtype=np.int64).reshape(-1, 2)
        V.setflags(write=False)
        E.setflags(write=False)
        object.__setattr__(self, "vertices", V)
        object.__setattr__(self, "edges", E)

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_segments(self) -> int:
        return int(self.edges.shape[0])

    def span(self) -> float:
        """Largest extent of the layout (1 when empty or degenerate)."""
        if self.num_vertices == 0:
            return 1.0
        return float(np.ptp(self.vertices, axis=0).max()) or 1.0

    def segment_lengths(self) -> np.ndarray:
        V, E = self.vertices, self.edges
        return np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1) if len(E) else np.zeros(0)

    def same_as(self, other: "Layout") -> bool:
        return (self.vertices.shape == other.vertices.shape and self.edges.shape == other.edges.shape
                and np.array_equal(self.vertices, other.vertices) and np.array_equal(self.edges, other.edges))


def layout_from_design(design) -> Layout:
    """The flat layout of a :class:`xshells.io.design.Design` (its in-plane coordinates).

    A design drawn off the z = 0 plane is projected onto its best-fit plane.
    """
    from ..io.fabrication import flat_coordinates

    return Layout(flat_coordinates(design.vertices), design.edges)


def layout_to_design(layout: Layout, source: str | None = None):
    """A validated :class:`Design` (z = 0); raises InputError like the file readers."""
    from ..io.design import design_from_arrays

    return design_from_arrays(np.c_[layout.vertices, np.zeros(layout.num_vertices)], layout.edges, source)


# ----------------------------------------------------------------------------- edits
def move_joint(layout: Layout, v: int, xy) -> Layout:
    _check_vertex(layout, v)
    V = layout.vertices.copy()
    V[v] = np.asarray(xy, float)[:2]
    return Layout(V, layout.edges)


def add_joint(layout: Layout, xy, connect_to: int | None = None) -> Layout:
    """Append a vertex at ``xy``, optionally joined to vertex ``connect_to`` by a new segment."""
    V = np.vstack([layout.vertices, np.asarray(xy, float)[:2]])
    E = layout.edges
    if connect_to is not None:
        _check_vertex(layout, connect_to)
        E = np.vstack([E, [connect_to, len(V) - 1]])
    return Layout(V, E)


def delete_joint(layout: Layout, v: int) -> Layout:
    """Remove vertex ``v`` and its segments; later vertex indices shift down by one."""
    _check_vertex(layout, v)
    E = layout.edges[~np.any(layout.edges == v, axis=1)]
    E = np.where(E > v, E - 1, E)
    return Layout(np.delete(layout.vertices, v, axis=0), E)


def add_segment(layout: Layout, a: int, b: int) -> Layout:
    """Join vertices ``a`` and ``b``; self-loops are refused, duplicates are left for validation to flag."""
    _check_vertex(layout, a)
    _check_vertex(layout, b)
    if a == b:
        raise InputError(f"a segment needs two different joints, got {a} twice")
    return Layout(layout.vertices, np.vstack([layout.edges, [a, b]]))


def delete_segment(layout: Layout, s: int) -> Layout:
    if not 0 <= s < layout.num_segments:
        raise InputError(f"no segment {s} (the layout has {layout.num_segments})")
    return Layout(layout.vertices, np.delete(layout.edges, s, axis=0))


def remove_unused_vertices(layout: Layout) -> Layout:
    used = np.unique(layout.edges)
    new = np.full(layout.num_vertices, -1, dtype=np.int64)
    new[used] = np.arange(len(used))
    return Layout(layout.vertices[used], new[layout.edges])


def _check_vertex(layout: Layout, v: int) -> None:
    if not 0 <= int(v) < layout.num_vertices:
        raise InputError(f"no joint {v} (the layout has {layout.num_vertices})")


# ----------------------------------------------------------------------------- warps
def _frame(layout: Layout):
    """Centroid and half-spans along x and y (for dimensionless warps)."""
    V = layout.vertices
    c = 0.5 * (V.min(axis=0) + V.max(axis=0))
    h = np.maximum(0.5 * np.ptp(V, axis=0), 1e-12 * layout.span())
    return c, h


def warp_scale(layout: Layout, sx: float, sy: float | None = None) -> Layout:
    """Scale about the layout's centre (``sy`` defaults to ``sx``)."""
    sy = sx if sy is None else sy
    if not (np.isfinite(sx) and np.isfinite(sy) and sx > 0 and sy > 0):
        raise InputError(f"scale factors must be positive, got {sx}, {sy}")
    c, _ = _frame(layout)
    return Layout(c + (layout.vertices - c) * [sx, sy], layout.edges)


def warp_bend(layout: Layout, amount: float) -> Layout:
    """Bend the layout into an arc: ``y += amount·h_y·(x/h_x)²`` (``amount`` in half-heights)."""
    c, h = _frame(layout)
    u = (layout.vertices - c) / h
    V = layout.vertices.copy()
    V[:, 1] += float(amount) * h[1] * u[:, 0] ** 2
    return Layout(V, layout.edges)


def warp_pinch(layout: Layout, amount: float) -> Layout:
    """Pinch the waist: ``y ← y·(1 − amount·(1 − (x/h_x)²))`` (``amount`` < 1 keeps the order of joints)."""
    if not amount < 1:
        raise InputError(f"pinch amount must be below 1, got {amount}")
    c, h = _frame(layout)
    u = (layout.vertices - c) / h
    V = layout.vertices.copy()
    V[:, 1] = c[1] + (V[:, 1] - c[1]) * (1.0 - float(amount) * (1.0 - np.clip(u[:, 0], -1, 1) ** 2))
    return Layout(V, layout.edges)


# ----------------------------------------------------------------------------- direct manipulation
# The paper's tools (§7, Fig. 10): a brush, a cage, and symmetric editing. Each is a pure function of the
# layout (the History keeps the layouts, so undo restores them exactly).

@dataclass(frozen=True)
class Mirror:
    """A mirror line of the layout: ``axis`` "x" mirrors x about ``x = c`` (left–right), "y" mirrors y about ``y = c``."""

    axis: str
    c: float

    def __post_init__(self):
        if self.axis not in ("x", "y"):
            raise InputError(f"mirror axis must be 'x' or 'y', got {self.axis!r}")

    @classmethod
    def through_centre(cls, layout: Layout, axis: str) -> "Mirror":
        c, _ = _frame(layout)
        return cls(axis, float(c[0] if axis == "x" else c[1]))

    def point(self, xy) -> np.ndarray:
        q = np.array(xy, float, copy=True)
        k = 0 if self.axis == "x" else 1
        q[..., k] = 2 * self.c - q[..., k]
        return q

    def vector(self, d) -> np.ndarray:
        q = np.array(d, float, copy=True)
        q[..., 0 if self.axis == "x" else 1] *= -1
        return q


def mirror_partner(layout: Layout, v: int, mirror: Mirror, tolerance: float | None = None) -> int | None:
    """The joint at ``v``'s mirror image (within ``tolerance``, default 1 % of the span), or None."""
    _check_vertex(layout, v)
    tol = 0.01 * layout.span() if tolerance is None else float(tolerance)
    return nearest_vertex(layout, mirror.point(layout.vertices[v]), tol)


def move_joint_mirrored(layout: Layout, v: int, xy, mirror: Mirror) -> Layout:
    """Move joint ``v`` to ``xy`` and its mirror partner by the mirrored displacement (a joint on the line slides along it).

    The partner moves by the mirror image of ``v``'s displacement, as the
    brush does, not to the mirror image of ``xy``: a partner is matched within
    1 % of the span, and putting it on the exact image turned any asymmetry
    up to that into a jump (manta ray, joint 110 moved along x: its partner
    116 jumped by (−13.3, +10.0)).
    """
    partner = mirror_partner(layout, v, mirror)
    V = layout.vertices.copy()
    xy = np.asarray(xy, float)[:2]
    if partner is None:
        V[v] = xy
    elif partner == v:  # on the mirror line (within the match tolerance): it slides along the line only
        d = xy - V[v]
        V[v] = V[v] + 0.5 * (d + mirror.vector(d))
    else:
        V[partner] = V[partner] + mirror.vector(xy - V[v])
        V[v] = xy
    return Layout(V, layout.edges)


def brush_weights(layout: Layout, centre, radius: float) -> np.ndarray:
    """Smooth falloff ``(1 − (r/R)²)²`` of the joints within ``radius`` of ``centre`` (1 at the centre, C¹ to 0 at R), (n,)."""
    if not (np.isfinite(radius) and radius > 0):
        raise InputError(f"brush radius must be positive, got {radius}")
    r2 = np.sum((layout.vertices - np.asarray(centre, float)[:2]) ** 2, axis=1) / float(radius) ** 2
    return np.where(r2 < 1.0, (1.0 - r2) ** 2, 0.0)


def brush(layout: Layout, centre, radius: float, displacement, mirror: Mirror | None = None) -> Layout:
    """Move the joints within ``radius`` of ``centre`` by ``displacement`` times their falloff weight.

    With ``mirror``, the mirrored stroke (centre and displacement mirrored)
    is added, so a symmetric layout stays symmetric.
    """
    d = np.asarray(displacement, float)[:2]
    V = layout.vertices + brush_weights(layout, centre, radius)[:, None] * d
    if mirror is not None:
        V = V + brush_weights(layout, mirror.point(np.asarray(centre, float)[:2]), radius)[:, None] * mirror.vector(d)
    return Layout(V, layout.edges)


@dataclass(frozen=True)
class Cage:
    """A coarse lattice of ``shape = (nx, ny)`` handles over the layout's bounding box (with a margin).

    The deformation is a tensor-product Bézier map (free-form deformation):
    moving handle (i, j) by ``d`` moves each joint by ``B_i(u) B_j(v) d``,
    with ``(u, v)`` its place in the box and ``B`` the Bernstein
    polynomials, so the layout deforms smoothly and the cage at rest maps
    every joint to itself.
    """

    lo: tuple
    hi: tuple
    shape: tuple = (4, 4)

    @classmethod
    def around(cls, layout: Layout, shape=(4, 4), margin: float = 0.05) -> "Cage":
        nx, ny = (int(v) for v in shape)
        if nx < 2 or ny < 2:
            raise InputError(f"a cage needs at least 2 × 2 handles, got {nx} × {ny}")
        V = layout.vertices
        pad = margin * layout.span()
        return cls(tuple(V.min(axis=0) - pad), tuple(V.max(axis=0) + pad), (nx, ny))

    def handles(self) -> np.ndarray:
        """Rest positions of the handles, (nx, ny, 2)."""
        nx, ny = self.shape
        u, v = np.linspace(0, 1, nx), np.linspace(0, 1, ny)
        lo, hi = np.asarray(self.lo), np.asarray(self.hi)
        return lo + (hi - lo) * np.stack(np.meshgrid(u, v, indexing="ij"), axis=-1)

    def weights(self, xy) -> np.ndarray:
        """``B_i(u) B_j(v)`` of points (m, 2), shape (m, nx, ny)."""
        from math import comb

        lo, hi = np.asarray(self.lo), np.asarray(self.hi)
        uv = np.clip((np.asarray(xy, float) - lo) / (hi - lo), 0.0, 1.0)
        nx, ny = self.shape
        bern = lambda n, t: np.stack([comb(n - 1, k) * t ** k * (1 - t) ** (n - 1 - k) for k in range(n)], axis=-1)  # noqa: E731
        return bern(nx, uv[:, 0])[:, :, None] * bern(ny, uv[:, 1])[:, None, :]


def cage_move(layout: Layout, cage: Cage, i: int, j: int, displacement) -> Layout:
    """Move cage handle (i, j) by ``displacement``: every joint moves by its Bernstein weight of that handle."""
    nx, ny = cage.shape
    if not (0 <= i < nx and 0 <= j < ny):
        raise InputError(f"no cage handle ({i}, {j}) in a {nx} × {ny} cage")
    w = cage.weights(layout.vertices)[:, i, j]
    return Layout(layout.vertices + w[:, None] * np.asarray(displacement, float)[:2], layout.edges)


def snap(xy, step: float) -> np.ndarray:
    """``xy`` rounded to a grid of ``step`` (no snapping for ``step`` ≤ 0)."""
    xy = np.asarray(xy, float)
    return xy if not step or step <= 0 else np.round(xy / step) * step


# ----------------------------------------------------------------------------- validation
_last_analysis: list = []  # [(layout, graph)] of the last layout analysed: a session asks twice per edit


def analyzed(layout: Layout):
    """:func:`xshells.linkage.graph.analyze` of ``layout`` (the last one's is kept); raises InputError."""
    from ..linkage.graph import analyze

    last = list(_last_analysis)  # another thread may replace it meanwhile
    if last and last[0][0] is layout:
        return last[0][1]
    graph = analyze(layout_to_design(layout))
    _last_analysis[:] = [(layout, graph)]
    return graph


def beam_pairing(layout: Layout, graph) -> dict:
    """How the beams pass through each joint: vertex -> (its neighbours, the pairs of neighbours joined by one beam).

    ``graph`` is the layout's :func:`xshells.linkage.graph.analyze`. At a valence-4 joint the two pairs are the
    two beams crossing there (chosen by the analysis as the most nearly straight continuations), at a
    valence-3 joint one pair continues through and the third neighbour ends there, at a valence-2 joint
    both beams end. Neighbours are vertex indices, so the pairing survives renumbered segments.
    """
    E = layout.edges.tolist()
    neighbours: list[set] = [set() for _ in range(layout.num_vertices)]
    for a, b in E:
        neighbours[a].add(b)
        neighbours[b].add(a)
    out = {}
    for v, slots in zip(np.asarray(graph.joint_vertex).tolist(), np.asarray(graph.joint_segments).tolist()):
        pairs = frozenset(frozenset(E[sg][1] if E[sg][0] == v else E[sg][0] for sg in row if sg >= 0) for row in slots)
        out[v] = (frozenset(neighbours[v]), pairs)
    return out


def repairings(layout: Layout, graph, baseline: dict) -> list[str]:
    """Joints whose beams would pass through differently from ``baseline`` (a :func:`beam_pairing`), one line.

    The analysis pairs the segments at a joint by straightness, so a drag that kinks a beam far enough at
    a neighbouring joint makes other segments the straighter continuation there: the layout then holds
    other beams than the ones drawn, and would deploy as another linkage without a word (a joint of the
    uniform grid moved by half a segment re-paired two neighbours). Only joints whose neighbours are
    those of the baseline are compared: a segment added or removed there is a new joint.
    """
    now = beam_pairing(layout, graph)
    changed = [v for v, (nb, pairs) in now.items() if v in baseline and baseline[v][0] == nb and baseline[v][1] != pairs]
    if not changed:
        return []
    v = changed[0]

    def describe(pairs) -> str:
        return " and ".join("–".join(str(n) for n in sorted(p)) for p in sorted(pairs, key=lambda p: sorted(p)) if len(p) == 2)

    more = f" (and joint{'s' * (len(changed) > 2)} {', '.join(str(c) for c in changed[1:6])})" if len(changed) > 1 else ""
    return [f"joint {v}: its beams would re-pair{more}, the beams through it joining neighbours {describe(now[v][1])} "
            f"instead of {describe(baseline[v][1])}: a beam is bent so sharply there that another segment "
            f"continues it more straightly; undo, or move less far"]


def topology_problems(layout: Layout, allow_crossings: bool = False, pairing: dict | None = None) -> list[str]:
    """Every defect that keeps the layout from being simulated, one line each (empty: fine).

    Checks: no segments, self-loops, valence above 4, duplicate edges,
    zero-length segments, disconnected parts; then the linkage analysis
    (e.g. a valence-3 joint that cannot be paired); then a layout turned
    inside out (:func:`inversions`). ``allow_crossings``: beams of one family
    may cross, as in a layered design that was opened so (the paper's
    two-layer two-bump design crosses 107 times; the simulation models no
    contact, and ``xshells deploy`` deploys it with a warning). ``pairing``:
    the :func:`beam_pairing` of the layout before the edit, whose beams must
    pass through the joints as they did (:func:`repairings`).
    """
    V, E = layout.vertices, layout.edges
    if len(E) == 0:
        return ["the layout has no segments"]
    out: list[str] = []
    if not np.all(np.isfinite(V)):
        out.append("a joint has a non-finite coordinate")
    loops = np.flatnonzero(E[:, 0] == E[:, 1])
    if loops.size:
        out.append(f"segment {loops[0]} is a self-loop")
    val = np.bincount(E.ravel(), minlength=len(V))
    high = np.flatnonzero(val > 4)
    if high.size:
        out.append(f"valence > 4 at joint{'s' if high.size > 1 else ''} "
                   + ", ".join(f"{v} ({val[v]})" for v in high[:6]) + (" …" if high.size > 6 else ""))
    key = np.sort(E, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    dup = np.flatnonzero(counts[inv.ravel()] > 1)
    if dup.size:
        out.append("duplicate edge: segments " + ", ".join(str(s) for s in dup[:6]) + " join the same joints")
    short = np.flatnonzero(layout.segment_lengths() <= ZERO_LENGTH_RELATIVE * layout.span())
    if short.size:
        out.append("zero-length segment" + ("s " if short.size > 1 else " ") + ", ".join(str(s) for s in short[:6]))
    parts = components(layout)
    if parts > 1:
        out.append(f"disconnected: the layout falls into {parts} parts")
    if not out:
        try:
            graph = analyzed(layout)
        except InputError as exc:
            out.append(str(exc).replace("<arrays>: ", ""))
        else:
            out += inversions(layout, graph, allow_crossings)
            if pairing is not None:
                out += repairings(layout, graph, pairing)
    return out


FAMILY_CROSSING = "beams of one family lie in one layer and would collide"
"""The end of :func:`inversions`' line for beams of one family that cross (a session spots a layered design by it)."""


def inversions(layout: Layout, graph, allow_crossings: bool = False) -> list[str]:
    """A layout turned inside out somewhere, one line each: a folded corner, beams of one family crossing.

    The analysis cannot see either: it gives every joint an opening angle in
    [0°, 180°] and labels the beams to suit. A corner (a valence-2 joint,
    where two beams end) dragged across the line between its two neighbours
    turns its cell inside out; the labelling then makes it open the other way
    than the rest, and a deployment folds it through 0° (Darth Vader with
    boundary joint 88 raised 38 mm: corner 153, found 104 s into the app's
    deployment). Beams of one family lie in one layer, so two that cross
    collide (:mod:`xshells.linkage.clearance` measures how close they come
    in a solved flat state; here the drawn segments are enough).
    """
    from ..linkage.clearance import beam_family

    V, E = layout.vertices, layout.edges
    out: list[str] = []
    neighbours: list[set] = [set() for _ in range(layout.num_vertices)]
    for a, b in E.tolist():
        neighbours[a].add(b)
        neighbours[b].add(a)

    def side(p, q, r) -> float:  # > 0 where r lies left of the line p → q
        return float((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))

    folded = []
    for j in np.flatnonzero(graph.valence == 2).tolist():
        u, w = sorted(neighbours[j])
        cell = (neighbours[u] & neighbours[w]) - {j}  # the corner's quad cell j, u, c, w
        if len(cell) == 1:
            c = cell.pop()
            if side(V[u], V[w], V[j]) * side(V[u], V[w], V[c]) > 0:  # j on c's side: the cell turned inside out
                folded.append((j, u, w))
    if folded:
        j, u, w = folded[0]
        more = f" (and corner{'s' * (len(folded) > 2)} {', '.join(str(f[0]) for f in folded[1:6])})" if len(folded) > 1 else ""
        out.append(f"joint {j} is folded through: it crossed the line from joint {u} to joint {w}, turning its cell inside "
                   f"out{more}; deployed, it would invert")
    if allow_crossings:
        return out
    # beams of one family that cross away from a joint (segments sharing a joint meet there)
    family = np.array([beam_family(graph, b) for b in range(graph.num_beams)])[np.asarray(graph.beam_of_segment)]
    P, Q = V[E[:, 0]], V[E[:, 1]]
    lo, hi = np.minimum(P, Q), np.maximum(P, Q)
    i, k = np.nonzero(np.triu((lo[:, None] <= hi[None]).all(-1) & (lo[None] <= hi[:, None]).all(-1), 1)
                      & (family[:, None] == family[None]))
    keep = (E[i][:, :, None] != E[k][:, None, :]).all(axis=(1, 2))
    i, k = i[keep], k[keep]

    def orient(p, q, r):
        return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])

    cross = (orient(P[i], Q[i], P[k]) * orient(P[i], Q[i], Q[k]) < 0) & (orient(P[k], Q[k], P[i]) * orient(P[k], Q[k], Q[i]) < 0)
    if cross.any():
        a, b = int(i[cross][0]), int(k[cross][0])
        out.append(f"segments {a} (joints {E[a, 0]}–{E[a, 1]}) and {b} (joints {E[b, 0]}–{E[b, 1]}) cross: "
                   + FAMILY_CROSSING)
    return out


def components(layout: Layout) -> int:
    """Number of connected parts among the vertices that carry a segment.

    A plain union-find (a few hundred joints): SciPy's graph module would add
    half a second to the app's start-up.
    """
    E = layout.edges
    if len(E) == 0:
        return 0
    parent = list(range(layout.num_vertices))

    def root(v: int) -> int:
        while parent[v] != v:
            parent[v] = parent[parent[v]]
            v = parent[v]
        return v

    for a, b in E.tolist():
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[ra] = rb
    return len({root(v) for v in np.unique(E).tolist()})


# ----------------------------------------------------------------------------- picking
def nearest_vertex(layout: Layout, xy, radius: float | None = None) -> int | None:
    """Index of the vertex nearest ``xy`` (None if farther than ``radius``)."""
    if layout.num_vertices == 0:
        return None
    d = np.linalg.norm(layout.vertices - np.asarray(xy, float)[:2], axis=1)
    v = int(np.argmin(d))
    return v if radius is None or d[v] <= radius else None


def nearest_segment(layout: Layout, xy, radius: float | None = None) -> int | None:
    """Index of the segment nearest ``xy`` (point-to-segment distance)."""
    if layout.num_segments == 0:
        return None
    p = np.asarray(xy, float)[:2]
    a, b = layout.vertices[layout.edges[:, 0]], layout.vertices[layout.edges[:, 1]]
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, 1) / np.maximum(np.sum(ab * ab, 1), 1e-300), 0, 1)
    d = np.linalg.norm(a + t[:, None] * ab - p, axis=1)
    s = int(np.argmin(d))
    return s if radius is None or d[s] <= radius else None


# ----------------------------------------------------------------------------- undo / redo
@dataclass
class History:
    """Undo/redo over immutable layouts (bounded, oldest dropped first)."""

    current: Layout
    limit: int = 200
    _undo: list = field(default_factory=list)
    _redo: list = field(default_factory=list)

    def push(self, layout: Layout) -> Layout:
        """Make ``layout`` current; a no-op edit is not recorded."""
        if layout.same_as(self.current):
            return self.current
        self._undo.append(self.current)
        del self._undo[: max(0, len(self._undo) - self.limit)]
        self._redo.clear()
        self.current = layout
        return layout

    def undo(self) -> Layout:
        if self._undo:
            self._redo.append(self.current)
            self.current = self._undo.pop()
        return self.current

    def redo(self) -> Layout:
        if self._redo:
            self._undo.append(self.current)
            self.current = self._redo.pop()
        return self.current

    def reset(self, layout: Layout) -> None:
        self.current, self._undo, self._redo = layout, [], []

    @property
    def can_undo(self) -> bool:
        return bool(self._undo)

    @property
    def can_redo(self) -> bool:
        return bool(self._redo)
