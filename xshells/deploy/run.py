"""The deployment job behind ``xshells deploy`` and ``xshells demo``: solve, then write every output."""
from __future__ import annotations

import csv
import io
import os
import sys
import time
from dataclasses import asdict, fields

import numpy as np

from ..errors import STOP
from ..io import read_design, read_rest_lengths
from ..io.export import atomic_write_text, finite_json
from ..linkage.export import scalar_fields, swept_mesh, write_centerlines
from ..linkage.linkage import Linkage
from .case import opened_angle
from .simulate import DeployOptions, StepRecord, deploy, max_abs_z, rest_length_solve, rest_length_warning


# result.json's "units": they follow the input and are never converted (README: Units)
UNITS = ("those of the input, never converted: lengths in the design's unit, stresses in that of E, energies in "
         "force × length and torques in force × length per radian (N·mm for a design in mm with E in MPa, as the "
         "bundled data); angles in degrees")


def _state_summary(linkage: Linkage) -> dict:
    parts = linkage.energy_parts()
    return {
        "energy": parts.total,
        "energy_stretch": parts.stretch,
        "energy_bend": parts.bend,
        "energy_twist": parts.twist,
        "average_angle_deg": float(np.degrees(linkage.average_angle())),
        "max_abs_z": max_abs_z(linkage.joint_positions()),  # the steps' own definition (simulate.max_abs_z)
        "joint_positions": linkage.joint_positions().tolist(),
    }


def bending_field(linkage: Linkage) -> np.ndarray:
    """√(bending-energy density) per rod vertex, the field of the rendered views (Fig. 6)."""
    return np.sqrt(np.maximum(scalar_fields(linkage)["bending_energy_density"], 0.0))


def _write_meshes(out_dir: str, tag: str, linkage: Linkage) -> None:
    """``TAG_centerlines.obj`` and the swept beams as ``TAG.obj`` and ``TAG.ply`` (one mesh for both)."""
    from ..io.sweep import write_obj, write_ply

    write_centerlines(os.path.join(out_dir, f"{tag}_centerlines.obj"), linkage)
    mesh = swept_mesh(linkage)
    write_obj(os.path.join(out_dir, f"{tag}.obj"), mesh)
    write_ply(os.path.join(out_dir, f"{tag}.ply"), mesh)


def _picture_args(out_dir: str, tag: str, linkage: Linkage) -> tuple:
    """The arguments of :func:`xshells.viz.render.render_linkage` for ``TAG.png`` (arrays: they travel to a writer)."""
    return (os.path.join(out_dir, f"{tag}.png"), linkage.rods.points.copy(), linkage.rods.edges, bending_field(linkage),
            f"{tag}: average angle {np.degrees(linkage.average_angle()):.1f}°")


def _write_outputs(out_dir: str, tag: str, linkage: Linkage, vmax: float | None = None) -> None:
    from ..viz.render import render_linkage

    _write_meshes(out_dir, tag, linkage)
    render_linkage(*_picture_args(out_dir, tag, linkage), vmax=vmax)


def _flat_view(linkage: Linkage) -> tuple:
    """The rod points in the layout plane's coordinates and those axes' names: the flat state seen from above,
    along the layout normal (a 3D view at 28° elevation made a nearly closed layout, the manta ray's
    2317 × 204, a sliver). A layout in the xy plane keeps x and y."""
    n = np.asarray(linkage.graph.layout_normal, float)
    k = int(np.argmax(np.abs(n)))
    if abs(abs(n[k]) - 1.0) < 1e-12:  # a coordinate plane: its own two coordinates, right-handed about n
        i, j = [(1, 2), (2, 0), (0, 1)][k]
        if n[k] < 0:
            i, j = j, i
        return linkage.rods.points[:, [i, j]], ("xyz"[i], "xyz"[j])
    u = np.cross(n, np.eye(3)[int(np.argmin(np.abs(n)))])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    P = linkage.rods.points - linkage.rods.points.mean(axis=0)
    return np.stack([P @ u, P @ v], axis=1), ("along the layout plane", "across, in the layout plane")


def _write_flat_outputs(out_dir: str, linkage: Linkage, design) -> None:
    if not linkage.graph.is_planar:  # no plane to look along: the 3D view
        _write_outputs(out_dir, "flat", linkage)
        return
    from ..viz.render import render_flat

    _write_meshes(out_dir, "flat", linkage)
    xy, axes = _flat_view(linkage)
    render_flat(os.path.join(out_dir, "flat.png"), xy, linkage.rods.edges, bending_field(linkage),
                f"flat: average angle {np.degrees(linkage.average_angle()):.1f}°, seen along the layout normal",
                axes=axes, unit="design units")  # lengths follow the design file, never converted
    if linkage.graph.is_planar:  # fabrication drawings of the flat layout with its rest lengths
        from ..io.fabrication import write_drawings

        write_drawings(out_dir, "flat_layout", design, linkage.rest_lengths)


# What the forked writers import once the flat state's files are written: lane 0 writes the deployed picture
# and the fabrication files, then the deployment plot; lane 1 (forked from lane 0 then) the Rhino file
_WRITER_IMPORTS = ("matplotlib.pyplot", "mpl_toolkits.mplot3d.art3d", "xshells.viz.render", "xshells.fabrication.run",
                   "xshells.fabrication.drawings", "rhino3dm", "xshells.rhino.write", "xshells.app.exports")
_FORKED: dict = {}  # in a forked writer: the linkage it was forked with


def _start_writer(out_dir: str, linkage: Linkage, design, background: bool):
    """The writer of a run (:mod:`.background`), its first job the flat state's files."""
    from .background import Background

    def first():
        _FORKED["linkage"] = linkage
        _write_flat_outputs(out_dir, linkage, design)

    return Background(first, imports=_WRITER_IMPORTS, lanes=2, inline=not background)


def _write_deployed_outputs(out_dir: str, linkage: Linkage, design, flat_angles, writer=None, warnings=None,
                            flat_xy=None) -> None:
    """The deployed state's files. ``writer``: from :func:`_start_writer` (None: all here); forked, its lane 0
    writes the picture and the fabrication files (then :func:`_finish`'s deployment plot: 1.03 against 1.06 s of
    overhead with it after the Rhino file, median of 5), its lane 1 the Rhino file, and this process the meshes,
    at the same time; :func:`_finish` joins it. ``flat_xy``: the fabrication files' flat layout (default the drawn one)."""
    from ..fabrication.run import plan_of, remove_fabrication_files, stale_note, write_fabrication
    from ..viz.render import render_linkage

    plan = plan_of(linkage, flat_angles, linkage.joint_angles(), skipped=warnings, xy=flat_xy)
    if plan is not None and warnings is not None:  # parts that make no sense, written all the same
        warnings.extend(plan.warnings)
    if plan is None:  # none written: an earlier run's cut list would sit beside this design's result
        # a design that is not flat has no flat layout drawing either (that of an earlier, flat one)
        removed = remove_fabrication_files(out_dir, flat_layout=not linkage.graph.is_planar)
        if removed and warnings is not None:
            warnings.append(stale_note(removed))
    if writer is not None and writer.forked:  # the flat layout, the deployed state and the strips (docs/rhino.md)
        from ..linkage.state import snapshot

        writer.submit(_write_3dm_forked, out_dir, snapshot(linkage), design, plan, lane=1)
    else:
        _write_3dm(out_dir, linkage, design, plan)
    submit = writer.submit if writer is not None else _now
    submit(render_linkage, *_picture_args(out_dir, "deployed", linkage))
    if plan is not None:  # cut list, strips, assembly (docs/fabrication.md)
        submit(write_fabrication, out_dir, plan)
    _write_meshes(out_dir, "deployed", linkage)


def _now(fn, *args) -> None:
    fn(*args)


def _write_3dm(out_dir: str, linkage: Linkage, design, plan) -> None:
    from ..rhino.write import write_3dm

    write_3dm(os.path.join(out_dir, "deployed.3dm"), flat_design=design if linkage.graph.is_planar else None,
              deployed=linkage, strips=plan)


def _write_3dm_forked(out_dir: str, snap: dict, design, plan) -> None:
    """:func:`_write_3dm` in a forked writer, its linkage put in the state ``snap`` (:func:`~xshells.linkage.state.snapshot`)."""
    from ..linkage.state import restore

    restore(_FORKED["linkage"], snap)
    _write_3dm(out_dir, _FORKED["linkage"], design, plan)


def _stress_row(linkage, strength) -> dict:
    """The largest stress of a state and where it is (its beam, the joint nearest to it)."""
    from ..analysis.stress import beam_report, rod_stresses

    st = rod_stresses(linkage, strength)
    k = int(np.argmax(st.von_mises))
    beams = beam_report(linkage, st)
    worst = max(beams, key=lambda b: b["max_von_mises"]) if beams else {"beam": -1, "nearest_joint": -1}
    return {"max_von_mises": st.max_von_mises, "utilization_max": st.max_utilization, "rod_vertex": k,
            "beam": worst["beam"], "nearest_joint": worst["nearest_joint"]}


def _stress_summary(steps_out, stress_rows, strength, linkage) -> dict:
    """Stress results of a deployment: the largest over its steps, and the first step at which a beam would break."""
    from ..analysis.stress import beam_report, rod_stresses

    first = None
    for row, extra in zip(steps_out, stress_rows):
        if strength is not None and extra["utilization_max"] >= 1.0:
            first = {"angle_deg": row["average_angle_deg"], "beam": extra["beam"], "nearest_joint": extra["nearest_joint"],
                     "utilization": extra["utilization_max"]}
            break
    final = rod_stresses(linkage, strength)
    return {
        "strength": strength,
        "max_von_mises": max([r["max_von_mises"] for r in stress_rows], default=final.max_von_mises),
        "utilization_max": (max([r["utilization_max"] for r in stress_rows], default=final.max_utilization)
                            if strength is not None else None),
        "first_failure": first,
        "deployed_beams": beam_report(linkage, final),
        "note": "von Mises of the largest normal and torsion shear stresses at each rod vertex (an upper bound); "
                "units: the design's stress unit (MPa for millimetres)",
    }


def _assembly_state(design_path, material, subdivision, rest_lengths_path, progress):
    """The design, its rest lengths read (or None), the linkage in its flat assembly state (rest lengths solved,
    or the file's relaxed), the warnings so far, how many of them are printed, and the seconds of the solve."""
    design = read_design(design_path)
    p = read_rest_lengths(rest_lengths_path, design.num_segments, design) if rest_lengths_path else None
    linkage = Linkage(design, material, subdivision=subdivision, rest_lengths=p)
    warnings = list(linkage.input_warnings())
    if design.note:  # e.g. a .3dm's layer and its units, converted to mm
        warnings = [design.note] + list(warnings)
    if p is not None:  # rest lengths far from the drawing: the flat state relaxes to another layout, said
        from ..fabrication.run import rest_lengths_note

        warnings += rest_lengths_note(linkage, design, rest_lengths_path)
    printed = _say(warnings, 0, progress)
    t1 = time.perf_counter()
    if p is None:  # a solve that did not converge is said (its report was thrown away)
        warnings += rest_length_warning(rest_length_solve(linkage), linkage)
        printed = _say(warnings, printed, progress)
    else:
        from ..solve import NewtonOptions, minimize

        minimize(linkage, fixed=linkage.rigid_pin_indices(), options=NewtonOptions(gradient_tolerance=1e-9, max_iterations=100))
    return design, p, linkage, warnings, printed, time.perf_counter() - t1


def run_deployment(design_path, material, *, out_dir, subdivision=10, target_angle=None, open_by=None, steps=40,
                   rest_lengths_path=None, direction="up", progress=True, name=None, start="auto", states=None,
                   strength=None, background=False, guide_path=None) -> dict:
    """Build the linkage, find its assembly state, deploy it and write the outputs into ``out_dir``.

    ``states``, a dict if given, receives copies of the ``"flat"`` and
    ``"deployed"`` linkages (for callers that check them further).
    ``strength`` (allowable stress) adds the utilization to every step and
    the first angle at which a beam would break (docs/analysis.md).
    ``background``: write the files in forked processes on the other core
    while the deployment goes on (:mod:`xshells.deploy.background`; the
    command line's choice), not in this process in turn, where at least
    3/4 of a core idled while the linkage was built and its rest lengths solved.
    ``guide_path``: a guide file (:mod:`.guide`): at the target angle the shell
    is held on its joint positions and let go.

    Returns the ``result.json`` content. Interrupting (Ctrl-C) keeps and
    writes the steps finished so far.
    """
    os.makedirs(out_dir, exist_ok=True)
    t0 = time.perf_counter()
    if background:  # the writers only where a core idles beside this one (see .background)
        from .background import IdleCores

        idle = IdleCores()
    design, p, linkage, warnings, printed, t_rest = _assembly_state(design_path, material, subdivision,
                                                                    rest_lengths_path, progress)
    guide = None
    if guide_path is not None:  # read before the deployment: a bad file is refused at once, not after the steps
        from .guide import read_guide

        guide = read_guide(guide_path, linkage.num_joints)
    flat = _state_summary(linkage)
    flat_angles = linkage.joint_angles().copy()  # for the joint table of the fabrication files
    flat_xy = None  # the fabrication files' layout: the drawn one, or the flat state that a file's rest lengths relax to
    if p is not None and linkage.graph.is_planar:
        from ..fabrication.run import flat_state_xy

        flat_xy = flat_state_xy(linkage)
    if states is not None:
        import copy

        states["flat"] = copy.deepcopy(linkage)
    if target_angle is None:
        target_angle = opened_angle(linkage, open_by, name)

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps, desc=f"deploying {name or os.path.basename(str(design_path))}", unit="step")

    from ..analysis.stress import check_strength

    strength = check_strength(strength)
    # the steps finished so far, each with its stresses (None without a strength): what an interrupted run keeps.
    # One list of pairs, appended once per step when everything is computed: an interrupt inside the stresses
    # drops that step whole (two lists appended one after the other left a step without its utilization_max,
    # and the interrupted run ended in a KeyError instead of its result.json)
    done = []

    def on_step(rec):
        # the utilization along the way; without a strength, the final state's stresses only. Deferred: a stop
        # inside the stresses would drop this step from the list while deploy() keeps its state as the last one
        with STOP.deferred():
            row = _stress_row(linkage, strength) if strength is not None else None
            done.append((rec, row))
        STOP.check()
        if bar is not None:
            bar.set_postfix(angle=f"{rec.average_angle_deg:.1f}°", z=f"{rec.max_abs_z:.3g}")
            bar.update(1)
        return False

    t2 = time.perf_counter()
    res = None
    interrupted = False
    writer = None
    try:  # the outer try only undoes the deferral that the inner one's finally starts
        try:  # an interrupt from here on keeps what is done: the flat files, the steps so far, result.json
            writer = _start_writer(out_dir, linkage, design, background and idle.idle() >= 0.75)
            t2 = time.perf_counter()
            res = deploy(linkage, target_angle, DeployOptions(steps=steps, direction=direction, start=start, guide=guide),
                         callback=on_step)
            STOP.check()
        except KeyboardInterrupt:
            interrupted = True
        except Exception:
            if not STOP.requested:
                raise
            interrupted = True  # the stop was raised inside library code that turned it into another error
        finally:
            # A stop from here on waits until the last files and result.json are written (seconds):
            # cut short, the run would leave deployed files without the result that describes them.
            # (Not ``with STOP.deferred()``: the deferral must begin the moment the deploy ends,
            # inside this finally, with no gap for a signal to land in.)
            STOP.deferring += 1
        if bar is not None:
            bar.close()
        t_deploy = time.perf_counter() - t2
        if states is not None:
            states["deployed"] = linkage
        finished = list(done)
        stress_rows = [row for _, row in finished if row is not None]
        result = _finish(out_dir, linkage, design, res, interrupted, flat_angles, stress_rows, strength, {
            "name": name, "flat": flat, "target_angle_deg": float(np.degrees(target_angle)), "warnings": warnings,
            "timings_s": {"rest_length_solve": t_rest, "deploy": t_deploy}, "steps": [rec for rec, _ in finished],
            "flat_xy": flat_xy, "guide_path": None if guide_path is None else str(guide_path)},
            t0, writer)
        writer = None
    finally:
        if writer is not None:  # an error on the way: the writer still ends before the command
            try:
                writer.join()
            except Exception:  # noqa: BLE001 (the error under way is the one to report)
                pass
        STOP.deferring -= 1  # also when the deploy failed with an error (the counter was left raised before)
    _say(result["warnings"], printed, progress)  # those of the last files (a stale file removed, a part skipped)
    if interrupted or STOP.requested:
        raise _stopped(out_dir, result)
    return result


def _say(warnings: list, printed: int, progress: bool) -> int:
    """Print the warnings from ``printed`` on (with the progress bar; without it the summary lists them all)."""
    if progress:
        for w in warnings[printed:]:
            print(f"warning: {w}", file=sys.stderr)
    return len(warnings)


def _note_refined_steps(result: dict, res) -> None:
    """result.json's ``refined_steps`` and a warning for each step that buckled the flat layout in one coarse step
    and was redone in sub-steps (:attr:`~.simulate.DeployOptions.max_buckling_step_deg`)."""
    result["refined_steps"] = res.refined_steps
    for r in res.refined_steps:
        result["warnings"].append(
            f"step {r['step']} ({r['from_deg']:.2f}° to {r['to_deg']:.2f}°) buckled the flat layout in one step: redone "
            f"from the flat state in {r['substeps']} sub-steps, so that it buckles at its first instability (in one "
            f"step it reached energy {r['energy_one_step']:.6g} there, in sub-steps {r['energy']:.6g}); more --steps "
            f"avoid the redo")


def _remove_if_present(path: str) -> bool:
    try:
        os.remove(path)
    except FileNotFoundError:
        return False
    return True


def _stopped(out_dir, result) -> KeyboardInterrupt:
    """The KeyboardInterrupt an interrupted run ends with, saying what it kept (the command line prints it)."""
    exc = KeyboardInterrupt()
    n = len(result["steps"])
    exc.kept = (f"the {n} finished step{'s' * (n != 1)} (to {result['deployed']['average_angle_deg']:.2f}°) "
                f"{'are' if n != 1 else 'is'} kept in {os.path.join(out_dir, 'result.json')} and the deployed files beside it" if n else
                f"no step finished: {os.path.join(out_dir, 'result.json')} keeps the assembly state")
    return exc


def _stop_message() -> str:
    """result.json's message of an interrupted run: Ctrl-C or SIGTERM."""
    if STOP.terminated:
        return "terminated (SIGTERM): the finished steps are kept, the deployed state is the last of them"
    return "interrupted by the user: the finished steps are kept, the deployed state is the last of them"


def _finish(out_dir, linkage, design, res, interrupted, flat_angles, stress_rows, strength, head, t0, writer=None) -> dict:
    """Write the deployed state's files, deployment.csv, deployment.png and, last, result.json; returns the result.

    ``writer``: from :func:`_start_writer` (None: every file written here).
    """
    deployed = _state_summary(linkage)
    if res is not None:
        deployed["torque"] = res.torque
        deployed["min_hessian_eigenvalue"] = res.min_hessian_eigenvalue
        deployed["stiffness_gap"] = res.stiffness_gap
        deployed["min_eigenvalue_at_fixed_angle"] = res.min_eigenvalue_at_fixed_angle
    try:  # a Ctrl-C outside the command line's handler: result.json is still written (each file is whole or absent)
        _write_deployed_outputs(out_dir, linkage, design, flat_angles, writer, head["warnings"], head.get("flat_xy"))
    except KeyboardInterrupt:
        interrupted = True
    steps_out = [asdict(s) for s in (res.steps if res is not None else head.get("steps", []))]
    for row, extra in zip(steps_out, stress_rows):
        row.update({k: v for k, v in extra.items() if k in ("max_von_mises", "utilization_max")})
    stress = _stress_summary(steps_out, stress_rows, strength, linkage)
    result = {
        "name": head["name"],
        "segments": linkage.num_segments,
        "joints": linkage.num_joints,
        "dof": linkage.num_vars,
        "subdivision": linkage.subdivision,
        "rest_lengths": linkage.rest_lengths.tolist(),
        "flat": head["flat"],
        "deployed": deployed,
        "target_angle_deg": head["target_angle_deg"],
        # complete: reached the target; stopped: ended short of it (the message says why); interrupted: Ctrl-C/SIGTERM
        "status": "interrupted" if interrupted else ("complete" if res.converged else "stopped"),
        "reached": bool(res is not None and res.converged),
        "message": _stop_message() if interrupted else res.message,
        "steps": steps_out,
        "timings_s": {**head["timings_s"], "total": time.perf_counter() - t0},
        "newton_iterations": res.newton_iterations if res is not None else sum(s["iterations"] for s in steps_out),
        "stress": stress,
        "utilization_max": stress["utilization_max"],
        "warnings": head["warnings"],
        "units": UNITS,
    }
    if res is not None:
        _note_refined_steps(result, res)
        if res.guide is not None:  # what the guide did (.guide.GuideReport); a guide not followed is warned of
            result["guide"] = {"file": head.get("guide_path"), **asdict(res.guide)}
            if not res.guide.held:
                result["warnings"].append(res.guide.note)
        # how the assembly state was held when it first relaxed (see DeployOptions.start)
        result["start"] = {"mode": res.start, "average_angle_deg": res.start_angle_deg, "note": res.start_note}
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(steps_out[0].keys()) if steps_out else [f.name for f in fields(StepRecord)])
    w.writeheader()  # a header even before the first step ends: a table with no rows, not an empty file
    w.writerows(steps_out)
    atomic_write_text(os.path.join(out_dir, "deployment.csv"), buf.getvalue())
    from ..viz.render import plot_deployment

    if not steps_out:  # none drawn: an earlier run's plot would sit beside this result as if it were its own
        if _remove_if_present(os.path.join(out_dir, "deployment.png")):
            head["warnings"].append("removed an earlier run's deployment.png: this run finished no step to plot")
    else:
        args = (plot_deployment, os.path.join(out_dir, "deployment.png"), [s["average_angle_deg"] for s in steps_out],
                [s["energy"] for s in steps_out], [s["torque"] for s in steps_out], head["name"] or "",
                [s["utilization_max"] for s in steps_out] if strength is not None else None)
        if writer is not None:  # lane 0, after the picture and the fabrication files (lane 1 has the Rhino file)
            writer.submit(*args)
        else:
            _now(*args)
    if writer is not None:  # every file is in place before result.json, which describes them
        writer.join()
    result["timings_s"]["total"] = time.perf_counter() - t0
    atomic_write_text(os.path.join(out_dir, "result.json"), finite_json(result, indent=1))
    if interrupted:
        raise _stopped(out_dir, result)
    return result
