"""``deployed.3dm`` from ``xshells deploy``: re-read with rhino3dm, it holds the expected layers, counts and units."""
import json
from collections import Counter

import numpy as np
import pytest

from data_paths import EXAMPLES
from xshells.cli import main
from xshells.io import read_design

rhino3dm = pytest.importorskip("rhino3dm")


def test_deploy_writes_a_layered_3dm_in_millimetres(tmp_path):
    design = EXAMPLES / "nonuniform_linkage.obj"
    assert main(["deploy", str(design), "--material", "rectangle:0.05,0.035", "--angle", "50", "--steps", "4",
                 "--subdivision", "4", "--out", str(tmp_path), "--no-progress"]) == 0
    f = rhino3dm.File3dm.Read(str(tmp_path / "deployed.3dm"))
    assert f is not None and f.Settings.ModelUnitSystem.name == "Millimeters"
    names = [layer.FullPath for layer in f.Layers]
    for layer in ("flat::beams", "flat::joints", "deployed::centerlines", "deployed::beams", "fabrication::strips"):
        assert layer in names, names
    count = Counter((names[o.Attributes.LayerIndex], type(o.Geometry).__name__) for o in f.Objects)
    d = read_design(design)
    joints = int(np.count_nonzero(np.bincount(d.edges.ravel()) >= 2))
    bom = json.loads((tmp_path / "bom.json").read_text())
    assert count[("flat::beams", "LineCurve")] == d.num_segments
    assert count[("flat::joints", "Point")] == joints == count[("flat::joints", "TextDot")]
    assert count[("deployed::centerlines", "PolylineCurve")] == d.num_segments
    assert count[("deployed::beams", "Mesh")] == 1
    assert count[("fabrication::strips", "PolylineCurve")] == bom["beams"]
    assert count[("fabrication::strips", "NurbsCurve")] == bom["holes"]  # the holes, as circles
    # the centerlines are the deployed rods: their ends are the deployed joints of result.json
    result = json.loads((tmp_path / "result.json").read_text())
    P = np.array(result["deployed"]["joint_positions"])
    ends = np.array([[o.Geometry.PointAtStart.X, o.Geometry.PointAtStart.Y, o.Geometry.PointAtStart.Z]
                     for o in f.Objects if names[o.Attributes.LayerIndex] == "deployed::centerlines"])
    dist = np.min(np.linalg.norm(ends[:, None, :] - P[None, :, :], axis=2), axis=1)
    assert np.median(dist) < 0.05 * np.ptp(P, axis=0).max()  # a rod starts at (half a joint edge from) a joint or free end
    mesh = next(o.Geometry for o in f.Objects if names[o.Attributes.LayerIndex] == "deployed::beams")
    assert mesh.VertexColors.Count == len(mesh.Vertices) > 0
    # its vertices are the swept beams of deployed.obj, stored in single precision (a picture of the state;
    # the centerlines carry it in double)
    V = np.array([[float(t) for t in line.split()[1:4]] for line in (tmp_path / "deployed.obj").read_text().splitlines()
                  if line.startswith("v ")])
    M = np.array([[p.X, p.Y, p.Z] for p in (mesh.Vertices[i] for i in range(len(mesh.Vertices)))])
    assert M.shape == V.shape
    assert np.abs(M - V).max() <= 1e-6 * np.ptp(V, axis=0).max()
    assert not mesh.Vertices.UseDoublePrecisionVertices


def test_optimize_writes_the_target_surface_it_fitted_and_reads_it_from_its_own_layer(tmp_path, reset_3dm_options):
    # deployed.3dm had no target layer; and --layer chose the surface's layer too, so one file could not hold both
    d = read_design(EXAMPLES / "nonuniform_linkage.obj")
    V = d.vertices * 200
    f = rhino3dm.File3dm()
    f.Settings.ModelUnitSystem = rhino3dm.UnitSystem.Millimeters
    design, target = f.Layers.AddLayer("design", (0, 0, 0, 255)), f.Layers.AddLayer("target", (0, 0, 0, 255))
    a, t = rhino3dm.ObjectAttributes(), rhino3dm.ObjectAttributes()
    a.LayerIndex, t.LayerIndex = design, target
    for i, j in d.edges:
        f.Objects.AddLine(rhino3dm.Point3d(*V[i]), rhino3dm.Point3d(*V[j]), a)
    lo, hi = V.min(axis=0) - 50, V.max(axis=0) + 50
    m = rhino3dm.Mesh()
    for x, y in ((lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1]), ((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2)):
        m.Vertices.Add(x, y, 0.0 if x in (lo[0], hi[0]) else 40.0)
    for k in range(4):
        m.Faces.AddFace(k, (k + 1) % 4, 4)
    f.Objects.AddMesh(m, t)
    path = str(tmp_path / "both.3dm")
    f.Write(path, 7)
    out = tmp_path / "o"
    assert main(["optimize", path, "--layer", "design", "--target-surface", path, "--target-layer", "target",
                 "--angle", "50", "--max-iters", "1", "--steps", "5", "--subdivision", "4", "--no-baseline",
                 "--out", str(out), "--no-progress"]) == 0
    g = rhino3dm.File3dm.Read(str(out / "deployed.3dm"))
    names = [layer.FullPath for layer in g.Layers]
    meshes = [o.Geometry for o in g.Objects if names[o.Attributes.LayerIndex] == "target"]
    assert len(meshes) == 1 and len(meshes[0].Vertices) == 5 and meshes[0].Faces.Count == 4
    assert "target surface both.3dm: layer 'target', units Millimeters" in json.loads((out / "result.json").read_text())["warnings"]
