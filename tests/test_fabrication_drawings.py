"""The strips' SVG and DXF (1:1 mm, one circle per hole where the cut list says) and the assembly drawing."""
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from data_paths import EXAMPLES
from xshells.fabrication import FabricationOptions, fabrication_plan
from xshells.fabrication.drawings import assembly_svg, beams_dxf, beams_svg
from xshells.io import read_design
from xshells.linkage.graph import analyze
from xshells.section import Material

NS = "{http://www.w3.org/2000/svg}"


@pytest.fixture(scope="module")
def manta():
    d = read_design(EXAMPLES / "manta_ray.obj")
    g = analyze(d)
    p = np.linalg.norm(d.vertices[d.edges[:, 1]] - d.vertices[d.edges[:, 0]], axis=1)
    return g, p, Material.uniform("rectangle", [10, 7], E=20000, nu=0.3)


@pytest.mark.parametrize("options", [FabricationOptions(), FabricationOptions(stock_length=2500, kerf=4),
                                     FabricationOptions(sheet=(1250, 2500), kerf=1)])
def test_dxf_has_one_circle_per_hole_inside_its_labelled_strip(manta, options, tmp_path):
    import ezdxf

    g, p, mat = manta
    plan = fabrication_plan(g, p, mat, options)
    path = tmp_path / "beams.dxf"
    path.write_bytes(beams_dxf(plan.beams, plan.nesting, plan.hole_diameter))
    doc = ezdxf.readfile(path)
    msp = doc.modelspace()
    assert {"CUT", "HOLES", "LABELS"} <= {layer.dxf.name for layer in doc.layers}
    strips = []
    for e in msp.query("LWPOLYLINE[layer=='CUT']"):
        P = np.array([v[:2] for v in e.get_points()])
        strips.append((P.min(axis=0), P.max(axis=0)))
    circles = np.array([[c.dxf.center.x, c.dxf.center.y, c.dxf.radius] for c in msp.query("CIRCLE")])
    assert all(c.dxf.layer == "HOLES" for c in msp.query("CIRCLE"))
    texts = [(t.dxf.text, np.array(t.dxf.insert)[:2]) for t in msp.query("TEXT[layer=='LABELS']")]
    by_label = {b.label: b for b in plan.beams}
    assert len(strips) == len(plan.beams) and len(circles) == sum(len(b.hole_positions) for b in plan.beams)
    np.testing.assert_allclose(circles[:, 2], plan.hole_diameter / 2)
    seen = 0
    for lo, hi in strips:
        inside = lambda q: np.all(q >= lo - 1e-6) and np.all(q <= hi + 1e-6)  # noqa: E731
        label = [t for t, q in texts if t in by_label and inside(q)]
        assert len(label) == 1
        b = by_label[label[0]]
        assert hi[0] - lo[0] == pytest.approx(b.length, abs=1e-6)
        assert hi[1] - lo[1] == pytest.approx(b.section.width, abs=1e-6)
        mine = circles[[inside(c[:2]) for c in circles]]
        np.testing.assert_allclose(np.sort(mine[:, 0]) - lo[0], b.hole_positions, atol=1e-6)
        np.testing.assert_allclose(mine[:, 1], 0.5 * (lo[1] + hi[1]), atol=1e-6)
        seen += len(mine)
    assert seen == len(circles)


def test_svg_is_at_one_to_one_in_mm(manta):
    g, p, mat = manta
    plan = fabrication_plan(g, p, mat, FabricationOptions(stock_length=2500))
    root = ET.fromstring(beams_svg(plan.beams, plan.nesting, plan.hole_diameter))
    w, h = (float(root.get(k).removesuffix("mm")) for k in ("width", "height"))
    vb = [float(v) for v in root.get("viewBox").split()]
    assert vb[2:] == pytest.approx([w, h])  # one user unit is one millimetre
    rects = root.findall(f".//{NS}rect[@class='strip']")
    assert len(rects) == len(plan.beams)
    lengths = {b.label: b.length for b in plan.beams}
    for r in rects:
        assert float(r.get("width")) == pytest.approx(lengths[r.get("data-beam")], abs=1e-3)
        assert float(r.get("height")) == pytest.approx(10.0)
    holes = root.findall(f".//{NS}circle[@class='hole']")
    assert len(holes) == sum(len(b.hole_positions) for b in plan.beams)
    stock = root.findall(f".//{NS}rect[@class='stock']")
    assert len(stock) == plan.nesting.stock_count
    assert all(float(s.get("width")) == pytest.approx(2500) for s in stock)


def test_assembly_draws_the_top_family_over_the_other(manta):
    g, p, mat = manta
    plan = fabrication_plan(g, p, mat)
    text = assembly_svg(plan.xy, plan.beams, plan.joints, plan.hole_diameter)
    root = ET.fromstring(text)
    beams = root.findall(f".//{NS}polyline[@class='beam']")
    assert len(beams) == len(plan.beams)
    order = [b.get("data-family") for b in beams]
    assert order == sorted(order, key=lambda f: f == "A")  # every B strip before (under) every A strip
    assert len(root.findall(f".//{NS}circle[@class='rivet']")) == g.num_joints
    labels = [t.get("data-beam") for t in root.findall(f".//{NS}text[@class='beam-label']")]
    assert sorted(set(labels)) == sorted(b.label for b in plan.beams)  # each strip at one end or both
    assert max(labels.count(x) for x in labels) <= 2
    w = float(root.get("width").removesuffix("mm"))
    span = np.ptp(plan.xy[:, 0])
    assert span < w < span + 400  # the layout at 1:1 plus margins for the labels
    top = fabrication_plan(g, p, mat, FabricationOptions(top="B"))
    text_b = assembly_svg(top.xy, top.beams, top.joints, top.hole_diameter, top="B")
    fam = re.findall(r'class="beam" data-beam="[AB]\d+" data-family="([AB])"', text_b)
    assert fam == sorted(fam, key=lambda f: f == "B")
    assert all(r.on_top.startswith("B") for r in top.joints)


@pytest.mark.parametrize("top", ["A", "B"])
def test_assembly_legend_names_the_colours_drawn(manta, top):
    # with --top B the legend said "family B on top (orange)" over blue B strips
    g, p, mat = manta
    plan = fabrication_plan(g, p, mat, FabricationOptions(top=top))
    root = ET.fromstring(assembly_svg(plan.xy, plan.beams, plan.joints, plan.hole_diameter, top=top))
    names = {"#d9822b": "orange", "#3f77b0": "blue"}
    drawn = {}
    for layer in ("upper", "lower"):
        strips = root.findall(f".//{NS}g[@id='{layer}']/{NS}polyline[@class='beam']")
        assert len({(s.get("data-family"), s.get("stroke")) for s in strips}) == 1
        drawn[layer] = (strips[0].get("data-family"), names[strips[0].get("stroke")])
    legend = next(t.text for t in root.iter(f"{NS}text") if t.text and t.text.startswith("assembly"))
    assert drawn["upper"][0] == top
    assert f"family {drawn['upper'][0]} on top ({drawn['upper'][1]})" in legend
    assert f"family {drawn['lower'][0]} below ({drawn['lower'][1]}," in legend


def test_joint_numbers_stay_inside_their_strip_and_the_scale_is_written(manta, tmp_path):
    # the last hole's number ran past the strip's end, across the cut line into the next strip
    import ezdxf

    g, p, mat = manta
    plan = fabrication_plan(g, p, mat, FabricationOptions(stock_length=2500))
    root = ET.fromstring(beams_svg(plan.beams, plan.nesting, plan.hole_diameter))
    strips = {r.get("data-beam"): (float(r.get("x")), float(r.get("width")))
              for r in root.findall(f".//{NS}rect[@class='strip']")}
    labels = root.findall(f".//{NS}text[@class='hole-label']")
    assert len(labels) == sum(len(b.hole_positions) for b in plan.beams)
    for t in labels:
        x, size, width = float(t.get("x")), float(t.get("font-size")), 0.55 * float(t.get("font-size")) * len(t.text)
        lo, hi = (x, x + width) if t.get("text-anchor", "start") == "start" else (x - width, x)
        x0, length = strips[t.get("data-beam")]
        assert x0 < lo and hi < x0 + length, (t.get("data-beam"), t.text)
    notes = [t.text for t in root.iter(f"{NS}text") if t.get("class") == "scale-note"]
    assert notes == ["dimensions in mm, scale 1:1 (print at 100 %)"]
    path = tmp_path / "beams.dxf"
    path.write_bytes(beams_dxf(plan.beams, plan.nesting, plan.hole_diameter))
    msp = ezdxf.readfile(path).modelspace()
    assert [t.dxf.text for t in msp.query("TEXT[layer=='NOTES']")] == notes
    cut = [np.array([v[:2] for v in e.get_points()]) for e in msp.query("LWPOLYLINE[layer=='CUT']")]
    boxes = [(P[:, 0].min(), P[:, 1].min(), P[:, 0].max(), P[:, 1].max()) for P in cut]
    numbers = [t for t in msp.query("TEXT[layer=='LABELS']") if t.dxf.text.isdigit()]
    for t in numbers:
        right = t.dxf.halign == 2  # aligned at its right end, before the hole
        x, y = (t.dxf.align_point if right else t.dxf.insert).vec2
        width = 0.55 * t.dxf.height * len(t.dxf.text)
        lo, hi = (x - width, x) if right else (x, x + width)
        assert any(b[0] < lo and hi < b[2] and b[1] < y < b[3] for b in boxes), t.dxf.text
    assert any(t.dxf.halign == 2 for t in numbers)


def _text_boxes(root, cls, width_per_char=0.55):
    """Each text's box as 4 corners (drawing units), from its attributes: estimated extent, rotation applied."""
    boxes = []
    for t in root.iter(f"{NS}text"):
        if t.get("class") != cls:
            continue
        x, y, fs = float(t.get("x")), float(t.get("y")), float(t.get("font-size") or 0) or None
        fs = fs or float(next(g.get("font-size") for g in root.iter(f"{NS}g") if t in list(g)))
        w = width_per_char * fs * len(t.text)
        x0 = x - w if t.get("text-anchor") == "end" else x
        C = np.array([[x0, y - 0.65 * fs], [x0 + w, y - 0.65 * fs], [x0 + w, y + 0.1 * fs], [x0, y + 0.1 * fs]])
        m = re.match(r"rotate\(([-\d.e]+) ([-\d.e]+) ([-\d.e]+)\)", t.get("transform") or "")
        if m:
            a, cx, cy = (float(v) for v in m.groups())
            R = np.array([[np.cos(np.radians(a)), -np.sin(np.radians(a))], [np.sin(np.radians(a)), np.cos(np.radians(a))]])
            C = (C - [cx, cy]) @ R.T + [cx, cy]
        boxes.append((t.text, C))
    return boxes


def _overlap(A, B):
    """Whether two convex quadrilaterals overlap (separating axis test)."""
    for P in (A, B):
        for i in range(4):
            e = P[(i + 1) % 4] - P[i]
            n = np.array([-e[1], e[0]])
            a, b = A @ n, B @ n
            if a.max() <= b.min() or b.max() <= a.min():
                return False
    return True


def test_assembly_labels_cover_neither_each_other_nor_the_joint_numbers_and_the_legend_fits():
    # the uniform grid drawn in metres: strip labels piled over each other at the strips' ends, over the joint
    # numbers, and the legend, sized with the segments, ran far past the drawing's right edge
    d = read_design(EXAMPLES / "uniform_linkage.obj")
    g = analyze(d)
    p = np.linalg.norm(d.vertices[d.edges[:, 1]] - d.vertices[d.edges[:, 0]], axis=1)
    plan = fabrication_plan(g, p, Material.uniform("rectangle", [0.01, 0.007], E=20000, nu=0.3),
                            FabricationOptions(units="m"))
    root = ET.fromstring(assembly_svg(plan.xy, plan.beams, plan.joints, plan.hole_diameter, plan.to_mm))
    labels = _text_boxes(root, "beam-label")
    numbers = _text_boxes(root, "joint-label")
    assert {t for t, _ in labels} == {b.label for b in plan.beams}
    bad = [(s, t) for i, (s, A) in enumerate(labels) for t, B in labels[i + 1:] + numbers if _overlap(A, B)]
    assert not bad, bad[:5]
    legend = root.find(f"{NS}text[@class='legend']")
    assert 0.55 * float(legend.get("font-size")) * len(legend.text) <= float(root.get("width").removesuffix("mm"))
