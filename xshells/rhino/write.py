"""Writing results as one layered Rhino ``.3dm`` (millimetres, the unit of every output).

Layers (Rhino writes the nesting as ``flat::beams``):

* ``flat/beams``: one line per segment of the flat layout; ``flat/joints``:
  a point and a TextDot (the design's vertex id) per joint;
* ``deployed/centerlines``: one polyline per segment of the deployed rods;
  ``deployed/beams``: the swept beams as one mesh, vertex colours by
  √(bending-energy density);
* ``actuators``: points and torque TextDots, where a command computed them;
* ``target``: the target surface, where one was used;
* ``fabrication/strips``: the strips laid out as in ``beams.svg`` (outlines
  as closed polylines, holes as circles), where the fabrication files were written.
"""
from __future__ import annotations

import os
import tempfile

import numpy as np

from ..errors import InputError


def _layer(rhino3dm, f, path: str, colour=(0, 0, 0, 255)) -> int:
    """The index of layer ``a/b`` (parents created as needed)."""
    parent_id, index = None, -1
    for depth, name in enumerate(path.split("/")):
        full = "::".join(path.split("/")[: depth + 1])
        found = [i for i, layer in enumerate(f.Layers) if layer.FullPath == full]
        if found:
            index = found[0]
        else:
            layer = rhino3dm.Layer()
            layer.Name = name
            layer.Color = colour
            if parent_id is not None:
                layer.ParentLayerId = parent_id
            index = f.Layers.Add(layer)
        parent_id = f.Layers[index].Id
    return index


def _attrs(rhino3dm, layer: int):
    a = rhino3dm.ObjectAttributes()
    a.LayerIndex = layer
    return a


def _mesh(rhino3dm, vertices, triangles, single: bool = False):
    """A rhino3dm mesh of ``vertices`` (n, 3) and ``triangles`` (t, 3).

    The bound methods are looked up once: each ``m.Vertices`` builds a new
    wrapper object, which took 3-4x the time of the ``Add`` itself.

    ``single``: store the vertices in single precision (Rhino's usual mesh
    vertices), for meshes that only show something. rhino3dm writes a mesh
    with double-precision vertices at about six times the cost: the manta ray's swept
    beams (13k vertices) took 0.29 s of ``Write`` in double, 0.05 s in single.
    """
    m = rhino3dm.Mesh()
    add, face = m.Vertices.Add, m.Faces.AddFace
    for x, y, z in np.asarray(vertices, float).tolist():
        add(x, y, z)
    if single:  # after the vertices: ``Add`` of a double switches the mesh (back) to double precision
        m.Vertices.UseDoublePrecisionVertices = False
    for a, b, c in np.asarray(triangles, int).tolist():
        face(a, b, c)
    return m


def write_3dm(path, *, flat_design=None, deployed=None, actuators=None, target=None, strips=None) -> str:
    """Write the given parts as layers of one ``.3dm`` (mm), atomically; returns the path.

    Parameters
    ----------
    flat_design : xshells.io.design.Design, optional
        The flat layout (lines, joints with their vertex ids).
    deployed : xshells.linkage.linkage.Linkage, optional
        A solved state: centerlines and the swept beam mesh.
    actuators : (joint positions (a, 3), torques (a,), vertex ids (a,)), optional
    target : (vertices (n, 3), triangles (t, 3)), optional
    strips : xshells.fabrication.run.FabricationPlan, optional
    """
    try:
        import rhino3dm
    except ImportError:  # pragma: no cover (a dependency)
        raise InputError("writing .3dm needs the rhino3dm package (pip install rhino3dm)") from None
    f = rhino3dm.File3dm()
    f.Settings.ModelUnitSystem = rhino3dm.UnitSystem.Millimeters
    f.Settings.ModelAbsoluteTolerance = 0.001
    P3 = lambda p: rhino3dm.Point3d(float(p[0]), float(p[1]), float(p[2]))  # noqa: E731
    if flat_design is not None:
        beams, joints = _layer(rhino3dm, f, "flat/beams", (60, 60, 60, 255)), _layer(rhino3dm, f, "flat/joints", (220, 40, 40, 255))
        V = np.asarray(flat_design.vertices, float)
        for a, b in flat_design.edges.tolist():
            f.Objects.AddLine(P3(V[a]), P3(V[b]), _attrs(rhino3dm, beams))
        valence = np.bincount(flat_design.edges.ravel(), minlength=len(V))
        for v in np.flatnonzero(valence >= 2).tolist():
            f.Objects.AddPoint(P3(V[v]), _attrs(rhino3dm, joints))
            f.Objects.AddTextDot(str(v), P3(V[v]), _attrs(rhino3dm, joints))
    if deployed is not None:
        from ..linkage.export import centerlines, scalar_fields, swept_mesh
        from ..app.exports import field_colors

        lines = _layer(rhino3dm, f, "deployed/centerlines", (40, 40, 160, 255))
        for pts in centerlines(deployed):
            pl = rhino3dm.Point3dList()
            for x, y, z in pts.tolist():
                pl.Add(x, y, z)
            f.Objects.AddPolyline(pl, _attrs(rhino3dm, lines))
        fields = scalar_fields(deployed)
        mesh = swept_mesh(deployed, fields)
        colours = field_colors(np.sqrt(np.maximum(mesh.fields["bending_energy_density"], 0.0)))
        # single precision (7 digits: 0.4 µm on a 4 m span): the swept beams show the state; the
        # centerlines above carry it in double
        m = _mesh(rhino3dm, mesh.vertices, mesh.triangles, single=True)
        add = m.VertexColors.Add
        for r, g, b in np.asarray(colours, dtype=np.int64).tolist():
            add(r, g, b)
        f.Objects.AddMesh(m, _attrs(rhino3dm, _layer(rhino3dm, f, "deployed/beams", (180, 120, 40, 255))))
    if actuators is not None:
        layer = _layer(rhino3dm, f, "actuators", (230, 120, 0, 255))
        for p, tau, v in zip(*actuators):
            f.Objects.AddPoint(P3(p), _attrs(rhino3dm, layer))
            f.Objects.AddTextDot(f"{v}: {tau:.4g}", P3(p), _attrs(rhino3dm, layer))
    if target is not None:
        Vt, Ft = target
        m = _mesh(rhino3dm, Vt, Ft)
        f.Objects.AddMesh(m, _attrs(rhino3dm, _layer(rhino3dm, f, "target", (120, 160, 120, 255))))
    if strips is not None:
        from ..fabrication.drawings import sheet_layout

        layer = _layer(rhino3dm, f, "fabrication/strips", (0, 0, 0, 255))
        placed, _, _ = sheet_layout(strips.beams, strips.nesting)
        for q in placed:
            b = strips.beams[q.beam]
            x0, y0, w = q.x, -q.y, b.section.width  # as the DXF: y mirrored so that it reads like the SVG
            pl = rhino3dm.Point3dList()
            for x, y in ((x0, y0), (x0 + b.length, y0), (x0 + b.length, y0 - w), (x0, y0 - w), (x0, y0)):
                pl.Add(x, y, 0.0)
            f.Objects.AddPolyline(pl, _attrs(rhino3dm, layer))
            for pos in b.hole_positions.tolist():
                f.Objects.AddCircle(rhino3dm.Circle(rhino3dm.Point3d(x0 + pos, y0 - 0.5 * w, 0.0), 0.5 * strips.hole_diameter),
                                    _attrs(rhino3dm, layer))
            f.Objects.AddTextDot(b.label, rhino3dm.Point3d(x0, y0 - 0.5 * w, 0.0), _attrs(rhino3dm, layer))
    from ..io.export import output_target, replace_with

    path = os.fspath(path)
    target = output_target(path)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(target), suffix=".3dm.tmp")
    os.close(fd)
    try:
        if not f.Write(tmp, 7):
            raise OSError(f"{path}: rhino3dm could not write the file")
        replace_with(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path
