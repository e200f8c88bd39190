"""Profiles, file reading and the one-line errors for bad input."""
import json
from pathlib import Path

import numpy as np
import pytest

import xshells
from xshells.errors import InputError
from xshells.section import profiles
from xshells.section.io import load_contour, load_section
from xshells.section.material import Material
from xshells.section.properties import polygon_moments

EXAMPLES = Path(xshells.__file__).parent / "data" / "examples" / "cross_sections"
SQUARE = [(0, 0), (1, 0), (1, 1), (0, 1)]


def one_line_error(call, *fragments):
    with pytest.raises(InputError) as info:
        call()
    message = str(info.value)
    assert "\n" not in message and message
    for fragment in fragments:
        assert fragment in message, message
    return message


# ---- exact polygon integrals -------------------------------------------------

def test_polygon_moments_of_offset_rectangle():
    w, h, cx, cy = 3.0, 2.0, 1.5, -0.5
    p = profiles.rectangle(w, h)
    A, Sx, Sy, Ixx, Iyy, Ixy = polygon_moments([p.outer + [cx, cy]])
    assert A == pytest.approx(w * h)
    assert (Sx / A, Sy / A) == pytest.approx((cx, cy))
    assert Ixx == pytest.approx(h * w ** 3 / 12 + A * cx ** 2)
    assert Iyy == pytest.approx(w * h ** 3 / 12 + A * cy ** 2)
    assert Ixy == pytest.approx(A * cx * cy)


def test_hole_is_subtracted():
    hollow = profiles.polygon(SQUARE, holes=[[(0.25, 0.25), (0.25, 0.75), (0.75, 0.75), (0.75, 0.25)]])
    assert polygon_moments(hollow.loops)[0] == pytest.approx(0.75)


@pytest.mark.parametrize("kind, params, area", [
    ("Rectangle", [12, 8], 96),
    ("I", [10, 5, 10, 5, 15, 5], 2 * 25 * 5 + 5 * 15),
    ("L", [20, 20, 2, 2], 20 * 2 + 18 * 2),
    ("+", [20, 20, 2, 2], 20 * 2 + 18 * 2),
    ("ellipse", [2, 1], 2 * np.pi),
])
def test_parametric_areas(kind, params, area):
    assert Material.uniform(kind, params, E=1, nu=0.3).area == pytest.approx(area)


def test_plus_parameters_are_widths_then_thicknesses():
    # '+' [a, b, t1, t2]: horizontal bar a wide and t1 thick; vertical bar b tall and t2 thick
    p = profiles.make_profile("+", [10, 4, 1, 2])
    assert np.ptp(p.outer, axis=0) == pytest.approx([10, 4])
    assert profiles.points_in_loop(np.array([[4.5, 0.4], [0.9, 1.9]]), p.outer).all()
    assert not profiles.points_in_loop(np.array([[4.5, 0.6]]), p.outer)[0]


# ---- example files -------------------------------------------------------------

@pytest.mark.parametrize("path", sorted(EXAMPLES.iterdir()), ids=lambda p: p.name)
def test_every_example_loads_with_positive_stiffness(path):
    material = Material.from_file(path, young=None if path.suffix == ".json" else 2600.0,
                                  poisson=None if path.suffix == ".json" else 0.35)
    B1, B2 = material.bending_stiffness
    for value in (material.area, material.stretching_stiffness, B1, B2, material.twisting_stiffness):
        assert value > 0 and np.isfinite(value)
    # J never exceeds the polar moment (equality only for circles and rings)
    assert material.torsion_constant <= material.section.polar_moment * (1 + 1e-9)


def test_json_parameters_are_read(tmp_path):
    spec = {"type": "Rectangle", "young": 20000, "poisson": 0.3, "params": [12, 8]}
    path = tmp_path / "r.json"
    path.write_text(json.dumps(spec))
    profile, E, nu = load_section(path)
    assert (profile.kind, profile.params, E, nu) == ("rectangle", (12.0, 8.0), 20000.0, 0.3)


def test_obj_contour_with_hole_and_scale(tmp_path):
    outer = [(0, 0), (4, 0), (4, 3), (0, 3)]
    hole = [(1, 1), (2, 1), (2, 2), (1, 2)]
    lines = [f"v {x} {y} 0" for x, y in outer + hole]
    lines += [f"l {i + 1} {(i + 1) % 4 + 1}" for i in range(4)]
    lines += [f"l {i + 5} {(i + 1) % 4 + 5}" for i in range(4)]
    (tmp_path / "c.obj").write_text("\n".join(lines))
    profile = load_contour(tmp_path / "c.obj", scale=2.0)
    assert len(profile.holes) == 1
    assert polygon_moments(profile.loops)[0] == pytest.approx(4 * 11)


# ---- bad input -----------------------------------------------------------------

def test_open_contour(tmp_path):
    path = tmp_path / "open.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nl 1 2\nl 2 3\nl 3 4\n")
    one_line_error(lambda: load_contour(path), "open.obj", "open")


def test_a_missing_contour_file_is_named_with_its_json_key(tmp_path):
    import json

    from xshells.section.io import load_section

    spec = tmp_path / "c.json"
    spec.write_text(json.dumps({"type": "contour", "path": "gone.obj", "young": 1, "poisson": 0.3}))
    one_line_error(lambda: load_section(spec), "c.json: 'path' names 'gone.obj', which is not a file")


def test_points_off_the_section_plane_are_refused_and_a_plane_z_is_dropped():
    # the z of [[0, 0, 5], [10, 0, 0], ...] was dropped without a word
    one_line_error(lambda: profiles.polygon([(0, 0, 5), (10, 0, 0), (10, 7, 99), (0, 7, 0)], name="p"),
                   "p: outer contour", "leave the section's plane")
    flat = profiles.polygon([(0, 0, 3), (10, 0, 3), (10, 7, 3), (0, 7, 3)], name="p")
    assert np.allclose(flat.outer, profiles.polygon([(0, 0), (10, 0), (10, 7), (0, 7)]).outer)


@pytest.mark.parametrize("record, words", [
    # these were "internal error (ValueError: setting an array element with a sequence)" and
    # "(ValueError: data must be finite ...)"
    ("v 1", "bad.obj:2: vertex 'v 1' has 1 coordinate; expected x y [z]"),
    ("v nan 0 0", "bad.obj:2: vertex 'v nan 0 0' has a coordinate that is not finite"),
    ("v inf 0 0", "bad.obj:2: vertex 'v inf 0 0' has a coordinate that is not finite"),
    ("v 1 zero 0", "bad.obj:2: bad vertex 'v 1 zero 0'"),
])
def test_a_malformed_obj_vertex_names_its_line(tmp_path, record, words):
    path = tmp_path / "bad.obj"
    path.write_text(f"v 0 0 0\n{record}\nv 1 1 0\nl 1 2 3 1\n")
    one_line_error(lambda: load_contour(path), words)


def test_a_non_finite_msh_node_is_named(tmp_path):
    path = tmp_path / "bad.msh"
    path.write_text("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0 0\n2 nan 0 0\n3 1 1 0\n$EndNodes\n"
                    "$Elements\n3\n1 1 2 0 1 1 2\n2 1 2 0 1 2 3\n3 1 2 0 1 3 1\n$EndElements\n")
    one_line_error(lambda: load_contour(path), "bad.msh: node 2 has a coordinate that is not finite")


@pytest.mark.parametrize("vertices, words", [
    # a tilted square was read as the 10 x 10 square; one drawn in xz was "open: a line ends at (0, 0)"
    ("v 0 0 0\nv 10 0 5\nv 10 10 0\nv 0 10 -5", "z goes from -5 to 5: it is not flat in the xy plane"),
    ("v 0 0 0\nv 10 0 0\nv 10 0 10\nv 0 0 10", "z goes from 0 to 10: it is drawn in another plane"),
])
def test_a_contour_whose_z_varies_is_refused(tmp_path, vertices, words):
    path = tmp_path / "c.obj"
    path.write_text(vertices + "\nl 1 2 3 4 1\n")
    one_line_error(lambda: load_contour(path), "c.obj: the contour's", words, "draw the section in the xy plane")


def test_a_contour_at_a_constant_z_is_read_and_unused_vertices_may_leave_the_plane(tmp_path):
    path = tmp_path / "c.obj"
    path.write_text("v 0 0 3\nv 10 0 3\nv 10 10 3\nv 0 10 3\nv 5 5 99\nl 1 2 3 4 1\n")
    assert polygon_moments(load_contour(path).loops)[0] == pytest.approx(100)
    path.write_text("v 0 0\nv 10 0\nv 10 10\nv 0 10\nl 1 2 3 4 1\n")  # no z at all
    assert polygon_moments(load_contour(path).loops)[0] == pytest.approx(100)


@pytest.mark.parametrize("spec, words", [
    ({"points": [[0, 0, 0], [1, 0, 0], [1, 1, 0]]}, "'points' must be [x, y] pairs of numbers, got [0, 0, 0] at position 1"),
    ({"points": [[0, 0], [1, 0], [1, "1"]]}, "got [1, \"1\"] at position 3"),
    ({"points": None}, "'points' must be a list of [x, y] pairs, got null"),
    ({"points": [[0, 0], [9, 0], [9, 9]], "holes": [[1, 1], [2, 1], [2, 2]]},
     "'holes' must be a list of point lists"),
    ({"points": [[0, 0], [9, 0], [9, 9]], "holes": [[[1, 1], [2, 1, 0], [2, 2]]]},
     "hole 1 of 'holes' must be [x, y] pairs of numbers, got [2, 1, 0] at position 2"),
])
def test_json_points_must_be_pairs(tmp_path, spec, words):
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"type": "polygon", "young": 1, "poisson": 0.3, **spec}))
    one_line_error(lambda: load_section(path), "p.json: ", words)


def test_a_contour_is_held_to_the_parametric_size_range(tmp_path):
    # a contour at 1e7 was accepted where a rectangle 1e7 wide was refused
    path = tmp_path / "big.obj"
    path.write_text("v 0 0\nv 2e7 0\nv 2e7 1e5\nv 0 1e5\nl 1 2 3 4 1\n")
    one_line_error(lambda: load_contour(path), "big.obj: the contour's width 2e+07 is outside 1e-06 to 1e+06",
                   "check the units")
    one_line_error(lambda: profiles.polygon([(0, 0), (1e-7, 0), (1e-7, 1e-7)], name="p"), "width 1e-07 is outside")
    one_line_error(lambda: profiles.make_profile("rectangle", [2e7, 1e5]), "is outside 1e-06 to 1e+06")
    assert profiles.polygon([(0, 0), (1e6, 0), (1e6, 1), (0, 1)]).kind == "polygon"
    assert profiles.polygon([(0, 0), (1e-6, 0), (1e-6, 1e-6), (0, 1e-6)]).kind == "polygon"


def test_self_intersecting_polygon():
    bow_tie = [(0, 0), (1, 1), (1, 0), (0, 1)]
    one_line_error(lambda: profiles.polygon(bow_tie, name="bowtie"), "bowtie", "intersects itself")


def test_self_intersecting_contour_file(tmp_path):
    path = tmp_path / "bowtie.obj"
    path.write_text("v 0 0\nv 1 1\nv 1 0\nv 0 1\nl 1 2 3 4 1\n")
    one_line_error(lambda: load_contour(path), "bowtie.obj", "intersects itself")


def test_zero_area():
    one_line_error(lambda: profiles.polygon([(0, 0), (1, 1), (2, 2)], name="line"), "line", "zero area")
    one_line_error(lambda: profiles.polygon([(1, 1)] * 4, name="dot"), "dot")


def test_hole_outside_outer_boundary():
    far = [(5, 5), (6, 5), (6, 6), (5, 6)]
    one_line_error(lambda: profiles.polygon(SQUARE, holes=[far], name="p"), "hole 1", "outside the outer boundary")


def test_hole_outside_outer_boundary_in_file(tmp_path):
    path = tmp_path / "two.obj"
    path.write_text("v 0 0\nv 1 0\nv 1 1\nv 0 1\nv 5 5\nv 6 5\nv 6 6\nv 5 6\nl 1 2 3 4 1\nl 5 6 7 8 5\n")
    one_line_error(lambda: load_contour(path), "two.obj", "hole outside the outer boundary")


def test_hole_crossing_outer_boundary():
    crossing = [(0.5, 0.5), (1.5, 0.5), (1.5, 0.7), (0.5, 0.7)]
    one_line_error(lambda: profiles.polygon(SQUARE, holes=[crossing], name="p"), "crosses")


@pytest.mark.parametrize("kind, params", [("rectangle", [1, -2]), ("ellipse", [0, 1]), ("I", [1, 1, 1, 1, -1, 1]),
                                          ("L", [-1, 1, 0.1, 0.1]), ("+", [1, 1, 0.1, -0.1])])
def test_negative_dimension(kind, params):
    one_line_error(lambda: profiles.make_profile(kind, params), "must be positive")


@pytest.mark.parametrize("kind, params, words", [
    # these divided by zero, found the torsion solve singular, or ran out of memory meshing
    ("ellipse", [1e-300, 1e-300], "is outside 1e-06 to 1e+06"), ("rectangle", [1e200, 1e200], "is outside"),
    ("rectangle", [100000, 1], "span 1e+05x"), ("I", [1, 1, 1, 1, 1, 1e-9], "is outside"),
    # the ratio was shown as "1e+03x, more than 1000x"
    ("rectangle", [1001, 1], "span 1001x (largest over smallest), more than 1000x"),
    ("rectangle", [1000.0001, 1], "span 1000.0001x"),
])
def test_dimensions_out_of_range_or_proportion(kind, params, words):
    one_line_error(lambda: profiles.make_profile(kind, params), words)


def test_wrong_parameter_count():
    one_line_error(lambda: profiles.make_profile("L", [1, 2, 3]), "takes 4 parameters")


@pytest.mark.parametrize("nu", [0.5, 0.7, -1.0, -2.0, float("nan")])
def test_poisson_ratio_out_of_range(nu):
    one_line_error(lambda: Material.uniform("rectangle", [1, 1], E=1, nu=nu), "Poisson", "(-1, 0.5)")


def test_nonpositive_young_modulus():
    one_line_error(lambda: Material.uniform("rectangle", [1, 1], E=0, nu=0.3), "Young")


def test_unknown_type(tmp_path):
    path = tmp_path / "hex.json"
    path.write_text(json.dumps({"type": "Hexagon", "young": 1, "poisson": 0.3, "params": [1]}))
    one_line_error(lambda: load_section(path), "hex.json", "unknown cross-section type 'Hexagon'")


def test_malformed_json(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text("{not json")
    one_line_error(lambda: load_section(path), "bad.json", "not valid JSON")


def test_contour_needs_material():
    one_line_error(lambda: load_section(EXAMPLES / "custom_A.obj"), "Young")


SQUARE_OBJ = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nl 1 2 3 4 1\n"


def write_json(tmp_path, name, spec):
    path = tmp_path / name
    path.write_text(json.dumps(spec))
    return path


def test_json_contour_scale_is_applied(tmp_path):
    (tmp_path / "sq.obj").write_text(SQUARE_OBJ)
    spec = {"type": "contour", "path": "sq.obj", "young": 1, "poisson": 0.3}
    unscaled = load_section(write_json(tmp_path, "a.json", spec))[0]
    doubled = load_section(write_json(tmp_path, "b.json", {**spec, "scale": 2}))[0]
    assert polygon_moments(unscaled.loops)[0] == pytest.approx(1)
    assert polygon_moments(doubled.loops)[0] == pytest.approx(4)


@pytest.mark.parametrize("scale", [0, -1, 0.0, float("inf")])
def test_json_contour_scale_must_be_positive(tmp_path, scale):
    # 0 used to fall back to 1 and a negative scale was accepted
    (tmp_path / "sq.obj").write_text(SQUARE_OBJ)
    path = write_json(tmp_path, "s.json", {"type": "contour", "path": "sq.obj", "scale": scale,
                                           "young": 1, "poisson": 0.3})
    message = one_line_error(lambda: load_section(path), "s.json", "'scale' must be a positive number, got ")
    assert message == f"{path}: 'scale' must be a positive number, got {json.dumps(scale)}"


@pytest.mark.parametrize("spec, fragments", [
    ({"type": "contour", "path": "sq.obj", "scael": 1000}, ["unknown key 'scael'", "did you mean 'scale'?"]),
    ({"type": "rectangle", "params": [10, 7], "foo": 1},
     ["unknown key 'foo'", "allowed keys: type, young, poisson, params"]),
    ({"type": "rectangle", "params": [10, 7], "E": 20000}, ["unknown key 'E'", "did you mean 'young'?"]),
    ({"type": "polygon", "points": [[0, 0], [1, 0], [1, 1]], "scale": 2}, ["unknown key 'scale'", "allowed keys"]),
])
def test_json_unknown_key_is_refused(tmp_path, spec, fragments):
    # an unknown key used to be ignored silently (a typo computed at the default)
    (tmp_path / "sq.obj").write_text(SQUARE_OBJ)
    spec = {"young": 1, "poisson": 0.3, **spec}
    if "E" in spec:
        del spec["young"]
    path = write_json(tmp_path, "k.json", spec)
    one_line_error(lambda: load_section(path), "k.json", *fragments)


def test_every_documented_json_key_is_accepted(tmp_path):
    (tmp_path / "sq.obj").write_text(SQUARE_OBJ)
    for spec in ({"type": "Rectangle", "young": 1, "poisson": 0.3, "params": [12, 8]},
                 {"type": "contour", "path": "sq.obj", "scale": 1, "young": 1, "poisson": 0.3},
                 {"type": "polygon", "points": SQUARE, "holes": [[(0.25, 0.25), (0.25, 0.75), (0.75, 0.75)]],
                  "young": 1, "poisson": 0.3}):
        load_section(write_json(tmp_path, "d.json", spec))


@pytest.mark.parametrize("params, shown", [([True, 7], "got true at position 1"),
                                           (["10", "7"], 'got "10" at position 1'),
                                           ([10, None], "got null at position 2"),
                                           ("10 7", 'got "10 7"')])
def test_json_params_must_be_numbers(tmp_path, params, shown):
    # true was read as 1 and "10" as 10
    path = write_json(tmp_path, "p.json", {"type": "rectangle", "young": 1, "poisson": 0.3, "params": params})
    one_line_error(lambda: load_section(path), "p.json", "'params' must be a list of numbers", shown)


@pytest.mark.parametrize("spec, fragment", [
    ({"path": "sq.obj", "points": SQUARE}, "'path' (a contour file) or 'points', not both"),
    ({"path": 5}, "'path' must be a file name (a string), got 5"),
])
def test_json_contour_path_is_checked(tmp_path, spec, fragment):
    path = write_json(tmp_path, "c.json", {"type": "contour", "young": 1, "poisson": 0.3, **spec})
    one_line_error(lambda: load_section(path), "c.json", fragment)
