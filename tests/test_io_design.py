"""Reading and writing designs: real files, round trips and one-line errors for bad input."""
from __future__ import annotations

import json
import os
import re
from pathlib import Path

import meshio
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from xshells.errors import InputError
from xshells.io import (
    Design, design_from_arrays, read_design, read_rest_lengths, write_design_obj, write_polylines_obj,
)

from data_paths import DATA, EXAMPLES, needs_data  # noqa: F401


def _design_files() -> list[Path]:
    found = [*EXAMPLES.glob("*.obj"), *EXAMPLES.glob("*/*.msh")]
    if DATA.is_dir():
        found += [*DATA.rglob("*.obj"), *DATA.rglob("*.msh")]
    return sorted(found)


# Files in the data that are genuinely not line-graph designs: a triangle mesh
# (a target surface). Cross-section contours load but are not linkages.
NOT_A_DESIGN = {"target_surface_0.msh": "no line elements"}


@pytest.mark.parametrize("path", _design_files(), ids=lambda p: p.name[:40])
def test_every_design_file_loads_or_fails_clearly(path):
    if path.name in NOT_A_DESIGN:
        with pytest.raises(InputError, match=NOT_A_DESIGN[path.name]) as err:
            read_design(path)
        assert str(path) in str(err.value) and "\n" not in str(err.value)
        return
    d = read_design(path)
    assert d.vertices.dtype == np.float64 and d.vertices.shape[1] == 3
    assert d.edges.dtype == np.int64 and d.edges.shape[1] == 2 and len(d.edges) > 0
    assert not d.vertices.flags.writeable and not d.edges.flags.writeable
    assert d.source == str(path)


@pytest.mark.parametrize("path", [p for p in _design_files() if p.name not in NOT_A_DESIGN],
                         ids=lambda p: p.name[:40])
def test_round_trip_is_exact(path, tmp_path):
    d = read_design(path)
    out = tmp_path / "copy.obj"
    write_design_obj(out, d)
    back = read_design(out)
    assert np.array_equal(back.vertices, d.vertices) and back.vertices.dtype == d.vertices.dtype
    assert np.array_equal(back.edges, d.edges) and back.edges.dtype == d.edges.dtype
    assert [p.name for p in tmp_path.iterdir()] == ["copy.obj"]  # no temporary left behind


@settings(max_examples=40, deadline=None)
@given(hnp.arrays(np.float64, (4, 3), elements=st.floats(-1e6, 1e6, allow_nan=False, width=64)))
def test_round_trip_any_finite_coordinates(tmp_path_factory, coords):
    coords[:, 0] += [0.0, 3e6, 6e6, 9e6]  # keep segments from collapsing to zero length
    d = design_from_arrays(coords, [[0, 1], [1, 2], [2, 3]])
    out = tmp_path_factory.mktemp("rt") / "d.obj"
    write_design_obj(out, d)
    assert np.array_equal(read_design(out).vertices, coords)


def test_obj_features(tmp_path):
    path = tmp_path / "features.obj"
    path.write_text(
        "# a comment\n\no thing\ng group\ns off\nvn 0 0 1\nvt 0 0\n"
        "v 0 0 0\nv 1 0 0 # trailing comment\nv 2 0 0 1.0\nv 3 0 0\n"
        "l 1 2 3\n"        # a polyline: two segments
        "l -1 -2\n"        # relative indices: vertices 4 and 3
        "l 1/1 4/2\n"      # vertex/texture references
    )
    d = read_design(path)
    assert d.edges.tolist() == [[0, 1], [1, 2], [3, 2], [0, 3]]
    assert d.edge_lines.tolist() == [12, 12, 13, 14]
    assert d.vertex_lines.tolist() == [8, 9, 10, 11]


def test_vertex_and_edge_order_are_kept(tmp_path):
    path = tmp_path / "order.obj"
    path.write_text("v 5 0 0\nv 0 0 0\nv 0 3 0\nl 3 1\nl 2 3\nl 1 2\n")
    d = read_design(path)
    assert d.vertices[:, 0].tolist() == [5, 0, 0]
    assert d.edges.tolist() == [[2, 0], [1, 2], [0, 1]]


TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
BAD_OBJ = [
    ("v 0 0 0\nv 1 0\nl 1 2\n", 2, "needs 3 coordinates"),
    ("v 0 0 0\nv 1 a 0\nl 1 2\n", 2, "malformed vertex"),
    ("v nan 0 0\nv 1 0 0\nl 1 2\n", 1, "non-finite"),
    ("v 0 0 0\nv inf 0 0\nl 1 2\n", 2, "non-finite"),
    (TRIANGLE + "l 1\n", 4, "at least 2"),
    (TRIANGLE + "l 1 x\n", 4, "malformed vertex index"),
    (TRIANGLE + "l 1 0\n", 4, "index 0"),
    # the index as written, not the 0-based pair "(0, 6) ... (0-based)"
    (TRIANGLE + "l 1 2\nl 1 7\n", 5, "vertex index 7 is out of range: the file defines 3 vertices"),
    (TRIANGLE + "l 1 2\nl 2 3 7/1\n", 5, "vertex index 7 is out of range: the file defines 3 vertices"),
    (TRIANGLE + "l -4 1\n", 4, "vertex index -4 is out of range: it counts back from the last vertex defined so "
                                "far, and only 3 are"),
    (TRIANGLE + "l 1 2\nl 2 1\n", 5, "duplicate edge"),
    (TRIANGLE + "l 2 3\nl 2 2\n", 5, "self-loop"),
    ("v 0 0 0\nv 1 0 0\nv 1 0 0\nl 1 2\nl 2 3\n", 5, "zero-length"),
    # 1e-9 beside segments of 1: a deployment of such a design once reported success without moving
    ("v 0 0 0\nv 1 0 0\nv 1.000000001 0 0\nv 2 0 0\nl 1 2\nl 2 3\nl 3 4\n", 6, "too short to simulate"),
    (TRIANGLE + "f 1 2 3\n", 4, "face record"),
    (TRIANGLE + "curv 0 1 1 2\n", 4, "unknown OBJ record"),
]


@pytest.mark.parametrize("text,line,what", BAD_OBJ, ids=[b[2] for b in BAD_OBJ])
def test_bad_obj_names_file_and_line(tmp_path, text, line, what):
    path = tmp_path / "bad_design.obj"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        read_design(path)
    msg = str(err.value)
    assert "\n" not in msg
    assert str(path) in msg and f"line {line}" in msg and what in msg, msg


def test_duplicate_edge_names_both_lines(tmp_path):
    path = tmp_path / "dup.obj"
    path.write_text(TRIANGLE + "l 1 2\nl 2 3\nl 2 1\n")
    with pytest.raises(InputError, match=r"line 6: duplicate edge .* already given at line 4"):
        read_design(path)


@pytest.mark.parametrize("text,what", [
    (TRIANGLE, "no line elements"),
    ("", "no line elements"),
])
def test_no_line_elements(tmp_path, text, what):
    path = tmp_path / "empty.obj"
    path.write_text(text)
    with pytest.raises(InputError, match=what):
        read_design(path)


def test_unreadable_files(tmp_path):
    with pytest.raises(InputError, match="cannot read file"):
        read_design(tmp_path / "missing.obj")
    binary = tmp_path / "binary.obj"
    binary.write_bytes(b"v 0 0 0\n\xff\xfe\x00garbage")
    with pytest.raises(InputError, match="not a text file"):
        read_design(binary)
    with pytest.raises(InputError, match="cannot read"):
        read_design(tmp_path / "missing.msh")
    corrupt = tmp_path / "corrupt.msh"
    corrupt.write_text("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0\n$EndNodes\n")
    with pytest.raises(InputError, match=r"corrupt\.msh: line 6: node 1 of 3 \('number x y z'\): expected 4 numbers, "
                                         r"got '1 0 0'$") as err:
        read_design(corrupt)
    assert "\n" not in str(err.value)
    corrupt.write_text("this is not gmsh at all\n")
    with pytest.raises(InputError, match=r"corrupt\.msh: line 1: not a gmsh file: it begins with 'this is not gmsh at "
                                         r"all', not \$MeshFormat"):
        read_design(corrupt)
    with pytest.raises(InputError, match="unknown design file type"):
        read_design(tmp_path / "design.stl")
    # a folder has no suffix: it said "unknown design file type ''"
    with pytest.raises(InputError, match=r"^\S+: a folder, not a design file \(\.obj, \.msh or \.3dm\)$"):
        read_design(tmp_path)


def test_a_byte_order_mark_is_read_past(tmp_path):
    """Windows editors begin a UTF-8 file with a byte-order mark: it was "line 1: unknown OBJ record '\\ufeffv'"."""
    path = tmp_path / "bom.obj"
    path.write_bytes(b"\xef\xbb\xbf" + TRIANGLE.encode() + b"l 1 2 3\n")
    d = read_design(path)
    assert d.vertices.tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0]] and d.edges.tolist() == [[0, 1], [1, 2]]


def _write_msh(path, points, cells, binary=False):
    meshio.write(path, meshio.Mesh(np.asarray(points, float), cells), file_format="gmsh22", binary=binary)


def test_msh_reading_and_errors(tmp_path):
    pts = [[0, 0, 0], [1, 0, 0], [1, 1, 0]]
    good = tmp_path / "good.msh"
    _write_msh(good, pts, [("line", np.array([[0, 1], [1, 2]]))])
    d = read_design(good)
    assert d.edges.tolist() == [[0, 1], [1, 2]] and np.array_equal(d.vertices, pts)

    tri = tmp_path / "tri.msh"
    _write_msh(tri, pts, [("triangle", np.array([[0, 1, 2]]))])
    with pytest.raises(InputError, match=r"tri\.msh: the design has no line elements \(cell types: triangle\)"):
        read_design(tri)

    badref = tmp_path / "badref.msh"  # an element naming node 7 of 4: meshio's IndexError text alone said little
    badref.write_text("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 1 1 0\n4 0 1 0\n$EndNodes\n"
                      "$Elements\n2\n1 1 2 0 0 1 2\n2 1 2 0 0 4 7\n$EndElements\n")
    with pytest.raises(InputError, match=r"badref\.msh: line 14: element 2 refers to node 7, which \$Nodes does not define"):
        read_design(badref)

    mixed = tmp_path / "mixed.msh"  # lines and a triangle: the triangle was dropped without a word
    _write_msh(mixed, pts, [("line", np.array([[0, 1], [1, 2]])), ("triangle", np.array([[0, 1, 2]]))])
    with pytest.raises(InputError, match=r"mixed\.msh: the design holds 1 triangle element besides its line elements"):
        read_design(mixed)

    dup = tmp_path / "dup.msh"
    _write_msh(dup, pts, [("line", np.array([[0, 1], [1, 2], [1, 0]]))])
    with pytest.raises(InputError, match=r"dup\.msh: edge 2: duplicate edge between node 0 and node 1, already given at edge 0"):
        read_design(dup)


def test_an_ascii_msh_with_node_data_reads_as_its_binary_twin(tmp_path):
    # meshio cannot read back the $NodeData of an ASCII file it writes itself ("could not be read to its
    # end"): such a design was refused; its nodes and elements are all a design needs
    src = EXAMPLES / "asymm_wings_pointy" / "flat_opt.msh"
    m = meshio.read(src)
    assert m.point_data  # the reference's files carry node data
    ascii_copy = tmp_path / "ascii.msh"
    meshio.write(ascii_copy, m, file_format="gmsh22", binary=False)
    a, b = read_design(ascii_copy), read_design(src)
    assert np.array_equal(a.edges, b.edges) and np.allclose(a.vertices, b.vertices, rtol=0, atol=1e-9)
    broken = tmp_path / "broken.msh"  # a damaged data block still fails in one line, not on the retry
    broken.write_text(ascii_copy.read_text().replace("$Elements", "$Elements\nx", 1))
    with pytest.raises(InputError, match=r"broken\.msh: line 165: the number of elements: expected 1 whole number, got 'x'"):
        read_design(broken)


GOOD_MSH22 = ("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 1 1 0\n4 0 1 0\n$EndNodes\n"
              "$Elements\n3\n1 1 2 0 0 1 2\n2 1 2 0 0 2 3\n3 1 2 0 0 3 4\n$EndElements\n")
GOOD_MSH41 = ("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 4 1 4\n1 0 0 4\n1\n2\n3\n4\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n"
              "$EndNodes\n$Elements\n1 3 1 3\n1 0 1 3\n1 1 2\n2 2 3\n3 3 4\n$EndElements\n")


# Each was read by meshio: several failed with its internals ("cannot reshape array of size 10 into shape
# (4,4)", "np.int32(-65535)", "cannot access local variable 'point_tags'"), and some gave a wrong design
# without a word (a node numbered 0 became the last node; an element with a node too many was read from
# its last two numbers).
MALFORMED_MSH = {
    "nodes cut short": (GOOD_MSH22[:GOOD_MSH22.index("3 1 1 0")],
                        r"the file ends inside \$Nodes, before node 3 of 4 \('number x y z'\) \(a truncated file\?\)"),
    "elements cut short": (GOOD_MSH22[:GOOD_MSH22.index("2 1 2 0 0 2 3")],
                           r"the file ends inside \$Elements, before element 2 of 3 \('number type tag-count tags\.\.\. "
                           r"nodes'\) \(a truncated file\?\)"),
    "no $Nodes": (GOOD_MSH22.replace(GOOD_MSH22[GOOD_MSH22.index("$Nodes"):GOOD_MSH22.index("$Elements")], ""),
                  r"line 4: \$Elements comes before \$Nodes"),
    "no $Elements": (GOOD_MSH22[:GOOD_MSH22.index("$Elements")], r"the file has no \$Elements section"),
    "a count too high": (GOOD_MSH22.replace("$Nodes\n4\n", "$Nodes\n5\n"),
                         r"line 10: \$Nodes ends before node 5 of 5 \('number x y z'\)"),
    "a coordinate not a number": (GOOD_MSH22.replace("2 1 0 0", "2 1,5 0 0"),
                                  r"line 7: node 2 of 4 \('number x y z'\): expected 4 numbers, got '2 1,5 0 0'"),
    "a node number given twice": (GOOD_MSH22.replace("4 0 1 0", "3 0 1 0"),
                                  r"line 9: node 3 is defined twice \(first at line 8\)"),
    "a node out of range": (GOOD_MSH22.replace("3 1 2 0 0 3 4", "3 1 2 0 0 3 9"),
                            r"line 15: element 3 refers to node 9, which \$Nodes does not define"),
    "node 0": (GOOD_MSH22.replace("3 1 2 0 0 3 4", "3 1 2 0 0 3 0"),
               r"line 15: element 3 refers to node 0, which \$Nodes does not define"),
    "a node too many": (GOOD_MSH22.replace("3 1 2 0 0 3 4", "3 1 2 0 0 3 4 1"),
                        r"line 15: element 3: a line element with 2 tags is 7 numbers, this line has 8"),
    "an unknown element type": (GOOD_MSH22.replace("3 1 2 0 0 3 4", "3 99 2 0 0 3 4"),
                                r"line 15: element type 99 is not a gmsh element type"),
    "an unsupported version": (GOOD_MSH22.replace("2.2 0 8", "7.3 0 8"),
                               r"line 2: gmsh format version '7\.3' is not supported \(2\.2 and 4\.1 are\)"),
    "binary garbage": (bytes(range(7, 250, 3)) * 4, r"line 1: not a gmsh file: it does not begin with \$MeshFormat"),
    "empty": ("", r"the file is empty, not a gmsh file"),
    "4.1 cut short": (GOOD_MSH41[:GOOD_MSH41.index("1 1 0")],
                      r"the file ends inside \$Nodes, before the coordinates of node 3 \(a truncated file\?\)"),
    "4.1 a node too few": (GOOD_MSH41.replace("3 3 4\n", "3 3\n"),
                           r"line 21: a line element \('number' and 2 nodes\): expected 3 whole numbers, got '3 3'"),
}


@pytest.mark.parametrize("case", MALFORMED_MSH)
def test_a_malformed_msh_is_one_line_naming_the_file_and_what_is_wrong(tmp_path, case):
    text, message = MALFORMED_MSH[case]
    path = tmp_path / "bad.msh"
    (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)
    with pytest.raises(InputError) as err:
        read_design(path)
    assert re.fullmatch(re.escape(str(path)) + ": " + message, str(err.value)), str(err.value)


def test_a_binary_msh_cut_short_or_damaged_is_one_line(tmp_path):
    good = tmp_path / "good.msh"
    _write_msh(good, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [("line", np.array([[0, 1], [1, 2], [2, 3]]))],
               binary=True)
    data = good.read_bytes()
    assert read_design(good).edges.tolist() == [[0, 1], [1, 2], [2, 3]]
    cut = tmp_path / "cut.msh"
    cut.write_bytes(data[:data.index(b"$Nodes") + 30])
    with pytest.raises(InputError, match=r"cut\.msh: the file ends inside \$Nodes, in its 4 nodes \(a truncated file\?\)$"):
        read_design(cut)
    damaged = tmp_path / "damaged.msh"  # the type of the first element block overwritten
    at = data.index(b"$Elements\n3\n") + len(b"$Elements\n3\n")
    damaged.write_bytes(data[:at] + b"\xff" * 4 + data[at + 4:])
    with pytest.raises(InputError, match=r"damaged\.msh: \$Elements, the block after 0 of its 3 elements: element type -1 "
                                         r"is not a gmsh element type$"):
        read_design(damaged)


def test_msh_versions_2_and_4_ascii_and_binary_read_alike(tmp_path):
    pts = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    edges = [[0, 1], [1, 2], [2, 3]]
    for name, text in (("a22.msh", GOOD_MSH22), ("a41.msh", GOOD_MSH41)):
        (tmp_path / name).write_text(text)
    for fmt, binary in (("gmsh22", True), ("gmsh", False), ("gmsh", True)):
        meshio.write(tmp_path / f"{fmt}{binary}.msh", meshio.Mesh(np.array(pts, float), [("line", np.array(edges))]),
                     file_format=fmt, binary=binary)
    for path in tmp_path.glob("*.msh"):
        d = read_design(path)
        assert d.edges.tolist() == edges and d.vertices.tolist() == pts, path.name


def test_design_from_arrays():
    d = design_from_arrays([[0, 0], [1, 0], [1, 1]], [[0, 1], [1, 2]])
    assert isinstance(d, Design) and d.source is None and d.vertices.shape == (3, 3)
    with pytest.raises(InputError, match=r"<arrays>: edge 1: vertex index out of range"):
        design_from_arrays(np.zeros((2, 3)) + [[0, 0, 0], [1, 0, 0]], [[0, 1], [1, 2]])
    with pytest.raises(InputError, match=r"node 1 has a non-finite coordinate \(nan, 0\.0, 0\.0\)$"):
        design_from_arrays([[0, 0, 0], [np.nan, 0, 0]], [[0, 1]])
    with pytest.raises(InputError, match="no line elements"):
        design_from_arrays([[0, 0, 0]], np.zeros((0, 2), int))
    with pytest.raises(InputError, match=r"node 1 lies 1e\+200 from the origin, beyond 1e\+12: check the units"):
        design_from_arrays([[0, 0, 0], [1e200, 0, 0]], [[0, 1]])  # an internal error from SciPy before


def test_write_polylines_obj(tmp_path):
    out = tmp_path / "centerlines.obj"
    a = np.array([[0, 0, 0], [1, 0, 0], [2, 0.5, 0]], float)
    b = np.array([[0, 1, 0], [1, 2, 0], [0, 2, 0]], float)
    write_polylines_obj(out, [a, b], closed=[False, True])
    d = read_design(out)
    assert np.array_equal(d.vertices, np.vstack([a, b]))
    assert d.edges.tolist() == [[0, 1], [1, 2], [3, 4], [4, 5], [5, 3]]
    with pytest.raises(ValueError):
        write_polylines_obj(out, [a[:1]])
    assert sorted(os.listdir(tmp_path)) == ["centerlines.obj"]


# ---------------------------------------------------------------- rest lengths

def _cases_with_rest_lengths():
    if not DATA.is_dir():
        return []
    cases = json.loads((DATA / "cases.json").read_text())["cases"]
    return [c for c in cases if "rest_lengths" in c]


@needs_data
@pytest.mark.parametrize("case", _cases_with_rest_lengths(), ids=lambda c: c["name"])
def test_real_rest_length_files(case):
    d = read_design(DATA / case["file"])
    p = read_rest_lengths(DATA / case["rest_lengths"], d.num_segments)
    assert p.shape == (d.num_segments,) and np.all(p > 0)
    # One value per segment in file order: each is close to its segment's
    # straight chord (the optimized beams are only gently curved).
    chord = np.linalg.norm(d.vertices[d.edges[:, 1]] - d.vertices[d.edges[:, 0]], axis=1)
    assert np.allclose(p / chord, 1.0, atol=0.01)


@pytest.mark.parametrize("text,what", [
    ("1.0\n2.0\n", r"2 rest lengths for a design with 3 segments"),
    ("1.0\n2.0\n3.0\n4.0\n", r"4 rest lengths for a design with 3 segments"),
    ("1.0\n0.0\n3.0\n", r"line 2: non-positive rest length"),
    ("1.0\n2.0\n-3.0", r"line 3: non-positive rest length"),
    ("1.0\nabc\n3.0\n", r"line 2: malformed rest length 'abc'"),
    ("1.0\nnan\n3.0\n", r"line 2: non-finite rest length"),
])
def test_bad_rest_lengths(tmp_path, text, what):
    path = tmp_path / "design_parameters.txt"
    path.write_text(text)
    with pytest.raises(InputError, match=what) as err:
        read_rest_lengths(path, 3)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("factor, refused", [(1.0, False), (2.5, False), (0.4, False), (10.0, True), (0.1, True)])
def test_rest_lengths_in_other_units_than_the_design_are_refused(tmp_path, factor, refused):
    # a file in cm for a design in mm: the solve failed with "reduced variable 57 is not finite"
    d = design_from_arrays([[0, 0, 0], [100, 0, 0], [100, 50, 0], [0, 50, 0]], [[0, 1], [1, 2], [2, 3], [3, 0]])
    path = tmp_path / "p.txt"
    path.write_text("\n".join(repr(factor * v) for v in (100.0, 50.0, 100.0, 50.0)))
    if refused:
        with pytest.raises(InputError, match=rf"p.txt: the rest lengths are a median {factor:g}x the design's drawn"):
            read_rest_lengths(path, 4, d)
    else:
        assert read_rest_lengths(path, 4, d).tolist() == [factor * v for v in (100.0, 50.0, 100.0, 50.0)]


def test_rest_length_layouts(tmp_path):
    path = tmp_path / "p.txt"
    path.write_text("  1.5\n2.25\n 3   # comment\n4e0")  # padded, no final newline
    assert read_rest_lengths(path, 4).tolist() == [1.5, 2.25, 3.0, 4.0]
    path.write_text("1 2\n3 4\n")
    assert read_rest_lengths(path, 4).tolist() == [1.0, 2.0, 3.0, 4.0]
    with pytest.raises(InputError, match="cannot read file"):
        read_rest_lengths(tmp_path / "none.txt", 4)


def test_the_msh_element_table_agrees_with_meshio_and_stands_without_its_private_one(tmp_path, monkeypatch):
    """gmsh's element types are our own table (the MSH format's numbers); meshio's private one only adds
    higher orders, so a meshio release that moves it does not stop .msh designs from reading."""
    import sys

    from meshio._common import num_nodes_per_cell
    from meshio.gmsh.common import _gmsh_to_meshio_type

    from xshells.io.design import _GMSH_ELEMENTS, _element_kinds

    for t, kind in _GMSH_ELEMENTS.items():
        if t in _gmsh_to_meshio_type:
            assert kind == (_gmsh_to_meshio_type[t], num_nodes_per_cell[_gmsh_to_meshio_type[t]]), t
    path = tmp_path / "two.msh"
    _write_msh(path, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [("line", np.array([[0, 2], [1, 3]]))])
    before = read_design(path)
    monkeypatch.setitem(sys.modules, "meshio.gmsh.common", None)  # its import now fails
    assert _element_kinds() == _GMSH_ELEMENTS
    after = read_design(path)
    np.testing.assert_array_equal(after.edges, before.edges)
    np.testing.assert_array_equal(after.vertices, before.vertices)
