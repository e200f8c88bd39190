"""Designs from Rhino .3dm files: round trip from a bundled OBJ, units, snapping within the file's tolerance,
near misses, curved curves, layers."""
import numpy as np
import pytest

from data_paths import EXAMPLES
from xshells.errors import InputError
from xshells.io import read_design

rhino3dm = pytest.importorskip("rhino3dm")


def _write(path, segments=(), polylines=(), units="Millimeters", tolerance=0.01, layers=("beams",), curves=()):
    """A .3dm with LineCurves ``segments`` [(p, q)], polylines [[p, ...]] and NURBS ``curves``, by layer index."""
    f = rhino3dm.File3dm()
    f.Settings.ModelUnitSystem = getattr(rhino3dm.UnitSystem, units)
    f.Settings.ModelAbsoluteTolerance = tolerance
    for name in layers:
        f.Layers.AddLayer(name, (0, 0, 0, 255))

    def attrs(layer):
        a = rhino3dm.ObjectAttributes()
        a.LayerIndex = layer
        return a

    for item in segments:
        (p, q), layer = (item if len(item) == 2 and np.ndim(item[0]) == 2 else (item, 0))
        f.Objects.AddLine(rhino3dm.Point3d(*p), rhino3dm.Point3d(*q), attrs(layer))
    for pts in polylines:
        pl = rhino3dm.Point3dList()
        for x, y, z in pts:
            pl.Add(x, y, z)
        f.Objects.AddPolyline(pl, attrs(0))
    for c, layer in curves:
        f.Objects.AddCurve(c, attrs(layer))
    assert f.Write(str(path), 7)
    return path


def _same_graph(a, b, scale=1.0):
    """Whether designs ``a`` and ``b`` have the same vertices (b = scale · a, any order) and the same segments."""
    assert a.num_vertices == b.num_vertices and a.num_segments == b.num_segments
    order = {tuple(np.round(v * scale, 6)): i for i, v in enumerate(b.vertices)}
    m = np.array([order[tuple(np.round(v * scale, 6))] for v in a.vertices])
    return {frozenset(e) for e in m[a.edges].tolist()} == {frozenset(e) for e in b.edges.tolist()}


def test_round_trip_of_a_bundled_design_as_lines_and_as_polylines(tmp_path):
    d = read_design(EXAMPLES / "manta_ray.obj")
    lines = _write(tmp_path / "lines.3dm", segments=[(d.vertices[a], d.vertices[b]) for a, b in d.edges])
    back = read_design(lines)
    assert _same_graph(d, back)
    assert "Millimeters" in back.note and "converted" not in back.note
    from xshells.linkage.graph import analyze

    beams = analyze(d)
    polys = [d.vertices[beams.beam_vertices(b)].tolist() for b in range(beams.num_beams)]  # one polyline per beam
    assert _same_graph(d, read_design(_write(tmp_path / "beams.3dm", polylines=polys)))


def test_a_design_in_metres_is_the_same_in_millimetres_and_deploys_to_the_same_energy(tmp_path):
    from xshells.deploy.simulate import rest_length_solve
    from xshells.linkage.linkage import Linkage
    from xshells.section import Material

    d = read_design(EXAMPLES / "manta_ray.obj")
    mm = read_design(_write(tmp_path / "mm.3dm", segments=[(d.vertices[a], d.vertices[b]) for a, b in d.edges]))
    m = read_design(_write(tmp_path / "m.3dm", units="Meters", tolerance=1e-5,
                           segments=[(d.vertices[a] / 1000, d.vertices[b] / 1000) for a, b in d.edges]))
    assert "converted to mm (x1000)" in m.note
    assert _same_graph(mm, m)
    energies = []
    for design in (mm, m):
        L = Linkage(design, Material.uniform("rectangle", [10, 7], E=20000, nu=0.3), subdivision=5)
        rest_length_solve(L)
        energies.append(L.energy())
    assert energies[1] == pytest.approx(energies[0], rel=1e-9)


def test_ends_within_the_tolerance_join_and_a_near_miss_is_refused(tmp_path):
    square = [((0, 0, 0), (100, 0, 0)), ((100, 0, 0), (100, 100, 0)), ((100, 100, 0), (0, 100, 0))]
    close = read_design(_write(tmp_path / "close.3dm", tolerance=0.01,
                               segments=square + [((0, 100.004, 0), (0, 0.003, 0))]))
    assert close.num_vertices == 4 and close.num_segments == 4  # closed up within 0.01 mm
    with pytest.raises(InputError, match=r"misses a vertex by 0\.2 millimeters, more than the file's tolerance 0\.01"):
        read_design(_write(tmp_path / "open.3dm", tolerance=0.01, segments=square + [((0, 100.2, 0), (0, 0, 0))]))


def test_curved_curves_and_layers_are_refused_in_one_line(tmp_path):
    arc = rhino3dm.NurbsCurve.CreateFromCircle(rhino3dm.Circle(rhino3dm.Point3d(0, 0, 0), 50.0))
    path = _write(tmp_path / "arc.3dm", curves=[(arc, 0)])
    with pytest.raises(InputError, match="is curved.*--sample"):
        read_design(path)
    from xshells.rhino import read_3dm_design

    sampled = read_3dm_design(path, sample=24)
    assert sampled.num_segments == 24 and sampled.num_vertices == 24  # closed: the ends snap together
    two = _write(tmp_path / "two.3dm", layers=("flat", "notes"),
                 segments=[(((0, 0, 0), (10, 0, 0)), 0), (((0, 5, 0), (10, 5, 0)), 1)])
    with pytest.raises(InputError, match="curves on several layers \\('flat', 'notes'\\): pick one with --layer"):
        read_design(two)
    assert read_3dm_design(two, layer="flat").num_segments == 1
    with pytest.raises(InputError, match="no layer 'beams'"):
        read_3dm_design(two, layer="beams")
    bad = tmp_path / "bad.3dm"
    bad.write_bytes(b"not a rhino file")
    with pytest.raises(InputError, match="not a readable Rhino .3dm file"):
        read_design(bad)


def test_a_target_surface_from_a_3dm_mesh_in_metres(tmp_path):
    from xshells.design.fitting import read_surface
    from xshells.inverse.surface import load_target

    cap = EXAMPLES / "targets" / "spherical_cap_R2000_30deg.obj"
    V, F = read_surface(cap)
    f = rhino3dm.File3dm()
    f.Settings.ModelUnitSystem = rhino3dm.UnitSystem.Meters
    f.Settings.ModelAbsoluteTolerance = 1e-6
    m = rhino3dm.Mesh()
    for x, y, z in (V / 1000).tolist():
        m.Vertices.Add(x, y, z)
    for a, b, c in F.tolist():
        m.Faces.AddFace(a, b, c)
    f.Objects.AddMesh(m)
    f.Write(str(tmp_path / "cap.3dm"), 7)
    V3, F3 = read_surface(tmp_path / "cap.3dm")
    assert F3.shape == F.shape
    np.testing.assert_allclose(np.sort(V3, axis=0), np.sort(V, axis=0), atol=1e-3)  # mm; Point3f is single precision
    assert load_target(tmp_path / "cap.3dm").diagonal == pytest.approx(load_target(cap).diagonal, rel=1e-6)
    empty = rhino3dm.File3dm()
    empty.Objects.AddLine(rhino3dm.Point3d(0, 0, 0), rhino3dm.Point3d(1, 0, 0))
    empty.Write(str(tmp_path / "lines.3dm"), 7)
    with pytest.raises(InputError, match="no mesh, Brep or extrusion"):
        read_surface(tmp_path / "lines.3dm")


def test_the_command_line_takes_layer_and_sample(tmp_path, capsys):
    from xshells.cli import main
    from xshells.rhino.read import set_defaults

    two = _write(tmp_path / "two.3dm", layers=("flat", "notes"),
                 segments=[(((0, 0, 0), (100, 0, 0)), 0), (((0, 50, 0), (100, 50, 0)), 1)])
    try:
        assert main(["fabricate", str(two), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
        assert "pick one with --layer" in capsys.readouterr().err
        assert main(["fabricate", str(two), "--layer", "notes", "--out", str(tmp_path / "o"), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert "Traceback" not in err and "\n" not in err.strip()  # read, then refused in one line (one segment, no joint)
        assert main(["deploy", str(two), "--sample", "0", "--out", str(tmp_path / "p"), "--no-progress"]) == 2
        assert "--sample must be from 1 to 1000 segments per curve, got 0" in capsys.readouterr().err
        d = read_design(EXAMPLES / "manta_ray.obj")
        m = _write(tmp_path / "manta_m.3dm", units="Meters", tolerance=1e-5,
                   segments=[(d.vertices[a] / 1000, d.vertices[b] / 1000) for a, b in d.edges])
        assert main(["fabricate", str(m), "--out", str(tmp_path / "f"), "--no-progress"]) == 0
        import json

        r = json.loads((tmp_path / "f" / "result.json").read_text())
        assert "Meters" in r["input"] and "converted to mm (x1000)" in r["input"]
        assert r["bom"]["beams"] == 26  # the manta ray's strips, in mm
    finally:
        set_defaults()  # the process-wide defaults back for the other tests


def test_an_empty_mesh_as_a_target_surface_is_one_line(tmp_path):
    # an internal error before ("data must be of shape (n, m)")
    import rhino3dm

    from xshells.design.fitting import read_surface
    from xshells.errors import InputError

    f = rhino3dm.File3dm()
    f.Objects.AddMesh(rhino3dm.Mesh())
    f.Write(str(tmp_path / "empty.3dm"), 7)
    with pytest.raises(InputError, match=r"empty.3dm: the surface's mesh has no vertices$"):
        read_surface(tmp_path / "empty.3dm")


@pytest.mark.parametrize("end, words", [((0, 0, 0), "is not a valid curve"), ((float("inf"), 0, 0), "non-finite coordinates")])
def test_a_degenerate_line_is_not_called_curved(tmp_path, end, words):
    import rhino3dm

    from xshells.errors import InputError
    from xshells.io import read_design

    f = rhino3dm.File3dm()
    f.Settings.ModelUnitSystem = rhino3dm.UnitSystem.Millimeters
    f.Objects.AddCurve(rhino3dm.LineCurve(rhino3dm.Point3d(0, 0, 0), rhino3dm.Point3d(100, 0, 0)))
    f.Objects.AddCurve(rhino3dm.LineCurve(rhino3dm.Point3d(0, 0, 0), rhino3dm.Point3d(*end)))
    f.Write(str(tmp_path / "d.3dm"), 7)
    with pytest.raises(InputError, match=rf"d.3dm: object 1 .*{words}"):  # "is curved ... give --sample" before
        read_design(tmp_path / "d.3dm")
