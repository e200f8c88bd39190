"""The app's simulation model: assembly state of a layout and warm-started deployed equilibria.

:class:`Simulation` owns one :class:`~xshells.linkage.linkage.Linkage`. The
first deployment walks up from the flat assembly state in small angle steps
(leaving the flat saddle on the "up" side, as :func:`xshells.deploy.simulate.deploy`
does); every later angle starts from the stored state nearest to it and
takes the same constrained Newton steps (:func:`xshells.solve.minimize` with
the average-angle constraint), so a slider move costs a few Newton
iterations. Every reached state is kept (in memory) for the deployment
animation. Work can be cancelled between and inside Newton solves.
"""
from __future__ import annotations

import bisect
import threading
import time
from dataclasses import dataclass

import numpy as np

from ..deploy.simulate import DeployOptions, _gradient_scale, _noise_floor, folded_joint, rest_length_solve
from ..errors import InputError
from ..linkage.linkage import Linkage
from ..linkage.state import restore, snapshot
from ..solve import NewtonOptions, minimize, smallest_eigenvalues
from .core import Layout, layout_to_design


class Cancelled(Exception):
    """Raised inside a solve when its cancel event is set."""


@dataclass(frozen=True)
class SimSettings:
    """Solver settings of the app.

    Attributes
    ----------
    max_step_deg : float
        Largest angle increment between two constrained solves (keeps Newton in its basin).
    direction : {"up", "down"}
    max_stored : int
        Deployed states kept for the animation (oldest extra states dropped).
    """

    max_step_deg: float = 2.0
    direction: str = "up"
    max_stored: int = 400


@dataclass(frozen=True)
class StateInfo:
    """Numbers shown in the UI for one equilibrium."""

    angle_deg: float
    energy: float
    energy_bend: float
    energy_twist: float
    energy_stretch: float
    torque: float
    max_abs_z: float
    converged: bool
    iterations: int
    message: str = ""


class Simulation:
    """A layout's linkage, its flat assembly state and the deployed states reached so far.

    Parameters
    ----------
    layout : Layout
    material : xshells.section.Material
    subdivision : int
    rest_lengths : (S,) array, optional
        Known rest lengths (skips the rest-length solve).
    settings : SimSettings
    cancel : threading.Event, optional
        Checked during the assembly solve.
    """

    def __init__(self, layout: Layout, material, subdivision: int = 8, rest_lengths=None,
                 settings: SimSettings = SimSettings(), cancel: threading.Event | None = None):
        self.settings = settings
        self.layout = layout
        self.material = material
        t0 = time.perf_counter()
        self.linkage = L = Linkage(layout_to_design(layout), material, subdivision=subdivision, rest_lengths=rest_lengths)
        if rest_lengths is None:
            rest_length_solve(L)
        else:
            minimize(L, fixed=L.rigid_pin_indices(), options=NewtonOptions(gradient_tolerance=1e-9, max_iterations=100),
                     callback=self._stopper(cancel))
        self.assembly_time_s = time.perf_counter() - t0
        self.flat = snapshot(L)
        self.flat_angle = L.average_angle()
        self.flat_info = self._info(True, 0)
        joints = np.arange(L.num_joints)
        self._a = np.zeros(L.num_vars)
        self._a[L.angle_indices()[joints]] = 1.0 / len(joints)
        self._pins = L.rigid_pin_indices()
        P = L.joint_positions()
        r2 = np.sum((P - P.mean(axis=0)) ** 2, axis=1)
        sign = 1.0 if settings.direction == "up" else -1.0
        self._hint = sign * (L.height_selector().T @ (r2.mean() - r2))
        self._z0 = L.height_selector() @ L.get_vars()
        scale = _gradient_scale(L) * np.sqrt(L.num_vars)
        tol = max(DeployOptions().newton.gradient_tolerance * scale, _noise_floor(L))
        self._newton = NewtonOptions(**{**DeployOptions().newton.__dict__, "gradient_tolerance": tol})
        # (angle_rad, snapshot, info), sorted by angle; the flat state is the first
        self.states: list[tuple[float, dict, StateInfo]] = [(self.flat_angle, self.flat, self.flat_info)]
        self.current_angle = self.flat_angle

    # ------------------------------------------------------------------ helpers
    @property
    def num_vars(self) -> int:
        return self.linkage.num_vars

    @staticmethod
    def _stopper(cancel):
        if cancel is None:
            return None

        def cb(it, report):
            if cancel.is_set():
                raise Cancelled()
            return False
        return cb

    def _info(self, converged: bool, iterations: int, message: str = "") -> StateInfo:
        L = self.linkage
        parts = L.energy_parts()
        g = L.gradient()
        z = L.height_selector() @ L.get_vars()
        z = z - getattr(self, "_z0", z)
        return StateInfo(float(np.degrees(L.average_angle())), parts.total, parts.bend, parts.twist, parts.stretch,
                         float(np.mean(g[L.angle_indices()])), float(np.abs(z).max()) if z.size else 0.0,
                         bool(converged), int(iterations), message)

    def _store(self, angle: float, info: StateInfo) -> None:
        keys = [s[0] for s in self.states]
        i = bisect.bisect_left(keys, angle)
        if i < len(keys) and abs(keys[i] - angle) < 1e-12:
            self.states[i] = (angle, snapshot(self.linkage), info)
        else:
            self.states.insert(i, (angle, snapshot(self.linkage), info))
        if len(self.states) > self.settings.max_stored:
            # thin the interior evenly, keeping the flat state and the extremes
            self.states = self.states[:1] + self.states[1:-1:2] + self.states[-1:]

    def _predict(self, angle: float) -> None:
        """Open every joint by the same amount so the average-angle constraint holds exactly.

        Used when Newton accepted a start whose constraint residual was below
        its (force-scaled) gradient tolerance and did not move at all.
        """
        x = self.linkage.get_vars()
        x[self.linkage.angle_indices()] += angle - float(self._a @ x)
        self.linkage.set_vars(x)

    def nearest_state(self, angle: float):
        return min(self.states, key=lambda s: abs(s[0] - angle))

    def angle_range_deg(self) -> tuple[float, float]:
        """Angles the slider offers: from the flat angle to just below 180°."""
        return float(np.degrees(self.flat_angle)), 175.0

    # ------------------------------------------------------------------ solving
    def solve_to(self, angle_deg: float, cancel: threading.Event | None = None, progress=None) -> StateInfo:
        """Move to the equilibrium at average angle ``angle_deg``, warm-started from the nearest stored state.

        Parameters
        ----------
        angle_deg : float
        cancel : threading.Event, optional
            When set, the solve stops (raising :class:`Cancelled`) and the
            linkage is left at the last converged state.
        progress : callable(fraction, text), optional

        Returns
        -------
        StateInfo of the reached state.
        """
        target = np.radians(float(angle_deg))
        if not 0 < target < np.pi:
            raise InputError(f"opening angle {angle_deg}° must lie strictly between 0° and 180°")
        start_angle, snap, info = self.nearest_state(target)
        restore(self.linkage, snap)
        if abs(start_angle - target) < 1e-10:
            self.current_angle = start_angle
            return info
        n = max(1, int(np.ceil(abs(np.degrees(target - start_angle)) / self.settings.max_step_deg)))
        stop = self._stopper(cancel)
        last = info
        for i in range(1, n + 1):
            if cancel is not None and cancel.is_set():
                raise Cancelled()
            angle = start_angle + (target - start_angle) * i / n
            report = minimize(self.linkage, fixed=self._pins, constraint=(self._a, angle), options=self._newton,
                              callback=stop, saddle_hint=self._hint)
            if abs(float(self._a @ self.linkage.get_vars()) - angle) > 1e-8:
                self._predict(angle)
                report = minimize(self.linkage, fixed=self._pins, constraint=(self._a, angle), options=self._newton,
                                  callback=stop, saddle_hint=self._hint)
            # a stalled solve, or a converged state with a joint folded through (not a linkage):
            # keep the linkage at the last good state, with its numbers, and say why
            why = folded_joint(self.linkage) if report.converged else f"the solver gave up ({report.message})"
            if why:
                _, snap, good = self.nearest_state(angle)
                restore(self.linkage, snap)
                self.current_angle = self.linkage.average_angle()
                return StateInfo(**{**good.__dict__, "converged": False, "message": f"stopped near {np.degrees(angle):.1f}°: {why}"})
            last = self._info(True, report.iterations)
            self._store(angle, last)
            self.current_angle = angle
            if progress is not None:
                progress(i / n, f"{np.degrees(angle):.1f}°")
        return last

    def show_state(self, angle_rad: float) -> StateInfo:
        """Restore the stored state nearest ``angle_rad`` (for the animation) and return its info."""
        a, snap, info = self.nearest_state(angle_rad)
        restore(self.linkage, snap)
        self.current_angle = a
        return info

    def stability(self) -> tuple[float, float]:
        """Smallest generalized eigenvalue of the free Hessian and the gap λ₂/λ₁ at the current state."""
        L = self.linkage
        free = np.setdiff1d(np.arange(L.num_vars), self._pins)
        H = L.hessian()[free][:, free]
        M = L.mass_matrix()[free][:, free]
        lam = smallest_eigenvalues(H, M, k=2)
        return float(lam[0]), float(lam[1] / lam[0]) if lam[0] != 0 else float("inf")
