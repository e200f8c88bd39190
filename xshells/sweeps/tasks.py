"""The task registry: what one sweep point runs.

A task is a function ``fn(params: dict, out_dir: str) -> dict`` of scalar
results. ``params`` is a case (the keys of a case JSON, paths absolute) plus
the task's own keys; the function writes whatever files it likes into
``out_dir``. A result with ``"converged": False`` is recorded as
*diverged*; an exception as *failed*, with its message.

Tasks whose code lives in other modules (``optimize``: ``xshells.design``,
``sparsify``: ``xshells.actuation``) import it only when used, and name it in
``requires`` (or register as "module:function"), so a missing module makes
:func:`get_task` report "task 'optimize' is not available yet" before a sweep
starts. To add a task::

    from xshells.sweeps.tasks import register_task, number
    register_task("mytask", "mypackage.mymodule:run_point", params={"alpha": number(minimum=0)})
"""
from __future__ import annotations

import importlib
import math
import os
import time
from dataclasses import dataclass, field
from typing import Callable

from ..errors import InputError

# ---------------------------------------------------------------- value checks
# A check takes a value from the spec and returns it normalised (so that 80
# and 80.0 hash to the same task), or raises ValueError with a short reason.
# The checks are pydantic type adapters, as the case files' schema; each also
# carries its JSON Schema (``check.json_schema``) for docs/sweep.schema.json.


def _adapter_check(annotation, normalise=None) -> Callable:
    from pydantic import TypeAdapter, ValidationError

    adapter = TypeAdapter(annotation)

    def check(v):
        if normalise is not None:
            v = normalise(v)
        try:
            return adapter.validate_python(v, strict=True)
        except ValidationError as exc:
            raise ValueError(f"{exc.errors()[0]['msg'].removeprefix('Value error, ')}, got {v!r}") from None

    check.json_schema = adapter.json_schema()
    return check


def _whole(v):
    # 8.0 (YAML, JSON) is the whole number 8; 8.5 stays a float and is refused
    return int(v) if isinstance(v, float) and math.isfinite(v) and v == int(v) else v


def number(minimum=None, maximum=None, *, open_min=False, integer=False) -> Callable:
    """A check for a finite number (``integer``: a whole number) within bounds."""
    from typing import Annotated

    from pydantic import Field

    bounds = {}
    if minimum is not None:
        bounds["gt" if open_min else "ge"] = minimum
    if maximum is not None:
        bounds["le"] = maximum
    kind = int if integer else float
    return _adapter_check(Annotated[kind, Field(allow_inf_nan=False, **bounds)], _whole if integer else None)


def choice(*options) -> Callable:
    from typing import Literal

    return _adapter_check(Literal[options])


def _text_check():
    from typing import Annotated

    from pydantic import Field

    return _adapter_check(Annotated[str, Field(min_length=1)])


text = _text_check()


def optional(check: Callable) -> Callable:
    def opt(v):
        return None if v is None else check(v)

    opt.json_schema = {"anyOf": [check.json_schema, {"type": "null"}]}
    return opt


def _number_list_check():
    from typing import Annotated

    from pydantic import Field

    return _adapter_check(Annotated[list[Annotated[float, Field(gt=0, allow_inf_nan=False)]], Field(min_length=1)])


number_list = _number_list_check()


def _flag_check():
    from typing import Union

    return _adapter_check(Union[bool, str])


flag = _flag_check()


# ---------------------------------------------------------------- registry


@dataclass(frozen=True)
class TaskDef:
    """One registered task.

    Attributes
    ----------
    name : str
    fn : callable or str
        The function, or ``"module:function"`` imported on first use.
    params : dict
        The task's own parameter keys -> value check.
    case : bool
        Whether the task takes a case (a design ``file``, material, ...).
    requires : tuple of str
        Further ``"module:attribute"`` that must import for the task to run.
    preload : tuple of str
        Modules that local workers import once, in the server they are forked
        from (imports only: nothing that starts threads, such as running JAX).
    check : callable or None
        ``check(params, where)``: the rules across the task's keys (flat keys, as the spec has them),
        checked for every task before any runs; one-line InputError.
    """

    name: str
    fn: Callable | str
    params: dict = field(default_factory=dict)
    case: bool = True
    requires: tuple = ()
    preload: tuple = ()
    check: Callable | None = None

    def resolve(self) -> Callable:
        """The task function; raises InputError when its module does not exist yet."""
        for ref in self.requires:
            _import(ref, self.name)
        return self.fn if callable(self.fn) else _import(self.fn, self.name)

    def __call__(self, params: dict, out_dir: str) -> dict:
        return self.resolve()(params, out_dir)


def _import(ref: str, task: str):
    module, _, attr = ref.partition(":")
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        # only a missing provider means "not yet"; a broken import elsewhere is a real bug
        if exc.name and (module == exc.name or module.startswith(exc.name + ".")):
            raise InputError(f"task '{task}' is not available yet") from None
        raise
    if not hasattr(mod, attr):
        raise InputError(f"task '{task}' is not available yet")
    return getattr(mod, attr)


REGISTRY: dict[str, TaskDef] = {}


def register_task(name: str, fn: Callable | str, *, params: dict | None = None, case: bool = True,
                  requires: tuple = (), preload: tuple = (), check: Callable | None = None) -> TaskDef:
    """Add (or replace) a task; returns its :class:`TaskDef`."""
    REGISTRY[name] = TaskDef(name, fn, dict(params or {}), case, tuple(requires), tuple(preload), check)
    return REGISTRY[name]


def get_task(name) -> TaskDef:
    """The registered task ``name``, checked importable (one-line InputError otherwise)."""
    if not isinstance(name, str) or name not in REGISTRY:
        raise InputError(f"task: unknown task {name!r} (known: {', '.join(sorted(REGISTRY))})")
    task = REGISTRY[name]
    task.resolve()
    return task


# ---------------------------------------------------------------- tasks


def _angle(params):
    """(target_angle, open_by) in radians from whichever angle key the case has."""
    import numpy as np

    if params.get("angle_deg") is not None:
        return float(np.radians(params["angle_deg"])), None
    if params.get("angle_rad") is not None:
        return float(params["angle_rad"]), None
    if params.get("open_by_deg") is not None:
        return None, float(np.radians(params["open_by_deg"]))
    return None, None


def deploy_task(params: dict, out_dir: str) -> dict:
    """Rest-length solve and deployment of one case (``xshells deploy``, quietly)."""
    from ..deploy.case import material_from_spec
    from ..deploy.run import run_deployment

    target, open_by = _angle(params)
    r = run_deployment(params["file"], material_from_spec(params.get("material") or {}), out_dir=out_dir,
                       subdivision=params.get("subdivision", 10), target_angle=target, open_by=open_by,
                       steps=params.get("steps", 40), rest_lengths_path=params.get("rest_lengths"),
                       direction=params.get("direction", "up"), start=params.get("start", "auto"), progress=False,
                       name=params.get("name") or os.path.splitext(os.path.basename(params["file"]))[0])
    d, f = r["deployed"], r["flat"]
    return {
        "converged": r["reached"],
        "message": r["message"],
        "energy": d["energy"],
        "energy_stretch": d["energy_stretch"],
        "energy_bend": d["energy_bend"],
        "energy_twist": d["energy_twist"],
        "average_angle_deg": d["average_angle_deg"],
        "target_angle_deg": r["target_angle_deg"],
        "max_abs_z": d["max_abs_z"],
        "torque": d.get("torque", float("nan")),
        "min_hessian_eigenvalue": d.get("min_hessian_eigenvalue", float("nan")),
        "flat_energy": f["energy"],
        "flat_angle_deg": f["average_angle_deg"],
        "segments": r["segments"],
        "joints": r["joints"],
        "dof": r["dof"],
        "newton_iterations": r["newton_iterations"],
        "time_rest_length_solve_s": r["timings_s"]["rest_length_solve"],
        "time_deploy_s": r["timings_s"]["deploy"],
    }


#: the sweep's case keys that a case file carries to ``xshells sparsify`` and ``optimize`` (a key left out here
#: was accepted by the spec and silently not used: a sparsify sweep over ``direction`` ran every task "up")
CASE_FILE_KEYS = ("name", "file", "subdivision", "material", "angle_deg", "angle_rad", "open_by_deg", "steps",
                  "rest_lengths", "direction")


def _write_case(params: dict, path: str) -> str:
    """A case JSON for the jobs that take one (paths are absolute, so it can live anywhere)."""
    import json

    from ..io.export import atomic_write_text

    atomic_write_text(path, json.dumps({k: params[k] for k in CASE_FILE_KEYS if params.get(k) is not None}, indent=1))
    return path


SPARSIFY_KEYS = ("eta", "p", "tau_max", "max_iterations")
SELECTION_KEYS = ("max_fit", "actuators", "tau_max")


def _check_sparsify(params: dict, where: str) -> None:
    """eq. 8's keys and the elimination's exclude each other (before any task runs, and in the task itself)."""
    if any(params.get(k) is not None for k in ("eta", "p", "max_iterations")) and \
            any(params.get(k) is not None for k in ("max_fit", "actuators")):
        raise InputError(f"{where}: give eta/p/max_iterations (eq. 8) or max_fit/actuators (elimination), not both")


def sparsify_task(params: dict, out_dir: str) -> dict:
    """Dense deployment, then sparse actuation (``xshells sparsify``, quietly).

    With ``eta`` or ``p`` (or ``max_iterations``) among the parameters it solves eq. 8 for that (η, p);
    otherwise it runs the default elimination (``max_fit``, default 1 %, or ``actuators``).
    """
    from ..actuation.run import run_selection, run_sparsify
    from ..actuation.selection import SelectionOptions
    from ..actuation.sparsify import SparsifyOptions

    os.makedirs(out_dir, exist_ok=True)
    case = _write_case(params, os.path.join(out_dir, "case.json"))
    keys = ("converged", "message", "num_actuators", "fit_mean", "fit_max", "work", "dense_work", "dense_torque",
            "time_s", "dense_deployment_time_s")
    if any(params.get(k) is not None for k in ("eta", "p", "max_iterations")):
        _check_sparsify(params, "sparsify")
        opts = SparsifyOptions(**{k: params[k] for k in SPARSIFY_KEYS if params.get(k) is not None})
        r = run_sparsify(case, out_dir, opts, progress=False)
        # η and p as used (defaults included), so that the trade-off plot has them without the spec naming them
        return {"eta": opts.eta, "p": opts.p, "objective": r["objective"], "iterations": r["iterations"],
                **{k: r[k] for k in keys}}
    sel = SelectionOptions(**{k: params[k] for k in SELECTION_KEYS if params.get(k) is not None})
    r = run_selection(case, out_dir, sel, progress=False)
    return {"method": "elimination", "max_fit": sel.max_fit, "actuators": sel.actuators, **{k: r[k] for k in keys}}


def optimize_task(params: dict, out_dir: str) -> dict:
    """Rest-length design optimization of one case for one (γ, β) (``xshells optimize``, quietly, no BFGS baseline)."""
    from ..design.objective import DesignWeights
    from ..design.optimize import OptimizeOptions
    from ..design.run import run_optimize

    os.makedirs(out_dir, exist_ok=True)
    case = _write_case(params, os.path.join(out_dir, "case.json"))
    weights = DesignWeights(**{k: params[k] for k in ("gamma", "beta") if params.get(k) is not None})
    options = OptimizeOptions(**{k: params[k] for k in ("max_iterations",) if params.get(k) is not None})
    r = run_optimize(case, out_dir, weights=weights, options=options, target_surface=params.get("target_surface"),
                     baseline=False, progress=False)
    return {
        "message": r["message"],
        "J": r["J"],
        "J_initial": r["initial"]["J"],
        "energy_flat": r["energy_flat"],
        "energy_deployed": r["energy_deployed"],
        "energy_deployed_initial": r["initial"]["energy_deployed"],
        **{k: v for k, v in r["terms"].items()},
        "planarity": r["constraints"]["planarity"],
        "min_angle_deg": r["constraints"]["min_angle_deg"],
        "target_angle_deg": r["target_angle_deg"],
        "iterations": r["iterations"],
        "time_s": r["time_s"],
    }


def noop_task(params: dict, out_dir: str) -> dict:
    """Does nothing (optionally sleeps or fails): measures the sweep machinery's own cost.

    Also returns the settings of the process it ran in (``blas_threads``,
    ``xla_flags``, ``malloc_trim_threshold``), to check what workers get.
    """
    if params.get("fail"):
        raise RuntimeError(params["fail"] if isinstance(params["fail"], str) else "failed on request")
    t0 = time.perf_counter()
    time.sleep(params.get("sleep_s", 0.0))
    return {"slept_s": time.perf_counter() - t0, "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS", ""),
            "xla_flags": os.environ.get("XLA_FLAGS", ""), "malloc_trim_threshold": os.environ.get("MALLOC_TRIM_THRESHOLD_", "")}


# what a task's outputs import on first use (PNGs, 3D views, the DXF drawing): 0.9 s per worker otherwise
_PLOTS = ("xshells.viz.render", "matplotlib.pyplot", "mpl_toolkits.mplot3d.art3d", "ezdxf")
register_task("deploy", deploy_task, preload=("xshells.deploy.run",) + _PLOTS)
register_task("sparsify", sparsify_task, requires=("xshells.actuation.run:run_selection",),
              preload=("xshells.actuation.run",) + _PLOTS,
              params={"eta": number(0), "p": number(0, 1, open_min=True), "tau_max": optional(number(0, open_min=True)),
                      "max_iterations": number(1, integer=True), "max_fit": number(0, 1, open_min=True),
                      "actuators": optional(number(1, integer=True))},
              check=_check_sparsify)
register_task("optimize", optimize_task, requires=("xshells.design.run:run_optimize",),
              preload=("xshells.design.run",) + _PLOTS,
              params={"gamma": number(0, 1), "beta": number(0), "max_iterations": number(1, integer=True),
                      "target_surface": text})
register_task("noop", noop_task, case=False, params={"sleep_s": number(0), "fail": flag})
BUILTIN_TASKS = tuple(REGISTRY)  # the tasks registered here (the published schema lists these)
