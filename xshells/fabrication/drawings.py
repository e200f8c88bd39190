"""Drawings for the workshop, at 1:1 in millimetres: the strips (``beams.svg``/``.dxf``) and the assembly (``assembly.svg``).

Strips lie along x, read like a page: the first bar, sheet or row at the
top. In the SVG y points down; the DXF mirrors y so that it reads the same.
In the DXF the strips' outlines are on layer ``CUT``, the holes (one CIRCLE
each) on ``HOLES``, beam and joint labels on ``LABELS``, and the outlines of
bars and sheets on ``STOCK`` (not to be cut), the scale note on ``NOTES``.
"""
from __future__ import annotations

import io
from dataclasses import dataclass
from xml.sax.saxutils import escape

import numpy as np

FAMILY_COLOURS = {"A": "#d9822b", "B": "#3f77b0"}
FAMILY_COLOUR_NAMES = {"A": "orange", "B": "blue"}  # what the assembly's legend calls them
SCALE_NOTE = "dimensions in mm, scale 1:1 (print at 100 %)"
NOTE_SIZE = 4.0  # mm: the scale note's text, in a band of twice that below the strips


@dataclass(frozen=True)
class StripPlacement:
    """Where a beam's strip lies in the drawing: lower-left x and top y (mm, y down), its stock's index."""

    beam: int
    x: float
    y: float
    stock: int


def sheet_layout(beams, nesting):
    """Strip placements and stock outlines in drawing coordinates (mm, y down).

    Returns ``(strips, stock, size)``: a list of :class:`StripPlacement`,
    a list of ``(x, y, w, h, label)`` stock rectangles and the drawing's
    ``(width, height)`` without margins.
    """
    w_max = max((b.section.width for b in beams), default=1.0)
    strips, stock = [], []
    if nesting.kind == "bars":
        L = nesting.stock_size[0]
        pitch = w_max + max(2 * nesting.kerf, 0.5 * w_max, 2.0)
        for s in range(nesting.stock_count):
            stock.append((0.0, s * pitch, L, w_max, f"bar {s + 1}"))
        strips = [StripPlacement(q.item, q.x, q.stock * pitch, q.stock) for q in nesting.placements]
        size = (L, nesting.stock_count * pitch)
    elif nesting.kind == "sheets":
        long, short = nesting.stock_size
        gap = 0.05 * short + 20.0
        for s in range(nesting.stock_count):
            stock.append((0.0, s * (short + gap), long, short, f"sheet {s + 1}"))
        strips = [StripPlacement(q.item, q.x, q.stock * (short + gap) + q.y, q.stock) for q in nesting.placements]
        size = (long, nesting.stock_count * (short + gap) - gap)
    else:
        strips = [StripPlacement(q.item, q.x, q.y, q.stock) for q in nesting.placements]
        size = (max((b.length for b in beams), default=0.0),
                max((q.y + beams[q.item].section.width for q in nesting.placements), default=0.0))
    return strips, stock, size


def _label_x(beam) -> float:
    """Where the beam's label goes along its strip: between its first two holes, or in its longest free stretch."""
    stops = np.concatenate([[0.0], beam.hole_positions, [beam.length]])
    gaps = np.diff(stops)
    if len(beam.hole_positions) >= 2:
        return float(0.5 * (beam.hole_positions[0] + beam.hole_positions[1]))
    i = int(np.argmax(gaps))
    return float(0.5 * (stops[i] + stops[i + 1]))


def _hole_label(pos: float, text: str, hole_diameter: float, size: float, length: float) -> tuple[float, str]:
    """Where a hole's joint number goes along its strip (mm from the cut start) and which end of it is there.

    After the hole, or before it where the text would run past the strip's
    end: the last hole's number crossed the cut line into the next strip.
    The width is estimated at 0.6 of the text size per digit.
    """
    gap = 0.5 * hole_diameter + 0.2 * size
    if pos + gap + 0.6 * size * len(text) <= length:
        return pos + gap, "start"
    return pos - gap, "end"


def beams_svg(beams, nesting, hole_diameter: float, margin: float = 10.0) -> str:
    """The strips on their stock as SVG at 1:1 in mm.

    Strips are ``<rect class="strip" data-beam=…>``, holes ``<circle
    class="hole" data-beam=… data-joint=… data-position=…>`` (position from
    the strip's cut start, mm), stock ``<rect class="stock">``.
    """
    strips, stock, (w, h) = sheet_layout(beams, nesting)
    W, H = w + 2 * margin, h + 2 * margin + 2 * NOTE_SIZE
    out = [f'<?xml version="1.0" encoding="UTF-8"?>\n'
           f'<svg xmlns="http://www.w3.org/2000/svg" width="{W:.3f}mm" height="{H:.3f}mm" viewBox="0 0 {W:.3f} {H:.3f}">\n'
           f'<title>X-shell strips, 1:1, mm ({nesting.kind})</title>\n'
           f'<g id="stock" fill="#f4f1ea" stroke="#999" stroke-width="0.3" stroke-dasharray="2 1">\n']
    for x, y, sw, sh, label in stock:
        out.append(f'<rect class="stock" data-label="{label}" x="{x + margin:.4f}" y="{y + margin:.4f}" '
                   f'width="{sw:.4f}" height="{sh:.4f}"/>\n')
    out.append('</g>\n<g id="cut" fill="white" stroke="black" stroke-width="0.2">\n')
    for q in strips:
        b = beams[q.beam]
        out.append(f'<rect class="strip" data-beam="{b.label}" data-length="{b.length:.4f}" x="{q.x + margin:.4f}" '
                   f'y="{q.y + margin:.4f}" width="{b.length:.4f}" height="{b.section.width:.4f}"/>\n')
    out.append('</g>\n<g id="holes" fill="none" stroke="red" stroke-width="0.15">\n')
    for q in strips:
        b = beams[q.beam]
        cy = q.y + margin + 0.5 * b.section.width
        for v, pos in zip(b.hole_vertices.tolist(), b.hole_positions.tolist()):
            out.append(f'<circle class="hole" data-beam="{b.label}" data-joint="{v}" data-position="{pos:.4f}" '
                       f'cx="{q.x + margin + pos:.4f}" cy="{cy:.4f}" r="{0.5 * hole_diameter:.4f}"/>\n')
    out.append('</g>\n<g id="labels" font-family="sans-serif" fill="black">\n')
    for q in strips:
        b = beams[q.beam]
        fs, fj = 0.55 * b.section.width, 0.35 * b.section.width
        cy = q.y + margin + 0.5 * b.section.width
        out.append(f'<text class="beam-label" data-beam="{b.label}" x="{q.x + margin + _label_x(b):.4f}" '
                   f'y="{cy + 0.35 * fs:.4f}" font-size="{fs:.4f}" text-anchor="middle" font-weight="bold">{b.label}</text>\n')
        for v, pos in zip(b.hole_vertices.tolist(), b.hole_positions.tolist()):
            x, anchor = _hole_label(pos, str(v), hole_diameter, fj, b.length)
            out.append(f'<text class="hole-label" data-beam="{b.label}" x="{q.x + margin + x:.4f}" y="{cy + 0.35 * fj:.4f}" '
                       f'font-size="{fj:.4f}" text-anchor="{anchor}">{v}</text>\n')
    for x, y, sw, sh, label in stock:
        out.append(f'<text class="stock-label" x="{x + margin:.4f}" y="{y + margin - 0.5:.4f}" font-size="{max(2.0, 0.4 * min(sh, 20)):.3f}" '
                   f'fill="#666">{escape(label)}</text>\n')
    out.append(f'<text class="scale-note" x="{margin:.4f}" y="{h + 2 * margin + 1.2 * NOTE_SIZE:.4f}" '
               f'font-size="{NOTE_SIZE:g}" fill="#444">{escape(SCALE_NOTE)}</text>\n')
    out.append("</g>\n</svg>\n")
    return "".join(out)


def beams_dxf(beams, nesting, hole_diameter: float) -> bytes:
    """The strips on their stock as DXF in mm: layers CUT, HOLES, LABELS, STOCK and NOTES (the scale note; y mirrored to
    read as the SVG)."""
    import ezdxf
    from ezdxf.enums import TextEntityAlignment

    strips, stock, (_, h) = sheet_layout(beams, nesting)
    doc = ezdxf.new("R2010")
    doc.units = ezdxf.units.MM
    for name, colour in (("CUT", 7), ("HOLES", 1), ("LABELS", 3), ("STOCK", 8), ("NOTES", 8)):
        doc.layers.add(name, color=colour)
    msp = doc.modelspace()

    def rect(x, y, w, h, layer):
        msp.add_lwpolyline([(x, -y), (x + w, -y), (x + w, -y - h), (x, -y - h)], close=True, dxfattribs={"layer": layer})

    for x, y, sw, sh, label in stock:
        rect(x, y, sw, sh, "STOCK")
        msp.add_text(label, height=max(2.0, 0.4 * min(sh, 20)), dxfattribs={"layer": "STOCK", "insert": (x, -y + 0.5)})
    for q in strips:
        b = beams[q.beam]
        rect(q.x, q.y, b.length, b.section.width, "CUT")
        cy = -(q.y + 0.5 * b.section.width)
        for v, pos in zip(b.hole_vertices.tolist(), b.hole_positions.tolist()):
            msp.add_circle((q.x + pos, cy), radius=0.5 * hole_diameter, dxfattribs={"layer": "HOLES"})
            fj = 0.35 * b.section.width
            x, anchor = _hole_label(pos, str(v), hole_diameter, fj, b.length)
            msp.add_text(str(v), height=fj, dxfattribs={"layer": "LABELS"}).set_placement(
                (q.x + x, cy - 0.35 * fj), align=TextEntityAlignment.LEFT if anchor == "start" else TextEntityAlignment.RIGHT)
        fs = 0.55 * b.section.width
        msp.add_text(b.label, height=fs, dxfattribs={"layer": "LABELS", "insert": (q.x + _label_x(b) - 0.9 * fs, cy - 0.35 * fs)})
    msp.add_text(SCALE_NOTE, height=NOTE_SIZE, dxfattribs={"layer": "NOTES", "insert": (0.0, -(h + 2 * NOTE_SIZE))})
    buf = io.StringIO()
    doc.write(buf)
    return buf.getvalue().encode("utf-8")


def assembly_svg(xy, beams, joints, hole_diameter: float, to_mm: float = 1.0, top: str = "A",
                 margin: float = 30.0) -> str:
    """The flat layout at 1:1 in mm with every strip at its width, the ``top`` family drawn over the other.

    Each strip is a ``<polyline class="beam" data-beam=… data-family=…>``;
    the top family is drawn over the other, whose centrelines are dashed
    (hidden lines) where the upper strips cover them. Rivets are ``<circle class="rivet"
    data-joint=…>`` with the joint's number (its design vertex id); each
    strip's label is written along it, beyond its ends (:func:`_beam_labels`).
    """
    P = np.asarray(xy, float) * to_mm
    seg = [np.linalg.norm(P[b.vertices[1:]] - P[b.vertices[:-1]], axis=1) for b in beams]
    med = float(np.median(np.concatenate(seg))) if seg else 10.0
    fb = max(1.5, 0.22 * med)
    fj = 0.55 * fb
    margin = margin + 6 * fb  # room for the labels beyond the strips' ends (moved out once where they collide)
    lo, hi = P.min(axis=0) - margin, P.max(axis=0) + margin
    W, H = hi - lo
    X = lambda q: (q[0] - lo[0], hi[1] - q[1])  # noqa: E731  (SVG y points down)
    bottom = "B" if top == "A" else "A"
    legend = (f"assembly, seen from the up side: family {top} on top ({FAMILY_COLOUR_NAMES.get(top, 'grey')}), family "
              f"{bottom} below ({FAMILY_COLOUR_NAMES.get(bottom, 'grey')}, centrelines dashed); numbers at rivets: design "
              "vertex ids; dimensions in mm, scale 1:1")
    # at most as wide as the drawing (0.55 of the size per character): sized with the segments alone, it ran
    # several times past the right edge of a layout drawn in metres
    fh = min(fb, 0.9 * W / (0.55 * len(legend)))
    out = [f'<?xml version="1.0" encoding="UTF-8"?>\n'
           f'<svg xmlns="http://www.w3.org/2000/svg" width="{W:.3f}mm" height="{H + 2 * fh:.3f}mm" '
           f'viewBox="0 {-2 * fh:.3f} {W:.3f} {H + 2 * fh:.3f}">\n'
           f'<title>X-shell assembly, 1:1, mm</title>\n'
           f'<text class="legend" x="{0.05 * W:.3f}" y="{-0.6 * fh:.3f}" font-size="{fh:.3f}" font-family="sans-serif">'
           f'{escape(legend)}</text>\n']

    def polyline(b, stroke, width, cls, extra=""):
        pts = " ".join(f"{x:.3f},{y:.3f}" for x, y in (X(P[v]) for v in b.vertices.tolist()))
        return (f'<polyline class="{cls}" data-beam="{b.label}" data-family="{b.family}" points="{pts}" fill="none" '
                f'stroke="{stroke}" stroke-width="{width:.3f}" stroke-linejoin="round"{extra}/>\n')

    edge = lambda b: max(0.08 * b.section.width, 0.3)  # noqa: E731  (outline of a strip)
    out.append('<g id="lower">\n')
    for b in beams:
        if b.family != top:
            out.append(polyline(b, "#1d3d5c", b.section.width + 2 * edge(b), "edge"))
            out.append(polyline(b, FAMILY_COLOURS.get(bottom, "#888"), b.section.width, "beam"))
    out.append('</g>\n<g id="upper">\n')
    for b in beams:
        if b.family == top:
            out.append(polyline(b, "#5c3310", b.section.width + 2 * edge(b), "edge"))
            out.append(polyline(b, FAMILY_COLOURS.get(top, "#888"), b.section.width, "beam"))
    out.append('</g>\n<g id="hidden">\n')  # the lower strips' centrelines, dashed where the upper ones hide them
    for b in beams:
        if b.family != top:
            dash = 0.12 * med
            out.append(polyline(b, "#1d3d5c", edge(b), "hidden-centreline",
                                f' stroke-dasharray="{dash:.3f} {0.6 * dash:.3f}"'))
    out.append(f'</g>\n<g id="rivets" font-size="{fj:.3f}" font-family="sans-serif" fill="#222">\n')
    for row in joints:
        x, y = X(P[row.joint])
        out.append(f'<circle class="rivet" data-joint="{row.joint}" cx="{x:.3f}" cy="{y:.3f}" r="{0.5 * hole_diameter:.3f}"/>'
                   f'<text class="joint-label" x="{x + 0.4 * fj:.3f}" y="{y - 0.4 * fj:.3f}">{row.joint}</text>\n')
    out.append(f'</g>\n<g id="beam-labels" font-size="{fb:.3f}" font-family="sans-serif" font-weight="bold" '
               f'>\n')
    for b, a, ang, off, anchor, dy in _beam_labels(beams, joints, [np.array(X(q)) for q in P], hole_diameter, fb, fj,
                                                  top):
        out.append(f'<text class="beam-label" data-beam="{b.label}" x="{a[0] + off:.3f}" y="{a[1] + dy:.3f}" '
                   f'text-anchor="{anchor}" fill="{FAMILY_COLOURS.get(b.family, "#000")}" '
                   f'transform="rotate({ang:.2f} {a[0]:.3f} {a[1]:.3f})">{b.label}</text>\n')
    out.append("</g>\n</svg>\n")
    return "".join(out)


def _beam_labels(beams, joints, XY, hole_diameter: float, fb: float, fj: float, top: str):
    """Where each strip's label goes in the assembly drawing: ``(beam, end point, angle, offset, anchor, dy)`` per label.

    A label runs along its strip beyond one of its ends (``offset`` from the
    end point along the strip, upright, rotated by ``angle`` degrees about
    that point; ``dy`` across it keeps the two families' labels apart). Where
    it would cover a label placed before, a joint number or another strip, it
    moves out by its own length once; where it still would, that end goes
    without one, and a strip with no clear place at either end gets the one
    that covers least (a text counts ten times a strip). Dense layouts drew
    the labels of neighbouring strips over each other and over the joint
    numbers at their ends. Text extents are estimated: 0.62 of the size per
    character, a band of 0.8 of it.
    """
    # obstacles as disks along the texts' centre lines: (centres, radii)
    pts, rad = [], []
    for row in joints:
        x, y = XY[row.joint]
        pts.append((x, y))
        rad.append(0.5 * hole_diameter)
        n = len(str(row.joint))
        for k in range(n):  # the joint number, right of and above its rivet
            pts.append((x + 0.4 * fj + 0.6 * fj * (k + 0.5), y - 0.7 * fj))
            rad.append(0.4 * fj)
    owner = [-1] * len(pts)
    for i, b in enumerate(beams):  # the strips, as disks of their width along their centre lines
        for p0, p1 in zip(b.vertices[:-1].tolist(), b.vertices[1:].tolist()):
            n = max(2, int(np.ceil(np.linalg.norm(XY[p1] - XY[p0]) / (0.5 * fb))) + 1)
            pts.extend(XY[p0] + np.outer(np.linspace(0.0, 1.0, n), XY[p1] - XY[p0]))
            rad.extend([0.5 * b.section.width] * n)
            owner.extend([i] * n)
    obstacles = [np.array(pts, float).reshape(-1, 2), np.array(rad, float)]
    owner = np.array(owner)
    placed = []
    for i, b in enumerate(beams):
        length = 0.62 * fb * len(b.label)
        options = []  # (end, cost, label, centres); cost: texts covered count 10, strips 1
        for end, (v0, v1) in enumerate(((b.vertices[0], b.vertices[1]), (b.vertices[-1], b.vertices[-2]))):
            a, c = XY[v0], XY[v1]
            t = (a - c) / max(np.linalg.norm(a - c), 1e-12)  # outward along the strip
            ang = float(np.degrees(np.arctan2(t[1], t[0])))
            sign, anchor = 1.0, "start"
            if ang > 90 or ang < -90:  # keep the text upright: it runs back towards the vertex's outside
                ang -= 180 * np.sign(ang)
                sign, anchor = -1.0, "end"
            dy = (-0.15 if b.family == top else 0.85) * fb
            v = np.array([-np.sin(np.radians(ang)), np.cos(np.radians(ang))])  # across the text, downwards
            for shift in (0.0, length + 0.6 * fb):
                off = 0.5 * hole_diameter + 0.4 * fb + shift
                s = np.arange(off + 0.4 * fb, off + length - 0.2 * fb, 0.5 * fb)  # along t, from the end point
                centres = a + np.outer(s, t) + (dy - 0.3 * fb) * v
                d = np.linalg.norm(centres[:, None, :] - obstacles[0][None, :, :], axis=2)
                hit = (d < 0.4 * fb + obstacles[1][None, :]).any(axis=0) & (owner != i)  # its own strip ends before it
                cost = 10 * int((hit & (owner < 0)).sum()) + int((hit & (owner >= 0)).sum())
                options.append((end, cost, (b, a, ang, sign * off, anchor, dy), centres))
        chosen = [next(o for o in options if o[0] == e and o[1] == 0) for e in (0, 1)
                  if any(o[0] == e and o[1] == 0 for o in options)]
        for _, _, label, centres in chosen or [min(options, key=lambda o: o[1])]:  # none clear: the least covering
            obstacles = [np.vstack([obstacles[0], centres]), np.concatenate([obstacles[1], np.full(len(centres), 0.4 * fb)])]
            owner = np.concatenate([owner, np.full(len(centres), -1)])
            placed.append(label)
    return placed
