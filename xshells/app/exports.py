"""Exports of the app: fabrication drawings (SVG, DXF), the deployed mesh (OBJ, PLY, glTF), the case JSON and a PNG.

Drawings are of the *flat* layout at 1:1 in millimetres (``units_to_mm``
converts the design's units; the bundled designs are in mm): one line per
beam segment, a circle and a label per joint, and each segment's rest length
written at its midpoint. Every file is written atomically (temporary file
in the destination folder, then :func:`os.replace`).
"""
from __future__ import annotations

import json
import os

import numpy as np

from ..errors import InputError
from ..io import fabrication
from ..io.export import atomic_write_bytes, atomic_write_text
from .core import Layout

MESH_FORMATS = (".obj", ".ply", ".gltf", ".glb")


def svg_text(layout: Layout, rest_lengths=None, units_to_mm: float = 1.0, margin_mm: float = 20.0) -> str:
    """The layout as an SVG drawing at 1:1 in mm (:func:`xshells.io.fabrication.svg_text`)."""
    return fabrication.svg_text(layout.vertices, layout.edges, rest_lengths, units_to_mm, margin_mm)


def write_svg(path, layout: Layout, rest_lengths=None, units_to_mm: float = 1.0) -> None:
    fabrication.write_svg(path, layout.vertices, layout.edges, rest_lengths, units_to_mm)


def dxf_bytes(layout: Layout, rest_lengths=None, units_to_mm: float = 1.0) -> bytes:
    """The layout as DXF in mm (:func:`xshells.io.fabrication.dxf_bytes`)."""
    return fabrication.dxf_bytes(layout.vertices, layout.edges, rest_lengths, units_to_mm)


def write_dxf(path, layout: Layout, rest_lengths=None, units_to_mm: float = 1.0) -> None:
    fabrication.write_dxf(path, layout.vertices, layout.edges, rest_lengths, units_to_mm)


def write_fabrication_files(folder, stem: str, layout: Layout, material, rest_lengths, kind: str) -> list[str]:
    """The workshop files of the layout (:mod:`xshells.fabrication`, default options), named ``stem_…``.

    ``kind`` ``"cutlist"``: the cut list, the joint table and the bill of
    materials; ``"strips"``: the strips (SVG, DXF) and the assembly drawing.
    Returns the paths written, the main one first.
    """
    from ..fabrication.drawings import assembly_svg, beams_dxf, beams_svg
    from ..fabrication.run import cutlist_csv, fabrication_plan, joints_csv
    from ..linkage.graph import analyze
    from .core import layout_to_design

    if rest_lengths is None:
        raise InputError("nothing solved yet: move the angle slider first (the cut list needs the rest lengths)")
    plan = fabrication_plan(analyze(layout_to_design(layout)), rest_lengths, material)
    path = lambda suffix: os.path.join(folder, f"{stem}_{suffix}")  # noqa: E731
    if kind == "cutlist":
        out = [path("cutlist.csv"), path("joints.csv"), path("bom.json")]
        atomic_write_text(out[0], cutlist_csv(plan))
        atomic_write_text(out[1], joints_csv(plan))
        atomic_write_text(out[2], json.dumps(plan.bill_of_materials(), indent=1))
    elif kind == "strips":
        out = [path("beams.svg"), path("beams.dxf"), path("assembly.svg")]
        atomic_write_text(out[0], beams_svg(plan.beams, plan.nesting, plan.hole_diameter))
        atomic_write_bytes(out[1], beams_dxf(plan.beams, plan.nesting, plan.hole_diameter))
        atomic_write_text(out[2], assembly_svg(plan.xy, plan.beams, plan.joints, plan.hole_diameter))
    else:
        raise InputError(f"unknown fabrication export {kind!r}")
    return out


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
               rest_lengths=None, direction: str = "up", steps: int | None = None, guide=None) -> list[str]:
    """Write a case JSON that ``xshells deploy`` and the app reload, with its design (and rest lengths) beside it.

    ``direction`` and ``steps`` are the deployment's (which way, and in how
    many increments, the flat state buckles: both decide the branch);
    ``guide`` (nj, 3) the case's guide (:mod:`xshells.deploy.guide`), written beside it.
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
    spec["direction"] = direction
    if steps is not None:
        spec["steps"] = int(steps)
    if rest_lengths is not None:
        rl_name = f"{stem}_rest_lengths.txt"
        atomic_write_text(os.path.join(folder, rl_name), "".join(f"{v!r}\n" for v in np.asarray(rest_lengths, float).tolist()))
        spec["rest_lengths"] = rl_name
        written.append(os.path.join(folder, rl_name))
    if guide is not None:
        from ..deploy.guide import guide_text

        guide_name = f"{stem}_guide.txt"
        atomic_write_text(os.path.join(folder, guide_name), guide_text(guide))
        spec["guide"] = guide_name
        written.append(os.path.join(folder, guide_name))
    atomic_write_text(path, json.dumps(spec, indent=1) + "\n")
    return [path] + written


def write_png(path, linkage, title: str = "") -> None:
    """A rendered view of the linkage coloured by √(bending energy density) (written atomically)."""
    from ..linkage.export import scalar_fields
    from ..viz.render import render_linkage

    field = np.sqrt(np.maximum(scalar_fields(linkage)["bending_energy_density"], 0.0))
    render_linkage(path, linkage.rods.points, linkage.rods.edges, field, title=title)
