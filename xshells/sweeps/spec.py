"""Sweep files: a base case, axes to vary, a task; checked before anything runs.

A sweep file (YAML or JSON) holds::

    name: quads            # optional; default: the file's name
    task: deploy           # a registered task (xshells.sweeps.tasks)
    base:                  # a case: the keys of a case JSON, paths relative to this file
      file: quad.obj
      subdivision: 5
      material: {type: rectangle, E: 20000, nu: 0.3, params: [0.01, 0.005]}
      angle_deg: 80
      steps: 5
    axes:                  # Cartesian product, in this order
      file: ["*.obj"]      # files or globs
      material.params: [[0.01, 0.005], [0.012, 0.006]]
      angle_deg: [70, 80]
    cases:                 # optional: explicit overrides, each crossed with the axes
      - {}
      - {material.E: 2000}

Case keys are checked by the case files' schema (:mod:`xshells.io.case_schema`).
Axis and case keys are dotted paths into the case (``material.E``; ``E``,
``nu`` and ``params`` are short for ``material.*``) or task parameters
(``eta``, ``p`` for sparsify; ``gamma``, ``beta`` for optimize). Every error
is one line naming the key, e.g. ``axes.angle_deg: empty axis``.
"""
from __future__ import annotations

import copy
import glob
import hashlib
import itertools
import json
import math
import os
from dataclasses import dataclass

from ..errors import InputError, check_input_file
from ..io.case_schema import field_check, validate_case
from . import tasks as T

TOP_KEYS = ("name", "task", "base", "axes", "cases")
ALIASES = {"E": "material.E", "young": "material.E", "nu": "material.nu", "params": "material.params",
           "stiff_axis": "material.stiff_axis", "design": "file", "flat_file": "file"}
PATH_KEYS = ("file", "rest_lengths", "material.contour_file", "target_surface")
ANGLE_KEYS = ("angle_deg", "angle_rad", "open_by_deg")
#: The most tasks a sweep file may expand to without ``--force`` (``max_tasks=None``): a spec of more is most
#: likely a mistake (an axis of a thousand values by accident), and expanding and checking 1.58 million tasks
#: took minutes and gigabytes before the first one ran.
MAX_TASKS = 100_000

# The case keys are checked by the case files' own schema (xshells.io.case_schema), one field at a
# time here and as a whole case once expanded; direction is a case key too (every task reads it from
# the case), start only the deploy task's option.
CASE_KEYS = ("name", "file", "rest_lengths", "subdivision", "steps", "angle_deg", "angle_rad", "open_by_deg",
             "material.type", "material.E", "material.nu", "material.params", "material.stiff_axis",
             "material.contour_file")
CASE_CHECKS = {k: field_check(k) for k in CASE_KEYS}
CASE_CHECKS.update({"direction": T.choice("up", "down"), "start": T.choice("auto", "average", "central-joint")})
#: case keys that only the deploy task honours (key -> where it comes from): refused for the other tasks, whose
#: dense deployment always starts "auto" (the key was accepted and silently not used)
DEPLOY_ONLY = {"start": "xshells deploy --start"}


@dataclass(frozen=True)
class Task:
    """One sweep point.

    Attributes
    ----------
    id : str
        Folder name: a readable stem and a hash of the task and its
        parameters (file *contents*, not paths), so it survives moving the
        sweep and changes when a design file changes.
    index : int
        Position in the sweep (the order of ``results.csv``).
    params : dict
        The case and task parameters handed to the task function (absolute paths).
    varying : dict
        The dotted keys that differ between tasks -> this task's value (paths relative to the spec).
    """

    id: str
    index: int
    params: dict
    varying: dict


@dataclass(frozen=True)
class SweepSpec:
    name: str
    task: str
    base_dir: str
    tasks: tuple
    varying_keys: tuple


def load_spec(path, *, max_tasks: int | None = MAX_TASKS, design_options: dict | None = None) -> SweepSpec:
    """Read and check a sweep file (``.yaml``, ``.yml`` or ``.json``); one-line InputError on any problem.

    A sweep of more than ``max_tasks`` tasks is refused before it is expanded (None: no limit).
    ``design_options``: how to read its ``.3dm`` designs (the command line's ``--layer`` and ``--sample``),
    see :func:`spec_from_dict`.
    """
    path = os.fspath(path)
    check_input_file(path, "sweep file")
    try:
        with open(path, encoding="utf-8") as fh:
            raw = fh.read()
    except OSError as exc:
        raise InputError(f"{path}: cannot read sweep file ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file (a sweep file is YAML or JSON in UTF-8)") from None
    if path.lower().endswith((".yaml", ".yml")):
        import yaml

        try:
            data = yaml.load(raw, Loader=_yaml_loader())
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f":{mark.line + 1}" if mark is not None else ""
            raise InputError(f"{path}{where}: not valid YAML ({getattr(exc, 'problem', None) or exc})") from None
        except ValueError as exc:  # an integer of more than 4300 digits (Python's limit on converting one)
            raise InputError(f"{path}: not valid YAML ({str(exc).split(';')[0]})") from None
    else:
        from ..io.strict_json import loads

        data = loads(raw, path)
    name = os.path.splitext(os.path.basename(path))[0]
    return spec_from_dict(data, os.path.dirname(os.path.abspath(path)), default_name=name, max_tasks=max_tasks,
                          design_options=design_options)


def _yaml_loader():
    """PyYAML's safe loader with YAML 1.2 floats: ``1e-4`` is a number, not the string '1e-4'.

    (YAML 1.1, which PyYAML follows, needs a dot in the mantissa: ``1.0e-4``;
    η and E are naturally written without one.)
    """
    import re

    import yaml

    class Loader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            # PyYAML keeps the last of repeated keys without a word: a sweep with ``steps: 3`` and later
            # ``steps: 4`` ran with 4
            seen = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=deep)
                if isinstance(key, str) and key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {key!r} is given twice in one mapping: give it once", key_node.start_mark)
                seen.add(key)
            return super().construct_mapping(node, deep=deep)

    Loader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?(?:[eE][-+]?[0-9]+)
                       |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                       |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                       |[-+]?\.(?:inf|Inf|INF)
                       |\.(?:nan|NaN|NAN))$""", re.X),
        list("-+0123456789."))
    return Loader


def spec_from_dict(data, base_dir: str, *, default_name: str = "sweep", max_tasks: int | None = MAX_TASKS,
                   design_options: dict | None = None) -> SweepSpec:
    """Check a parsed sweep and expand it into tasks (paths relative to ``base_dir``); more than ``max_tasks``
    tasks (None: no limit) are refused before they are expanded.

    ``design_options`` (``{"layer": ..., "sample": ...}``, None values ignored) become parameters of each task
    whose design is a ``.3dm``: so they reach the workers (other processes, other machines) and enter the
    task's id, and a re-run with another ``--sample`` does not take the earlier result for its own.
    """
    if not isinstance(data, dict):
        raise InputError("sweep: must be a mapping with keys task, base, axes (and optionally name, cases)")
    _unknown(data, TOP_KEYS, "")
    task = T.get_task(data.get("task", "deploy"))
    allowed = dict(CASE_CHECKS) if task.case else {}
    if task.case and task.name != "deploy":
        allowed.update({k: _deploy_only(k, task.name) for k in DEPLOY_ONLY})
    allowed.update(task.params)
    base = _overrides(data.get("base") or {}, "base", allowed, base_dir)
    axes = data.get("axes") or {}
    if not isinstance(axes, dict):
        raise InputError("axes: must be a mapping key -> list of values")
    axis_values = []
    for raw_key, values in axes.items():
        key = _key(raw_key, allowed, f"axes.{raw_key}")
        where = f"axes.{raw_key}"
        if isinstance(values, (str, int, float)) and key != "file":
            raise InputError(f"{where}: must be a list of values, got {values!r}")
        values = [values] if isinstance(values, str) else values
        if not isinstance(values, list):
            raise InputError(f"{where}: must be a list of values, got {values!r}")
        if key == "file":
            values = _expand_globs(values, base_dir, where)
        checked = [_check(key, v, f"{where}[{i}]", allowed, base_dir) for i, v in enumerate(values)]
        if not checked:
            raise InputError(f"{where}: empty axis")
        axis_values.append((key, checked))
    cases = data.get("cases")
    if cases is None:
        cases = [{}]
    if not isinstance(cases, list) or not cases:
        raise InputError("cases: must be a non-empty list of mappings")
    cases = [_overrides(c, f"cases[{i}]", allowed, base_dir) for i, c in enumerate(cases)]
    spelled = {}
    for raw, (key, _) in zip(axes, axis_values):
        if key in spelled:
            raise InputError(f"axes: {spelled[key]} and {raw} name the same key ({key}): give it once")
        spelled[key] = raw
    _check_angle_keys(base, cases, [k for k, _ in axis_values])
    _check_size(cases, axes, axis_values, max_tasks)

    points = []
    for case in cases:
        for combo in itertools.product(*[v for _, v in axis_values]):
            flat = dict(base)
            for key, value in list(case.items()) + [(k, v) for (k, _), v in zip(axis_values, combo)]:
                if key in ANGLE_KEYS:  # replaces the base's angle of any kind (two kinds in a case and the axes are refused above)
                    for other in ANGLE_KEYS:
                        flat.pop(other, None)
                flat[key] = value
            points.append(flat)
    if task.case:
        for p in points:
            if "file" not in p:
                raise InputError("base.file: missing (give a design file in base, an axis or every case)")
    _add_design_options(points, design_options)
    if task.case:
        for i, p in enumerate(points):  # the whole case, as a case file: the rules across keys too
            validate_case(_nest({k: v for k, v in p.items() if k in CASE_KEYS}), f"sweep task {i}")
            _default_material(p)
        _check_profiles(points)
    if task.check is not None:  # the task's own rules across its keys, before anything runs
        for i, p in enumerate(points):
            task.check(p, f"sweep task {i}")
    order = _ordered_keys([{k: None for k, _ in axis_values}] + points)  # axes first, in the spec's order
    varying = tuple(k for k in order if len({_canon(p.get(k)) for p in points}) > 1)
    tasks = []
    seen = {}
    for i, flat in enumerate(points):
        tid = _task_id(task.name, flat)
        if tid in seen:
            raise InputError(f"axes: tasks {seen[tid]} and {i} have identical parameters (a value repeated in an axis or case?)")
        seen[tid] = i
        params = _nest(flat)
        shown = {k: (os.path.relpath(flat[k], base_dir) if k in PATH_KEYS and flat.get(k) else flat.get(k)) for k in varying}
        tasks.append(Task(tid, i, params, shown))
    name = data.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise InputError(f"name: must be a non-empty string, got {name!r}")
    return SweepSpec(name, task.name, base_dir, tuple(tasks), varying)


# ---------------------------------------------------------------- helpers


#: the command line's options of a .3dm design, which become task parameters (xshells.cli: --layer, --sample)
DESIGN_OPTIONS = ("layer", "sample")


def _add_design_options(points: list, options: dict | None) -> None:
    """Give each task whose design is a ``.3dm`` the ``options`` given; refuse them where no design is one."""
    given = {k: v for k, v in (options or {}).items() if v is not None}
    if not given:
        return
    unknown = set(given) - set(DESIGN_OPTIONS)
    if unknown:
        raise ValueError(f"design options are {', '.join(DESIGN_OPTIONS)}, got {', '.join(sorted(unknown))}")
    sample = given.get("sample")
    if sample is not None:
        from ..rhino.read import MAX_SAMPLE

        if isinstance(sample, bool) or not isinstance(sample, int) or not 1 <= sample <= MAX_SAMPLE:
            raise InputError(f"--sample must be from 1 to {MAX_SAMPLE} segments per curve, got {sample}")
    hits = [p for p in points if str(p.get("file") or "").lower().endswith(".3dm")]
    if not hits:  # they would be ignored, as xshells deploy refuses them with an .obj
        names = [f"--{k}" for k in DESIGN_OPTIONS if k in given]
        raise InputError(f"{' and '.join(names)} read{'s' * (len(names) == 1)} a .3dm design: no task's file is one")
    for p in hits:
        p.update(given)


def _check_angle_keys(base: dict, cases: list, axis_keys: list) -> None:
    """One kind of angle (angle_deg, angle_rad or open_by_deg) in the base, and in each case with the axes.

    A case's or an axis's angle replaces the base's, whatever its kind; but of two kinds given together the
    later silently replaced the other (``axes: {angle_deg: [60], angle_rad: [1]}`` ran 1 rad only), or made
    the cases' tasks identical (a cases angle under an ``open_by_deg`` axis).
    """
    axes = [f"axes.{k}" for k in axis_keys if k in ANGLE_KEYS]
    groups = [[f"base.{k}" for k in base if k in ANGLE_KEYS]]
    groups += [[f"cases[{i}].{k}" for k in case if k in ANGLE_KEYS] + axes for i, case in enumerate(cases)]
    for names in groups:
        if len({n.rsplit(".", 1)[1] for n in names}) > 1:
            raise InputError(f"{' and '.join(names)}: give one of {', '.join(ANGLE_KEYS)} (they set the same angle)")


def _check_size(cases: list, axes: dict, axis_values: list, max_tasks: int | None) -> None:
    """Refuse a sweep of more than ``max_tasks`` tasks, naming the factors of the product."""
    count = len(cases) * math.prod(len(values) for _, values in axis_values)
    if max_tasks is None or count <= max_tasks:
        return
    factors = ([f"{len(cases)} cases"] if len(cases) > 1 else []) + [
        f"{raw} {len(values)}" for raw, (_, values) in zip(axes, axis_values)]
    raise InputError(f"axes: {' × '.join(factors)} make {count:,} tasks, more than the limit of {max_tasks:,}: "
                     "give fewer values, or --force to run them all")


def _deploy_only(key: str, task: str):
    """The check of a deploy-only key for another task: refuses any value, saying why."""
    def refuse(value):
        raise ValueError(f"only the deploy task takes {key} ({DEPLOY_ONLY[key]}); the {task} task does not use it")

    return refuse


def _unknown_key(where: str, raw, known) -> InputError:
    """'unknown key', with the nearest known name when there is one (as for case files)."""
    import difflib

    names = [k.split(".")[-1] for k in known] + list(known)
    close = difflib.get_close_matches(str(raw).split(".")[-1], names, n=1, cutoff=0.6)
    hint = f"did you mean '{close[0]}'?" if close else f"known: {', '.join(sorted(known))}"
    return InputError(f"{where}: unknown key ({hint})")


def _unknown(d: dict, known, prefix: str) -> None:
    for k in d:
        if k not in known:
            raise _unknown_key(f"{prefix}{k}", k, known)


def _key(raw, allowed: dict, where: str) -> str:
    key = ALIASES.get(raw, raw) if isinstance(raw, str) else raw
    if key not in allowed:
        raise _unknown_key(where, raw, allowed)
    return key


def _overrides(d, where: str, allowed: dict, base_dir: str) -> dict:
    """A mapping of case keys -> checked values, ``material: {...}`` flattened into ``material.*``."""
    if not isinstance(d, dict):
        raise InputError(f"{where}: must be a mapping, got {d!r}")
    out, spelled = {}, {}

    def put(key, name, value):
        # two spellings of one key (E and material.E, E and young) kept the later without a word
        if key in out:
            raise InputError(f"{where}: {spelled[key]} and {name} name the same key ({key}): give it once")
        out[key], spelled[key] = _check(key, value, f"{where}.{name}", allowed, base_dir), name

    for raw, value in d.items():
        if raw == "material" and "material.type" in allowed:
            if not isinstance(value, dict):
                raise InputError(f"{where}.material: must be a mapping {{type, E, nu, params, stiff_axis}}")
            for sub, v in value.items():
                key = _key("material." + str(sub) if sub != "young" else "material.E", allowed, f"{where}.material.{sub}")
                put(key, f"material.{sub}", v)
            continue
        put(_key(raw, allowed, f"{where}.{raw}"), raw, value)
    return out


def _check(key: str, value, where: str, allowed: dict, base_dir: str):
    try:
        value = allowed[key](value)
    except ValueError as exc:
        raise InputError(f"{where}: {exc}") from None
    if key in PATH_KEYS and value is not None:
        path = value if os.path.isabs(value) else os.path.normpath(os.path.join(base_dir, value))
        try:  # a named pipe would block the id's hash (and the task), a folder fail it
            check_input_file(path)
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None
        if not os.path.isfile(path):
            raise InputError(f"{where}: no such file {value!r}")
        if key == "file":  # a glob's stray .txt was found only when its task ran
            from ..io.design import DESIGN_SUFFIXES

            suffix = os.path.splitext(path)[1].lower()
            if suffix not in DESIGN_SUFFIXES:
                raise InputError(f"{where}: {os.path.relpath(path, base_dir)!r} is not a design file (unknown type "
                                 f"{suffix!r}: expected {', '.join(DESIGN_SUFFIXES[:-1])} or {DESIGN_SUFFIXES[-1]})")
        value = path
    return value


def _default_material(p: dict) -> None:
    """The case file's default for each material key a task leaves out (``xshells.deploy.case``), in place.

    Key by key, as a case file's ``{"material": {"E": 20000}}`` is a 10 × 7 rectangle of ν 0.3: filling
    only a base without any material key refused ``E: 2e4`` alone ("rectangle takes 2 parameters, got 0")
    and gave an ``ellipse`` axis the rectangle's 10 × 7. Called after the case check, which refuses a
    type other than the rectangle without its params; a contour keeps its section file's E and ν.
    """
    from ..deploy.case import DEFAULT_MATERIAL
    from ..section.profiles import canonical_type

    kind = p.setdefault("material.type", DEFAULT_MATERIAL["type"])
    if str(kind).strip().lower() == "contour":
        return
    for key in ("E", "nu"):
        p.setdefault(f"material.{key}", DEFAULT_MATERIAL[key])
    if not p.get("material.params") and canonical_type(kind) == "rectangle":
        p["material.params"] = list(DEFAULT_MATERIAL["params"])


def _check_profiles(points) -> None:
    """Build each distinct parametric cross-section once (microseconds): a bad type or parameter count fails now."""
    from ..section.profiles import make_profile

    seen = set()
    for p in points:
        kind, params = p.get("material.type", "rectangle"), p.get("material.params", [])
        if p.get("material.contour_file") or _canon([kind, params]) in seen:
            continue
        seen.add(_canon([kind, params]))
        try:
            make_profile(kind, params)
        except InputError as exc:
            raise InputError(f"material: {str(exc).split(': ', 1)[-1]}") from None


def _expand_globs(values, base_dir: str, where: str) -> list:
    out = []
    for i, v in enumerate(values):
        if isinstance(v, str) and any(c in v for c in "*?["):
            pattern = v if os.path.isabs(v) else os.path.join(base_dir, v)
            hits = sorted(glob.glob(pattern))  # sorted: the same spec gives the same task order everywhere
            if not hits:
                raise InputError(f"{where}[{i}]: no file matches {v!r}")
            out.extend(hits)
        else:
            out.append(v)
    return out


def _ordered_keys(points) -> list:
    keys = []
    for p in points:
        keys.extend(k for k in p if k not in keys)
    return keys


def _canon(v) -> str:
    return json.dumps(v, sort_keys=True)


_DIGESTS: dict = {}


def _file_digest(path: str) -> str:
    st = os.stat(path)
    key = (path, st.st_mtime_ns, st.st_size)
    if key not in _DIGESTS:
        with open(path, "rb") as fh:
            _DIGESTS[key] = hashlib.sha256(fh.read()).hexdigest()
    return _DIGESTS[key]


def _task_id(task: str, flat: dict) -> str:
    ident = {k: ({"name": os.path.basename(v), "sha256": _file_digest(v)} if k in PATH_KEYS and v else v)
             for k, v in flat.items()}
    h = hashlib.sha256(_canon({"task": task, "params": ident}).encode()).hexdigest()[:12]
    stem = os.path.splitext(os.path.basename(flat["file"]))[0] if flat.get("file") else task
    stem = "".join(c if c.isalnum() or c in "-_." else "_" for c in stem)[:40]
    return f"{stem}-{h}"


def _nest(flat: dict) -> dict:
    """``{"material.E": 1}`` -> ``{"material": {"E": 1}}``."""
    out: dict = {}
    for k, v in flat.items():
        head, _, tail = k.partition(".")
        if tail:
            out.setdefault(head, {})[tail] = copy.deepcopy(v)
        else:
            out[k] = copy.deepcopy(v)
    return out
