"""Exporting a linkage: centerlines and swept beam surfaces with scalar fields.

Swept surfaces use the true cross-section outline (of the first material
when several are used) and carry per-vertex fields: bending, twisting and
stretching energy densities and the corresponding stress measures of
:meth:`xshells.rod.ElasticRods.stress_measures`. Units follow the input
(with mm and MPa: energy densities in N·mm/mm = N, stresses in MPa).
"""
from __future__ import annotations

import os

import numpy as np

from ..io.export import write_polylines_obj
from ..io.sweep import SweptMesh, swept_beam_mesh, write_obj, write_ply
from .linkage import Linkage


def centerlines(linkage: Linkage) -> list[np.ndarray]:
    """Each rod segment's centerline, a list of (k + 1, 3) arrays in segment order."""
    rods = linkage.rods
    return [rods.points[a:b].copy() for a, b in zip(rods.vertex_offsets[:-1], rods.vertex_offsets[1:])]


def scalar_fields(linkage: Linkage) -> dict[str, np.ndarray]:
    """Per-rod-vertex scalar fields (each (V,)) for colouring."""
    m = linkage.materials[0]
    return linkage.rods.stress_measures(young=m.E, shear=m.G, fibre=m.extreme_fibre_distances)


def swept_mesh(linkage: Linkage, fields: dict | None = None) -> SweptMesh:
    """Triangle surface of all beams, swept with the cross-section outline."""
    rods = linkage.rods
    _, m1, m2 = rods.material_frames()
    counts = np.diff(rods.edge_offsets)
    return swept_beam_mesh(rods.points, counts, m1, m2, linkage.materials[0].outline,
                           vertex_fields=scalar_fields(linkage) if fields is None else fields)


def write_centerlines(path, linkage: Linkage) -> None:
    write_polylines_obj(path, centerlines(linkage))


def write_swept(path, linkage: Linkage) -> None:
    """Write the swept beams as ``.obj`` (first field as a texture coordinate) or ``.ply`` (all fields)."""
    mesh = swept_mesh(linkage)
    ext = os.path.splitext(str(path))[1].lower()
    if ext == ".ply":
        write_ply(path, mesh)
    elif ext == ".obj":
        write_obj(path, mesh)
    else:
        raise ValueError(f"{path}: unknown mesh format {ext!r} (use .obj or .ply)")
