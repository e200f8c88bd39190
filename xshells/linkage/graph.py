"""Graph analysis of a design: joints, free ends, the two beams at each joint, full rods.

Conventions (following the paper, §3, and the reference implementation's
semantics):

* A vertex of valence 1 is a **free end**; valence 2, 3 or 4 is a **joint**
  coupling exactly two beams, A and B; valence above 4 is an error. Vertices
  of valence 0 (unused) are kept in the design's numbering but belong to
  nothing; they are listed in ``unused_vertices`` and ignored otherwise.
* At a joint each beam is a pair of incident segments that it passes
  through, or one segment that ends there:

  - valence 4: the perfect matching of the four edges into two pairs that
    makes the pairs most nearly opposite (least total cosine between the
    outward edge directions);
  - valence 3: the most nearly opposite pair is one beam, the remaining
    edge the other; a pair whose far ends share a neighbour other than the
    joint is skipped because joining it would close a triangle, not a quad;
  - valence 2: a corner; the two segments are two different beams, each
    ending at the joint (the first in file order starts as beam A).

* Each beam at a joint has an *incoming* slot and an *outgoing* slot (the
  segment before and after the joint when walking along the beam); a beam
  that ends at the joint uses one of them. Its unit tangent ``t`` points
  from incoming to outgoing (for a pair: the normalized difference of the
  two outward edge directions, i.e. the bisector of the straight-through
  direction).
* The joint normal is ``n = normalize(t_A x t_B)``. Labels are then made
  consistent over the whole network: normals agree between neighbouring
  joints (swapping A and B flips n), a segment is labelled the same (A or
  B) at both of its joints where the topology allows (exchanging A with B
  and reversing the new B keeps n), and the majority of opening angles
  ``alpha = angle(t_A, t_B)`` are acute.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from xshells.errors import InputError
from xshells.io.design import Design, _readonly

__all__ = ["LinkageGraph", "analyze", "reduced_dof_count", "BEAM_A", "BEAM_B", "INCOMING", "OUTGOING"]

BEAM_A, BEAM_B = 0, 1
INCOMING, OUTGOING = 0, 1
_NONE = -1
# Below this |t_A x t_B| the joint's beams are (anti)parallel and the normal
# must come from the neighbourhood instead.
_DEGENERATE_SINE = 1e-8
# Singular-value ratio under which the design counts as lying in a plane.
_PLANAR_TOLERANCE = 1e-9


@dataclass(frozen=True, eq=False)
class LinkageGraph:
    """Topology of a beam network, with the A/B beam structure at each joint.

    ``n`` vertices, ``m`` segments, ``nj`` joints, ``nf`` free ends, ``nb`` beams.

    Attributes
    ----------
    design : Design
    valence : ndarray, shape (n,), int64
        Number of segments at each vertex.
    joint_vertex : ndarray, shape (nj,), int64
        The vertex of each joint, in increasing vertex order.
    vertex_joint : ndarray, shape (n,), int64
        Joint index of each vertex, -1 for free ends and unused vertices.
    free_end_vertex : ndarray, shape (nf,), int64
    unused_vertices : ndarray, shape (nu,), int64
        Vertices no segment touches (kept in the numbering, otherwise ignored).
    joint_segments : ndarray, shape (nj, 2, 2), int64
        ``[j, beam, slot]``: segment id of beam A (0) / B (1) on the
        incoming (0) / outgoing (1) side of joint j, or -1.
    joint_segment_points_away : ndarray, shape (nj, 2, 2), bool
        Whether that segment's local direction (``edges[s, 0] -> edges[s, 1]``)
        points away from the joint; False where the slot is empty.
    joint_tangents : ndarray, shape (nj, 2, 3), float64
        Unit tangents ``t_A``, ``t_B`` of the two beams at each joint
        (incoming -> outgoing), from the straight segment chords of the layout.
    joint_normals : ndarray, shape (nj, 3), float64
        Unit ``t_A x t_B`` (consistently oriented over the network).
    joint_opening_angles : ndarray, shape (nj,), float64
        ``alpha = angle(t_A, t_B)`` in [0, pi].
    segment_joints : ndarray, shape (m, 2), int64
        Joint at the start (``edges[s, 0]``) and end (``edges[s, 1]``) of each
        segment, -1 at a free end.
    segment_labels : ndarray, shape (m, 2), int64
        Beam label (0 = A, 1 = B) of the segment at its start/end joint, -1 at
        a free end.
    beams : tuple of ndarray, each shape (L_b, 2), int64
        Each full rod as its segments in order: column 0 the segment id,
        column 1 +1 if walked from ``edges[s, 0]`` to ``edges[s, 1]``, else -1.
    beam_closed : ndarray, shape (nb,), bool
        Whether a beam closes on itself (passes through every joint it meets).
    beam_of_segment : ndarray, shape (m,), int64
    layout_normal : ndarray, shape (3,), float64
        Normal of the best-fit plane of the layout.
    is_planar : bool
        Whether the layout lies in that plane (a flat assembly state).
    crossings : str
        For a flat layout, a one-line warning naming segments that cross without a joint ('' if
        none): no contact is modelled, so they pass through each other (a layered design).
    labels_consistent : bool
        Whether every joint-to-joint segment has the same label at both ends.
    bends : str
        A one-line warning naming nodes of valence 2 that look like the bends of a beam drawn as a polyline
        ('' if none): each is a hinge where two beams end (see :func:`_bends`).
    """

    design: Design = field(repr=False)
    valence: np.ndarray = field(repr=False)
    joint_vertex: np.ndarray = field(repr=False)
    vertex_joint: np.ndarray = field(repr=False)
    free_end_vertex: np.ndarray = field(repr=False)
    unused_vertices: np.ndarray = field(repr=False)
    joint_segments: np.ndarray = field(repr=False)
    joint_segment_points_away: np.ndarray = field(repr=False)
    joint_tangents: np.ndarray = field(repr=False)
    joint_normals: np.ndarray = field(repr=False)
    joint_opening_angles: np.ndarray = field(repr=False)
    segment_joints: np.ndarray = field(repr=False)
    segment_labels: np.ndarray = field(repr=False)
    beams: tuple = field(repr=False)
    beam_closed: np.ndarray = field(repr=False)
    beam_of_segment: np.ndarray = field(repr=False)
    layout_normal: np.ndarray = field(repr=False)
    is_planar: bool = False
    crossings: str = ""  # a warning naming segments that cross without a joint ('' if none)
    labels_consistent: bool = True
    bends: str = ""  # a warning naming nodes of valence 2 that look like bends of a polyline beam ('' if none)

    @property
    def num_segments(self) -> int:
        return int(self.design.edges.shape[0])

    @property
    def num_joints(self) -> int:
        return int(self.joint_vertex.shape[0])

    @property
    def num_free_ends(self) -> int:
        return int(self.free_end_vertex.shape[0])

    @property
    def num_beams(self) -> int:
        return len(self.beams)

    @property
    def segment_joint_ends(self) -> np.ndarray:
        """Number of joint ends (0, 1 or 2) of each segment, shape (m,)."""
        return np.count_nonzero(self.segment_joints >= 0, axis=1)

    def dof(self, subdivision: int = 10) -> int:
        """Reduced DoF count with ``subdivision`` edges per segment (see :func:`reduced_dof_count`)."""
        return reduced_dof_count(self.num_joints, self.segment_joint_ends, subdivision)

    def beam_vertices(self, b: int) -> np.ndarray:
        """Vertex ids along beam ``b`` in walking order, shape (L_b + 1,)."""
        steps = self.beams[b]
        E = self.design.edges
        seg, direction = steps[:, 0], steps[:, 1]
        starts = np.where(direction > 0, E[seg, 0], E[seg, 1])
        ends = np.where(direction > 0, E[seg, 1], E[seg, 0])
        return np.append(starts, ends[-1])

    def summary(self, subdivision: int = 10) -> str:
        """A few lines describing the network's size and beam structure."""
        lengths = [len(b) for b in self.beams]
        longest = int(np.argmax(lengths))
        hist = np.bincount(self.valence, minlength=5)
        return "\n".join([
            f"design: {self.design.label()}",
            f"segments: {self.num_segments}  joints: {self.num_joints}  free ends: {self.num_free_ends}"
            + (f"  unused vertices: {len(self.unused_vertices)}" if len(self.unused_vertices) else ""),
            "joint valences: " + ", ".join(f"{v}: {hist[v]}" for v in (2, 3, 4)),
            f"beams: {self.num_beams} ({int(self.beam_closed.sum())} closed), "
            f"longest: beam {longest} with {lengths[longest]} segments",
            f"layout: {'planar' if self.is_planar else 'not planar'}; "
            f"A/B labels {'consistent' if self.labels_consistent else 'not consistent'} across segments",
            f"reduced DoF at k={subdivision}: {self.dof(subdivision)}",
        ])


def reduced_dof_count(num_joints: int, segment_joint_ends, subdivision: int = 10) -> int:
    """Size of the reduced variable vector x (before pinning a joint).

    A segment is a rod of k edges: k + 1 vertices (3 variables each) and k
    material angles, 4k + 3 variables. Each joint end takes over two
    vertices (the terminal edge) and one angle, 7 variables, and each joint
    adds 9 of its own (position 3, rotation 3, opening angle, two edge
    lengths). So a joint-to-joint segment keeps 4k - 11 (29 at k = 10), a
    joint-to-free-end segment 4k - 4, and

        dof = 9 * num_joints + sum_s (4k + 3 - 7 * joint_ends(s)).

    Parameters
    ----------
    num_joints : int
    segment_joint_ends : array_like of int, shape (m,)
        Number of joint ends (0, 1 or 2) of each segment.
    subdivision : int
        Edges per segment, k >= 3 (below that the two terminal edges of a
        joint-to-joint segment would overlap).
    """
    k = int(subdivision)
    if k < 3:
        raise InputError(f"subdivision must be at least 3 edges per segment, got {subdivision}")
    ends = np.asarray(segment_joint_ends, dtype=np.int64)
    return int(9 * num_joints + np.sum(4 * k + 3 - 7 * ends))


def analyze(design: Design) -> LinkageGraph:
    """Find joints, free ends and the A/B beams at each joint; trace full beams.

    Parameters
    ----------
    design : Design

    Returns
    -------
    LinkageGraph

    Raises
    ------
    InputError
        A node of valence above 4, a disconnected design (its components are
        named), two used nodes at the same position, no joint at all, or a
        valence-3 joint that cannot be paired without closing a triangle.
    """
    V, E = design.vertices, design.edges
    valence = np.bincount(E.ravel(), minlength=len(V)).astype(np.int64)
    _check_valence(design, valence)
    _check_connected(design, valence)
    _check_same_position(design)
    joint_vertex = np.flatnonzero(valence >= 2)
    if joint_vertex.size == 0:
        raise InputError(f"{design.label()}: the design has no joint (no node of valence 2, 3 or 4)")
    vertex_joint = np.full(len(V), _NONE, dtype=np.int64)
    vertex_joint[joint_vertex] = np.arange(len(joint_vertex))

    incident = _incident_segments(E, len(V))
    layout_normal, is_planar = _layout_plane(V[valence > 0])
    crossings = _crossings(design, layout_normal) if is_planar else ""
    slots = np.full((len(joint_vertex), 2, 2), _NONE, dtype=np.int64)
    for j, v in enumerate(joint_vertex.tolist()):
        slots[j] = _pair_beams(design, v, incident, valence)

    tangents = _beam_tangents(V, E, joint_vertex, slots)
    slots, tangents, normals = _orient_normals(E, joint_vertex, vertex_joint, slots, tangents, layout_normal)
    slots, tangents, consistent = _make_labels_consistent(E, joint_vertex, vertex_joint, slots, tangents)
    alpha = _opening_angles(tangents)
    if np.count_nonzero(alpha < np.pi / 2) < np.count_nonzero(alpha >= np.pi / 2):
        slots, tangents = _swap_angle_definition(slots, tangents, np.ones(len(slots), dtype=bool))
        alpha = _opening_angles(tangents)

    segment_joints, segment_labels = _segment_ends(E, joint_vertex, slots)
    points_away = np.zeros(slots.shape, dtype=bool)
    filled = slots >= 0
    points_away[filled] = E[slots[filled], 0] == np.broadcast_to(joint_vertex[:, None, None], slots.shape)[filled]
    beams, closed = _trace_beams(E, joint_vertex, slots)
    beam_of_segment = np.empty(len(E), dtype=np.int64)
    for b, steps in enumerate(beams):
        beam_of_segment[steps[:, 0]] = b

    ro = _readonly
    return LinkageGraph(
        design=design,
        valence=ro(valence),
        joint_vertex=ro(joint_vertex),
        vertex_joint=ro(vertex_joint),
        free_end_vertex=ro(np.flatnonzero(valence == 1)),
        unused_vertices=ro(np.flatnonzero(valence == 0)),
        joint_segments=ro(slots),
        joint_segment_points_away=ro(points_away),
        joint_tangents=ro(tangents),
        joint_normals=ro(normals),
        joint_opening_angles=ro(alpha),
        segment_joints=ro(segment_joints),
        segment_labels=ro(segment_labels),
        beams=tuple(ro(b) for b in beams),
        beam_closed=ro(np.array(closed, dtype=bool)),
        beam_of_segment=ro(beam_of_segment),
        layout_normal=ro(layout_normal),
        is_planar=bool(is_planar),
        labels_consistent=bool(consistent),
        crossings=crossings,
        bends=_bends(design, valence, incident),
    )


def _check_valence(design: Design, valence: np.ndarray) -> None:
    high = np.flatnonzero(valence > 4)
    if high.size:
        v = int(high[0])
        more = f" (and {high.size - 1} more such nodes)" if high.size > 1 else ""
        raise InputError(f"{design.label()}: {design.where_vertex(v)} has valence {int(valence[v])}; "
                         f"a joint couples two beams, so valence must be 1 to 4{more}")


# Two used nodes closer than this fraction of the layout's diagonal are at the same position (round-off),
# as a segment that short is zero-length to the design reader.
_SAME_POSITION_RELATIVE = 1e-12


def _check_same_position(design: Design) -> None:
    """Name two used nodes at the same position: two joints that look like one.

    Each holds its own segments, so the beams there are not joined: the linkage failed later with "its two
    beams are parallel" at one of them, or with two segments that overlap. Checked after connectivity, so a
    soup of separate segments (a section's contour) is still called disconnected; unused duplicates are harmless.
    """
    from scipy.spatial import cKDTree

    used = np.unique(design.edges)
    W = design.vertices[used]
    W = (W - W.mean(axis=0)) / (float(np.max(np.abs(W - W.mean(axis=0)))) or 1.0)  # no overflow, any units
    diag = float(np.linalg.norm(np.ptp(W, axis=0)))
    pairs = cKDTree(W).query_pairs(_SAME_POSITION_RELATIVE * diag, output_type="ndarray")
    if not len(pairs):
        return
    pairs = np.sort(used[pairs], axis=1)
    a, b = (int(x) for x in pairs[np.lexsort((pairs[:, 0], pairs[:, 1]))[0]])  # the pair completed first in the file
    raise InputError(f"{design.label()}: {design.where_vertex(a)} and {design.where_vertex(b)} are at the same "
                     f"position {tuple(design.vertices[a].tolist())}: merge them (as two nodes, the beams there are "
                     "not joined)")


def _check_connected(design: Design, valence: np.ndarray) -> None:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n, E = len(valence), design.edges
    adjacency = coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n))
    _, component = connected_components(adjacency, directed=False)
    used = np.flatnonzero(valence > 0)
    labels, first, sizes = np.unique(component[used], return_index=True, return_counts=True)
    if len(labels) == 1:
        return
    order = np.argsort(-sizes, kind="stable")
    shown = order[:5]
    parts = [f"{int(sizes[c])} nodes incl. {design.where_vertex(int(used[first[c]]))}" for c in shown]
    more = f", and {len(labels) - len(shown)} more" if len(labels) > len(shown) else ""
    raise InputError(f"{design.label()}: disconnected design with {len(labels)} components: "
                     + "; ".join(parts) + more)


def segment_crossings(P: np.ndarray, E: np.ndarray):
    """Which pairs of segments of a flat drawing cross properly, away from a shared node.

    Parameters
    ----------
    P : (k, 2) float
        Node positions in the drawing's plane.
    E : (s, 2) int
        Segments as node pairs.

    Returns
    -------
    s, t : (m,) int
        Candidate pairs (s < t) that share no node: segments whose midpoints lie within the longest
        segment of each other.
    cross : (m,) bool
        Whether the pair crosses properly: each segment's ends strictly on both sides of the other's
        line, beyond round-off.
    length : (s,) float
        Each segment's length.
    """
    from scipy.spatial import cKDTree

    a, b = P[E[:, 0]], P[E[:, 1]]
    length = np.linalg.norm(b - a, axis=1)
    none = np.zeros(0, np.int64)
    if not len(E):
        return none, none, np.zeros(0, bool), length
    pairs = cKDTree(0.5 * (a + b)).query_pairs(float(length.max()), output_type="ndarray")
    if not len(pairs):
        return none, none, np.zeros(0, bool), length
    s, t = pairs.min(axis=1), pairs.max(axis=1)
    shared = (E[s, 0] == E[t, 0]) | (E[s, 0] == E[t, 1]) | (E[s, 1] == E[t, 0]) | (E[s, 1] == E[t, 1])
    s, t = s[~shared], t[~shared]

    def side(p, q, r):  # twice the signed area of (p, q, r)
        return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])

    eps = 1e-9 * length[s] * length[t]
    d1, d2 = side(a[s], b[s], a[t]), side(a[s], b[s], b[t])
    d3, d4 = side(a[t], b[t], a[s]), side(a[t], b[t], b[s])
    cross = (((d1 > eps) & (d2 < -eps)) | ((d1 < -eps) & (d2 > eps))) & \
            (((d3 > eps) & (d4 < -eps)) | ((d3 < -eps) & (d4 > eps)))
    return s, t, cross, length


def beam_families(graph: "LinkageGraph") -> tuple[np.ndarray, int]:
    """Split the beams into two families, the two beams through every joint in different ones.

    An X-shell's scissor deployment opens the angle between its two families at every joint; that needs
    the beams' crossing graph to be bipartite. A cell bounded by an odd number of beams (a pentagon drawn
    into a quad net) makes it odd, and no labelling opens every joint.

    Returns
    -------
    family : (nb,) int
        0 or 1 per beam (``graph.beams``); where the split fails, as far as it got.
    conflict : int
        A joint whose two beams fell into the same family, or -1 if the split holds.
    """
    bos = np.asarray(graph.beam_of_segment)
    js = np.asarray(graph.joint_segments)
    nb = len(graph.beams)
    adjacent: list[list[tuple[int, int]]] = [[] for _ in range(nb)]
    for j in range(js.shape[0]):
        a, b = js[j, 0][js[j, 0] >= 0], js[j, 1][js[j, 1] >= 0]
        if len(a) and len(b):
            ba, bb = int(bos[a[0]]), int(bos[b[0]])
            adjacent[ba].append((bb, j))
            adjacent[bb].append((ba, j))
    family = np.full(nb, -1, np.int64)
    for first in range(nb):
        if family[first] >= 0:
            continue
        family[first] = 0
        queue = deque([first])
        while queue:
            u = queue.popleft()
            for v, j in adjacent[u]:
                if family[v] < 0:
                    family[v] = 1 - family[u]
                    queue.append(v)
                elif family[v] == family[u]:
                    return family, j
    return family, -1


def _crossings(design: Design, normal: np.ndarray) -> str:
    """A one-line warning naming segments of a flat layout that cross away from a shared node ('' if none).

    The simulation models no contact: segments crossing without a joint pass through each other.
    That is what a layered design means (the paper's two-layer two-bump design crosses 107 times,
    its layers stacked), and a mistake anywhere else (a diagonal drawn across a grid deployed with
    "reached the target angle" and no word), so it is said, not refused. Candidates are the pairs of
    segments whose midpoints lie within the longest segment of each other; a crossing is proper
    (each segment's ends strictly on both sides of the other's line, beyond round-off).
    """
    V, E = design.vertices, design.edges
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(normal, u)
    P = np.stack([V @ u, V @ w], axis=1)
    P = P - P.mean(axis=0)
    s, t, cross, length = segment_crossings(P, E)
    if not len(s):
        return ""
    if not cross.any():
        return _touching(design, P, s, t, length)
    k = np.flatnonzero(cross)
    first = k[np.argmin(np.maximum(s[k], t[k]))]  # the pair completed earliest in the file
    i, j = sorted((int(s[first]), int(t[first])))
    more = f" ({len(k) - 1} more such crossing{'s' if len(k) > 2 else ''})" if len(k) > 1 else ""
    return (f"{design.where_edge(j)} (between {design.where_vertex(int(E[j, 0]))} and "
            f"{design.where_vertex(int(E[j, 1]))}) crosses {design.where_edge(i)} without a joint{more}: the "
            f"simulation passes such beams through each other (no contact is modelled), as a layered design "
            f"intends; anywhere else put a node where they cross")


TOUCH_TOLERANCE = 1e-3
"""A free end (valence 1) within this fraction of the shorter segment's length of another segment that
shares no node with it touches that segment in the drawing (a T drawn with an end snapped onto a beam)."""


def _touching(design: Design, P: np.ndarray, s: np.ndarray, t: np.ndarray, length: np.ndarray) -> str:
    """A one-line warning naming a free end that touches another segment without a node there ('' if none).

    ``P``: the layout's points in its plane, (n, 2); ``s``, ``t``: candidate pairs of segments sharing no
    node; ``length``: every segment's length. The drawing shows a connection that the model does not make:
    the end stays free (a T-junction drawn without splitting the other beam at a node).
    """
    E = design.edges
    # Only a free end can be the loose leg of a T. A joint's vertex near another segment is connected to the
    # network already: a short segment beside a long one (a 0.1-long rung between two 100-long segments)
    # put the rung's far joint within the tolerance of the long one, and "that end is free" was false.
    free = np.bincount(E.ravel(), minlength=len(P)) == 1
    for one, other in ((s, t), (t, s)):
        a, b = P[E[one, 0]], P[E[one, 1]]
        for end in (0, 1):
            q = P[E[other, end]]
            d = b - a
            u = np.einsum("ij,ij->i", q - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
            foot = a + np.clip(u, 0.0, 1.0)[:, None] * d
            gap = np.linalg.norm(q - foot, axis=1)
            hit = (gap <= TOUCH_TOLERANCE * np.minimum(length[one], length[other])) & free[E[other, end]]
            if hit.any():
                k = int(np.flatnonzero(hit)[0])
                i, j, v = int(one[k]), int(other[k]), int(E[other[k], end])
                return (f"{design.where_edge(j)} ends at {design.where_vertex(v)} on {design.where_edge(i)} "
                        f"(between {design.where_vertex(int(E[i, 0]))} and {design.where_vertex(int(E[i, 1]))}) "
                        f"without sharing a node: the two are not connected, that end is free; to join them, "
                        f"split the other beam at a node there")
    return ""


BEND_DEGREES = 10.0
"""A node of valence 2 whose two segments are within this angle of straight looks like a bend of one beam."""


def _bends(design: Design, valence: np.ndarray, incident: list[list[int]]) -> str:
    """A one-line warning when the nodes of valence 2 look like the bends of beams drawn as polylines ('' if not).

    A node of valence 2 is a joint where two beams end: a hinge, free to turn (the paper's corners and boundary
    nodes). A curved beam drawn as a polyline (rad7_poly.obj: each segment split in three on an arc) thus
    became 172 hinges, its beams one or two segments long; the only word was an inversion at the start of the
    deployment. Said, not refused, when a segment joins two such nearly straight nodes (a run of bends: none
    in the 80 bundled designs, 90 in rad7_poly.obj) or when nearly straight ones outnumber the joints of
    valence 3 and 4 (at most 0.18 of them in the bundled designs, 3.7 in rad7_poly.obj).
    """
    V, E = design.vertices, design.edges
    two = np.flatnonzero(valence == 2)
    if not len(two):
        return ""
    ends = np.array([[_far_vertex(E, s, int(v)) for s in incident[v]] for v in two.tolist()])
    a, b = V[ends[:, 0]] - V[two], V[ends[:, 1]] - V[two]
    cos = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    off = 180.0 - np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))  # 0: straight through
    straight = np.zeros(len(V), dtype=bool)
    straight[two[off < BEND_DEGREES]] = True
    run = straight[E[:, 0]] & straight[E[:, 1]]
    if not run.any() and np.count_nonzero(straight) <= np.count_nonzero(valence >= 3):
        return ""
    v = int(np.flatnonzero(straight)[0])
    n = int(np.count_nonzero(straight))
    more = f" and {n - 1} more node{'s' * (n > 2)} of valence 2" if n > 1 else ", a node of valence 2,"
    return (f"{design.label()}: {design.where_vertex(v)}{more} join{'s' * (n == 1)} two segments nearly in line "
            f"({float(off[np.searchsorted(two, v)]):.2g}° off straight): such a node is a hinge where two beams end, "
            f"not a bend along one beam, so a beam drawn as a polyline folds there; draw each beam straight from "
            f"joint to joint")


def _incident_segments(E: np.ndarray, n: int) -> list[list[int]]:
    """Segments at each vertex, in file order, shape n lists."""
    incident: list[list[int]] = [[] for _ in range(n)]
    for s, (a, b) in enumerate(E.tolist()):
        incident[a].append(s)
        incident[b].append(s)
    return incident


def _layout_plane(points: np.ndarray) -> tuple[np.ndarray, bool]:
    """Best-fit plane of points (k >= 3, 3): unit normal (3,) and whether all points lie on it.

    The normal's sign is fixed so that its largest component is positive.
    """
    centered = points - points.mean(axis=0)
    _, sing, vt = np.linalg.svd(centered, full_matrices=False)
    normal = vt[-1]  # least-variance direction; any perpendicular if collinear
    if normal[np.argmax(np.abs(normal))] < 0:
        normal = -normal
    planar = sing[-1] <= _PLANAR_TOLERANCE * max(sing[0], 1e-300)
    return normal, bool(planar)


def _outward_directions(V: np.ndarray, E: np.ndarray, v: int, segs: list[int]) -> np.ndarray:
    """Unit vectors from vertex v along each segment, shape (len(segs), 3)."""
    other = np.where(E[segs, 0] == v, E[segs, 1], E[segs, 0])
    d = V[other] - V[v]
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _far_vertex(E: np.ndarray, s: int, v: int) -> int:
    return int(E[s, 1] if E[s, 0] == v else E[s, 0])


def _pair_beams(design: Design, v: int, incident: list[list[int]], valence: np.ndarray) -> np.ndarray:
    """Assign the segments at joint vertex v to beams A and B, shape (2, 2) [beam, slot]."""
    E = design.edges
    segs = incident[v]
    u = _outward_directions(design.vertices, E, v, segs)
    cos = u @ u.T
    same = np.argwhere(np.triu(cos > 1.0 - 1e-12, k=1))
    if len(same):  # two segments leaving in one direction lie on top of each other (a beam through them folds back)
        a, b = (_far_vertex(E, segs[i], v) for i in same[0])
        raise InputError(f"{design.label()}: {design.where_vertex(v)}: its segments to {design.where_vertex(a)} and "
                         f"{design.where_vertex(b)} overlap (they leave it in the same direction)")
    slots = np.full((2, 2), _NONE, dtype=np.int64)
    if len(segs) == 2:
        # A corner: each beam ends here, so each segment is its own beam.
        slots[BEAM_A, INCOMING], slots[BEAM_B, INCOMING] = segs
    elif len(segs) == 3:
        pair = _valence3_pair(E, v, segs, cos, incident, design)
        rest = ({0, 1, 2} - set(pair)).pop()
        slots[BEAM_A] = segs[pair[0]], segs[pair[1]]
        slots[BEAM_B, INCOMING] = segs[rest]
    else:
        matchings = (((0, 1), (2, 3)), ((0, 2), (1, 3)), ((0, 3), (1, 2)))
        scores = [cos[p] + cos[q] for p, q in matchings]
        # The most nearly opposite matching; the pair holding the first
        # segment in file order becomes beam A.
        p, q = matchings[int(np.argmin(scores))]
        slots[BEAM_A] = segs[p[0]], segs[p[1]]
        slots[BEAM_B] = segs[q[0]], segs[q[1]]
    return slots


def _valence3_pair(E, v, segs, cos, incident, design) -> tuple[int, int]:
    """The straightest pair of the three edges at v that does not close a triangle."""
    candidates = sorted(((cos[a, b], a, b) for a in range(3) for b in range(a + 1, 3)))
    for _, a, b in candidates:
        va, vb = _far_vertex(E, segs[a], v), _far_vertex(E, segs[b], v)
        na = {_far_vertex(E, s, va) for s in incident[va]}
        nb = {_far_vertex(E, s, vb) for s in incident[vb]}
        # Joining a and b into one beam would make the face on that side a
        # triangle when both far ends share another neighbour besides v.
        if len(na & nb) <= 1:
            return a, b
    raise InputError(f"{design.label()}: {design.where_vertex(v)}: cannot pair the 3 segments of this "
                     "joint into a beam without closing a triangle")


def _beam_tangents(V, E, joint_vertex, slots) -> np.ndarray:
    """Unit tangent of each beam at each joint, incoming -> outgoing, shape (nj, 2, 3)."""
    nj = len(joint_vertex)
    t = np.zeros((nj, 2, 3))
    for j, v in enumerate(joint_vertex.tolist()):
        for beam in (BEAM_A, BEAM_B):
            s_in, s_out = slots[j, beam]
            vec = np.zeros(3)
            if s_in >= 0:
                vec -= _unit(V[_far_vertex(E, s_in, v)] - V[v])
            if s_out >= 0:
                vec += _unit(V[_far_vertex(E, s_out, v)] - V[v])
            t[j, beam] = _unit(vec)
    return t


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x)


def _opening_angles(tangents: np.ndarray) -> np.ndarray:
    cos = np.einsum("ji,ji->j", tangents[:, BEAM_A], tangents[:, BEAM_B])
    return np.arccos(np.clip(cos, -1.0, 1.0))


def _swap_rod_labels(slots, tangents, mask):
    """Exchange A and B at the masked joints (flips t_A x t_B, keeps alpha)."""
    slots, tangents = slots.copy(), tangents.copy()
    slots[mask] = slots[mask][:, ::-1]
    tangents[mask] = tangents[mask][:, ::-1]
    return slots, tangents


def _swap_angle_definition(slots, tangents, mask):
    """New A = old B, new B = old A reversed: alpha -> pi - alpha, normal kept."""
    slots, tangents = _swap_rod_labels(slots, tangents, mask)
    slots[mask, BEAM_B] = slots[mask, BEAM_B][:, ::-1]
    tangents[mask, BEAM_B] *= -1.0
    return slots, tangents


def _joint_neighbours(E, joint_vertex, vertex_joint, slots, j):
    """(beam at j, neighbour joint, segment) for each joint-to-joint segment at joint j."""
    v = joint_vertex[j]
    for beam in (BEAM_A, BEAM_B):
        for s in slots[j, beam]:
            if s < 0:
                continue
            k = vertex_joint[_far_vertex(E, int(s), int(v))]
            if k >= 0:
                yield beam, int(k), int(s)


def _orient_normals(E, joint_vertex, vertex_joint, slots, tangents, layout_normal):
    """Make joint normals agree between neighbours (breadth first), swapping A/B where needed.

    Returns slots (nj, 2, 2), tangents (nj, 2, 3), normals (nj, 3).
    """
    nj = len(joint_vertex)
    normals = np.zeros((nj, 3))
    visited = np.zeros(nj, dtype=bool)
    swap = np.zeros(nj, dtype=bool)
    raw = np.cross(tangents[:, BEAM_A], tangents[:, BEAM_B])
    for root in range(nj):
        if visited[root]:
            continue
        visited[root] = True
        queue = deque([(root, layout_normal)])
        while queue:
            j, reference = queue.popleft()
            n = raw[j]
            if np.linalg.norm(n) < _DEGENERATE_SINE:
                # Beams (anti)parallel here: borrow the neighbour's normal,
                # made perpendicular to this joint's beam A.
                t = tangents[j, BEAM_A]
                n = reference - np.dot(reference, t) * t
                if np.linalg.norm(n) < _DEGENERATE_SINE:
                    n = np.cross(t, [1.0, 0.0, 0.0] if abs(t[0]) < 0.9 else [0.0, 1.0, 0.0])
            n = _unit(n)
            if np.dot(n, reference) < 0:
                n, swap[j] = -n, True
            normals[j] = n
            for _, k, _ in _joint_neighbours(E, joint_vertex, vertex_joint, slots, j):
                if not visited[k]:
                    visited[k] = True
                    queue.append((k, n))
    slots, tangents = _swap_rod_labels(slots, tangents, swap)
    return slots, tangents, normals


def _make_labels_consistent(E, joint_vertex, vertex_joint, slots, tangents):
    """Give each joint-to-joint segment the same label at both ends where possible.

    Breadth first from joint 0, redefining the angle (A <-> B, keeping the
    normal) of each newly reached joint that disagrees with its parent.
    Returns slots, tangents and whether every segment ended up consistent.
    """
    nj = len(joint_vertex)
    slots, tangents = slots.copy(), tangents.copy()
    visited = np.zeros(nj, dtype=bool)
    for root in range(nj):
        if visited[root]:
            continue
        visited[root] = True
        queue = deque([root])
        while queue:
            j = queue.popleft()
            for beam, k, s in _joint_neighbours(E, joint_vertex, vertex_joint, slots, j):
                if visited[k]:
                    continue
                visited[k] = True
                if _label_of(slots[k], s) != beam:
                    one = np.zeros(nj, dtype=bool)
                    one[k] = True
                    slots, tangents = _swap_angle_definition(slots, tangents, one)
                queue.append(k)
    consistent = all(
        _label_of(slots[k], s) == beam
        for j in range(nj)
        for beam, k, s in _joint_neighbours(E, joint_vertex, vertex_joint, slots, j)
    )
    return slots, tangents, consistent


def _label_of(joint_slots: np.ndarray, s: int) -> int:
    """Beam (0 = A, 1 = B) holding segment s among one joint's slots (2, 2)."""
    return int(np.argwhere(joint_slots == s)[0, 0])


def _segment_ends(E, joint_vertex, slots):
    """Joint and label at each end of each segment, shapes (m, 2) and (m, 2)."""
    m = len(E)
    seg_joint = np.full((m, 2), _NONE, dtype=np.int64)
    seg_label = np.full((m, 2), _NONE, dtype=np.int64)
    for j, v in enumerate(joint_vertex.tolist()):
        for beam in (BEAM_A, BEAM_B):
            for s in slots[j, beam]:
                if s >= 0:
                    end = 0 if E[s, 0] == v else 1
                    seg_joint[s, end] = j
                    seg_label[s, end] = beam
    return seg_joint, seg_label


def _trace_beams(E, joint_vertex, slots):
    """Chain segments that pass straight through joints into full beams.

    Returns a list of (L, 2) int64 arrays [segment, direction] and a list of
    closed flags. Open beams come first, each started from the lowest
    segment id with a loose end; closed loops follow.
    """
    # continuation[(s, end)] = (s2, end2): leaving segment s through its
    # `end` vertex, the beam enters segment s2 at its `end2` vertex.
    continuation: dict[tuple[int, int], tuple[int, int]] = {}
    for j, v in enumerate(joint_vertex.tolist()):
        for beam in (BEAM_A, BEAM_B):
            a, b = (int(x) for x in slots[j, beam])
            if a >= 0 and b >= 0:
                ea, eb = (0 if E[a, 0] == v else 1), (0 if E[b, 0] == v else 1)
                continuation[(a, ea)] = (b, eb)
                continuation[(b, eb)] = (a, ea)

    m = len(E)
    used = np.zeros(m, dtype=bool)
    beams, closed = [], []

    def walk(s: int, enter: int) -> np.ndarray:
        steps = []
        while True:
            used[s] = True
            leave = 1 - enter
            steps.append((s, 1 if enter == 0 else -1))
            nxt = continuation.get((s, leave))
            if nxt is None or used[nxt[0]]:
                return np.array(steps, dtype=np.int64)
            s, enter = nxt

    for s in range(m):
        if used[s]:
            continue
        for end in (0, 1):
            if (s, end) not in continuation:
                # A loose end: walk the whole beam from here (so it starts
                # where the beam starts, not midway).
                beams.append(walk(s, end))
                closed.append(False)
                break
    for s in range(m):
        if not used[s]:
            beams.append(walk(s, 0))
            closed.append(True)
    return beams, closed
