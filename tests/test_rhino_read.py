"""Designs from Rhino .3dm files: round trip from a bundled OBJ, units, snapping within the file's tolerance,
near misses, curved curves, layers."""
import dataclasses

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


def _manta_lines():
    d = read_design(EXAMPLES / "manta_ray.obj")
    return d, [rhino3dm.LineCurve(rhino3dm.Point3d(*d.vertices[a]), rhino3dm.Point3d(*d.vertices[b])) for a, b in d.edges]


def _block(f, name, geometry, layer=0):
    """A block definition of ``geometry`` on layer index ``layer``; returns its id."""
    a = rhino3dm.ObjectAttributes()
    a.LayerIndex = layer
    index = f.InstanceDefinitions.Add(name, "", "", "", rhino3dm.Point3d(0, 0, 0), tuple(geometry), (a,) * len(geometry))
    return f.InstanceDefinitions[index].Id


def _place(f, idef, xform, layer=0):
    a = rhino3dm.ObjectAttributes()
    a.LayerIndex = layer
    f.Objects.AddInstanceObject(rhino3dm.InstanceReference(idef, xform), a)


def _new(units="Millimeters", tolerance=0.01, layers=("design",)):
    f = rhino3dm.File3dm()
    f.Settings.ModelUnitSystem = getattr(rhino3dm.UnitSystem, units)
    f.Settings.ModelAbsoluteTolerance = tolerance
    for name in layers:
        f.Layers.AddLayer(name, (0, 0, 0, 255))
    return f


def test_a_design_placed_as_a_block_is_read_where_it_is_placed(tmp_path):
    # the definition's own lines were read as the design, the placement's move ignored
    d, lines = _manta_lines()
    turn = rhino3dm.Transform.Rotation(0.5, rhino3dm.Vector3d(0, 0, 1), rhino3dm.Point3d(0, 0, 0))
    half = rhino3dm.Transform.Scale(rhino3dm.Point3d(0, 0, 0), 0.5)
    move = rhino3dm.Transform.Multiply(rhino3dm.Transform.Translation(5000, -300, 20), rhino3dm.Transform.Multiply(turn, half))
    f = _new()
    _place(f, _block(f, "manta", lines), move)
    f.Write(str(tmp_path / "block.3dm"), 7)
    c, s = np.cos(0.5), np.sin(0.5)
    expect = 0.5 * d.vertices @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + [5000, -300, 20]
    placed = read_design(tmp_path / "block.3dm")
    moved = dataclasses.replace(d, vertices=expect)
    assert _same_graph(moved, placed)
    # nested: the manta block inside a block placed twice, the transforms composed; unplaced definitions are no design
    f = _new()
    inner = _block(f, "manta", lines)
    outer = _block(f, "pair", [rhino3dm.InstanceReference(inner, rhino3dm.Transform.Translation(0, 1000, 0))])
    _block(f, "unused", [rhino3dm.LineCurve(rhino3dm.Point3d(0, 0, 0), rhino3dm.Point3d(1, 0, 0))])
    _place(f, outer, rhino3dm.Transform.Translation(100, 0, 0))
    _place(f, outer, rhino3dm.Transform.Translation(100, 5000, 0))
    f.Write(str(tmp_path / "nested.3dm"), 7)
    two = read_design(tmp_path / "nested.3dm")
    assert two.num_vertices == 2 * d.num_vertices and two.num_segments == 2 * d.num_segments
    np.testing.assert_allclose(two.vertices.min(axis=0), d.vertices.min(axis=0) + [100, 1000, 0], atol=1e-9)
    np.testing.assert_allclose(two.vertices.max(axis=0), d.vertices.max(axis=0) + [100, 6000, 0], atol=1e-9)
    # a stretched block would change the beams' shape: refused in one line naming it
    f = _new()
    stretch = rhino3dm.Transform.Scale(rhino3dm.Plane.WorldXY(), 2.0, 1.0, 1.0)
    _place(f, _block(f, "manta", lines), stretch)
    f.Write(str(tmp_path / "stretched.3dm"), 7)
    with pytest.raises(InputError, match=r"stretched.3dm: object \d+ \(a block placement\) of block 'manta' is "
                                         r"stretched, sheared or projected.*Explode"):
        read_design(tmp_path / "stretched.3dm")
    # ... but a stretched block of other things, on another layer, does not stop the design from being read
    f = _new(layers=("design", "notes"))
    _place(f, _block(f, "title", [rhino3dm.LineCurve(rhino3dm.Point3d(0, 0, 0), rhino3dm.Point3d(1, 0, 0))], layer=1),
           stretch)
    _place(f, _block(f, "manta", lines), rhino3dm.Transform.Translation(0, 0, 0))
    f.Write(str(tmp_path / "titled.3dm"), 7)
    from xshells.rhino import read_3dm_design

    assert _same_graph(d, read_3dm_design(tmp_path / "titled.3dm", layer="design"))
    # a block whose objects are not in the file (linked to another): no design, said so, not an empty placement
    f = _new()
    idef = _block(f, "linked", lines[:2])
    for oid in next(d for d in f.InstanceDefinitions if d.Name == "linked").GetObjectIds():
        f.Objects.Delete(oid)
    _place(f, idef, rhino3dm.Transform.Translation(0, 0, 0))
    f.Objects.AddLine(rhino3dm.Point3d(0, 0, 0), rhino3dm.Point3d(0, 100, 0))
    f.Objects.AddLine(rhino3dm.Point3d(-50, 50, 0), rhino3dm.Point3d(50, 50, 0))
    f.Write(str(tmp_path / "linked.3dm"), 7)
    with pytest.raises(InputError, match=r"linked.3dm: block 'linked' \(placed by object 0\) is linked to a file"):
        read_design(tmp_path / "linked.3dm")


def test_a_target_mesh_placed_as_a_block_is_read_where_it_is_placed(tmp_path):
    from xshells.rhino import read_3dm_surface

    m = rhino3dm.Mesh()
    for p in ((0, 0, 0), (100, 0, 0), (100, 100, 10), (0, 100, 0)):
        m.Vertices.Add(*p)
    m.Faces.AddFace(0, 1, 2, 3)
    f = _new(layers=("target",))
    _place(f, _block(f, "srf", [m]), rhino3dm.Transform.Translation(0, 0, 500))
    f.Write(str(tmp_path / "srf.3dm"), 7)
    V, F = read_3dm_surface(tmp_path / "srf.3dm")
    assert len(F) == 2 and V[:, 2].min() == 500 and V[:, 2].max() == 510


def test_a_target_mesh_far_from_the_origin_keeps_its_vertices(tmp_path):
    # map coordinates in metres: read in single precision, 400 vertices became fewer and moved by up to 92.8 mm
    from xshells.rhino import read_3dm_surface

    n = 20
    X, Y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    V = np.c_[X.ravel(), Y.ravel(), 0.35 * (X.ravel() ** 2 - Y.ravel() ** 2)] + [500000.0, 5000000.0, 120.0]
    m = rhino3dm.Mesh()
    for p in V.tolist():
        m.Vertices.AddPoint3d(*p)
    for i in range(n - 1):
        for j in range(n - 1):
            m.Faces.AddFace(i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j)
    f = _new("Meters", 1e-4, layers=())
    f.Objects.AddMesh(m)
    f.Write(str(tmp_path / "utm.3dm"), 7)
    Vr, Fr = read_3dm_surface(tmp_path / "utm.3dm")
    assert len(Vr) == n * n and len(Fr) == 2 * (n - 1) ** 2
    np.testing.assert_allclose(Vr, V * 1000, rtol=0, atol=1e-6)  # mm


def test_the_near_miss_window_follows_the_design_not_only_the_tolerance(tmp_path):
    # The uniform linkage at 200 mm a unit (free ends 30 mm from a joint) saved in metres with a 1 mm tolerance
    # was refused (100 tolerances = 100 mm); a 2 mm miss at a 0.01 mm tolerance passed as a free end.
    d = read_design(EXAMPLES / "uniform_linkage.obj")
    V = d.vertices * 200
    metres = read_design(_write(tmp_path / "m.3dm", units="Meters", tolerance=1e-3,
                                segments=[(V[a] / 1000, V[b] / 1000) for a, b in d.edges]))
    assert (metres.num_vertices, metres.num_segments) == (d.num_vertices, d.num_segments)
    np.testing.assert_allclose(np.sort(metres.vertices, axis=0), np.sort(V, axis=0), atol=1e-9)
    m, _ = _manta_lines()
    segs = [(m.vertices[a].copy(), m.vertices[b]) for a, b in m.edges]
    segs[5][0][0] += 2.0
    with pytest.raises(InputError, match=r"far.3dm: the end of object 5 at .* misses a vertex by 2 millimeters, more "
                                         r"than the file's tolerance 0\.01: join them in Rhino \(or set the tolerance "
                                         r"above 2 millimeters\), or, for a free end, keep it at least 4\.1 millimeters"):
        read_design(_write(tmp_path / "far.3dm", tolerance=0.01, segments=segs))


def test_an_unmeshed_surface_beside_a_mesh_is_refused(tmp_path):
    # the Brep was dropped and the mesh alone taken as the target, without a word
    from xshells.rhino import read_3dm_surface

    m = rhino3dm.Mesh()
    for p in ((0, 0, 0), (100, 0, 0), (100, 100, 0)):
        m.Vertices.Add(*p)
    m.Faces.AddFace(0, 1, 2)
    f = _new(layers=())
    f.Objects.AddMesh(m)
    f.Objects.AddBrep(rhino3dm.Brep.CreateFromBox(rhino3dm.Box(rhino3dm.BoundingBox(0, 0, 0, 10, 10, 10))))
    f.Write(str(tmp_path / "both.3dm"), 7)
    with pytest.raises(InputError, match=r"both.3dm: object 1 is a surface saved without its render mesh"):
        read_3dm_surface(tmp_path / "both.3dm")
    f.Objects.Delete(f.Objects[1].Attributes.Id)
    f.Objects.AddSphere(rhino3dm.Sphere(rhino3dm.Point3d(0, 0, 0), 1000))  # a NURBS surface: no mesh at all
    f.Write(str(tmp_path / "sphere.3dm"), 7)
    with pytest.raises(InputError, match=r"sphere.3dm: object 1 is a NurbsSurface, which carries no mesh"):
        read_3dm_surface(tmp_path / "sphere.3dm")


def test_a_layer_name_of_several_layers_is_ambiguous(tmp_path):
    # A::design was taken for "design" without a word about B::design
    from xshells.rhino import read_3dm_design

    f = _new(layers=())
    for parent, y in (("A", 0), ("B", 50)):
        top = rhino3dm.Layer()
        top.Name = parent
        pi = f.Layers.Add(top)
        child = rhino3dm.Layer()
        child.Name = "design"
        child.ParentLayerId = f.Layers[pi].Id
        a = rhino3dm.ObjectAttributes()
        a.LayerIndex = f.Layers.Add(child)
        f.Objects.AddLine(rhino3dm.Point3d(0, y, 0), rhino3dm.Point3d(100, y, 0), a)
        f.Objects.AddLine(rhino3dm.Point3d(50, y - 20, 0), rhino3dm.Point3d(50, y + 20, 0), a)
    f.Write(str(tmp_path / "two.3dm"), 7)
    with pytest.raises(InputError, match=r"two.3dm: layer 'design' is ambiguous \('A::design', 'B::design'\): give its "
                                         r"full path$"):
        read_3dm_design(tmp_path / "two.3dm", layer="design")
    assert read_3dm_design(tmp_path / "two.3dm", layer="B::design").vertices[:, 1].min() == 30


def _mesh_file(path, units="Millimeters", layers=("target",), scale=1.0):
    """A 2 m square with a bump, meshed 8 x 8, once on each of ``layers``."""
    f = _new(units, 1e-6 * scale if units == "Meters" else 0.001, layers=layers)
    n = 9
    X, Y = np.meshgrid(np.linspace(0, 2000, n), np.linspace(0, 2000, n))
    Z = 300 * np.exp(-((X - 1000) ** 2 + (Y - 1000) ** 2) / 800**2)
    for k in range(len(layers)):
        m = rhino3dm.Mesh()
        for p in np.c_[X.ravel(), Y.ravel(), Z.ravel()].tolist():
            m.Vertices.Add(*(c / (1000 if units == "Meters" else 1) for c in p))
        for i in range(n - 1):
            for j in range(n - 1):
                m.Faces.AddFace(i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j)
        a = rhino3dm.ObjectAttributes()
        a.LayerIndex = k
        f.Objects.AddMesh(m, a)
    f.Write(str(path), 7)
    return path


def test_inverse_on_a_3dm_in_metres_says_so_and_speaks_mm(tmp_path, capsys, reset_3dm_options):
    # no line said the surface was converted, result.json called its units the file's, --spacing had no unit
    from xshells.cli import main
    from xshells.inverse.run import units_text
    from xshells.inverse.surface import load_target

    path = _mesh_file(tmp_path / "cap_m.3dm", units="Meters")
    surface = load_target(path)
    assert surface.note == "cap_m.3dm: layer 'target', units Meters, converted to mm (x1000)"
    assert units_text(surface).startswith("mm (the .3dm surface is read in mm")
    assert main(["inverse", str(path), "--spacing", "0.3", "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "xshells inverse: note: cap_m.3dm: layer 'target', units Meters, converted to mm (x1000)"
    assert err[1].startswith("xshells inverse: error: --spacing 0.3 mm gives about") and len(err) == 2
    assert main(["inverse", str(path), "--beams", "even", "--material", "rectangle:120,7", "--spacing", "200",
                 "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "beams (120 mm wide) would overlap (gap 66.1 mm)" in err and "joint spacing (200 mm)" in err


def test_the_target_layer_is_chosen_apart_from_the_design_layer(tmp_path, capsys, reset_3dm_options):
    # --layer chose both (the design's layer was looked for among the surfaces); inverse had no layer option
    from xshells.cli import main

    two = _mesh_file(tmp_path / "two.3dm", layers=("a", "b"))
    out = str(tmp_path / "o")
    assert main(["inverse", str(two), "--spacing", "5000", "--out", out, "--no-progress"]) == 2
    assert "surfaces on several layers ('a', 'b'): pick one with --target-layer" in capsys.readouterr().err
    assert main(["inverse", str(two), "--target-layer", "b", "--spacing", "5000", "--out", out, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "note: two.3dm: layer 'b', units Millimeters" in err and "--spacing 5000 mm is larger than" in err
    obj = EXAMPLES / "targets" / "spherical_cap_R2000_30deg.obj"
    assert main(["inverse", str(obj), "--target-layer", "b", "--out", out, "--no-progress"]) == 2
    assert f"--target-layer reads a .3dm target surface: {obj} is not one" in capsys.readouterr().err
    assert main(["optimize", str(EXAMPLES / "quad.obj"), "--target-layer", "b", "--out", out, "--no-progress"]) == 2
    assert "--target-layer reads a .3dm target surface: none is given" in capsys.readouterr().err


def test_fabricate_refuses_units_for_a_3dm_and_both_commands_say_the_conversion_without_progress(tmp_path, capsys, reset_3dm_options):
    # --units m on a file in metres scaled it x1000 a second time; --no-progress hid the conversion
    import json

    from xshells.cli import main

    d = read_design(EXAMPLES / "manta_ray.obj")
    m = _write(tmp_path / "manta_m.3dm", units="Meters", tolerance=1e-5,
               segments=[(d.vertices[a] / 1000, d.vertices[b] / 1000) for a, b in d.edges])
    assert main(["fabricate", str(m), "--units", "m", "--out", str(tmp_path / "f"), "--no-progress"]) == 2
    assert capsys.readouterr().err.strip() == (f"xshells fabricate: error: {m}: --units m does not apply to a .3dm: the "
                                               "file states its units (Meters) and is read in mm; leave --units out")
    note = "  note: manta_m.3dm: layer 'beams', units Meters, converted to mm (x1000)"
    assert main(["fabricate", str(m), "--subdivision", "4", "--out", str(tmp_path / "f"), "--no-progress"]) == 0
    assert note in capsys.readouterr().out.splitlines()
    assert json.loads((tmp_path / "f" / "bom.json").read_text())["sections"][0]["total_length_mm"] > 20000  # 26 m
    assert main(["analyze", str(m), "--supports", "lowest:4", "--load", "self-weight", "--density", "1e-9",
                 "--steps", "5", "--subdivision", "4", "--no-critical", "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    assert note in capsys.readouterr().out.splitlines()
