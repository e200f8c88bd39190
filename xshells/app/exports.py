"""Exports of the app: fabrication drawings (SVG, DXF), the deployed mesh (OBJ, PLY, glTF), the case JSON and a PNG.

Drawings are of the *flat* layout at 1:1 in millimetres (``units_to_mm``
converts the design's units; the bundled designs are in mm): one line per
beam segment, a circle and a label per joint, and each segment's rest length
written at its midpoint. Every file is written atomically (temporary file
in the destination folder, then :func:`os.replace`).
"""
from __future__ import annotations

import io
import json
import os
from xml.sax.saxutils import escape

import numpy as np

from ..errors import InputError
from ..io.export import atomic_write_bytes, atomic_write_text
from .core import Layout

MESH_FORMATS = (".obj", ".ply", ".gltf", ".glb")


def _rest(layout: Layout, rest_lengths) -> np.ndarray:
    p = layout.segment_lengths() if rest_lengths is None else np.asarray(rest_lengths, float)
    if p.shape != (layout.num_segments,):
        raise InputError(f"rest lengths: expected {layout.num_segments} values, got {p.size}")
    return p


def _joint_vertices(layout: Layout) -> np.ndarray:
    return np.unique(layout.edges)


def svg_text(layout: Layout, rest_lengths=None, units_to_mm: float = 1.0, margin_mm: float = 20.0) -> str:
    """The flat layout as an SVG drawing at 1:1 in mm (y up in the design, so flipped for SVG).

    Beams are ``<line class="beam">`` with ``data-segment`` and
    ``data-rest-length`` (mm); joints are ``<circle class="joint">`` with a
    ``<text class="joint-label">``; rest lengths are ``<text class="rest-length">``.
    """
    V = layout.vertices * units_to_mm
    p = _rest(layout, rest_lengths) * units_to_mm
    lo, hi = V.min(axis=0) - margin_mm, V.max(axis=0) + margin_mm
    w, h = hi - lo
    X = lambda q: (q[0] - lo[0], hi[1] - q[1])  # noqa: E731  (SVG y points down)
    fs = max(2.0, 0.12 * float(np.median(layout.segment_lengths())) * units_to_mm)
    out = [f'<?xml version="1.0" encoding="UTF-8"?>\n'
           f'<svg xmlns="http://www.w3.org/2000/svg" width="{w:.3f}mm" height="{h:.3f}mm" viewBox="0 0 {w:.3f} {h:.3f}">\n'
           f'<title>X-shell flat layout, 1:1, mm</title>\n<g id="beams" stroke="black" stroke-width="0.3" fill="none">\n']
    for s, (a, b) in enumerate(layout.edges.tolist()):
        (x1, y1), (x2, y2) = X(V[a]), X(V[b])
        out.append(f'<line class="beam" data-segment="{s}" data-rest-length="{p[s]:.4f}" '
                   f'x1="{x1:.4f}" y1="{y1:.4f}" x2="{x2:.4f}" y2="{y2:.4f}"/>\n')
    out.append(f'</g>\n<g id="rest-lengths" fill="blue" font-size="{fs * 0.8:.3f}" text-anchor="middle" font-family="sans-serif">\n')
    for s, (a, b) in enumerate(layout.edges.tolist()):
        x, y = X(0.5 * (V[a] + V[b]))
        out.append(f'<text class="rest-length" data-segment="{s}" x="{x:.4f}" y="{y:.4f}">{p[s]:.2f}</text>\n')
    out.append(f'</g>\n<g id="joints" font-size="{fs:.3f}" font-family="sans-serif">\n')
    for v in _joint_vertices(layout).tolist():
        x, y = X(V[v])
        out.append(f'<circle class="joint" data-joint="{v}" cx="{x:.4f}" cy="{y:.4f}" r="{fs / 3:.3f}" fill="red"/>'
                   f'<text class="joint-label" x="{x + fs / 2:.4f}" y="{y - fs / 2:.4f}">{escape(str(v))}</text>\n')
    out.append("</g>\n</svg>\n")
    return "".join(out)


def write_svg(path, layout: Layout, rest_lengths=None, units_to_mm: float = 1.0) -> None:
    atomic_write_text(path, svg_text(layout, rest_lengths, units_to_mm))


def dxf_bytes(layout: Layout, rest_lengths=None, units_to_mm: float = 1.0) -> bytes:
    """The flat layout as DXF (mm): layer BEAMS (LINE per segment), JOINTS (CIRCLE), LABELS and REST_LENGTHS (TEXT)."""
    import ezdxf

    V = layout.vertices * units_to_mm
    p = _rest(layout, rest_lengths) * units_to_mm
    fs = max(2.0, 0.12 * float(np.median(layout.segment_lengths())) * units_to_mm)
    doc = ezdxf.new("R2010")
    doc.units = ezdxf.units.MM
    for name, color in (("BEAMS", 7), ("JOINTS", 1), ("LABELS", 3), ("REST_LENGTHS", 5)):
        doc.layers.add(name, color=color)
    msp = doc.modelspace()
    for s, (a, b) in enumerate(layout.edges.tolist()):
        msp.add_line(tuple(V[a]), tuple(V[b]), dxfattribs={"layer": "BEAMS"})
        mid = 0.5 * (V[a] + V[b])
        msp.add_text(f"{p[s]:.2f}", height=0.8 * fs, dxfattribs={"layer": "REST_LENGTHS", "insert": tuple(mid)})
    for v in _joint_vertices(layout).tolist():
        msp.add_circle(tuple(V[v]), radius=fs / 3, dxfattribs={"layer": "JOINTS"})
        msp.add_text(str(v), height=fs, dxfattribs={"layer": "LABELS", "insert": tuple(V[v] + fs / 2)})
    buf = io.StringIO()
    doc.write(buf)
    return buf.getvalue().encode("utf-8")


def write_dxf(path, layout: Layout, rest_lengths=None, units_to_mm: float = 1.0) -> None:
    atomic_write_bytes(path, dxf_bytes(layout, rest_lengths, units_to_mm))


def field_colors(values: np.ndarray, cmap: str = "viridis") -> np.ndarray:
    """(N, 3) uint8 colours of a scalar field, scaled to its 1st–99th percentile range."""
    from matplotlib import colormaps

    v = np.asarray(values, float)
    if v.size == 0:
        return np.zeros((0, 3), np.uint8)
    lo, hi = np.percentile(v, [1, 99])
    t = np.clip((v - lo) / (hi - lo), 0, 1) if hi > lo else np.zeros_like(v)
    return (colormaps[cmap](t)[:, :3] * 255).astype(np.uint8)


def write_mesh(path, mesh, field: str | None = None) -> None:
    """Write a :class:`xshells.io.sweep.SweptMesh` as OBJ, PLY (all fields) or glTF/GLB (``field`` as vertex colours)."""
    from ..io.sweep import write_obj, write_ply

    ext = os.path.splitext(str(path))[1].lower()
    if ext == ".obj":
        write_obj(path, mesh)
    elif ext == ".ply":
        write_ply(path, mesh)
    elif ext in (".gltf", ".glb"):
        import trimesh

        colors = None
        if field is not None and field in mesh.fields:
            colors = np.c_[field_colors(mesh.fields[field]), np.full(len(mesh.vertices), 255, np.uint8)]
        tm = trimesh.Trimesh(mesh.vertices, mesh.triangles, vertex_colors=colors, process=False)
        if ext == ".glb":
            atomic_write_bytes(path, tm.export(file_type="glb"))
        else:
            # a self-contained .gltf: buffers embedded as data URIs
            files = tm.export(file_type="gltf", embed_buffers=True)
            data = files["model.gltf"] if isinstance(files, dict) else files
            atomic_write_bytes(path, data if isinstance(data, bytes) else str(data).encode())
    else:
        raise InputError(f"{path}: unknown mesh format {ext!r} (use {', '.join(MESH_FORMATS)})")


def write_case(path, name: str, layout: Layout, material: dict, subdivision: int, angle_deg: float | None,
               rest_lengths=None) -> list[str]:
    """Write a case JSON that ``xshells deploy`` and the app reload, with its design (and rest lengths) beside it.

    Returns the paths written.
    """
    from ..io.export import write_design_obj
    from .core import layout_to_design

    path = os.fspath(path)
    folder, stem = os.path.dirname(os.path.abspath(path)), os.path.splitext(os.path.basename(path))[0]
    design_name = f"{stem}_flat.obj"
    write_design_obj(os.path.join(folder, design_name), layout_to_design(layout))
    written = [os.path.join(folder, design_name)]
    spec = {"name": name, "file": design_name, "subdivision": int(subdivision),
            "material": {k: v for k, v in material.items() if k in ("type", "params", "E", "nu", "stiff_axis")}}
    if angle_deg is not None:
        spec["angle_deg"] = float(angle_deg)
    if rest_lengths is not None:
        rl_name = f"{stem}_rest_lengths.txt"
        atomic_write_text(os.path.join(folder, rl_name), "".join(f"{v!r}\n" for v in np.asarray(rest_lengths, float).tolist()))
        spec["rest_lengths"] = rl_name
        written.append(os.path.join(folder, rl_name))
    atomic_write_text(path, json.dumps(spec, indent=1) + "\n")
    return [path] + written


def write_png(path, linkage, title: str = "") -> None:
    """A rendered view of the linkage coloured by √(bending energy density) (written atomically)."""
    from ..linkage.export import scalar_fields
    from ..viz.render import render_linkage

    field = np.sqrt(np.maximum(scalar_fields(linkage)["bending_energy_density"], 0.0))
    render_linkage(path, linkage.rods.points, linkage.rods.edges, field, title=title)
