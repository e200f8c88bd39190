"""Beams of a design: tracing, holes, cut lengths and margins on tiny hand-computed designs and the bundled ones."""
import numpy as np
import pytest

from data_paths import EXAMPLES
from xshells.errors import InputError
from xshells.fabrication import beam_sections, joint_table, trace_beams, units_to_mm
from xshells.io import read_design, read_rest_lengths
from xshells.io.design import Design
from xshells.linkage.graph import analyze
from xshells.section import Material

MAT = Material.uniform("rectangle", [10, 7], E=20000, nu=0.3)


def _plan(V, E, p, margin=None):
    g = analyze(Design(np.asarray(V, float), np.asarray(E)))
    return g, trace_beams(g, p, beam_sections(MAT, g.num_segments), end_margin=margin)


def _grid_with_free_ends():
    """Two A rods (y = 0, 1) and two B rods (x = 0, 1), each free - joint - joint - free; rods 3 long."""
    V = [[-1, 0, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0], [-1, 1, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0],
         [0, -1, 0], [0, 2, 0], [1, -1, 0], [1, 2, 0]]
    E = [[0, 1], [1, 2], [2, 3], [4, 5], [5, 6], [6, 7], [8, 1], [1, 5], [5, 9], [10, 2], [2, 6], [6, 11]]
    return np.array(V, float) * 100, E


def test_free_ends_get_the_free_segment_and_the_margin_beyond_the_outermost_hole():
    V, E = _grid_with_free_ends()
    p = np.array([90.0, 101.0, 80.0, 95.0, 99.0, 85.0, 70.0, 102.0, 60.0, 75.0, 98.0, 65.0])
    g, beams = _plan(V, E, p, margin=4.0)
    assert [b.label for b in beams] == ["A01", "A02", "B01", "B02"]
    by_first = {tuple(b.hole_vertices): b for b in beams}
    a = by_first[(1, 2)]  # the rod at y = 0, walked along +x from its free end at x = -1
    np.testing.assert_allclose(a.hole_positions, [4 + 90, 4 + 90 + 101])
    assert a.length == pytest.approx(90 + 101 + 80 + 8)
    assert a.starts_free and a.ends_free and not a.closed
    b = by_first[(2, 6)]  # the rod at x = 1, along +y: 10 -> 2 -> 6 -> 11
    np.testing.assert_allclose(b.hole_positions, [4 + 75, 4 + 75 + 98])
    assert b.length == pytest.approx(75 + 98 + 65 + 8)
    rows = joint_table(g, beams, g.joint_opening_angles)
    assert len(rows) == 4 and all(r.on_top.startswith("A") for r in rows)
    assert {(r.beam_a[0], r.beam_b[0]) for r in rows} == {("A", "B")}
    np.testing.assert_allclose([r.flat_angle_deg for r in rows], 90.0)


def test_default_margin_is_half_the_section_width():
    V, E = _grid_with_free_ends()
    _, beams = _plan(V, E, np.full(12, 100.0))
    assert all(b.margin == 5.0 and b.length == pytest.approx(310.0) for b in beams)


def test_valence_two_corners_end_two_beams_with_a_hole_each():
    """A quad: four corners of valence 2, so four one-segment beams, a hole at each end."""
    V = [[0, 0, 0], [300, 0, 0], [300, 200, 0], [0, 200, 0]]
    E = [[0, 1], [1, 2], [2, 3], [3, 0]]
    p = np.array([301.0, 199.0, 302.0, 198.0])
    g, beams = _plan(V, E, p, margin=6.0)
    assert len(beams) == 4 and sorted(b.family for b in beams) == ["A", "A", "B", "B"]
    for b in beams:
        s = int(b.segments[0])
        assert len(b.hole_positions) == 2 and not (b.starts_free or b.ends_free)
        np.testing.assert_allclose(b.hole_positions, [6.0, 6.0 + p[s]])
        assert b.length == pytest.approx(p[s] + 12.0)
    rows = joint_table(g, beams, g.joint_opening_angles)
    assert all(r.beam_a != r.beam_b for r in rows)


def test_valence_three_joints_end_the_rungs_of_a_ladder():
    """Two long rails through valence-3 joints, three rungs ending at them."""
    V = [[0, 0, 0], [100, 0, 0], [200, 0, 0], [0, 100, 0], [100, 100, 0], [200, 100, 0]]
    E = [[0, 1], [1, 2], [3, 4], [4, 5], [0, 3], [1, 4], [2, 5]]
    p = np.array([100.0, 101.0, 99.0, 102.0, 98.0, 97.0, 96.0])
    _, beams = _plan(V, E, p, margin=5.0)
    lengths = sorted(round(b.length, 6) for b in beams)
    assert lengths == sorted([201.0 + 10, 201.0 + 10, 98.0 + 10, 97.0 + 10, 96.0 + 10])
    rails = [b for b in beams if len(b.hole_positions) == 3]
    assert len(rails) == 2 and len({b.family for b in rails}) == 1


def test_a_closed_ring_is_cut_open_at_one_joint_listed_at_both_ends():
    n = 8
    ang = 2 * np.pi * np.arange(n) / n
    ring = np.c_[np.cos(ang), np.sin(ang), 0 * ang] * 200
    spokes = np.c_[np.cos(ang), np.sin(ang), 0 * ang] * 320
    V = np.vstack([ring, spokes])
    E = [[i, (i + 1) % n] for i in range(n)] + [[i, n + i] for i in range(n)]
    p = np.linalg.norm(V[np.array(E)[:, 1]] - V[np.array(E)[:, 0]], axis=1)
    _, beams = _plan(V, E, p, margin=5.0)
    loop = [b for b in beams if b.closed]
    assert len(loop) == 1
    b = loop[0]
    assert b.hole_vertices[0] == b.hole_vertices[-1] and len(b.hole_vertices) == n + 1
    assert b.length == pytest.approx(p[:n].sum() + 10.0)


def test_real_designs_every_joint_on_two_beams_and_holes_spaced_by_rest_lengths():
    for design, rl in ((EXAMPLES / "manta_ray.obj", None),
                       (EXAMPLES / "asymm_wings_pointy" / "flat_opt.msh", EXAMPLES / "asymm_wings_pointy" / "design_parameters.txt")):
        d = read_design(design)
        p = read_rest_lengths(rl, d.num_segments) if rl else np.linalg.norm(np.diff(d.vertices[d.edges], axis=1)[:, 0], axis=1)
        g = analyze(d)
        beams = trace_beams(g, p, beam_sections(MAT, g.num_segments))
        count = np.zeros(d.num_vertices, int)
        for b in beams:
            for v in set(b.hole_vertices.tolist()):
                count[v] += 1
            between = np.diff(b.hole_positions)
            np.testing.assert_allclose(between.sum(), p[b.segments].sum()
                                       - (p[b.segments[0]] if b.starts_free else 0) - (p[b.segments[-1]] if b.ends_free else 0))
        assert np.all(count[g.joint_vertex] == 2)


def test_labels_number_each_family_across_the_layout():
    """Every beam of a family runs the same way; numbers increase across the family's direction."""
    V, E = _grid_with_free_ends()
    _, beams = _plan(V, E, np.full(12, 100.0))
    for fam in "AB":
        mine = [b for b in beams if b.family == fam]
        assert [b.label for b in mine] == [f"{fam}01", f"{fam}02"]
        assert mine[0].direction_deg == pytest.approx(mine[1].direction_deg)
        t = np.radians(mine[0].direction_deg)
        across = np.array([-np.sin(t), np.cos(t)])
        c = [V[b.vertices][:, :2].mean(axis=0) @ across for b in mine]
        assert c[0] < c[1]


def test_units_and_bad_rest_lengths():
    assert units_to_mm("m") == 1000.0 and units_to_mm("IN") == 25.4
    with pytest.raises(InputError, match="unknown unit"):
        units_to_mm("furlong")
    V, E = _grid_with_free_ends()
    with pytest.raises(InputError, match="expected 12 values"):
        _plan(V, E, np.ones(5))


def test_an_odd_cycle_of_beams_warns_that_one_family_cannot_lie_on_top():
    # three lines crossing pairwise: two of the three joints can alternate families, the third cannot; the joint
    # table listed its first beam as on top without a word
    from xshells.fabrication import fabrication_plan

    V = [[0, 0, 0], [1000, 0, 0], [500, 800, 0], [-200, 0, 0], [1200, 0, 0], [1106, -169.6, 0], [394, 969.6, 0],
         [606, 969.6, 0], [-106, -169.6, 0]]
    E = [[3, 0], [0, 1], [1, 4], [5, 1], [1, 2], [2, 6], [7, 2], [2, 0], [0, 8]]
    g = analyze(Design(np.asarray(V, float), np.asarray(E)))
    p = np.linalg.norm(np.diff(np.asarray(V, float)[E], axis=1)[:, 0], axis=1)
    plan = fabrication_plan(g, p, MAT)
    family = {b.label: b.family for b in plan.beams}
    same = [r.joint for r in plan.joints if family[r.beam_a] == family[r.beam_b]]
    assert len(same) == 1
    (w,) = [w for w in plan.warnings if "cannot be layered" in w]
    assert f"at 1 of 3 joints both strips are of one family (joint {same[0]}:" in w and "\n" not in w
    assert plan.bill_of_materials()["warnings"] == [w]
    V, E = _grid_with_free_ends()  # a grid alternates everywhere: no warning
    g = analyze(Design(np.asarray(V, float), np.asarray(E)))
    p = np.linalg.norm(np.diff(np.asarray(V, float)[np.asarray(E)], axis=1)[:, 0], axis=1)
    assert fabrication_plan(g, p, MAT).warnings == ()
