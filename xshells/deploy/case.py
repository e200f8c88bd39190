"""Case files: a JSON object with the keys of an entry of the paper's ``cases.json``.

Keys: ``file`` (design; ``flat_file`` wins when present), ``subdivision``,
``material`` (``{type, E, nu, params, stiff_axis}`` or ``{type: "contour",
contour_file, E, nu}``), one of ``angle_deg``, ``angle_rad`` or
``open_by_deg``, ``steps``, ``rest_lengths`` (a file), ``direction`` and
``guide`` (a file of joint positions: :mod:`xshells.deploy.guide`). Paths are relative
to the case file. The schema (types, ranges, units) is
:mod:`xshells.io.case_schema`, published as ``docs/case.schema.json``.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, check_input_file


@dataclass(frozen=True)
class Case:
    name: str
    design_path: str
    material: dict
    subdivision: int = 10
    angle_rad: float | None = None
    open_by_rad: float | None = None
    steps: int = 40
    rest_lengths_path: str | None = None
    direction: str = "up"
    guide_path: str | None = None


DEFAULT_MATERIAL = {"type": "rectangle", "E": 20000.0, "nu": 0.3, "params": [10.0, 7.0]}


def load_case(path) -> Case:
    from ..io.strict_json import loads

    check_input_file(path, "case file")
    try:
        with open(path, encoding="utf-8-sig") as fh:  # JSON is UTF-8; -sig drops a byte-order mark (Windows editors)
            spec = loads(fh.read(), str(path))
    except OSError as exc:
        raise InputError(f"{path}: cannot read case file ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text file (byte {exc.start} is not UTF-8): a case file is JSON") from None
    from ..io.case_schema import validate_case

    case = validate_case(spec, path)
    base = os.path.dirname(os.path.abspath(path))
    rel = lambda p: p if os.path.isabs(p) else os.path.join(base, p)  # noqa: E731
    key = "flat_file" if case.flat_file else "file"
    if os.path.isdir(rel(case.flat_file or case.file)):  # "file": "." is the case's own folder
        raise InputError(f"{path}: key '{key}' = {json.dumps(case.flat_file or case.file)}: a folder, not a design file "
                         "(.obj, .msh or .3dm)")
    angle = None
    if case.angle_deg is not None:
        angle = float(np.radians(case.angle_deg))
    elif case.angle_rad is not None:
        angle = float(case.angle_rad)
    material = case.material.model_dump(exclude_none=True) if case.material is not None else dict(DEFAULT_MATERIAL)
    if material.get("contour_file"):
        material["contour_file"] = rel(material["contour_file"])
    return Case(
        name=case.name or os.path.splitext(os.path.basename(path))[0],
        design_path=rel(case.flat_file or case.file),
        material=material,
        subdivision=case.subdivision,
        angle_rad=angle,
        open_by_rad=float(np.radians(case.open_by_deg)) if case.open_by_deg is not None else None,
        steps=case.steps,
        rest_lengths_path=rel(case.rest_lengths) if case.rest_lengths else None,
        direction=case.direction or "up",
        guide_path=rel(case.guide) if case.guide else None,
    )


def case_guide(case: Case, num_joints: int | None):
    """The case's guide (nj, 3) (:mod:`.guide`), or None where it names none (``num_joints`` None: its rows are
    not counted here; :func:`.simulate.deploy` counts them)."""
    if case.guide_path is None:
        return None
    from .guide import read_guide

    return read_guide(case.guide_path, num_joints)


def material_spec_from_option(option: str | None, young: float | None = None, poisson: float | None = None,
                              grade: str | None = None, density: float | None = None, strength: float | None = None) -> dict:
    """A case's material object from a ``--material`` option: ``TYPE:P1,P2,...`` or a cross-section JSON file,
    with ``--grade``, ``--density``, ``--strength`` where given."""
    # named as the user gave them (the material's own checks name only the section type)
    if young is not None and not (np.isfinite(young) and young > 0):
        raise InputError(f"--young must be a positive Young's modulus (MPa for a design in mm), got {young:g}")
    if poisson is not None and not (np.isfinite(poisson) and -1.0 < poisson < 0.5):
        raise InputError(f"--poisson must lie in (-1, 0.5), got {poisson:g}")
    extra = {k: v for k, v in (("grade", grade), ("density", density), ("strength", strength)) if v is not None}
    if extra:
        from ..analysis.materials import named_material
        from ..analysis.stress import check_strength

        check_strength(strength, "--strength")
        check_density(density)
        if grade is not None:
            named_material(grade)
        spec = material_spec_from_option(option, young, poisson)
        if grade is not None:  # the grade's E and ν unless given on the line
            spec = {k: v for k, v in spec.items() if not (k in ("E", "nu") and {"E": young, "nu": poisson}[k] is None)}
        spec.update(extra)
        return spec
    option = option or "rectangle:10,7"
    if option.lower().endswith(".json"):  # the section file has its own E and ν: override only what is given
        spec = {"type": "contour", "contour_file": os.path.abspath(option)}
        spec.update({k: float(v) for k, v in (("E", young), ("nu", poisson)) if v is not None})
        return spec
    E = 20000.0 if young is None else float(young)
    nu = 0.3 if poisson is None else float(poisson)
    kind, _, params = option.partition(":")
    try:
        values = [float(v) for v in params.split(",")] if params else []
    except ValueError:
        raise InputError(f"--material {option}: parameters must be numbers, as in rectangle:10,7") from None
    from ..section.profiles import PARAM_NAMES, _check_params, canonical_type

    # checked here, naming the option: the section's own checks said "profile: unknown cross-section type"
    # and "must be positive, got inf", naming neither the option nor what a valid value is
    where = f"--material {option}"
    canonical = canonical_type(kind, where)
    names = PARAM_NAMES[canonical].split(", ")
    if len(values) != len(names):
        raise InputError(f"{where}: {kind} takes {len(names)} parameters ({PARAM_NAMES[canonical]}), got {len(values)}")
    for label, value in zip(names, values):
        if not (np.isfinite(value) and value > 0):
            raise InputError(f"{where}: {kind} dimension {label} must be a positive finite number, got {value:g}")
    _check_params(canonical, values, len(names), where)  # the section's range and aspect checks, naming the option
    return {"type": kind, "params": values, "E": E, "nu": nu}


def check_density(density) -> None:
    """``--density``, if given, is a positive finite mass per volume (the rods' masses must be positive)."""
    if density is not None and not (np.isfinite(density) and density > 0):
        raise InputError(f"--density must be a positive mass per volume (t/mm³ for a design in mm), got {density:g}")


def with_material_options(spec: dict, grade=None, density=None, strength=None) -> dict:
    """A case's material object with ``--grade``/``--density``/``--strength`` laid over it (checked first;
    a grade replaces the case's E, ν, density and strength unless those are given too)."""
    given = {k: v for k, v in (("grade", grade), ("density", density), ("strength", strength)) if v is not None}
    if not given:
        return dict(spec)
    material_spec_from_option(None, grade=grade, density=density, strength=strength)  # the same checks
    out = {k: v for k, v in spec.items() if grade is None or k not in ("E", "nu", "density", "strength")}
    out.update(given)
    return out


def case_for_design(design_path: str, material: dict, *, subdivision: int = 10, steps: int = 40,
                    angle_deg: float | None = None, rest_lengths_path: str | None = None) -> dict:
    """A case object (as in a case file) for a bare design file, with absolute paths."""
    case = {"name": os.path.splitext(os.path.basename(design_path))[0], "file": os.path.abspath(design_path),
            "material": material, "subdivision": int(subdivision), "steps": int(steps)}
    if angle_deg is not None:
        case["angle_deg"] = float(angle_deg)
    if rest_lengths_path:
        case["rest_lengths"] = os.path.abspath(rest_lengths_path)
    return case


def resolve_grade(spec: dict) -> dict:
    """The material object with a named ``grade``'s E, ν, density and strength filled in where not given."""
    if not spec.get("grade"):
        return spec
    from ..analysis.materials import named_material

    m = named_material(spec["grade"])
    out = {"E": m.E, "nu": m.nu, "density": m.density, "strength": m.strength}
    out.update({k: v for k, v in spec.items() if v is not None})
    return out


def material_strength(spec: dict) -> float | None:
    """The allowable stress of a case's material object (its own, or its grade's), or None."""
    s = resolve_grade(spec).get("strength")
    return None if s is None else float(s)


def material_from_spec(spec: dict):
    """A :class:`xshells.section.Material` from a case's material object."""
    from ..section import Material

    spec = resolve_grade(spec)
    density = float(spec.get("density", 1.0)) if spec.get("density") is not None else 1.0
    kind = str(spec.get("type", "rectangle")).strip()
    if kind.lower() == "contour":  # case-insensitive, as the other types
        kind = "contour"
    axis = spec.get("stiff_axis")
    if kind == "contour" and str(spec["contour_file"]).lower().endswith(".json"):  # E and ν from the file unless given
        return Material.from_file(spec["contour_file"], young=spec.get("E"), poisson=spec.get("nu"), stiff_axis=axis,
                                  density=density)
    E, nu = float(spec.get("E", 20000.0)), float(spec.get("nu", 0.3))
    if kind == "contour":
        return Material.from_file(spec["contour_file"], young=E, poisson=nu, stiff_axis=axis, density=density)
    from ..section.profiles import canonical_type

    # a rectangle given without dimensions is the default one (docs/case.md: rectangle 10 × 7)
    params = spec.get("params") or ([10.0, 7.0] if canonical_type(kind) == "rectangle" else [])
    return Material.uniform(kind, params, E=E, nu=nu, stiff_axis=axis, density=density)


def target_angle(case: Case, linkage, angle_deg=None) -> float:
    """The case's target average angle (radians): ``angle_deg`` if given, else the case's
    angle, else the linkage's current angle opened by ``open_by`` (default 60°)."""
    if angle_deg is not None:
        return float(np.radians(angle_deg))
    if case.angle_rad is not None:
        return float(case.angle_rad)
    return opened_angle(linkage, case.open_by_rad, case.name)


def opened_angle(linkage, open_by: float | None, name: str | None) -> float:
    """The linkage's current average angle opened by ``open_by`` radians (default 60°); one line naming
    both numbers where the sum leaves (0°, 180°) (the deployment alone would name only the sum)."""
    drawn = linkage.average_angle()
    by = open_by if open_by is not None else np.radians(60.0)
    if not 0.0 < drawn + by < np.pi:
        key = f"open_by_deg {np.degrees(by):.4g}" if open_by is not None else "the default opening of 60°"
        raise InputError(f"{name or 'the design'}: {key}: the drawn average angle {np.degrees(drawn):.4g}° opened by "
                         f"{np.degrees(by):.4g}° is {np.degrees(drawn + by):.4g}°, outside (0°, 180°); "
                         f"give a smaller open_by_deg or an angle_deg")
    return drawn + by


MATERIAL_OPTIONS = ("material", "young", "poisson")
DESIGN_OPTIONS = (*MATERIAL_OPTIONS, "subdivision", "steps")


def add_design_options(parser, steps_default: int) -> None:
    """The options that make a case of a bare design file (``xshells optimize`` and ``xshells sparsify``)."""
    parser.add_argument("--material", help="for a design file: TYPE:P1,P2,... (e.g. rectangle:10,7, the default) or a cross-section JSON file")
    parser.add_argument("--young", type=float, help="for a design file: Young's modulus (default 20000, MPa)")
    parser.add_argument("--poisson", type=float, help="for a design file: Poisson's ratio (default 0.3)")
    parser.add_argument("--subdivision", type=int, help="for a design file: edges per segment (default 10)")
    parser.add_argument("--steps", type=int, help=f"for a design file: deployment increments (default {steps_default})")


def check_counts(subdivision, steps) -> None:
    """``--subdivision`` and ``--steps`` as given on the command line (None: not given); one line when out of range."""
    # the same bounds as the case schema's (xshells/io/case_schema.py): beyond them a run only runs out of time
    if subdivision is not None and not 3 <= subdivision <= 1000:
        raise InputError(f"--subdivision must be from 3 to 1000 edges per segment, got {subdivision}")
    if steps is not None and not 1 <= steps <= 100000:
        raise InputError(f"--steps must be from 1 to 100000, got {steps}")


def refuse_case_options(args, options=DESIGN_OPTIONS) -> None:
    """One line when any of ``options`` (argparse names) is given with a case file: it would contradict the case."""
    given = [f"--{k}" for k in options if getattr(args, k) is not None]
    if given:
        raise InputError(f"{', '.join(given)} contradict{'s' if len(given) == 1 else ''} the case file; edit the case file instead")


def case_path_from_args(args, command: str, steps_default: int) -> str:
    """``args.case`` if it is a case file, else the case of the design it names, written to ``args.out/case.json``.

    A case file with any of :data:`DESIGN_OPTIONS` is refused (they would contradict it).
    """
    path = args.case
    if path.lower().endswith(".json"):
        refuse_case_options(args)
        return path
    if not path.lower().endswith((".obj", ".msh", ".3dm")):
        raise InputError(f"{path}: {command} takes a case file (.json) or a design (.obj, .msh, .3dm)")
    if not os.path.exists(path):
        raise InputError(f"{path}: no such file")
    from ..io.export import atomic_write_text

    check_counts(args.subdivision, args.steps)
    # the case records the run's angle too: re-run from OUT/case.json, it deploys where this run did
    case = case_for_design(path, material_spec_from_option(args.material, args.young, args.poisson),
                           subdivision=10 if args.subdivision is None else args.subdivision,
                           steps=steps_default if args.steps is None else args.steps, angle_deg=getattr(args, "angle", None))
    os.makedirs(args.out, exist_ok=True)
    out = os.path.join(args.out, "case.json")
    atomic_write_text(out, json.dumps(case, indent=1))
    return out
