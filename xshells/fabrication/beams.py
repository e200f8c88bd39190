"""The continuous beams (strips) of a design: their holes, cut lengths and sections; the joint table.

A beam is one of the linkage graph's full rods (:attr:`LinkageGraph.beams`):
the chain of segments that passes straight through joints. On the straight
rest beam the holes sit at the joints, spaced by the segments' rest lengths
(joint to joint, as the simulation defines them). The strip is cut
``end_margin`` beyond its outermost hole, or beyond its free end where the
beam ends free. Positions are measured from the strip's cut start.

Beams are labelled by family (A or B, the linkage's pairing at the joints)
and numbered across the layout: within a family every beam runs the same
way along the family's mean direction, and they are numbered in order
across it (A01, A02, … from one side of the layout to the other).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..linkage.clearance import beam_family

# Lengths in the outputs are millimetres; a design drawn in other units says which.
UNITS_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4, "ft": 304.8}


# Rest lengths that belong to a flat layout lie within 0.03 % of its segment lengths (the six rest-length files of
# the reference data, on their own flat designs); the preoptimized banana's file on the optimized banana's layout,
# same segment count, is off by -22 % .. +48 % on 205 of 264 segments. 5 % leaves a wide margin both ways.
REST_LENGTH_TOLERANCE = 0.05


def rest_length_mismatch(rest_lengths, xy, edges, tolerance: float = REST_LENGTH_TOLERANCE) -> str | None:
    """Why the rest lengths do not belong to the flat layout ``xy`` (one line), or None when every segment's rest
    length is within ``tolerance`` (relative) of its length in the layout.

    Holes are spaced by the rest lengths and the assembly is drawn from the
    layout: rest lengths of another design with the same segment count make
    strips that do not fit the drawing, written without a word.
    """
    p = np.asarray(rest_lengths, float)
    XY = np.asarray(xy, float)
    E = np.asarray(edges, np.int64)
    flat = np.linalg.norm(XY[E[:, 1]] - XY[E[:, 0]], axis=1)
    off = np.abs(p / np.maximum(flat, np.finfo(float).tiny) - 1.0)
    bad = np.flatnonzero(off > tolerance)
    if len(bad) == 0:
        return None
    s = int(np.argmax(off))
    return (f"segment {s} (vertices {E[s, 0]}-{E[s, 1]}) has rest length {p[s]:.6g} but is {flat[s]:.6g} long in the "
            f"flat layout ({100 * (p[s] / max(flat[s], np.finfo(float).tiny) - 1):+.1f} %); {len(bad)} of {len(p)} "
            f"segments differ by more than {100 * tolerance:g} %")


def units_to_mm(units: str) -> float:
    """The factor from ``units`` (mm, cm, m, in, ft) to millimetres; one line for anything else."""
    key = str(units).strip().lower()
    if key not in UNITS_TO_MM:
        raise InputError(f"--units {units}: unknown unit (use one of {', '.join(UNITS_TO_MM)})")
    return UNITS_TO_MM[key]


@dataclass(frozen=True)
class Section:
    """A beam's cross-section as the workshop sees it (mm).

    ``width`` lies in the layout plane (the section's extent along the
    material director d1, the stiff in-plane direction); ``depth`` is along
    the layout's normal (d2), the direction in which the strips bend to
    deploy.
    """

    label: str
    width: float
    depth: float


@dataclass(frozen=True)
class Beam:
    """One continuous strip.

    Attributes
    ----------
    label : str
        ``A07``: family and number.
    family : str
        ``"A"`` or ``"B"``.
    index : int
        The graph's beam index (:attr:`LinkageGraph.beams`).
    vertices : ndarray, shape (L + 1,)
        Input vertex ids along the strip from its cut start (a closed beam
        repeats its first vertex at the end).
    segments : ndarray, shape (L,)
        Segment ids in the same order.
    hole_vertices : ndarray, shape (h,)
        The joints at the holes, in order (input vertex ids).
    hole_positions : ndarray, shape (h,)
        Hole centres from the strip's cut start (mm).
    length : float
        Cut length (mm).
    margin : float
        Material left beyond the outermost hole or free end at each end (mm).
    starts_free, ends_free : bool
        Whether the strip's first / last vertex is a free end (not a hole).
    closed : bool
        A closed loop: cut open at its first joint, whose hole appears at
        both ends (the ends overlap there and are riveted together).
    section : Section
    direction_deg : float
        Direction of the strip from its start to its end in the flat layout,
        degrees from the layout's x axis.
    """

    label: str
    family: str
    index: int
    vertices: np.ndarray
    segments: np.ndarray
    hole_vertices: np.ndarray
    hole_positions: np.ndarray
    length: float
    margin: float
    starts_free: bool
    ends_free: bool
    closed: bool
    section: Section
    direction_deg: float


@dataclass(frozen=True)
class JointRow:
    """One rivet: the joint (input vertex id), the two beams it joins, which lies on top, its angles (degrees)."""

    joint: int
    beam_a: str
    beam_b: str
    on_top: str
    flat_angle_deg: float
    deployed_angle_deg: float | None = None


def beam_sections(materials, num_segments: int, to_mm: float = 1.0) -> list[Section]:
    """The :class:`Section` of every segment, from one material or one per segment."""
    mats = list(materials) if isinstance(materials, (list, tuple)) else [materials]
    if len(mats) not in (1, num_segments):
        raise InputError(f"materials: expected 1 or {num_segments} (one per segment), got {len(mats)}")
    cache: dict[int, Section] = {}
    for m in mats:
        if id(m) not in cache:
            ext = np.ptp(np.asarray(m.fibre_extents, float), axis=1) * to_mm
            prof = m.profile
            kind = prof.kind if prof.params else str(prof.name).replace("\\", "/").rsplit("/", 1)[-1]
            cache[id(m)] = Section(f"{kind} {ext[0]:.4g}x{ext[1]:.4g}", float(ext[0]), float(ext[1]))
    return [cache[id(mats[0] if len(mats) == 1 else mats[s])] for s in range(num_segments)]


def _family_axis(directions: np.ndarray) -> np.ndarray:
    """The mean undirected direction (2,) of unit vectors (n, 2), with a deterministic sign (x ≥ 0, or y > 0)."""
    if len(directions) == 0:
        return np.array([1.0, 0.0])
    w, v = np.linalg.eigh(directions.T @ directions)
    a = v[:, -1]
    if a[0] < -1e-12 or (abs(a[0]) <= 1e-12 and a[1] < 0):
        a = -a
    return a


def trace_beams(graph, rest_lengths, sections: list[Section], *, xy=None, end_margin: float | None = None,
                to_mm: float = 1.0) -> list[Beam]:
    """Every continuous beam of ``graph`` as a :class:`Beam`, labelled and ordered (A01…, then B01…).

    Parameters
    ----------
    graph : LinkageGraph
    rest_lengths : (m,) array
        Per-segment rest lengths (design units), joint to joint.
    sections : list of Section, length m
        From :func:`beam_sections` (mm).
    xy : (n, 2) array, optional
        In-plane coordinates of the flat layout (for numbering and
        direction; default: the design's vertices projected on its plane).
    end_margin : float, optional
        Material beyond the outermost hole or free end, mm (default: half the
        strip's section width).
    to_mm : float
        Design units to mm.
    """
    from ..io.fabrication import flat_coordinates

    p = np.asarray(rest_lengths, float)
    if p.shape != (graph.num_segments,):
        raise InputError(f"rest lengths: expected {graph.num_segments} values (one per segment), got {p.size}")
    XY = flat_coordinates(graph.design.vertices, graph.layout_normal) if xy is None else np.asarray(xy, float)
    raw = []
    for b, steps in enumerate(graph.beams):
        verts = graph.beam_vertices(b)
        d = XY[verts[-1]] - XY[verts[0]]
        if graph.beam_closed[b] or np.linalg.norm(d) < 1e-12:  # a loop: its principal direction
            P = XY[verts] - XY[verts].mean(axis=0)
            d = np.linalg.eigh(P.T @ P)[1][:, -1]
        raw.append((b, "AB"[beam_family(graph, b)], steps, verts, d / np.linalg.norm(d)))
    beams = []
    for fam in "AB":
        members = [r for r in raw if r[1] == fam]
        axis = _family_axis(np.array([r[4] for r in members]).reshape(-1, 2))
        across = np.array([-axis[1], axis[0]])
        keyed = []
        for b, _, steps, verts, d in members:
            if d @ axis < 0:  # every beam of a family runs the same way
                steps, verts, d = steps[::-1], verts[::-1], -d
            c = XY[verts].mean(axis=0)
            keyed.append((round(float(c @ across), 9), round(float(c @ axis), 9), b, steps, verts, d))
        keyed.sort(key=lambda t: t[:3])
        width = max(2, len(str(len(keyed))))
        for i, (_, _, b, steps, verts, d) in enumerate(keyed):
            beams.append(_beam(graph, f"{fam}{i + 1:0{width}d}", fam, b, steps, verts, d, p, sections, end_margin, to_mm))
    return beams


def _beam(graph, label, fam, b, steps, verts, d, p, sections, end_margin, to_mm) -> Beam:
    segs = np.asarray(steps[:, 0], np.int64)
    s = np.concatenate([[0.0], np.cumsum(p[segs])]) * to_mm
    sec = sections[int(segs[0])]
    widths = {sections[int(x)].label for x in segs}
    if len(widths) > 1:  # a beam whose segments differ in section: named by all of them, sized by the widest
        sec = max((sections[int(x)] for x in segs), key=lambda q: q.width)
        sec = Section(" / ".join(sorted(widths)), sec.width, sec.depth)
    margin = 0.5 * sec.width if end_margin is None else float(end_margin)
    is_joint = graph.vertex_joint[verts] >= 0
    holes = np.flatnonzero(is_joint)
    return Beam(label=label, family=fam, index=int(b), vertices=np.asarray(verts, np.int64), segments=segs,
                hole_vertices=np.asarray(verts[holes], np.int64), hole_positions=margin + s[holes],
                length=float(s[-1] + 2 * margin), margin=margin, starts_free=not bool(is_joint[0]),
                ends_free=not bool(is_joint[-1]), closed=bool(graph.beam_closed[b]), section=sec,
                direction_deg=float(np.degrees(np.arctan2(d[1], d[0]))))


def joint_table(graph, beams: list[Beam], flat_angles, deployed_angles=None, top: str = "A") -> list[JointRow]:
    """One :class:`JointRow` per joint, in the graph's joint order (increasing vertex id).

    ``on_top`` is the beam of family ``top`` (A by default): the strips of one
    family form the upper layer everywhere, so every strip stays in one
    layer. The model has no offset between the layers (the paper's joints are
    points), so which family lies on top does not change the simulation.
    """
    label_of = {bm.index: bm.label for bm in beams}
    family_of = {bm.index: bm.family for bm in beams}
    flat = np.degrees(np.asarray(flat_angles, float))
    dep = None if deployed_angles is None else np.degrees(np.asarray(deployed_angles, float))
    rows = []
    for j, v in enumerate(graph.joint_vertex.tolist()):
        ab = []
        for slot in (0, 1):
            s = int(next(x for x in graph.joint_segments[j, slot] if x >= 0))
            ab.append(int(graph.beam_of_segment[s]))
        fams = [family_of[x] for x in ab]
        upper = ab[fams.index(top)] if fams.count(top) == 1 else ab[0]
        rows.append(JointRow(int(v), label_of[ab[0]], label_of[ab[1]], label_of[upper], float(flat[j]),
                             None if dep is None else float(dep[j])))
    return rows
