"""Swept beam surfaces: closedness, orientation, volume, fields and file round trips."""
import os
from collections import Counter

import meshio
import numpy as np
import pytest

from xshells.io.sweep import (enclosed_volume, outer_loop, ply_property_names,
                              swept_beam_mesh, triangulate_polygon, write_obj, write_ply)

RECT = np.array([[-5.0, -3.5], [5.0, -3.5], [5.0, 3.5], [-5.0, 3.5]])
# An I profile: non-convex, so a naive fan would cap it wrongly.
I_BEAM = np.array([[-5, -5], [5, -5], [5, -4], [0.5, -4], [0.5, 4], [5, 4], [5, 5],
                   [-5, 5], [-5, 4], [-0.5, 4], [-0.5, -4], [-5, -4]], dtype=float)
I_AREA = 2 * 10 * 1 + 1 * 8


def straight_rod(n=6, length=30.0):
    """Points along z with m1 = x, m2 = y; returns points, m1, m2."""
    z = np.linspace(0.0, length, n + 1)
    pts = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    return pts, np.tile([1.0, 0, 0], (n, 1)), np.tile([0, 1.0, 0], (n, 1))


def bent_rod(n=12, radius=40.0, twist=1.3):
    """A helix-like arc with twisted directors."""
    s = np.linspace(0, 1.5, n + 1)
    pts = np.column_stack([radius * np.cos(s), radius * np.sin(s), 5 * s])
    t = np.diff(pts, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    ref = np.cross(t, [0, 0, 1.0])
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    other = np.cross(t, ref)
    th = twist * np.linspace(0, 1, n)[:, None]
    m1 = np.cos(th) * ref + np.sin(th) * other
    return pts, m1, np.cross(t, m1)


def edge_uses(triangles):
    """How many times each undirected edge appears, and each directed edge."""
    directed = Counter()
    for a, b, c in triangles.tolist():
        directed.update([(a, b), (b, c), (c, a)])
    undirected = Counter()
    for (a, b), n in directed.items():
        undirected[(min(a, b), max(a, b))] += n
    return undirected, directed


def assert_closed_and_oriented(mesh):
    undirected, directed = edge_uses(mesh.triangles)
    assert set(undirected.values()) == {2}
    # Consistent orientation: each edge is traversed once in each direction.
    assert set(directed.values()) == {1}


def test_straight_rectangle_is_closed_box_with_exact_volume():
    pts, m1, m2 = straight_rod()
    mesh = swept_beam_mesh(pts, [6], m1, m2, RECT)
    assert mesh.vertices.shape == (7 * 4, 3)
    assert mesh.triangles.shape == (6 * 4 * 2 + 2 * 2, 3)
    assert_closed_and_oriented(mesh)
    vol = enclosed_volume(mesh.vertices, mesh.triangles)
    assert vol > 0
    assert vol == pytest.approx(70.0 * 30.0, rel=1e-12)
    # x along m1 (world x), y along m2 (world y).
    assert np.allclose(mesh.vertices[:4, :2], RECT)


@pytest.mark.parametrize("flip_outline", [False, True])
@pytest.mark.parametrize("left_handed", [False, True])
def test_orientation_independent_of_outline_and_frame_handedness(flip_outline, left_handed):
    pts, m1, m2 = straight_rod()
    outline = RECT[::-1] if flip_outline else RECT
    if left_handed:
        m2 = -m2
    mesh = swept_beam_mesh(pts, [6], m1, m2, outline)
    assert_closed_and_oriented(mesh)
    assert enclosed_volume(mesh.vertices, mesh.triangles) == pytest.approx(2100.0, rel=1e-12)


def test_non_convex_outline_caps_exactly():
    pts, m1, m2 = straight_rod(n=3, length=12.0)
    mesh = swept_beam_mesh(pts, [3], m1, m2, [I_BEAM])
    assert_closed_and_oriented(mesh)
    assert enclosed_volume(mesh.vertices, mesh.triangles) == pytest.approx(I_AREA * 12.0, rel=1e-12)


def test_triangulation_covers_polygon_with_ccw_triangles():
    # Collinear points on the edges must not create T-junctions.
    poly = np.array([[0, 0], [1, 0], [2, 0], [2, 1], [2, 2], [1, 2], [0, 2], [0, 1]], float)
    tri = triangulate_polygon(poly)
    assert tri.shape == (6, 3)
    a, b, c = (poly[tri[:, i]] for i in range(3))
    areas = 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    assert np.all(areas >= 0) and areas.sum() == pytest.approx(4.0)
    boundary = {(i, (i + 1) % 8) for i in range(8)}
    directed = {(t[i], t[(i + 1) % 3]) for t in tri.tolist() for i in range(3)}
    assert boundary <= directed


def test_outer_loop_picks_largest_and_makes_it_ccw():
    hole = 0.5 * RECT[::-1]
    loop = outer_loop([hole, RECT[::-1]])
    assert np.array_equal(loop, RECT)


def test_section_material_outline_is_accepted():
    from xshells.section import Material
    outline = Material.uniform("rectangle", [10, 7], E=2e4, nu=0.3).outline
    pts, m1, m2 = straight_rod()
    mesh = swept_beam_mesh(pts, [6], m1, m2, outline)
    assert enclosed_volume(mesh.vertices, mesh.triangles) == pytest.approx(2100.0, rel=1e-12)


def test_bent_rods_are_finite_closed_and_fields_copied():
    p1, a1, b1 = bent_rod()
    p2, a2, b2 = straight_rod(n=4)
    pts = np.concatenate([p1, p2])
    m1, m2 = np.concatenate([a1, a2]), np.concatenate([b1, b2])
    energy = np.arange(len(pts), dtype=float) ** 1.5
    mesh = swept_beam_mesh(pts, [12, 4], m1, m2, I_BEAM, {"bending energy": energy})
    assert np.all(np.isfinite(mesh.vertices))
    assert_closed_and_oriented(mesh)
    assert enclosed_volume(mesh.vertices, mesh.triangles) > 0
    k = len(I_BEAM)
    assert np.array_equal(mesh.fields["bending energy"], np.repeat(energy, k))
    assert np.array_equal(mesh.rod_of_vertex, np.repeat([0, 1], [13 * k, 5 * k]))
    # I_BEAM's points average to 0, so each ring is centred on its vertex.
    rings = mesh.vertices.reshape(len(pts), k, 3)
    assert np.allclose(rings.mean(axis=1), pts, atol=1e-9)


def test_bad_inputs_raise():
    pts, m1, m2 = straight_rod()
    with pytest.raises(ValueError, match="points"):
        swept_beam_mesh(pts, [5], m1, m2, RECT)
    with pytest.raises(ValueError, match="m2"):
        swept_beam_mesh(pts, [6], m1, m2[:-1], RECT)
    with pytest.raises(ValueError, match="field"):
        swept_beam_mesh(pts, [6], m1, m2, RECT, {"s": np.zeros(3)})
    with pytest.raises(ValueError, match="zero area"):
        swept_beam_mesh(pts, [6], m1, m2, np.zeros((4, 2)))


def test_ply_property_names_are_sanitised_and_distinct():
    assert ply_property_names(["bending energy", "x", "σ-max", "bending_energy"]) == [
        "bending_energy", "x_1", "__max", "bending_energy_1"]


@pytest.fixture
def mesh_with_fields():
    pts, m1, m2 = bent_rod(n=5)
    rng = np.random.default_rng(0)
    fields = {"bending energy": rng.random(6), "stress": rng.normal(size=6)}
    return swept_beam_mesh(pts, [5], m1, m2, RECT, fields)


def no_temp_files(folder):
    return [f for f in os.listdir(folder) if f.startswith(".tmp-")] == []


def test_ply_round_trip(tmp_path, mesh_with_fields):
    mesh = mesh_with_fields
    path = tmp_path / "beam.ply"
    write_ply(path, mesh)
    back = meshio.read(path)
    assert back.points.shape == mesh.vertices.shape
    assert np.array_equal(back.points, mesh.vertices)
    assert np.array_equal(back.cells_dict["triangle"], mesh.triangles)
    assert np.array_equal(back.point_data["bending_energy"], mesh.fields["bending energy"])
    assert np.array_equal(back.point_data["stress"], mesh.fields["stress"])
    assert no_temp_files(tmp_path)


def read_obj(path):
    v, vt, f = [], [], []
    for line in open(path, encoding="utf-8"):
        tok = line.split()
        if not tok or tok[0] == "#":
            continue
        if tok[0] == "v":
            v.append([float(t) for t in tok[1:4]])
        elif tok[0] == "vt":
            vt.append(float(tok[1]))
        elif tok[0] == "f":
            corners = [t.split("/") for t in tok[1:]]
            assert all(len(c) == 1 or c[0] == c[1] for c in corners)
            f.append([int(c[0]) - 1 for c in corners])
    return np.array(v), np.array(vt), np.array(f)


def test_obj_round_trip(tmp_path, mesh_with_fields):
    mesh = mesh_with_fields
    path = tmp_path / "beam.obj"
    write_obj(path, mesh)
    v, vt, f = read_obj(path)
    assert np.array_equal(v, mesh.vertices)
    assert np.array_equal(f, mesh.triangles)
    assert np.array_equal(vt, mesh.fields["bending energy"])
    assert no_temp_files(tmp_path)
    # meshio agrees on the vertex count.
    assert len(meshio.read(path).points) == len(mesh.vertices)


def test_obj_without_fields(tmp_path):
    pts, m1, m2 = straight_rod()
    mesh = swept_beam_mesh(pts, [6], m1, m2, RECT)
    write_obj(tmp_path / "plain.obj", mesh)
    v, vt, f = read_obj(tmp_path / "plain.obj")
    assert len(vt) == 0 and np.array_equal(f, mesh.triangles)


def test_failed_write_leaves_no_partial_file(tmp_path, mesh_with_fields, monkeypatch):
    path = tmp_path / "beam.ply"
    path.write_text("old")

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError):
        write_ply(path, mesh_with_fields)
    assert path.read_text() == "old"
    assert no_temp_files(tmp_path)
