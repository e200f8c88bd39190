"""Graph analysis: valences, A/B beams at joints, beam tracing, DoF counts."""
from __future__ import annotations

import json
from pathlib import Path

import meshio
import numpy as np
import pytest

from xshells.errors import InputError
from xshells.io import design_from_arrays, read_design
from xshells.linkage.graph import BEAM_A, BEAM_B, analyze, reduced_dof_count

from data_paths import DATA, EXAMPLES, needs_data  # noqa: F401


def _linkage_files() -> list[Path]:
    found = [*EXAMPLES.rglob("*.obj"), *EXAMPLES.rglob("*.msh")]
    if DATA.is_dir():
        found += [*DATA.rglob("*.obj"), *DATA.rglob("*.msh")]
    # Cross-section contours, target surfaces and a triangle mesh (see test_io_design) are not linkages.
    return sorted(p for p in found if "cross_sections" not in p.parts and "targets" not in p.parts
                  and p.name != "target_surface_0.msh")


def _cross_section_files() -> list[Path]:
    return sorted((DATA / "examples" / "cross_sections").glob("*.[om][bs][jh]")) if DATA.is_dir() else []


def _check_invariants(g):
    d = g.design
    E = d.edges
    nj = g.num_joints
    assert g.num_joints + g.num_free_ends + len(g.unused_vertices) == d.num_vertices
    assert np.array_equal(g.valence[g.joint_vertex] >= 2, np.ones(nj, bool))
    # Every incident segment sits in exactly one slot of its joint.
    for j, v in enumerate(g.joint_vertex):
        slots = g.joint_segments[j]
        listed = sorted(int(s) for s in slots.ravel() if s >= 0)
        incident = sorted(np.flatnonzero((E[:, 0] == v) | (E[:, 1] == v)).tolist())
        assert listed == incident
        for beam in (BEAM_A, BEAM_B):
            assert np.any(slots[beam] >= 0)
            for slot in (0, 1):
                s = slots[beam, slot]
                assert g.joint_segment_points_away[j, beam, slot] == (s >= 0 and E[s, 0] == v)
    t = g.joint_tangents
    assert np.allclose(np.linalg.norm(t, axis=2), 1.0)
    assert np.allclose(np.linalg.norm(g.joint_normals, axis=1), 1.0)
    cross = np.cross(t[:, 0], t[:, 1])
    sine = np.linalg.norm(cross, axis=1)
    ok = sine > 1e-6
    assert np.allclose(cross[ok] / sine[ok, None], g.joint_normals[ok])
    assert np.allclose(np.cos(g.joint_opening_angles), np.einsum("ji,ji->j", t[:, 0], t[:, 1]))
    if g.is_planar:  # a flat layout: all joint normals agree with the plane's
        assert np.allclose(np.abs(g.joint_normals @ g.layout_normal), 1.0)
        assert np.all(g.joint_normals @ g.joint_normals[0] > 0)
    # Beams partition the segments and are connected walks.
    steps = np.concatenate(g.beams)
    assert sorted(steps[:, 0].tolist()) == list(range(d.num_segments))
    for b in range(g.num_beams):
        verts = g.beam_vertices(b)
        seg, direction = g.beams[b][:, 0], g.beams[b][:, 1]
        assert np.array_equal(np.where(direction > 0, E[seg, 0], E[seg, 1]), verts[:-1])
        assert g.beam_closed[b] == (verts[0] == verts[-1] and len(seg) > 2)


@pytest.mark.parametrize("path", _linkage_files(), ids=lambda p: p.name[:40])
def test_every_linkage_analyzes(path):
    g = analyze(read_design(path))
    _check_invariants(g)
    assert g.num_joints > 0
    assert f"segments: {g.num_segments}" in g.summary()


@needs_data
@pytest.mark.parametrize("path", _cross_section_files(), ids=lambda p: p.name)
def test_cross_section_contours_are_not_linkages(path):
    # Profile outlines, not beam networks: several separate loops.
    with pytest.raises(InputError, match=r"disconnected design with \d+ components: \d+ nodes incl\. node") as err:
        analyze(read_design(path))
    assert str(path) in str(err.value) and "\n" not in str(err.value)


@needs_data
@pytest.mark.parametrize("path", sorted(DATA.rglob("*_opt.msh")) + sorted(DATA.rglob("linkage_0.msh"))
                         if DATA.is_dir() else [], ids=lambda p: "/".join(p.parts[-2:]))
def test_beam_pairing_matches_reference_joint_edges(path):
    """The reference code stored each joint's edge vectors eA, eB and normal n in these files.

    Our pairing must group the same segments (eA along one of our beams, eB
    along the other) with the same A/B labels up to one global exchange, and
    the normals must agree up to one global sign.
    """
    mesh = meshio.read(path)
    g = analyze(read_design(path))
    ref = {k: mesh.point_data[k][g.joint_vertex] for k in ("eA", "eB", "n")}
    eA, eB = (ref[k] / np.linalg.norm(ref[k], axis=1, keepdims=True) for k in ("eA", "eB"))
    tA, tB = g.joint_tangents[:, 0], g.joint_tangents[:, 1]
    same = np.abs(np.sum(tA * eA, 1)) + np.abs(np.sum(tB * eB, 1))
    swapped = np.abs(np.sum(tA * eB, 1)) + np.abs(np.sum(tB * eA, 1))
    assert np.all(same > swapped) or np.all(swapped > same)
    assert np.min(np.maximum(same, swapped)) > 2 * 0.99
    signs = np.sign(np.sum(g.joint_normals * ref["n"], axis=1))
    assert np.all(signs == signs[0])


# ---------------------------------------------------------------- hand-made joints

def _star(directions, order=None):
    """A joint at the origin with unit spokes, edges listed in ``order``."""
    pts = [[0.0, 0.0, 0.0]] + [[np.cos(a), np.sin(a), 0.0] for a in np.radians(directions)]
    order = range(len(directions)) if order is None else order
    return design_from_arrays(pts, [[0, i + 1] for i in order])


def _pairs(g, j=0):
    return [sorted(int(s) for s in g.joint_segments[j, beam] if s >= 0) for beam in (BEAM_A, BEAM_B)]


def test_valence4_pairs_most_nearly_opposite_edges():
    # Spokes listed E, N, W, S: naive pairing by file order would be wrong.
    g = analyze(_star([0, 90, 180, 270]))
    assert sorted(_pairs(g)) == [[0, 2], [1, 3]]
    # A skewed X with 50 degree opening, spokes in scrambled file order.
    g = analyze(_star([0, 50, 180, 230], order=[3, 0, 1, 2]))  # edge i goes to spoke order[i]
    # edges: 0 -> 230deg, 1 -> 0deg, 2 -> 50deg, 3 -> 180deg
    assert sorted(_pairs(g)) == [[0, 2], [1, 3]]
    assert np.isclose(min(g.joint_opening_angles[0], np.pi - g.joint_opening_angles[0]), np.radians(50))
    # Not exactly opposite: the best matching still wins.
    g = analyze(_star([0, 80, 170, 275]))
    assert sorted(_pairs(g)) == [[0, 2], [1, 3]]
    assert g.num_beams == 2 and g.num_free_ends == 4 and g.num_joints == 1


def test_valence3_straightest_pair_is_one_beam():
    g = analyze(_star([0, 100, 175]))
    a, b = _pairs(g)
    assert sorted([a, b], key=len) == [[1], [0, 2]]
    assert g.num_beams == 2


def test_valence3_avoids_closing_a_triangle():
    # v's spokes a (west) and b (almost east) are straightest, but a and b
    # share the neighbour w, so joining them would close a triangle.
    pts = [[0, 0, 0], [-1, 0, 0], [1, 0.2, 0], [0, 1, 0], [0, -1, 0]]  # v a b c w
    d = design_from_arrays(pts, [[0, 1], [0, 2], [0, 3], [1, 4], [2, 4]])
    g = analyze(d)
    j = int(g.vertex_joint[0])
    assert sorted(_pairs(g, j), key=len) == [[1], [0, 2]]  # beam a-v-c, b ends at v


def test_valence2_corner_is_two_beams():
    d = design_from_arrays([[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 1], [1, 2]])
    g = analyze(d)
    assert g.num_joints == 1 and g.num_free_ends == 2 and g.num_beams == 2
    assert sorted(_pairs(g), key=len) == [[0], [1]]
    assert np.isclose(g.joint_opening_angles[0], np.pi / 2)


def test_quad_of_corners():
    g = analyze(read_design(EXAMPLES / "quad.obj"))
    assert g.num_joints == 4 and g.num_free_ends == 0
    assert g.num_beams == 4 and not g.beam_closed.any()  # a rod ends at every corner


def test_unused_vertex_is_kept_but_ignored():
    d = design_from_arrays([[0, 0, 0], [1, 0, 0], [5, 5, 5], [1, 1, 0]], [[0, 1], [1, 3]])
    g = analyze(d)
    assert g.unused_vertices.tolist() == [2]
    assert g.vertex_joint[2] == -1 and 2 not in g.free_end_vertex
    assert g.is_planar


def test_closed_beams_are_detected():
    # An octagonal ring crossed at each vertex by a short radial beam: the
    # ring passes through every joint, so it is one closed beam.
    n = 8
    ring = [[np.cos(a), np.sin(a), 0.0] for a in 2 * np.pi * np.arange(n) / n]
    inner = [[0.5 * x, 0.5 * y, 0.0] for x, y, _ in ring]
    outer = [[1.5 * x, 1.5 * y, 0.0] for x, y, _ in ring]
    edges = [[i, (i + 1) % n] for i in range(n)] + [[n + i, i] for i in range(n)] + [[i, 2 * n + i] for i in range(n)]
    g = analyze(design_from_arrays(ring + inner + outer, edges))
    assert g.beam_closed.sum() == 1
    closed = g.beams[int(np.flatnonzero(g.beam_closed)[0])]
    assert sorted(closed[:, 0].tolist()) == list(range(n))
    assert g.num_beams == 1 + n  # the ring plus one radial beam per crossing
    _check_invariants(g)


# ---------------------------------------------------------------- errors

def test_valence_above_four_names_the_node(tmp_path):
    path = tmp_path / "star.obj"
    path.write_text("v 0 0 0\n" + "".join(f"v {np.cos(a)} {np.sin(a)} 0\n" for a in np.arange(5))
                    + "".join(f"l 1 {i + 2}\n" for i in range(5)))
    with pytest.raises(InputError, match=r"star\.obj: node 0 \(line 1\) has valence 5") as err:
        analyze(read_design(path))
    assert "\n" not in str(err.value)


def test_overlapping_segments_at_a_joint_are_named(tmp_path):
    # Found by the deploy fuzz test: nodes 1 and 3 coincide, so two segments of the X lie on top of
    # each other and the beam through them folds back (it was an internal error in the joint frames).
    # Coincident nodes are now named as such first (below); here node 3 lies halfway along node 1's segment.
    path = tmp_path / "x.obj"
    path.write_text("v 0 0 0\nv 0 100 0\nv 100 100 0\nv 25 75 0\nv 50 50 0\nl 1 5\nl 5 3\nl 2 5\nl 5 4\n")
    with pytest.raises(InputError, match=r"x\.obj: node 4 \(line 5\): its segments to node 1 \(line 2\) and "
                                         r"node 3 \(line 4\) overlap") as err:
        analyze(read_design(path))
    assert "\n" not in str(err.value)


def test_two_nodes_at_the_same_position_are_named(tmp_path):
    """Two joints drawn on top of each other look like one, but the beams there are not joined: the
    linkage failed with "joint at vertex 24node 24 (line 25): its two beams are parallel" (dupjoint.obj),
    or with two overlapping segments at a neighbour. The real cause is named: merge the two nodes."""
    path = tmp_path / "x.obj"
    path.write_text("v 0 0 0\nv 0 100 0\nv 100 100 0\nv 0 100 0\nv 50 50 0\nl 1 5\nl 5 3\nl 2 5\nl 5 4\n")
    with pytest.raises(InputError, match=r"^\S*x\.obj: node 1 \(line 2\) and node 3 \(line 4\) are at the same "
                                         r"position \(0\.0, 100\.0, 0\.0\): merge them") as err:
        analyze(read_design(path))
    assert "\n" not in str(err.value)
    # within round-off of the design's size, in any units; an unused duplicate is harmless
    path.write_text("v 0 0 0\nv 0 1e5 0\nv 1e5 1e5 0\nv 1e-9 100000.0000000001 0\nv 5e4 5e4 0\nv 0 0 0\n"
                    "l 1 5\nl 5 3\nl 2 5\nl 5 4\n")
    with pytest.raises(InputError, match=r"node 1 \(line 2\) and node 3 \(line 4\) are at the same position"):
        analyze(read_design(path))
    path.write_text("v 0 0 0\nv 0 100 0\nv 100 100 0\nv 100 0 0\nv 50 50 0\nv 0 0 0\nl 1 5\nl 5 3\nl 2 5\nl 5 4\n")
    assert analyze(read_design(path)).num_joints == 1


def test_disconnected_design_names_components(tmp_path):
    path = tmp_path / "two.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 5 5 0\nv 6 5 0\nv 6 6 0\nv 9 9 9\nl 1 2 3\nl 4 5 6\n")
    with pytest.raises(InputError) as err:
        analyze(read_design(path))
    msg = str(err.value)
    assert "two.obj: disconnected design with 2 components" in msg
    assert "3 nodes incl. node 0 (line 1)" in msg and "3 nodes incl. node 3 (line 4)" in msg


def _grid_with_diagonal():
    """A 4 × 4 lattice of unit cells, and a segment across it from corner to corner without joints."""
    xs, ys = np.meshgrid(np.arange(5.0), np.arange(5.0), indexing="ij")
    V = np.c_[xs.ravel(), ys.ravel(), np.zeros(25)]
    idx = np.arange(25).reshape(5, 5)
    E = [(idx[i, j], idx[i + 1, j]) for i in range(4) for j in range(5)] + \
        [(idx[i, j], idx[i, j + 1]) for i in range(5) for j in range(4)]
    return V, E, (idx[0, 1], idx[1, 4])


def test_segments_crossing_without_a_joint_are_named():
    """No contact is modelled: such beams pass through each other. Said (it deployed with "reached the
    target angle" and nothing else), not refused: a layered design crosses so by intent."""
    V, E, diagonal = _grid_with_diagonal()
    assert analyze(design_from_arrays(V, E)).crossings == ""  # segments meeting at shared nodes only
    g = analyze(design_from_arrays(V, E + [diagonal], "x.obj"))
    # from (0, 1) to (1, 4): across the segments x = 0..1 at y = 2 and y = 3 (the lattice's 2 x-segments there)
    assert g.crossings.startswith("edge 40 (between ") and "crosses edge " in g.crossings
    assert "without a joint (1 more such crossing)" in g.crossings and "no contact is modelled" in g.crossings


def test_a_segment_ending_on_another_without_a_node_is_named():
    """A T drawn with one end on another beam's segment, that beam not split there: the drawing shows a
    connection, the model leaves the end free (it deployed with "reached the target angle" and no word)."""
    V, E, _ = _grid_with_diagonal()
    # a stub from node 1 at (0, 1) to node 25 at (0.5, 2), the middle of the segment from (0, 2) to (1, 2)
    V = np.vstack([V, [[0.5, 2.0, 0.0]]])
    g = analyze(design_from_arrays(V, E + [(1, 25)], "t.obj"))
    assert g.crossings.startswith("edge 40 ends at node 25 on edge ") and "not connected, that end is free" in g.crossings
    # a gap of a hundredth of the segment is a gap, not a touch
    V[25] = [0.5, 1.99, 0.0]
    assert analyze(design_from_arrays(V, E + [(1, 25)], "t.obj")).crossings == ""


def test_a_joint_beside_a_segment_is_not_a_free_end_on_it():
    """A 0.1-long rung between two columns of 100-long segments puts the rung's far joint 0.1 from the
    near column's horizontal segment, within the tolerance: it was warned "that end is free", but the
    node is a valence-4 joint. Only a free end (valence 1) can be a T's loose leg."""
    xs, ys = [0.0, 100.0, 100.1, 200.0, 300.0], [0.0, 100.0, 200.0, 300.0, 400.0]
    V = np.array([(x, y, 0.0) for x in xs for y in ys])
    idx = np.arange(25).reshape(5, 5)
    E = [(idx[i, j], idx[i + 1, j]) for i in range(4) for j in range(5)] + \
        [(idx[i, j], idx[i, j + 1]) for i in range(5) for j in range(4)]
    g = analyze(design_from_arrays(V, E, "shortseg.obj"))
    assert g.valence[idx[2, 1]] == 4 and g.crossings == ""


def _polyline_grid(bends: int, sag: float):
    """A 3 x 3 grid of joints whose segments are each drawn as a polyline of ``bends`` nodes on a shallow arc."""
    V, E, index = [], [], {}

    def node(p):
        key = tuple(np.round(p, 9))
        if key not in index:
            index[key] = len(V)
            V.append([*p, 0.0])
        return index[key]

    for i in range(3):
        for j in range(3):
            for di, dj in ((1, 0), (0, 1)):
                if i + di > 2 or j + dj > 2:
                    continue
                a, b = np.array([i, j], float), np.array([i + di, j + dj], float)
                normal = np.array([-(b - a)[1], (b - a)[0]])
                ts = np.linspace(0.0, 1.0, bends + 2)
                points = [a + t * (b - a) + sag * 4 * t * (1 - t) * normal for t in ts]
                ids = [node(p) for p in points]
                E += list(zip(ids[:-1], ids[1:]))
    return np.array(V), E


def test_a_beam_drawn_as_a_polyline_is_said_to_hinge_at_its_bends():
    """A node of valence 2 is a hinge where two beams end: a curved beam drawn as a polyline (rad7_poly.obj)
    became hinges at every bend, and the user heard only of an inversion when the deployment started."""
    V, E = _polyline_grid(2, 0.05)
    g = analyze(design_from_arrays(V, E, "poly.obj"))
    assert g.bends.startswith("poly.obj: node 1 and 23 more nodes of valence 2 join two segments nearly in line (")
    assert "such a node is a hinge where two beams end, not a bend along one beam" in g.bends
    # one bend per segment: no run of bends, but more of them than joints of valence 3 and 4 (4 + 1 here)
    V, E = _polyline_grid(1, 0.02)
    assert "and 11 more nodes of valence 2" in analyze(design_from_arrays(V, E, "poly.obj")).bends
    # the corners of a plain grid (valence 2, at right angles) and the quad of four corners are hinges by intent
    V, E = _polyline_grid(0, 0.0)
    assert analyze(design_from_arrays(V, E)).bends == ""
    assert analyze(read_design(EXAMPLES / "quad.obj")).bends == ""


@needs_data
def test_no_paper_design_is_said_to_bend_at_a_hinge():
    for case in json.loads((DATA / "cases.json").read_text())["cases"]:
        g = analyze(read_design(DATA / (case.get("flat_file") or case["file"])))
        assert g.bends == "", (case["name"], g.bends)


@needs_data
def test_no_paper_design_has_an_end_on_another_segment():
    for case in json.loads((DATA / "cases.json").read_text())["cases"]:
        g = analyze(read_design(DATA / (case.get("flat_file") or case["file"])))
        assert " ends at " not in g.crossings, (case["name"], g.crossings)


@needs_data
def test_the_papers_layered_design_is_analyzed_with_its_crossings_named():
    case = next(c for c in json.loads((DATA / "cases.json").read_text())["cases"] if c["name"] == "two_layer_two_bump")
    g = analyze(read_design(DATA / case["file"]))
    assert g.is_planar and "106 more such crossings" in g.crossings


def test_design_without_joint():
    with pytest.raises(InputError, match="no joint"):
        analyze(design_from_arrays([[0, 0, 0], [1, 0, 0]], [[0, 1]]))


# ---------------------------------------------------------------- beams

def test_uniform_grid_beams_are_straight_lines():
    d = read_design(EXAMPLES / "uniform_linkage.obj")
    g = analyze(d)
    _check_invariants(g)
    V = d.vertices
    for b in range(g.num_beams):
        pts = V[g.beam_vertices(b)]
        direction = pts[-1] - pts[0]
        off = np.cross(pts - pts[0], direction / np.linalg.norm(direction))
        assert np.allclose(off, 0.0, atol=1e-5 * np.linalg.norm(direction)), f"beam {b} is not straight"
    # Independently: the number of distinct lines carrying segments.
    E = d.edges
    u = V[E[:, 1]] - V[E[:, 0]]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u *= np.where((u[:, 0] < -1e-9) | ((np.abs(u[:, 0]) <= 1e-9) & (u[:, 1] < 0)), -1, 1)[:, None]
    offset = V[E[:, 0], 0] * u[:, 1] - V[E[:, 0], 1] * u[:, 0]
    num_lines = 0
    for direction in np.unique(np.round(u[:, :2], 2), axis=0):
        on = np.all(np.isclose(u[:, :2], direction, atol=0.01), axis=1)
        gaps = np.diff(np.sort(offset[on]))
        num_lines += 1 + int(np.count_nonzero(gaps > 1e-3))
    assert g.num_beams == num_lines == 26
    assert g.labels_consistent and not g.beam_closed.any()


# ---------------------------------------------------------------- DoF

def _enumerated_dof(g, k):
    """Count free rod variables one by one (independently of the closed formula)."""
    total = 9 * g.num_joints
    for start_joint, end_joint in g.segment_joints:
        free_vertices = set(range(k + 1))
        free_angles = set(range(k))
        if start_joint >= 0:
            free_vertices -= {0, 1}
            free_angles -= {0}
        if end_joint >= 0:
            free_vertices -= {k - 1, k}
            free_angles -= {k - 1}
        total += 3 * len(free_vertices) + len(free_angles)
    return total


def test_dof_formula_small_cases():
    assert reduced_dof_count(1, [2], 10) == 9 + 29
    assert reduced_dof_count(1, [1], 10) == 9 + 36
    assert reduced_dof_count(146, [2] * 264, 10) == 8970
    with pytest.raises(InputError, match="at least 3"):
        reduced_dof_count(1, [2], 2)


def _cases():
    if not DATA.is_dir():
        return []
    return json.loads((DATA / "cases.json").read_text())["cases"]


@needs_data
@pytest.mark.parametrize("case", _cases(), ids=lambda c: c["name"])
def test_dof_formula_on_cases(case):
    g = analyze(read_design(DATA / case["file"]))
    for k in sorted({3, 10, case.get("subdivision", 10)}):
        assert g.dof(k) == _enumerated_dof(g, k)
    if g.num_free_ends == 0:
        assert g.dof(10) == 29 * g.num_segments + 9 * g.num_joints


@needs_data
def test_dof_matches_paper_table_1():
    table = json.loads((DATA / "cases.json").read_text())["paper_table_1"]
    sizes = {}
    for case in _cases():
        g = analyze(read_design(DATA / case["file"]))
        sizes[(g.num_segments, g.num_joints)] = g
    for row in table:
        g = sizes.get((row["segments"], row["joints"]))
        assert g is not None, f"{row['figure']}: no case with {row['segments']} segments, {row['joints']} joints"
        assert g.dof(10) == row["dof"], row["figure"]


def _pentagon_beams(r: float = 500.0):
    """Five beams along a pentagon's sides, each past its two corners: a five-sided cell, no triangle."""
    ang = np.pi / 2 + 2 * np.pi * np.arange(5) / 5
    C = r * np.c_[np.cos(ang), np.sin(ang)]
    P, E = [*C], []
    for i in range(5):
        a, b = C[i], C[(i + 1) % 5]
        P += [a - 0.3 * (b - a), b + 0.3 * (b - a)]
        E += [(5 + 2 * i, i), (i, (i + 1) % 5), ((i + 1) % 5, 6 + 2 * i)]
    return np.c_[np.array(P), np.zeros(len(P))], np.array(E)


def test_beam_families_split_a_grid_and_refuse_an_odd_cell():
    from xshells.linkage.graph import beam_families

    P, E = _pentagon_beams()
    g = analyze(design_from_arrays(P, E, source="pentagon"))
    family, conflict = beam_families(g)
    assert conflict in range(5)  # every joint of the pentagon is one
    # a 3 x 4 grid of beams: two families, each joint's beams in different ones
    xs, ys = np.arange(4) * 100.0, np.arange(3) * 100.0
    pts = [(x, y) for x in xs for y in ys]
    idx = {p: i for i, p in enumerate(pts)}
    E = [(idx[(x, y)], idx[(x, y + 100.0)]) for x in xs for y in ys[:-1]] + \
        [(idx[(x, y)], idx[(x + 100.0, y)]) for x in xs[:-1] for y in ys]
    g = analyze(design_from_arrays(np.c_[np.array(pts), np.zeros(len(pts))], np.array(E), source="grid"))
    family, conflict = beam_families(g)
    assert conflict == -1 and sorted(np.bincount(family)) == [3, 4]
    for j in range(len(g.joint_vertex)):
        a, b = g.joint_segments[j, 0], g.joint_segments[j, 1]
        if (a >= 0).any() and (b >= 0).any():
            assert family[g.beam_of_segment[a[a >= 0][0]]] != family[g.beam_of_segment[b[b >= 0][0]]]


@needs_data
@pytest.mark.parametrize("path", _linkage_files(), ids=lambda p: p.name)
def test_every_bundled_design_splits_into_two_families(path):
    from xshells.linkage.graph import beam_families

    assert beam_families(analyze(read_design(path)))[1] == -1
