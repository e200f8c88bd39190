"""The fabrication plan of a design and its files: cut list, joint table, strips, assembly, bill of materials.

:func:`fabrication_plan` computes everything from the design, its rest
lengths and its material(s); :func:`write_fabrication` writes the files.
``xshells fabricate`` runs them after a rest-length solve; ``deploy``,
``optimize`` and ``inverse`` call them with their own rest lengths.
"""
from __future__ import annotations

import csv
import io
import json
import os
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import InputError
from ..io.export import atomic_write_bytes, finite_json
from .beams import beam_sections, joint_table, rest_length_mismatch, trace_beams, units_to_mm
from .nesting import Nesting, nest_bars, nest_sheets, no_nesting

CUTLIST_COLUMNS = ("beam", "family", "length_mm", "holes", "hole_positions_mm", "joints", "section")
UNIT_NAMES = {"mm": "millimetres", "cm": "centimetres", "m": "metres", "in": "inches", "ft": "feet"}
FABRICATION_FILES = ("cutlist.csv", "joints.csv", "beams.svg", "beams.dxf", "assembly.svg", "bom.json")


@dataclass(frozen=True)
class FabricationOptions:
    """Settings of the fabrication outputs; lengths in mm.

    Attributes
    ----------
    end_margin : float or None
        Material beyond the outermost hole or free end (default: half the section width).
    hole_diameter : float or None
        Rivet holes (default: a third of the section width); must be smaller than the width.
    stock_length : float or None
        Nest the strips onto bars of this length.
    sheet : (float, float) or None
        Nest the strips onto sheets W × H instead (laser cutting).
    kerf : float
        Material lost to a cut: between pieces on a bar, between strips on a sheet.
    units : str
        The design's length unit (mm, cm, m, in, ft); outputs are converted to mm.
    top : str
        The family whose strips form the upper layer ("A" or "B").
    """

    end_margin: float | None = None
    hole_diameter: float | None = None
    stock_length: float | None = None
    sheet: tuple | None = None
    kerf: float = 3.0
    units: str = "mm"
    top: str = "A"


@dataclass(frozen=True)
class FabricationPlan:
    """Everything the workshop files hold (mm)."""

    beams: list
    joints: list
    nesting: Nesting
    hole_diameter: float
    to_mm: float
    units: str
    xy: np.ndarray = field(repr=False)
    top: str = "A"
    warnings: tuple = ()  # one line each: parts that can be cut but make no sense (:func:`_short_arms`)

    def bill_of_materials(self) -> dict:
        """Totals per section, counts, stock used and how well it is used."""
        per = {}
        for b in self.beams:
            e = per.setdefault(b.section.label, {"section": b.section.label, "width_mm": b.section.width,
                                                 "depth_mm": b.section.depth, "beams": 0, "total_length_mm": 0.0})
            e["beams"] += 1
            e["total_length_mm"] += b.length
        holes = int(sum(len(b.hole_positions) for b in self.beams))
        return {
            "units": "mm",
            "design_units": self.units,
            "units_note": ("lengths are the design's, in mm" if self.units == "mm" else
                           f"the design's units are {UNIT_NAMES.get(self.units, self.units)} ({self.units}); every length "
                           f"here is converted to mm (x{self.to_mm:g})"),
            "sections": list(per.values()),
            "orientation": "each strip lies flat: its section width in the layout plane, its depth along the layout's "
                           "normal; beams run from their cut start (hole positions are measured from it)",
            "beams": len(self.beams),
            "beams_per_family": {f: sum(b.family == f for b in self.beams) for f in "AB"},
            "closed_beams": [b.label for b in self.beams if b.closed],
            "joints": len(self.joints),
            "rivets": len(self.joints),
            "holes": holes,
            "hole_diameter_mm": self.hole_diameter,
            "total_length_mm": float(sum(b.length for b in self.beams)),
            "longest_beam": max(self.beams, key=lambda b: b.length).label if self.beams else None,
            "longest_beam_mm": max((b.length for b in self.beams), default=0.0),
            "top_family": self.top,
            "warnings": list(self.warnings),
            "stock": self.nesting.summary(),
            "placements": [{"beam": self.beams[q.item].label, "stock": q.stock + 1, "x_mm": q.x, "y_mm": q.y}
                           for q in self.nesting.placements] if self.nesting.kind != "none" else [],
            "beam_details": [{"beam": b.label, "family": b.family, "length_mm": b.length,
                              "start_vertex": int(b.vertices[0]), "end_vertex": int(b.vertices[-1]),
                              "direction_deg": b.direction_deg, "starts_free": b.starts_free, "ends_free": b.ends_free,
                              "closed": b.closed, "margin_mm": b.margin} for b in self.beams],
        }


def _format(x: float) -> str:
    return f"{x:.3f}"


def cutlist_csv(plan: FabricationPlan) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CUTLIST_COLUMNS)
    for b in plan.beams:
        w.writerow([b.label, b.family, _format(b.length), len(b.hole_positions),
                    " ".join(_format(x) for x in b.hole_positions), " ".join(str(v) for v in b.hole_vertices),
                    b.section.label])
    return buf.getvalue()


def joints_csv(plan: FabricationPlan) -> str:
    deployed = any(r.deployed_angle_deg is not None for r in plan.joints)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["joint", "beam_a", "beam_b", "on_top", "flat_angle_deg"] + (["deployed_angle_deg"] if deployed else []))
    for r in plan.joints:
        w.writerow([r.joint, r.beam_a, r.beam_b, r.on_top, f"{r.flat_angle_deg:.4f}"]
                   + ([f"{r.deployed_angle_deg:.4f}"] if deployed else []))
    return buf.getvalue()


def fabrication_plan(graph, rest_lengths, materials, options: FabricationOptions = FabricationOptions(), *,
                     flat_angles=None, deployed_angles=None, xy=None) -> FabricationPlan:
    """The strips, their holes, the joint table and the nesting of a design.

    Parameters
    ----------
    graph : LinkageGraph
    rest_lengths : (m,) array
        Per-segment rest lengths, design units.
    materials : Material or list of Material (one per segment)
    options : FabricationOptions
    flat_angles, deployed_angles : (nj,) arrays, optional
        Joint opening angles (radians) of the flat assembly state and of the
        deployed state (default flat: the design's own angles).
    xy : (n, 2) array, optional
        The flat layout's in-plane coordinates (default the drawn design's;
        :func:`flat_state_xy` where the rest lengths are not the drawn ones).
        Rest lengths far from the drawing are said by the commands
        (:func:`rest_lengths_note`), not refused here: xshells optimize moves
        them away from the drawn design by design, and the app exports such
        a design's strips too.
    """
    from ..io.fabrication import flat_coordinates

    to_mm = units_to_mm(options.units)
    top = str(options.top).upper()
    if top not in ("A", "B"):
        raise InputError(f"top family must be A or B, got {options.top!r}")
    sections = beam_sections(materials, graph.num_segments, to_mm)
    width = min(s.width for s in sections)
    hole = width / 3 if options.hole_diameter is None else float(options.hole_diameter)
    if not (np.isfinite(hole) and hole > 0):
        raise InputError(f"--hole-diameter must be a positive length in mm, got {options.hole_diameter!r}")
    if hole >= width:
        raise InputError(f"--hole-diameter {hole:g} mm is not smaller than the section width {width:g} mm")
    if options.end_margin is not None:
        m = float(options.end_margin)
        if not np.isfinite(m):
            raise InputError(f"--end-margin must be a finite length in mm, got {options.end_margin!r}")
        if m < 0.5 * hole:
            raise InputError(f"--end-margin {options.end_margin!r} mm must be at least the hole radius ({0.5 * hole:g} mm): "
                             "the outermost holes would break out of the strip ends")
    XY = flat_coordinates(graph.design.vertices, graph.layout_normal) if xy is None else np.asarray(xy, float)
    beams = trace_beams(graph, rest_lengths, sections, xy=XY, end_margin=options.end_margin, to_mm=to_mm)
    _check_hole_spacing(beams, hole, options.units)
    flat = graph.joint_opening_angles if flat_angles is None else flat_angles
    joints = joint_table(graph, beams, flat, deployed_angles, top=top)
    warnings = tuple(w for w in (_short_arms(beams, options.units), _same_family_joints(beams, joints)) if w)
    lengths = [b.length for b in beams]
    widths = [b.section.width for b in beams]
    labels = [b.label for b in beams]
    if options.stock_length is not None and options.sheet is not None:
        raise InputError("give --stock-length (bars) or --sheet (sheets), not both")
    if options.stock_length is not None:
        nesting = nest_bars(lengths, options.stock_length, options.kerf, labels)
    elif options.sheet is not None:
        nesting = nest_sheets(lengths, widths, options.sheet, options.kerf, labels)
    else:
        nesting = no_nesting(widths, options.kerf)
    return FabricationPlan(beams, joints, nesting, float(hole), to_mm, str(options.units).strip().lower(), XY, top, warnings)


def _check_hole_spacing(beams, hole: float, units: str) -> None:
    """Refuse strips whose holes would overlap (closer than a hole's diameter): not a part anyone can drill.

    A design drawn in other units than its section's is the usual cause (the bundled unit-sized linkages
    with the default 10 mm section: holes 0.49 mm apart for 3.3 mm holes, all drawn without a word)."""
    worst = None
    for b in beams:
        gaps = np.diff(np.sort(np.asarray(b.hole_positions, float)))
        if len(gaps) and (worst is None or gaps.min() < worst[0]):
            worst = (float(gaps.min()), b.label)
    if worst is not None and worst[0] < hole:
        raise InputError(f"strip {worst[1]}: holes {worst[0]:.3g} mm apart, closer than their diameter ({hole:.3g} mm): "
                         f"the segments are too short for the section; is the design drawn in {units} (the units it is read "
                         f"in), or is the section too wide?")


def render_fabrication(plan: FabricationPlan) -> dict[str, bytes]:
    """The content of every file of :data:`FABRICATION_FILES`, by name (nothing written)."""
    from .drawings import assembly_svg, beams_dxf, beams_svg

    text = {"cutlist.csv": cutlist_csv(plan), "joints.csv": joints_csv(plan),
            "beams.svg": beams_svg(plan.beams, plan.nesting, plan.hole_diameter),
            "assembly.svg": assembly_svg(plan.xy, plan.beams, plan.joints, plan.hole_diameter, plan.to_mm, plan.top),
            "bom.json": json.dumps(plan.bill_of_materials(), indent=1)}
    files = {name: text[name].encode("utf-8") for name in text}
    files["beams.dxf"] = beams_dxf(plan.beams, plan.nesting, plan.hole_diameter)
    return {name: files[name] for name in FABRICATION_FILES}


def write_file_set(out_dir: str, files: dict) -> list[str]:
    """Write ``files`` (name → bytes) into ``out_dir`` as one set; the paths written.

    A stop (Ctrl-C, SIGTERM) waits until the whole set is in place (a
    fraction of a second; the caller checks :data:`~xshells.errors.STOP`
    after): cut short, it left the first files of this run beside the rest
    of the previous run's. A write that fails removes every file of the
    set, old or new, before the error goes on: none, rather than a mix.
    Each file is written atomically.
    """
    from ..errors import STOP

    paths = [os.path.join(out_dir, name) for name in files]
    with STOP.deferred():
        try:
            for path, data in zip(paths, files.values()):
                atomic_write_bytes(path, data)
        except BaseException:
            for path in paths:
                try:
                    os.remove(path)
                except OSError:
                    pass
            raise
    return paths


def _same_family_joints(beams, joints) -> str:
    """One line when some joint holds two beams of one family, else "": there "one family on top" cannot hold.

    An odd cycle of crossing beams (three lines crossing pairwise) cannot be
    split into two families that alternate at every joint; the joint table
    then lists the first beam as on top, which says nothing about layers.
    """
    family = {b.label: b.family for b in beams}
    same = [r for r in joints if family[r.beam_a] == family[r.beam_b]]
    if not same:
        return ""
    r = same[0]
    return (f"the strips cannot be layered one family over the other: at {len(same)} of {len(joints)} joints both strips "
            f"are of one family (joint {r.joint}: {r.beam_a} and {r.beam_b}, both {family[r.beam_a]}; on_top there is "
            f"{r.on_top}, the first listed): an odd cycle of crossing beams; decide those joints' layers by hand")


def _short_arms(beams, units: str) -> str:
    """One line when a strip's arm (joint to joint, or joint to free end) is shorter than its section is wide, else "".

    Such a part can be cut, but it is a plate, not a beam (the slender rods
    of the model): usually the design and the section are in different
    units. The hole-spacing check misses it where a strip has one hole (the
    bundled single linkage: 10 mm strips for arms 0.17 mm long, a hole
    0.17 mm from a free end); deploy's slenderness warning is the same test.
    """
    worst, count = None, 0
    for b in beams:
        stops = list(np.asarray(b.hole_positions, float))
        names = [f"joint {v}" for v in b.hole_vertices.tolist()]
        if b.starts_free:
            stops, names = [b.margin] + stops, ["its free end"] + names
        if b.ends_free:
            stops, names = stops + [b.length - b.margin], names + ["its free end"]
        if len(stops) < 2:
            continue
        arms = np.diff(stops)
        k = int(np.argmin(arms))
        if arms[k] < b.section.width:
            count += 1
            if worst is None or arms[k] / b.section.width < worst[0]:
                worst = (arms[k] / b.section.width, b, arms[k], names[k], names[k + 1])
    if worst is None:
        return ""
    _, b, arm, a, c = worst
    return (f"{count} of {len(beams)} strips have an arm shorter than their section is wide: strip {b.label}, "
            f"{arm:.4g} mm from {a} to {c} for a {b.section.width:.4g} mm wide section; is the design drawn in {units} "
            "(the units it is read in), or is the section too wide?")


def write_fabrication(out_dir: str, plan: FabricationPlan) -> list[str]:
    """Write the files of :data:`FABRICATION_FILES` into ``out_dir`` as one set (:func:`write_file_set`); the paths."""
    return write_file_set(out_dir, render_fabrication(plan))


def rest_lengths_note(linkage, design, rest_lengths_path) -> list[str]:
    """A warning (a list of at most one line) where the rest lengths of ``rest_lengths_path`` are far from the drawn
    segments (:data:`~.beams.REST_LENGTH_TOLERANCE`): the flat state then relaxes to another layout.

    Not refused: xshells optimize keeps the drawn design and moves its rest lengths by design (30 % on a unit
    grid); a file of another design with the same segment count looks the same, so it is said.
    """
    from ..io.fabrication import flat_coordinates

    if not linkage.graph.is_planar:
        return []
    bad = rest_length_mismatch(linkage.rest_lengths, flat_coordinates(design.vertices, linkage.graph.layout_normal),
                               design.edges)
    if not bad:
        return []
    return [f"{rest_lengths_path}: the rest lengths are not the drawn flat layout's: {bad}: the strips are cut to "
            "the rest lengths and drawn in the flat state they relax to (as after xshells optimize; if the file is "
            "another design's, this is not that design)"]


def flat_state_xy(linkage) -> np.ndarray:
    """In-plane coordinates (n, 2) of every design vertex in ``linkage``'s current flat state, in the drawn layout's
    axes: the layout that rest lengths other than the drawn ones (a file, an optimization) relax to."""
    from ..io.fabrication import flat_coordinates

    return flat_coordinates(linkage.vertex_positions(), linkage.graph.layout_normal, frame=linkage.graph.design.vertices)


def plan_of(linkage, flat_angles, deployed_angles=None, rest_lengths=None, skipped: list | None = None,
            xy=None) -> FabricationPlan | None:
    """The fabrication plan (default options) of a command that solved ``linkage``; None for a layout that is not
    flat, or that cannot be built with its section (then why goes into ``skipped``, if given).

    ``flat_angles``: the joint angles of its flat assembly state; ``rest_lengths``
    default to the linkage's own; ``xy``: the flat layout (default the drawn
    design; :func:`flat_state_xy` where the rest lengths are not the drawn ones).
    """
    if not linkage.graph.is_planar:
        return None
    p = linkage.rest_lengths if rest_lengths is None else rest_lengths
    mats = linkage.materials if len(linkage.materials) > 1 else linkage.materials[0]
    try:
        return fabrication_plan(linkage.graph, p, mats, flat_angles=flat_angles, deployed_angles=deployed_angles, xy=xy)
    except InputError as exc:  # a layout no one can build with its section: no drawings of it
        if skipped is not None:
            skipped.append(f"fabrication files not written: {exc}")
        return None


FLAT_LAYOUT_FILES = ("flat_layout.svg", "flat_layout.dxf")


def remove_fabrication_files(out_dir: str, flat_layout: bool = False) -> list[str]:
    """Remove the files of :data:`FABRICATION_FILES` from ``out_dir``, where a command writes none this time; the names
    removed. Only these names: left there, an earlier run's cut list sat beside another design's result. With
    ``flat_layout``, also :data:`FLAT_LAYOUT_FILES` (a design that is not flat has no flat layout drawing)."""
    removed = []
    for name in FABRICATION_FILES + (FLAT_LAYOUT_FILES if flat_layout else ()):
        try:
            os.remove(os.path.join(out_dir, name))
        except FileNotFoundError:
            continue
        removed.append(name)
    return removed


def stale_note(removed: list[str]) -> str:
    """The warning that says which earlier fabrication files were removed."""
    return f"removed an earlier run's fabrication files, not written for this design: {', '.join(removed)}"


def write_outputs_of(out_dir: str, linkage, flat_angles, deployed_angles=None, rest_lengths=None, xy=None,
                     warnings: list | None = None) -> list[str]:
    """The fabrication files of a command that solved ``linkage`` (``optimize``, ``inverse``); [] for a non-flat layout,
    or one that cannot be built (then an earlier run's files are removed, and ``warnings``, if given, says so)."""
    plan = plan_of(linkage, flat_angles, deployed_angles, rest_lengths, skipped=warnings, xy=xy)
    if plan is None:
        removed = remove_fabrication_files(out_dir)
        if removed and warnings is not None:
            warnings.append(stale_note(removed))
        return []
    if warnings is not None:
        warnings.extend(plan.warnings)
    return write_fabrication(out_dir, plan)


def run_fabrication(design_path, material, *, out_dir, options: FabricationOptions = FabricationOptions(), subdivision=10,
                    rest_lengths_path=None, name=None, progress=True) -> dict:
    """The job behind ``xshells fabricate``: rest lengths (solved, or read), then every fabrication file.

    Returns the ``result.json`` content (the bill of materials under ``bom``).
    """
    import sys
    import time

    from ..io import read_design, read_rest_lengths
    from ..linkage.linkage import Linkage

    t0 = time.perf_counter()
    os.makedirs(out_dir, exist_ok=True)
    if units_to_mm(options.units) != 1.0 and str(design_path).lower().endswith(".3dm"):  # refused before any work
        # the reader has converted the file's own units to mm already: a second conversion scaled it x1000
        from ..rhino.read import file_units

        raise InputError(f"{design_path}: --units {options.units} does not apply to a .3dm: the file states its units "
                         f"({file_units(design_path)}) and is read in mm; leave --units out")
    design = read_design(design_path)
    linkage = Linkage(design, material, subdivision=subdivision,
                      rest_lengths=read_rest_lengths(rest_lengths_path, design.num_segments, design) if rest_lengths_path else None)
    if not linkage.graph.is_planar:
        raise InputError(f"{design_path}: the layout is not flat; fabricate needs the flat design "
                         "(a case's flat_file, or the flat .obj/.msh)")
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=3, desc=f"fabricating {name or os.path.basename(str(design_path))}", unit="stage")
    try:
        if bar is not None:
            bar.set_postfix(stage="rest lengths" if rest_lengths_path is None else "rest lengths (file)")
        xy, warnings = None, []
        if rest_lengths_path is None:
            from ..deploy.simulate import rest_length_solve, rest_length_warning

            warnings += rest_length_warning(rest_length_solve(linkage), linkage)  # said, not thrown away
        else:
            # the strips are cut to the file's rest lengths, and drawn in the flat state those relax to, as
            # `xshells deploy` draws them (rest lengths that xshells optimize moved, or another design's)
            warnings += rest_lengths_note(linkage, design, rest_lengths_path)
            from ..solve import NewtonOptions, minimize

            minimize(linkage, fixed=linkage.rigid_pin_indices(), options=NewtonOptions(gradient_tolerance=1e-9, max_iterations=100))
            xy = flat_state_xy(linkage)
        t_rest = time.perf_counter() - t0
        if bar is not None:
            bar.update(1)
            bar.set_postfix(stage="beams and nesting")
        t1 = time.perf_counter()
        mats = linkage.materials if len(linkage.materials) > 1 else linkage.materials[0]
        plan = fabrication_plan(linkage.graph, linkage.rest_lengths, mats, options, flat_angles=linkage.joint_angles(),
                                xy=xy)
        if warnings:
            plan = replace(plan, warnings=tuple(warnings) + tuple(plan.warnings))
        if bar is not None:
            bar.update(1)
            bar.set_postfix(stage="files")
        files = render_fabrication(plan)
        t_fab = time.perf_counter() - t1
        bom = plan.bill_of_materials()
        result = _fabricate_result(design_path, design, linkage, rest_lengths_path, name, bom, t_rest, t_fab, t0)
        # result.json in the same set: an interrupted run left the new files beside the previous run's result
        write_file_set(out_dir, {**files, "result.json": finite_json(result, indent=1).encode("utf-8")})
        if bar is not None:
            bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    from ..errors import STOP

    STOP.check()  # a stop that waited for the files
    if progress and plan.units != "mm":
        print(f"note: {bom['units_note']}", file=sys.stderr)
    return result


def _fabricate_result(design_path, design, linkage, rest_lengths_path, name, bom, t_rest, t_fab, t0) -> dict:
    """The ``result.json`` of ``xshells fabricate``."""
    import time

    return {
        "name": name or os.path.splitext(os.path.basename(str(design_path)))[0],
        "design": os.path.abspath(str(design_path)),
        "segments": linkage.num_segments,
        "joints": linkage.num_joints,
        "rest_lengths": "file: " + os.path.abspath(rest_lengths_path) if rest_lengths_path else "rest-length solve",
        "input": design.note,  # how a .3dm was read (its layer, units and the conversion to mm), else None
        "bom": bom,
        "files": list(FABRICATION_FILES),
        # fabrication: tracing, nesting and drawing the files (their writing, last, is not counted)
        "timings_s": {"rest_lengths": t_rest, "fabrication": t_fab, "total": time.perf_counter() - t0},
    }
