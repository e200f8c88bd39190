"""Case files: a JSON object with the keys of an entry of the paper's ``cases.json``.

Keys: ``file`` (design; ``flat_file`` wins when present), ``subdivision``,
``material`` (``{type, E, nu, params, stiff_axis}`` or ``{type: "contour",
contour_file, E, nu}``), one of ``angle_deg``, ``angle_rad`` or
``open_by_deg``, ``steps`` and ``rest_lengths`` (a file). Paths are relative
to the case file.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from ..errors import InputError


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


DEFAULT_MATERIAL = {"type": "rectangle", "E": 20000.0, "nu": 0.3, "params": [10.0, 7.0]}


def load_case(path) -> Case:
    try:
        with open(path) as fh:
            spec = json.load(fh)
    except OSError as exc:
        raise InputError(f"{path}: cannot read case file ({exc.strerror})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    if not isinstance(spec, dict) or "file" not in spec:
        raise InputError(f"{path}: a case is a JSON object with at least a 'file' key")
    base = os.path.dirname(os.path.abspath(path))
    rel = lambda p: p if os.path.isabs(p) else os.path.join(base, p)  # noqa: E731
    angle = None
    if spec.get("angle_deg") is not None:
        angle = np.radians(float(spec["angle_deg"]))
    elif spec.get("angle_rad") is not None:
        angle = float(spec["angle_rad"])
    material = dict(spec.get("material") or DEFAULT_MATERIAL)
    if material.get("contour_file"):
        material["contour_file"] = rel(material["contour_file"])
    return Case(
        name=str(spec.get("name", os.path.splitext(os.path.basename(path))[0])),
        design_path=rel(spec.get("flat_file") or spec["file"]),
        material=material,
        subdivision=int(spec.get("subdivision", 10)),
        angle_rad=angle,
        open_by_rad=np.radians(float(spec["open_by_deg"])) if spec.get("open_by_deg") is not None else None,
        steps=int(spec.get("steps", 40)),
        rest_lengths_path=rel(spec["rest_lengths"]) if spec.get("rest_lengths") else None,
    )


def material_spec_from_option(option: str | None, young: float | None = None, poisson: float | None = None) -> dict:
    """A case's material object from a ``--material`` option: ``TYPE:P1,P2,...`` or a cross-section JSON file."""
    E = 20000.0 if young is None else float(young)
    nu = 0.3 if poisson is None else float(poisson)
    option = option or "rectangle:10,7"
    if option.endswith(".json"):
        return {"type": "contour", "contour_file": os.path.abspath(option), "E": E, "nu": nu}
    kind, _, params = option.partition(":")
    try:
        values = [float(v) for v in params.split(",")] if params else []
    except ValueError:
        raise InputError(f"--material {option}: parameters must be numbers, as in rectangle:10,7") from None
    return {"type": kind, "params": values, "E": E, "nu": nu}


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


def material_from_spec(spec: dict):
    """A :class:`xshells.section.Material` from a case's material object."""
    from ..section import Material

    kind = spec.get("type", "rectangle")
    E, nu = float(spec.get("E", 20000.0)), float(spec.get("nu", 0.3))
    axis = spec.get("stiff_axis")
    if kind == "contour":
        return Material.from_file(spec["contour_file"], young=E, poisson=nu, stiff_axis=axis)
    return Material.uniform(kind, spec.get("params", []), E=E, nu=nu, stiff_axis=axis)


def target_angle(case: Case, linkage, angle_deg=None) -> float:
    """The case's target average angle (radians): ``angle_deg`` if given, else the case's
    angle, else the linkage's current angle opened by ``open_by`` (default 60°)."""
    if angle_deg is not None:
        return float(np.radians(angle_deg))
    if case.angle_rad is not None:
        return float(case.angle_rad)
    return linkage.average_angle() + (case.open_by_rad if case.open_by_rad is not None else np.radians(60.0))
