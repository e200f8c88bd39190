"""The xshells Hops components: Deploy, Optimize, Sparsify, Analyze and Inverse.

Each runs the command of the same name in this process, exactly as the
command line does, on a ``.3dm`` written from its inputs (the Grasshopper
document's units and tolerance): so a component and ``xshells deploy`` on
the same lines give the same state, and reading, snapping, unit conversion
and every input check are the command's own. The geometry comes back from
the ``.3dm`` the command writes (in mm), scaled to the document's units.
Energies, torques and stresses stay in mm, N and MPa (the Report says so).
"""
from __future__ import annotations

import json
import os
import tempfile

from ..errors import InputError
from .hops import Component, Context, Param

MATERIAL = (
    Param("Section", "Text", "cross-section TYPE:P1,P2 (e.g. rectangle:10,7), in mm", default="rectangle:10,7"),
    Param("Young", "Number", "Young's modulus, MPa", default=20000.0),
    Param("Poisson", "Number", "Poisson's ratio", default=0.3),
)
SAMPLE = Param("Sample", "Integer", "straight segments per curved curve (0: curved curves are refused)", default=0)
LINES = Param("Lines", "Curve", "the flat layout: lines and polylines, each vertex a joint or a free end", many=True)
ANGLE = Param("Angle", "Number", "deployed average opening angle, degrees (0: open by 60° from the flat state)",
              default=0.0)
CENTERLINES = Param("Centerlines", "Curve", "the rods' centerlines, one polyline per segment", many=True)
BEAMS = Param("Beams", "Mesh", "the beams, swept with their section (vertex colours: √bending energy)")
REPORT = Param("Report", "Text", "what the command said, and the units")


def _write_design(path: str, curves, ctx: Context) -> None:
    import rhino3dm

    f = rhino3dm.File3dm()
    f.Settings.ModelUnitSystem = getattr(rhino3dm.UnitSystem, ctx.units)
    f.Settings.ModelAbsoluteTolerance = float(ctx.tolerance) if ctx.tolerance > 0 else 0.001
    layer = rhino3dm.Layer()
    layer.Name = "Grasshopper"
    attrs = rhino3dm.ObjectAttributes()
    attrs.LayerIndex = f.Layers.Add(layer)
    if not curves:
        raise InputError("input 'Lines' is empty: connect the flat layout's lines")
    for k, c in enumerate(curves):
        if not isinstance(c, rhino3dm.Curve):
            raise InputError(f"input 'Lines': item {k} is a {type(c).__name__}, not a line or polyline")
        f.Objects.AddCurve(c, attrs)
    if not f.Write(path, 7):
        raise InputError(f"could not write the design for the solve ({path})")


def _write_mesh(path: str, mesh, ctx: Context, name: str) -> None:
    import rhino3dm

    if not isinstance(mesh, rhino3dm.Mesh):
        raise InputError(f"input {name!r}: a mesh is needed, got a {type(mesh).__name__}")
    f = rhino3dm.File3dm()
    f.Settings.ModelUnitSystem = getattr(rhino3dm.UnitSystem, ctx.units)
    f.Objects.AddMesh(mesh)
    if not f.Write(path, 7):
        raise InputError(f"could not write the surface for the solve ({path})")


def _layers(path: str, ctx: Context) -> dict:
    """The objects of a result ``.3dm`` by layer full path, scaled from mm to the document's units."""
    import rhino3dm

    from .read import RHINO_UNITS_TO_MM

    f = rhino3dm.File3dm.Read(path)
    if f is None:
        raise InputError(f"the command wrote no readable {os.path.basename(path)}")
    names = [layer.FullPath for layer in f.Layers]
    xf = rhino3dm.Transform.Scale(rhino3dm.Point3d(0, 0, 0), 1.0 / RHINO_UNITS_TO_MM[ctx.units])
    out: dict = {}
    for o in f.Objects:
        g = o.Geometry
        g.Transform(xf)
        out.setdefault(names[o.Attributes.LayerIndex], []).append(g)
    return out


def _common(values: dict) -> list:
    section = str(values["Section"]).strip()
    if not section:  # it ran with the default 10 × 7 without a word
        raise InputError("input 'Section': empty (give TYPE:P1,P2,..., e.g. rectangle:10,7)")
    if section.lower().endswith(".json") or "/" in section or "\\" in section:
        # the command would read a file on the server, relative to where the server runs
        raise InputError(f"input 'Section': give TYPE:P1,P2,... (e.g. rectangle:10,7), not a file ({section!r}): "
                         "the server does not read files from the canvas")
    return ["--material", str(values["Section"]), "--young", repr(float(values["Young"])),
            "--poisson", repr(float(values["Poisson"]))]


def _optional(values: dict, name: str, flag: str, positive: bool = True) -> list:
    v = values.get(name)
    if v is None or (positive and v == 0):  # 0: the command's default
        return []
    if positive and not v > 0:  # a negative angle ran at the default angle without a word
        raise InputError(f"input {name!r}: must be 0 (the default) or positive, got {v:g}")
    return [flag, repr(v) if isinstance(v, float) else str(v)]


# The command's options and files, as the component inputs they come from: an error names what the
# Grasshopper user connected ("input 'Steps'"), not the command line built for them ("--steps").
OPTION_INPUTS = {"--steps": "Steps", "--subdivision": "Subdivision", "--angle": "Angle", "--sample": "Sample",
                 "--young": "Young", "--poisson": "Poisson", "--material": "Section", "--max-fit": "MaxFit",
                 "--actuators": "Actuators", "--load": "Loads", "--supports": "Supports", "--density": "Density",
                 "--max-iters": "MaxIters", "--spacing": "Spacing", "--grading": "Grading", "--tries": "Tries",
                 "--direction": "Direction", "--target-surface": "Target"}
FILE_INPUTS = {"design.3dm": "Lines", "surface.3dm": "Surface", "target.3dm": "Target"}


def _run(argv: list, tmp: str) -> tuple[int, str]:
    """Runs ``xshells ARGV`` here; returns (exit code, out folder). Input errors raise InputError, in the
    component's words (:func:`as_inputs`); ``tmp`` is the folder of the files written for the command."""
    from ..cli import run_in_process

    try:
        return run_in_process(_joined(argv)), argv[argv.index("--out") + 1]
    except InputError as exc:
        raise InputError(as_inputs(str(exc), tmp)) from None


def as_inputs(message: str, tmp: str) -> str:
    """A command's error message with its options and the files written in ``tmp`` named as component inputs."""
    import re

    for name, param in FILE_INPUTS.items():
        path = os.path.join(tmp, name)
        message = message.replace(path + ": ", f"input {param!r}: ").replace(path, f"input {param!r}")
    message = message.replace(tmp, "the server's work folder")
    message = re.sub(r" \(see xshells [a-z]+ --help\)$", "", message)
    return re.sub(r"--[a-z][a-z-]*(?![a-z-])",
                  lambda m: f"input {OPTION_INPUTS[m.group(0)]!r}" if m.group(0) in OPTION_INPUTS else m.group(0),
                  message)


def _joined(argv: list) -> list:
    """Every option built here takes a value: joined as ``--flag=value``, so that a value that starts with
    "-" (-inf, "-1%", a Loads text "--help") is read as the value, not as another option."""
    joined, i = [], 0
    while i < len(argv):
        if argv[i].startswith("--") and "=" not in argv[i] and i + 1 < len(argv):
            joined.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            joined.append(argv[i])
            i += 1
    return joined


def _result(out: str) -> dict:
    try:
        with open(os.path.join(out, "result.json")) as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return {}


def _report(command: str, result: dict, code: int) -> tuple[str, list]:
    warnings = [str(w) for w in result.get("warnings", [])]
    msg = result.get("message") or result.get("status") or ("done" if code == 0 else "finished with warnings")
    text = (f"xshells {command}: {msg}. Geometry in the document's units; energies in N·mm, torques in N·mm, "
            "stresses in MPa (the solve works in mm).")
    if code != 0:
        warnings.insert(0, str(msg))
    return text, warnings


def _state_outputs(layers: dict) -> dict:
    beams = layers.get("deployed::beams", [])
    return {"Centerlines": layers.get("deployed::centerlines", []), "Beams": beams[0] if beams else None}


def _tmp():
    return tempfile.TemporaryDirectory(prefix="xshells-hops-")


def _on_lines(command: str, values: dict, ctx: Context, options, result_3dm: str):
    """Runs ``xshells COMMAND`` on the input lines with the shared options (material, steps, subdivision,
    angle, sampling) and ``options(tmp)``'s own; returns (exit code, result.json, the result's layers)."""
    with _tmp() as tmp:
        design = os.path.join(tmp, "design.3dm")
        _write_design(design, values["Lines"], ctx)
        argv = [command, design, *_common(values), "--steps", str(values["Steps"]), "--subdivision",
                str(values["Subdivision"]), *options(tmp), "--out", os.path.join(tmp, "out"),
                *_optional(values, "Angle", "--angle"), *_optional(values, "Sample", "--sample")]
        code, out = _run(argv, tmp)
        return code, _result(out), _layers(os.path.join(out, result_3dm), ctx)


def solve_deploy(values: dict, ctx: Context) -> dict:
    if values["Direction"] not in ("up", "down"):
        raise InputError(f"input 'Direction': up or down, got {values['Direction']!r}")
    code, r, layers = _on_lines("deploy", values, ctx, lambda tmp: ["--direction", values["Direction"]], "deployed.3dm")
    d = r.get("deployed", {})
    ev = d.get("min_eigenvalue_at_fixed_angle")
    text, warnings = _report("deploy", r, code)
    return {**_state_outputs(layers), "Energy": d.get("energy"), "Torque": d.get("torque"),
            "Stable": None if ev is None else bool(ev >= 0), "Report": text, "_warnings": warnings}


def solve_optimize(values: dict, ctx: Context) -> dict:
    def options(tmp):
        if values.get("Target") is None:
            return ["--max-iters", str(values["MaxIters"])]
        path = os.path.join(tmp, "target.3dm")
        _write_mesh(path, values["Target"], ctx, "Target")
        return ["--max-iters", str(values["MaxIters"]), "--target-surface", path]

    code, r, layers = _on_lines("optimize", values, ctx, options, "deployed.3dm")
    text, warnings = _report("optimize", r, code)
    return {"Layout": layers.get("flat::beams", []), **_state_outputs(layers), "Report": text, "_warnings": warnings}


def solve_sparsify(values: dict, ctx: Context) -> dict:
    import rhino3dm

    # Actuators > 0 chooses the count, else MaxFit the deviation (the command refuses both at once)
    count = _optional(values, "Actuators", "--actuators")
    code, r, layers = _on_lines("sparsify", values, ctx, lambda tmp: count or ["--max-fit", str(values["MaxFit"])],
                                "actuated.3dm")
    exact = dict(zip(r.get("actuated_joints", []), r.get("torques", [])))  # the dots round the torques
    points, torques = [], []
    for g in layers.get("actuators", []):
        if isinstance(g, rhino3dm.TextDot):  # "vertex: torque"
            vertex, shown = g.Text.split(":")
            points.append((g.Point.X, g.Point.Y, g.Point.Z))
            torques.append(float(exact.get(int(vertex), shown)))
    text, warnings = _report("sparsify", r, code)
    return {"Actuated": points, "Torques": torques, **_state_outputs(layers), "Report": text,
            "_warnings": warnings}


def solve_analyze(values: dict, ctx: Context) -> dict:
    loads = [a for load in values["Loads"] for a in ("--load", str(load))]
    density = _optional(values, "Density", "--density")
    code, r, layers = _on_lines("analyze", values, ctx, lambda tmp: ["--supports", str(values["Supports"]), *loads,
                                                                     *density], "loaded.3dm")
    text, warnings = _report("analyze", r, code)
    return {**_state_outputs(layers), "MaxStress": r.get("max_von_mises"), "Report": text, "_warnings": warnings}


def solve_inverse(values: dict, ctx: Context) -> dict:
    if values["Direction"] not in ("up", "down"):
        raise InputError(f"input 'Direction': up or down, got {values['Direction']!r}")
    from .read import RHINO_UNITS_TO_MM

    with _tmp() as tmp:
        surface = os.path.join(tmp, "surface.3dm")
        _write_mesh(surface, values["Surface"], ctx, "Surface")
        spacing = values.get("Spacing") or 0.0
        argv = ["inverse", surface, *_common(values), "--angle", repr(float(values["Angle"])),
                "--grading", repr(float(values["Grading"])), "--max-iters", str(values["MaxIters"]),
                "--direction", values["Direction"], "--tries", str(values["Tries"]), "--out", os.path.join(tmp, "out")]
        if spacing > 0:  # in the document's units; the command works in mm
            argv += ["--spacing", repr(spacing * RHINO_UNITS_TO_MM[ctx.units])]
        code, out = _run(argv, tmp)
        r = _result(out)
        layers = _layers(os.path.join(out, "inverse.3dm"), ctx)
    text, warnings = _report("inverse", r, code)
    return {"Layout": layers.get("flat::beams", []), **_state_outputs(layers), "FitMean": r.get("fit_mean"),
            "FitMax": r.get("fit_max"), "Coverage": r.get("coverage"), "Report": text, "_warnings": warnings}


def components() -> list[Component]:
    """The five components, by URI."""
    steps = Param("Steps", "Integer", "deployment increments", default=40)
    sub = Param("Subdivision", "Integer", "rod edges per segment", default=10)
    direction = Param("Direction", "Text", "up or down: which way the flat layout buckles", default="up")
    return [
        Component("/deploy", "Deploy", "Deploys a flat X-shell layout to its angle (as xshells deploy).",
                  (LINES, *MATERIAL, ANGLE, steps, direction, sub, SAMPLE),
                  (CENTERLINES, BEAMS, Param("Energy", "Number", "elastic energy, N·mm"),
                   Param("Torque", "Number", "actuation torque per joint, N·mm"),
                   Param("Stable", "Boolean", "the deployed state is stable at its angle"), REPORT),
                  solve_deploy),
        Component("/optimize", "Optimize", "Optimizes the rest lengths so the deployed shape fits a target and "
                  "the energies are low (paper eq. 5, as xshells optimize).",
                  (LINES, *MATERIAL, ANGLE, Param("Target", "Mesh", "the target surface (default: the deployed "
                                                  "shape's own joint quads)", optional=True),
                   Param("MaxIters", "Integer", "design-optimization iterations", default=20), steps, sub, SAMPLE),
                  (Param("Layout", "Curve", "the flat layout's segments", many=True), CENTERLINES, BEAMS, REPORT),
                  solve_optimize),
        Component("/sparsify", "Sparsify", "Chooses a few actuated joints and their torques (as xshells sparsify).",
                  (LINES, *MATERIAL, ANGLE, Param("Actuators", "Integer", "how many actuators (0: as few as keep "
                                                  "the fit within MaxFit)", default=0),
                   Param("MaxFit", "Text", "allowed deviation from the densely actuated shape (e.g. 1%)", default="1%"),
                   steps, sub, SAMPLE),
                  # not "Actuators", the input's name: one name for an input and an output confused them
                  (Param("Actuated", "Point", "the actuated joints", many=True),
                   Param("Torques", "Number", "their torques, N·mm", many=True), CENTERLINES, BEAMS, REPORT),
                  solve_sparsify),
        Component("/analyze", "Analyze", "The deployed shell on supports under loads: stresses, reactions, "
                  "stability (as xshells analyze).",
                  (LINES, *MATERIAL, ANGLE, Param("Supports", "Text", "lowest:N or joints:i,j,...", default="lowest:4"),
                   Param("Loads", "Text", "self-weight | point:VERTEX:FX,FY,FZ | area:Q (N, N/mm²)", many=True,
                         optional=True),
                   Param("Density", "Number", "density, t/mm³ (4.2e-10 is 420 kg/m³), for self-weight", default=0.0),
                   steps, sub, SAMPLE),
                  (CENTERLINES, BEAMS, Param("MaxStress", "Number", "largest von Mises stress, MPa"), REPORT),
                  solve_analyze),
        Component("/inverse", "Inverse", "A flat X-shell that deploys onto a surface (as xshells inverse).",
                  (Param("Surface", "Mesh", "the target surface"), *MATERIAL,
                   Param("Angle", "Number", "deployed average opening angle, degrees", default=90.0),
                   Param("Spacing", "Number", "joint spacing along the beams (0: 1/12 of the diagonal, or a quarter of the width where less)", default=0.0),
                   Param("Grading", "Number", "the net's grading, degrees (0: even spacing)", default=0.0),
                   Param("MaxIters", "Integer", "design-optimization iterations", default=20), direction,
                   Param("Tries", "Integer", "designs per net, the fit weight doubled each time; the best is kept "
                         "(each costs a whole design's time)", default=1)),
                  (Param("Layout", "Curve", "the flat layout's segments", many=True), CENTERLINES, BEAMS,
                   Param("FitMean", "Number", "mean joint distance to the surface / its diagonal"),
                   Param("FitMax", "Number", "largest joint distance / the diagonal"),
                   Param("Coverage", "Number", "share of the surface within 0.75 spacing of a beam"), REPORT),
                  solve_inverse),
    ]
