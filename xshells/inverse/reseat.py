"""Re-seating: go on optimizing from the state that the design's own deployment from flat reaches.

The guided optimization (:mod:`.guide`) follows one equilibrium of the design, from the state held on the
surface down to no load. The design's own deployment from flat, as ``xshells deploy`` runs it, can end on
another equilibrium (:mod:`.checks` measures each stage's), and then every later iteration improves a state
that the case never reaches. Measured on the asymmetric clapper's realizable target (even net at 16β,
2026-12-07): the tracked state fitted the surface within 0.25 % of the diagonal at every stage, while the
stages' own deployments fitted at 1.9–6.2 %, and no design without load could be kept at all.

Re-seating deploys the design as it stands from flat. It then moves that state rigidly onto the tracked
one, so that the fitting term, built in the tracked state's frame, applies to it. That state becomes the
problem's deployed state, with no load and no springs, and the optimization goes on from there. It now
follows a state that a deployment from flat reaches, and the checks of its designs follow it too.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ReseatOptions:
    """Settings of the re-seating rounds (:func:`optimize_reseated`).

    Attributes
    ----------
    rounds : int
        At most this many rounds per design, each only while the best design checked so far is not close
        (:data:`.board.CLOSE`; 0: never).
    iterations : int
        Design-optimization iterations per round.
    checkpoint_every : int
        The design is checked every this many iterations, and at the end of the round.
    """

    rounds: int = 2
    iterations: int = 30
    checkpoint_every: int = 10


def seat(problem, onto_tracked, steps: int, direction: str) -> str:
    """Make the deployment from flat of ``problem``'s current design its deployed state, with no load.

    Parameters
    ----------
    problem : DesignProblem
        Its ``deployed`` equilibrium is replaced (the flat one and the design stay).
    onto_tracked : callable((j, 3) joints) -> (4, 4)
        The rigid motion that places a deployment's joints onto the state the optimization tracks, in the
        problem's frame.
    steps : int
        Deployment steps, as the case asks.
    direction : {"up", "down"}

    Returns
    -------
    str
        "" where seated; else why not (the deployment stopped, or its state does not solve), with the
        problem left as it was.
    """
    from ..deploy.simulate import DeployOptions, deploy
    from ..design.equilibrium import ConstrainedEquilibrium

    angle = problem.deployed.angle
    L = copy.deepcopy(problem.flat.L)
    res = deploy(L, angle, DeployOptions(steps=steps, direction=direction))
    if not res.converged:
        return f"its deployment from flat stopped: {res.message}"
    T = onto_tracked(L.joint_positions())
    L.apply_rigid_motion(T[:3, :3], T[:3, 3])
    seated = ConstrainedEquilibrium(L, angle, newton=problem.deployed.newton)
    try:
        seated.solve()  # the deployment's own equilibrium, moved: a few iterations at most
    except ArithmeticError as exc:
        return f"its deployment from flat does not solve where seated ({exc})"
    problem.deployed = seated
    problem._cache = {}
    return ""


def optimize_reseated(problem, onto_tracked, steps: int, direction: str, options: ReseatOptions, min_angle=None,
                      check=None, callback=None, min_clearance: float | None = None) -> dict:
    """One round: :func:`seat`, then ``options.iterations`` of design optimization (eq. 5) from there.

    ``check()`` is called every ``options.checkpoint_every`` iterations and at the end (the design as it
    stands; :class:`.checks.StageChecks`). ``callback(record)`` after every iteration; True stops.
    Ctrl-C raises KeyboardInterrupt after the iteration it came in. ``min_clearance``: the optimizer's.

    Returns
    -------
    dict
        ``{"why": ...}`` where it could not be seated; else ``iterations``, ``J`` and ``message`` of the
        optimization.
    """
    from ..design.optimize import OptimizeOptions, optimize

    why = seat(problem, onto_tracked, steps, direction)
    if why:
        return {"why": why}
    every, limit = options.checkpoint_every, options.iterations

    def on_iteration(rec):
        stop = bool(callback(rec)) if callback is not None else False
        if check is not None and every and rec.iteration and rec.iteration % every == 0 and rec.iteration < limit \
                and not stop:
            check()
        return stop

    res = optimize(problem, OptimizeOptions(max_iterations=limit, min_angle=min_angle, min_clearance=min_clearance),
                   callback=on_iteration)
    if check is not None:
        check()
    if res.interrupted:
        raise KeyboardInterrupt
    return {"iterations": int(res.iterations), "J": float(res.history[-1].J) if res.history else float("nan"),
            "message": res.message}


def seat_direction(checked: list, asked: str) -> str:
    """The direction to deploy a design in for its seat: that of its last check that deployed (the one whose
    image fitted the surface better, :func:`.checks.check_stage`), else ``asked``."""
    for _, r in reversed(checked):
        if "direction" in r:
            return r["direction"]
    return asked


def wants_reseat(best: dict, diagonal: float) -> bool:
    """Whether the best design checked so far (:func:`.run._best_stage`) is not close (:data:`.board.CLOSE`)."""
    from .board import close_misses

    if "design" not in best:
        return True
    return close_misses({"fit_mean": best["fit"] / diagonal, "fit_max": best["top"] / diagonal}) > 0


def tracked_fit(surface, joints) -> tuple:
    """(mean, max) distance of ``joints`` (in the surface's frame) to the surface, relative to its diagonal."""
    from .metrics import surface_distances

    d = surface_distances(surface, np.asarray(joints, float)) / surface.diagonal
    return float(d.mean()), float(d.max())
