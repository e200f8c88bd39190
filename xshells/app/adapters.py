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
    the dense torque per joint. Uses ``xshells.actuation.sparsify(linkage,
    tau_ref, callback=...)`` whose callback receives records with
    ``iteration``, ``objective`` and ``num_actuators``; the result has
    ``torques``, ``actuated``, ``message`` and ``converged``.

``progress(iteration: int, value: float, text: str) -> None``;
``cancel: threading.Event`` (set = stop after the current iteration).
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass

import numpy as np

NOT_AVAILABLE = "not available yet"


@dataclass(frozen=True)
class OptimizeOutcome:
    rest_lengths: np.ndarray
    message: str
    success: bool


@dataclass(frozen=True)
class ActuateOutcome:
    torques: np.ndarray
    actuated: np.ndarray
    message: str
    success: bool


def _lookup(module: str, name: str):
    """``module.name`` or None when the module (or the name) does not exist yet."""
    try:
        mod = importlib.import_module(module)
    except ImportError:
        return None
    return getattr(mod, name, None)


def _present(module: str) -> bool:
    """Whether ``module`` exists, without importing it (cheap enough for start-up)."""
    import importlib.util

    try:
        return importlib.util.find_spec(module) is not None
    except ImportError:  # a missing parent package
        return False


def modules_present() -> tuple[bool, bool]:
    """(optimization, actuation) modules exist; the entry points are checked when used."""
    return _present("xshells.design.optimize"), _present("xshells.actuation.sparsify")


def optimize_available() -> bool:
    return _lookup("xshells.design.objective", "DesignProblem") is not None and \
        _lookup("xshells.design.optimize", "optimize") is not None


def actuate_available() -> bool:
    return _lookup("xshells.actuation", "sparsify") is not None


def run_optimize(linkage, target_angle: float, *, progress, cancel) -> OptimizeOutcome:
    """Optimize the rest lengths for a low-energy deployment at ``target_angle`` (see the module docstring)."""
    Problem = _lookup("xshells.design.objective", "DesignProblem")
    optimize = _lookup("xshells.design.optimize", "optimize")
    if Problem is None or optimize is None:
        raise NotImplementedError(f"design optimization: {NOT_AVAILABLE}")
    problem = Problem(linkage, target_angle)

    def cb(rec) -> bool:
        progress(int(rec.iteration), float(rec.J), f"J = {rec.J:.4g}")
        return cancel.is_set()

    res = optimize(problem, callback=cb)
    return OptimizeOutcome(np.asarray(res.rest_lengths, float), str(res.message), bool(res.success))


def run_actuate(linkage, torque: float, *, progress, cancel) -> ActuateOutcome:
    """Find sparse joint torques that hold the current deployed shape (see the module docstring)."""
    sparsify = _lookup("xshells.actuation", "sparsify")
    if sparsify is None:
        raise NotImplementedError(f"sparse actuation: {NOT_AVAILABLE}")

    def cb(rec) -> bool:
        progress(int(rec.iteration), float(rec.objective), f"{rec.num_actuators} actuators")
        return cancel.is_set()

    res = sparsify(linkage, float(torque), callback=cb)
    return ActuateOutcome(np.asarray(res.torques, float), np.asarray(res.actuated), str(res.message), bool(res.converged))
