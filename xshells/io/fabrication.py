"""Fabrication drawings of a flat layout: SVG and DXF at 1:1 in millimetres.

One line per beam segment, a circle and a label per joint (its vertex index
in the design file, 0-based), and each segment's rest length written at its
midpoint. ``units_to_mm`` converts the design's units (the bundled designs
are in mm). Files are written atomically (temporary file, then rename).
"""
from __future__ import annotations

import io
from xml.sax.saxutils import escape

import numpy as np

from ..errors import InputError
from .export import atomic_write_bytes, atomic_write_text


def flat_coordinates(vertices, normal=None, frame=None) -> np.ndarray:
    """In-plane coordinates (n, 2) of a flat design's vertices (n, 3), seen from the layout's up side.

    A design in the z = 0 plane keeps its x, y; one drawn in another plane
    is projected onto its best-fit plane, in axes (u, v) with u × v along
    ``normal`` (3,): the layout's "up" normal (``LinkageGraph.layout_normal``,
    which ``--direction up`` means). By default that normal's own rule: the
    plane's normal with its largest component positive. Without it the axes'
    order was the SVD's, and a design drawn in a tilted plane was drawn, in
    four of six random orientations, as seen from below: mirrored.
    ``frame`` (m, 3), default ``vertices``: the points whose plane sets the
    axes, e.g. the drawn design for a state of it relaxed in its plane,
    which its own round-off out of the plane would otherwise turn to its
    principal axes.
    """
    V = np.asarray(vertices, float)
    F = V if frame is None else np.asarray(frame, float)
    if np.ptp(F[:, 2]) == 0:
        return V[:, :2].copy()
    c = F.mean(axis=0)
    _, _, vt = np.linalg.svd(F - c, full_matrices=False)
    if normal is None:  # the rule of linkage.graph's layout plane (this module sits below it)
        normal = vt[2] if vt[2][np.argmax(np.abs(vt[2]))] > 0 else -vt[2]
    axes = vt[:2].copy()
    if np.cross(axes[0], axes[1]) @ np.asarray(normal, float) < 0:
        axes[1] = -axes[1]
    return (V - c) @ axes.T


def _lengths(V: np.ndarray, E: np.ndarray) -> np.ndarray:
    return np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1) if len(E) else np.zeros(0)


def _checked(vertices, edges, rest_lengths):
    V = np.asarray(vertices, float).reshape(-1, 2)
    E = np.asarray(edges, np.int64).reshape(-1, 2)
    p = _lengths(V, E) if rest_lengths is None else np.asarray(rest_lengths, float)
    if p.shape != (len(E),):
        raise InputError(f"rest lengths: expected {len(E)} values, got {p.size}")
    return V, E, p


def _font_size(V, E, units_to_mm) -> float:
    return max(2.0, 0.12 * float(np.median(_lengths(V, E))) * units_to_mm) if len(E) else 2.0


def svg_text(vertices, edges, rest_lengths=None, units_to_mm: float = 1.0, margin_mm: float = 20.0) -> str:
    """The flat layout as an SVG drawing at 1:1 in mm (y up in the design, so flipped for SVG).

    Parameters
    ----------
    vertices : (n, 2) array
        In-plane coordinates (see :func:`flat_coordinates`).
    edges : (m, 2) int array
    rest_lengths : (m,) array, optional
        Written at each segment's midpoint (default: the drawn lengths).

    Beams are ``<line class="beam">`` with ``data-segment`` and
    ``data-rest-length`` (mm); joints are ``<circle class="joint">`` with a
    ``<text class="joint-label">``; rest lengths are ``<text class="rest-length">``.
    """
    V0, E, p = _checked(vertices, edges, rest_lengths)
    V, p = V0 * units_to_mm, p * units_to_mm
    lo, hi = V.min(axis=0) - margin_mm, V.max(axis=0) + margin_mm
    w, h = hi - lo
    X = lambda q: (q[0] - lo[0], hi[1] - q[1])  # noqa: E731  (SVG y points down)
    fs = _font_size(V0, E, units_to_mm)
    out = [f'<?xml version="1.0" encoding="UTF-8"?>\n'
           f'<svg xmlns="http://www.w3.org/2000/svg" width="{w:.3f}mm" height="{h:.3f}mm" viewBox="0 0 {w:.3f} {h:.3f}">\n'
           f'<title>X-shell flat layout, 1:1, mm</title>\n<g id="beams" stroke="black" stroke-width="0.3" fill="none">\n']
    for s, (a, b) in enumerate(E.tolist()):
        (x1, y1), (x2, y2) = X(V[a]), X(V[b])
        out.append(f'<line class="beam" data-segment="{s}" data-rest-length="{p[s]:.4f}" '
                   f'x1="{x1:.4f}" y1="{y1:.4f}" x2="{x2:.4f}" y2="{y2:.4f}"/>\n')
    out.append(f'</g>\n<g id="rest-lengths" fill="blue" font-size="{fs * 0.8:.3f}" text-anchor="middle" font-family="sans-serif">\n')
    for s, (a, b) in enumerate(E.tolist()):
        x, y = X(0.5 * (V[a] + V[b]))
        out.append(f'<text class="rest-length" data-segment="{s}" x="{x:.4f}" y="{y:.4f}">{p[s]:.2f}</text>\n')
    out.append(f'</g>\n<g id="joints" font-size="{fs:.3f}" font-family="sans-serif">\n')
    for v in np.unique(E).tolist():
        x, y = X(V[v])
        out.append(f'<circle class="joint" data-joint="{v}" cx="{x:.4f}" cy="{y:.4f}" r="{fs / 3:.3f}" fill="red"/>'
                   f'<text class="joint-label" x="{x + fs / 2:.4f}" y="{y - fs / 2:.4f}">{escape(str(v))}</text>\n')
    out.append("</g>\n</svg>\n")
    return "".join(out)


def dxf_bytes(vertices, edges, rest_lengths=None, units_to_mm: float = 1.0) -> bytes:
    """The flat layout as DXF (mm): layer BEAMS (LINE per segment), JOINTS (CIRCLE), LABELS and REST_LENGTHS (TEXT)."""
    import ezdxf

    V0, E, p = _checked(vertices, edges, rest_lengths)
    V, p = V0 * units_to_mm, p * units_to_mm
    fs = _font_size(V0, E, units_to_mm)
    doc = ezdxf.new("R2010")
    doc.units = ezdxf.units.MM
    for name, color in (("BEAMS", 7), ("JOINTS", 1), ("LABELS", 3), ("REST_LENGTHS", 5)):
        doc.layers.add(name, color=color)
    msp = doc.modelspace()
    for s, (a, b) in enumerate(E.tolist()):
        msp.add_line(tuple(V[a]), tuple(V[b]), dxfattribs={"layer": "BEAMS"})
        mid = 0.5 * (V[a] + V[b])
        msp.add_text(f"{p[s]:.2f}", height=0.8 * fs, dxfattribs={"layer": "REST_LENGTHS", "insert": tuple(mid)})
    for v in np.unique(E).tolist():
        msp.add_circle(tuple(V[v]), radius=fs / 3, dxfattribs={"layer": "JOINTS"})
        msp.add_text(str(v), height=fs, dxfattribs={"layer": "LABELS", "insert": tuple(V[v] + fs / 2)})
    buf = io.StringIO()
    doc.write(buf)
    return buf.getvalue().encode("utf-8")


def write_svg(path, vertices, edges, rest_lengths=None, units_to_mm: float = 1.0) -> None:
    atomic_write_text(path, svg_text(vertices, edges, rest_lengths, units_to_mm))


def write_dxf(path, vertices, edges, rest_lengths=None, units_to_mm: float = 1.0) -> None:
    atomic_write_bytes(path, dxf_bytes(vertices, edges, rest_lengths, units_to_mm))


def write_drawings(out_dir: str, name: str, design, rest_lengths) -> list:
    """``name``.svg and ``name``.dxf of a flat design with its rest lengths into ``out_dir``; the paths written."""
    import os

    xy = flat_coordinates(design.vertices)
    paths = [os.path.join(out_dir, f"{name}.svg"), os.path.join(out_dir, f"{name}.dxf")]
    write_svg(paths[0], xy, design.edges, rest_lengths)
    write_dxf(paths[1], xy, design.edges, rest_lengths)
    return paths
