"""Hooks from the app to design optimization (:mod:`xshells.design`) and sparse actuation (:mod:`xshells.actuation`).

Both packages are imported lazily, only when the user presses *Optimize* or
*Actuate*; when one is missing (or lacks the entry points below) the UI shows
"not available yet" instead of failing. Progress comes back one record per
iteration as ``(iteration, value, text)``; the UI plots ``value`` and can
stop a run (the cancel event) and resume it (run again from the result).

Adapter signatures (what the app calls; plug in new implementations here)
--------------------------------------------------------------------------
``run_optimize(linkage, target_angle, *, progress, cancel) -> OptimizeOutcome``
    ``linkage`` is at its flat assembly state; ``target_angle`` in radians.
    Uses ``xshells.design.objective.DesignProblem(linkage, target_angle)`` and
    ``xshells.design.optimize.optimize(problem, callback=...)`` whose callback
    receives records with ``iteration`` and ``J`` and returns True to stop;
    the result has ``rest_lengths``, ``message`` and ``success``.
``run_actuate(linkage, torque, *, progress, cancel) -> ActuateOutcome``
    ``linkage`` is at the densely actuated deployed equilibrium, ``torque``
    the dense torque per joint. Uses ``xshells.actuation.select_actuators(linkage,
    tau_ref, callback=...)`` (the fewest actuators within 1 % of the span) whose
    callback receives one point per accepted cut with ``num_actuators`` and
    ``fit_mean``; the result has ``torques``, ``actuated``, ``message`` and
    ``converged``.

``progress(iteration: int, value: float, text: str) -> None``;
``cancel: threading.Event`` (set = stop after the current iteration).
"""
from __future__ import annotations

import importlib
import os
from dataclasses import dataclass

import numpy as np

NOT_AVAILABLE = "not available yet"


@dataclass(frozen=True)
class OptimizeOutcome:
    """What a design optimization run gives the app.

    ``before`` / ``after``: the objective's terms at the start and at the
    design returned (the best feasible iterate, which may be the start) (``J``, ``flat_energy``, ``deployed_energy``), for the
    before/after comparison.
    """

    rest_lengths: np.ndarray
    message: str
    success: bool
    iterations: int = 0
    before: dict | None = None
    after: dict | None = None
    rest_lengths_before: np.ndarray | None = None
    energy_scale: float | None = None  # the deployed energy at the start: the terms' energies are divided by it


@dataclass(frozen=True)
class ActuateOutcome:
    """What a sparse actuation run gives the app: torque per joint, indices of the actuated joints."""

    torques: np.ndarray
    actuated: np.ndarray
    message: str
    success: bool
    state: dict | None = None  # the sparsely actuated equilibrium (select_actuators hands the linkage back dense)


def _lookup(module: str, name: str):
    """``module.name`` or None when the module (or the name) does not exist yet."""
    try:
        mod = importlib.import_module(module)
    except ImportError:
        return None
    return getattr(mod, name, None)


def _present(module: str) -> bool:
    """Whether ``module`` exists, without importing it or its package (cheap enough for start-up).

    ``find_spec("a.b.c")`` would import the package ``a.b``, whose ``__init__``
    may load the solver; only ``a`` is looked up here, and ``b/c`` on disk.
    """
    import importlib.util

    top, *rest = module.split(".")
    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):
        return False
    if spec is None or not rest:
        return spec is not None
    for base in spec.submodule_search_locations or []:
        path = os.path.join(base, *rest)
        if os.path.isfile(path + ".py") or os.path.isfile(os.path.join(path, "__init__.py")):
            return True
    return False


def modules_present() -> tuple[bool, bool]:
    """(optimization, actuation) modules exist; the entry points are checked when used."""
    return _present("xshells.design.optimize"), _present("xshells.actuation.selection")


def optimize_available() -> bool:
    return _lookup("xshells.design.objective", "DesignProblem") is not None and \
        _lookup("xshells.design.optimize", "optimize") is not None


def actuate_available() -> bool:
    return _lookup("xshells.actuation", "select_actuators") is not None


def _terms(rec) -> dict:
    return {k: float(getattr(rec, k)) for k in ("J", "flat_energy", "deployed_energy") if hasattr(rec, k)}


def run_optimize(linkage, target_angle: float, *, progress, cancel, max_iterations: int | None = None) -> OptimizeOutcome:
    """Optimize the rest lengths for a low-energy deployment at ``target_angle`` (see the module docstring)."""
    Problem = _lookup("xshells.design.objective", "DesignProblem")
    optimize = _lookup("xshells.design.optimize", "optimize")
    if Problem is None or optimize is None:
        raise NotImplementedError(f"design optimization: {NOT_AVAILABLE}")
    p_before = np.array(linkage.rest_lengths, float)
    problem = Problem(linkage, target_angle)
    records: list = []

    def cb(rec) -> bool:
        records.append(rec)
        progress(int(rec.iteration), float(rec.J), f"J = {rec.J:.4g}")
        return cancel.is_set()

    kw = {}
    if max_iterations is not None:
        kw["options"] = _lookup("xshells.design.optimize", "OptimizeOptions")(max_iterations=int(max_iterations))
    res = optimize(problem, callback=cb, **kw)
    history = list(getattr(res, "history", None) or records)
    try:  # the design returned (the best feasible iterate; the problem is left there)
        after = {k: float(v) for k, v in problem.terms(res.q).items() if k in ("J", "flat_energy", "deployed_energy")}
    except Exception:  # noqa: BLE001  (an older DesignProblem: fall back to the last record)
        after = _terms(history[-1]) if history else None
    return OptimizeOutcome(np.asarray(res.rest_lengths, float), str(res.message), bool(res.success),
                           int(getattr(res, "iterations", len(history))), _terms(history[0]) if history else None, after,
                           p_before, float(getattr(problem, "E0", np.nan)))


def run_actuate(linkage, torque: float, *, progress, cancel, max_iterations: int | None = None) -> ActuateOutcome:
    """Find few joint torques that hold the current deployed shape within 1 % of the span (see the module docstring).

    Runs ``xshells sparsify``'s default, the elimination of
    :func:`xshells.actuation.select_actuators`; ``progress`` gets one call per
    accepted cut (the cut's number, its mean deviation in % of the span, "N actuators, mean …").
    ``max_iterations`` is not used by it (the elimination ends by itself;
    ``cancel`` stops it after the current cut, keeping the best answer so far).
    """
    select = _lookup("xshells.actuation", "select_actuators")
    if select is None:
        raise NotImplementedError(f"sparse actuation: {NOT_AVAILABLE}")
    cuts = [0]

    def cb(point) -> bool:
        cuts[0] += 1
        n = point.num_actuators
        progress(cuts[0], 100.0 * float(point.fit_mean), f"{n} actuator{'s' if n != 1 else ''}, mean {100 * point.fit_mean:.2f}%")
        return cancel.is_set()

    res = select(linkage, float(torque), callback=cb)
    return ActuateOutcome(np.asarray(res.torques, float), np.asarray(res.actuated), str(res.message), bool(res.converged),
                          getattr(res, "state", None))
