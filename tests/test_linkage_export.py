"""Exporting linkage centerlines and swept beams."""
import meshio
import numpy as np

from xshells.io import read_design
from xshells.io.sweep import enclosed_volume
from xshells.linkage.export import centerlines, swept_mesh, write_centerlines, write_swept
from xshells.linkage.linkage import Linkage
from xshells.section import Material

from data_paths import EXAMPLES


def small():
    return Linkage(read_design(EXAMPLES / "nonuniform_linkage.obj"), Material.uniform("rectangle", [0.1, 0.07], E=20000, nu=0.3), subdivision=4)


def test_centerlines_and_swept_mesh(tmp_path):
    L = small()
    lines = centerlines(L)
    assert len(lines) == L.num_segments and all(len(c) == 5 for c in lines)
    mesh = swept_mesh(L)
    assert np.isfinite(mesh.vertices).all()
    # each rod's tube encloses about area x length
    assert enclosed_volume(mesh.vertices, mesh.triangles) > 0
    assert "bending_energy_density" in mesh.fields and "bending_stress" in mesh.fields
    write_centerlines(tmp_path / "c.obj", L)
    write_swept(tmp_path / "s.ply", L)
    write_swept(tmp_path / "s.obj", L)
    m = meshio.read(tmp_path / "s.ply")
    assert len(m.points) == len(mesh.vertices)
    assert "bending_energy_density" in m.point_data
    assert (tmp_path / "c.obj").read_text().count("\nl ") + (tmp_path / "c.obj").read_text().startswith("l ") >= L.num_segments
