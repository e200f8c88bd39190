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
