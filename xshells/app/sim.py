"""The app's simulation model: assembly state of a layout and warm-started deployed equilibria.

:class:`Simulation` owns one :class:`~xshells.linkage.linkage.Linkage`. A
deployment from the flat assembly state is :func:`xshells.deploy.simulate.deploy`
itself, with the steps and direction ``xshells deploy`` takes for the
exported case, so both leave the flat saddle on the same side; every later
angle starts from the stored state nearest to it and takes constrained
Newton steps (:func:`xshells.solve.minimize` with the average-angle
constraint), so a slider move costs a few Newton iterations. Every reached state is kept (in memory) for the deployment
animation. Work can be cancelled between and inside Newton solves.
"""
from __future__ import annotations

import bisect
import inspect
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ..deploy.simulate import DeployOptions, _gradient_scale, _noise_floor, deploy, folded_joint, rest_length_solve
from ..errors import InputError
from ..linkage.linkage import Linkage
from ..linkage.state import restore, snapshot
from ..solve import NewtonOptions, NewtonReport, minimize, smallest_eigenvalues
from .core import Layout, layout_to_design


# xshells.deploy.simulate.rest_length_solve checks a cancel callback where it accepts one
_REST_LENGTH_SOLVE_TAKES_CALLBACK = "callback" in inspect.signature(rest_length_solve).parameters
# and xshells.deploy.simulate.deploy inside each step's Newton solve where it accepts one (else between steps only)
_DEPLOY_TAKES_NEWTON_CALLBACK = "newton_callback" in inspect.signature(deploy).parameters


class Cancelled(Exception):
    """Raised inside a solve when its cancel event is set."""


@dataclass(frozen=True)
class SimSettings:
    """Solver settings of the app.

    Attributes
    ----------
    max_step_deg : float
        Largest angle increment between two constrained solves from a deployed state (keeps Newton in its basin).
    direction : {"up", "down"}
    max_stored : int
        Deployed states kept for the animation (oldest extra states dropped).
    steps : int
        Angle increments of a deployment from the flat state (a case's ``steps``, as ``xshells deploy``).
    guide : (nj, 3) float or None
        A case's guide (:mod:`xshells.deploy.guide`): a deployment from the flat state ends held on it and let
        go, as ``xshells deploy`` does. Used while the layout has as many joints, else left out.
    """

    max_step_deg: float = 6.0
    direction: str = "up"
    max_stored: int = 400
    steps: int = DeployOptions().steps
    guide: np.ndarray | None = field(default=None, repr=False, compare=False)


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


@dataclass(frozen=True)
class WarmOptions:
    """Settings of :meth:`Simulation.warm_start`.

    Attributes
    ----------
    max_relative_step : float
        Largest relative change of any rest length in one continuation step.
    min_step : float
        Smallest fraction of the edit a failed step is halved down to before giving up.
    max_iterations : int
        Newton iterations a step may take (more means it left the branch's basin: halve).
    preview : bool
        A drag's preview: a looser tolerance (``preview_tolerance_factor`` times the deployment's).
    sigma_factor : float
        First Hessian shift of the Newton corrections (:class:`xshells.solve.NewtonOptions`).
    """

    max_relative_step: float = 0.3
    min_step: float = 1.0 / 64
    max_iterations: int = 40
    preview: bool = False
    preview_tolerance_factor: float = 100.0
    sigma_factor: float = 1e-5


@dataclass(frozen=True)
class WarmReport:
    """How a warm start went: success, why not, continuation steps, Newton iterations, time,
    and the branch test against the previous state (out-of-plane shape flipped, relative energy change)."""

    ok: bool
    message: str
    steps: int = 0
    iterations: int = 0
    time_s: float = 0.0
    flipped: bool = False
    energy_change: float = 0.0


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
            if cancel is not None and cancel.is_set():
                raise Cancelled()
            if _REST_LENGTH_SOLVE_TAKES_CALLBACK:  # checked inside the solve, once it can be
                rest_length_solve(L, callback=self._stopper(cancel))
            else:  # only between the stages (the solve itself takes no callback yet)
                rest_length_solve(L)
            if cancel is not None and cancel.is_set():
                raise Cancelled()
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
        from ..deploy.simulate import max_abs_z

        return StateInfo(float(np.degrees(L.average_angle())), parts.total, parts.bend, parts.twist, parts.stretch,
                         float(np.mean(g[L.angle_indices()])), max_abs_z(L.joint_positions()),  # deploy's own measure
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
        if cancel is not None and cancel.is_set():
            raise Cancelled()  # superseded while the assembly state was built: no start relaxation for nothing
        start_angle, snap, info = self.nearest_state(target)
        restore(self.linkage, snap)
        if abs(start_angle - target) < 1e-10:
            self.current_angle = start_angle
            return info
        if snap is self.flat:
            return self._deploy(target, cancel, progress)
        n = max(1, int(np.ceil(abs(np.degrees(target - start_angle)) / self.settings.max_step_deg)))
        stop = self._stopper(cancel)
        last = info
        for i in range(1, n + 1):
            if cancel is not None and cancel.is_set():
                raise Cancelled()
            angle = start_angle + (target - start_angle) * i / n
            try:
                report = minimize(self.linkage, fixed=self._pins, constraint=(self._a, angle), options=self._newton,
                                  callback=stop, saddle_hint=self._hint)
                if abs(float(self._a @ self.linkage.get_vars()) - angle) > 1e-8:
                    self._predict(angle)
                    report = minimize(self.linkage, fixed=self._pins, constraint=(self._a, angle), options=self._newton,
                                      callback=stop, saddle_hint=self._hint)
            except Cancelled:
                raise
            except Exception as exc:  # noqa: BLE001  (a degenerate state, e.g. a NaN Hessian: stop here and say so)
                report = NewtonReport(message=f"the state became degenerate ({type(exc).__name__})")
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

    def _deploy(self, target: float, cancel, progress) -> StateInfo:
        """Deploy from the flat state to ``target`` (radians) as ``xshells deploy`` does, storing every step's state.

        The same function with the same steps and direction as the command
        line: which way the flat state buckles depends on the size of the
        first step, and with 6° steps of its own the app buckled Darth Vader
        (joint 32 raised 38 mm) into the mirror image of the command line's
        dome (16, 14 or 20 steps give that bowl too; 40 and 50 the dome).
        """
        L = self.linkage

        def step(rec) -> bool:
            if cancel is not None and cancel.is_set():
                raise Cancelled()
            self._store(float(self._a @ L.get_vars()), self._info(True, rec.iterations))
            if progress is not None:
                progress(rec.step / self.settings.steps, f"{rec.average_angle_deg:.1f}°")
            return False

        if progress is not None:  # the start relaxation (before the first step) reports nothing by itself
            progress(0.0, f"{np.degrees(self.flat_angle):.1f}° (relaxing the flat state before the first step)")
        kw = {"newton_callback": self._stopper(cancel)} if _DEPLOY_TAKES_NEWTON_CALLBACK and cancel is not None else {}
        guide = self.settings.guide
        guide = guide if guide is not None and len(guide) == L.num_joints else None  # a topology edit leaves it out
        result = deploy(L, target, DeployOptions(steps=self.settings.steps, direction=self.settings.direction, guide=guide),
                        callback=step, **kw)
        if result.converged and guide is not None:  # the guided state replaces the last step's stored one
            self._store(float(self._a @ L.get_vars()), self._info(True, 0))
        if result.converged:
            self.current_angle = float(self._a @ L.get_vars())
            return self.nearest_state(self.current_angle)[2]
        # stopped short: keep the linkage at the last state reached (or flat), with its numbers, and say why
        angle, snap, good = self.nearest_state(np.radians(result.reached_angle_deg))
        restore(L, snap)
        self.current_angle = angle
        return StateInfo(**{**good.__dict__, "converged": False, "message": result.message})

    # ------------------------------------------------------------------ warm start after an edit
    def can_warm_start_from(self, previous: "Simulation | None") -> bool:
        """Whether ``previous`` has the same subdivision, material and direction, and a deployed state.

        Its segments may differ (a topology edit): :meth:`warm_start` then
        transfers what the two layouts share and may still fall back.
        """
        return (previous is not None and previous is not self
                and previous.linkage.subdivision == self.linkage.subdivision and previous.material is self.material
                and len(previous.states) > 1 and previous.settings.direction == self.settings.direction)

    def _same_variables(self, previous: "Simulation") -> bool:
        return previous.num_vars == self.num_vars and np.array_equal(previous.layout.edges, self.layout.edges)

    def _transfer(self, previous: "Simulation", snap: dict, angle: float, newton, stop):
        """A state of this linkage from ``previous``'s state ``snap`` after a topology edit; None where it cannot.

        Joints and segments are matched by the positions of their vertices in
        the two layouts (a topology edit moves no joint). Every shared joint
        keeps its variables and frame, every shared segment its rod (points,
        angles, frames), and a new segment starts straight out of its joint,
        twist-free. Refused (None) when a joint is new or its beams were
        relabelled or turned around, or the first equilibrium fails. The
        shared segments keep their old rest lengths here; the caller then
        continues to this layout's.

        Returns ``(snapshot, rest lengths)`` of the equilibrium at ``angle``.
        """
        from ..linkage.linkage import _rotate

        L0, L1 = previous.linkage, self.linkage
        g0, g1 = L0.graph, L1.graph
        k = L1.subdivision
        place = {tuple(np.round(v, 9)): i for i, v in enumerate(previous.layout.vertices.tolist())}
        vmap = np.array([place.get(tuple(np.round(v, 9)), -1) for v in self.layout.vertices.tolist()])
        E0, E1 = previous.layout.edges, self.layout.edges
        seg0 = {(int(a), int(b)): s for s, (a, b) in enumerate(E0.tolist())}
        match = np.full(len(E1), -1)  # new segment -> old segment with the same ends in the same order
        for s1, (a, b) in enumerate(E1.tolist()):
            if vmap[a] >= 0 and vmap[b] >= 0:
                match[s1] = seg0.get((int(vmap[a]), int(vmap[b])), -1)
        # each new joint's beams as old beams: source[j1, X'] = (old beam, +1 same way / -1 turned around)
        joint0 = np.full(g1.num_joints, -1)
        source = np.zeros((g1.num_joints, 2, 2), np.int64)
        for j1, v1 in enumerate(g1.joint_vertex.tolist()):
            j0 = int(g0.vertex_joint[vmap[v1]]) if vmap[v1] >= 0 else -1
            if j0 < 0:
                return None  # a new joint: nothing to start it from
            for beam in (0, 1):
                seen = set()
                for slot in (0, 1):
                    s1 = int(g1.joint_segments[j1, beam, slot])
                    if s1 < 0 or match[s1] < 0:
                        continue
                    where = np.argwhere(g0.joint_segments[j0] == match[s1])
                    if len(where) != 1:
                        return None
                    old_beam, old_slot = (int(v) for v in where[0])
                    seen.add((old_beam, 1 if old_slot == slot else -1))
                if len(seen) != 1:
                    return None  # a beam made only of new segments, or of two old beams
                source[j1, beam] = seen.pop()
            if source[j1, 0, 0] == source[j1, 1, 0]:
                return None
            joint0[j1] = j0
        restore(L0, snap)
        x0, r0 = L0.get_vars(), L0.rods
        rv0 = L0.rod_vars(x0)
        V3_0 = 3 * r0.num_vertices
        P1 = L1.rods.points.copy()
        th1 = np.zeros(L1.rods.num_edges)
        t_src, d1_src, twist_src = L1.rods.t_src.copy(), L1.rods.d1_src.copy(), L1.rods.ref_twist_src.copy()
        P0 = rv0[:V3_0].reshape(-1, 3)
        for s1, s0 in enumerate(match.tolist()):
            if s0 < 0:
                continue
            P1[s1 * (k + 1): (s1 + 1) * (k + 1)] = P0[s0 * (k + 1): (s0 + 1) * (k + 1)]
            th1[s1 * k: (s1 + 1) * k] = rv0[V3_0 + s0 * k: V3_0 + (s0 + 1) * k]
            t_src[s1 * k: (s1 + 1) * k] = r0.t_src[s0 * k: (s0 + 1) * k]
            d1_src[s1 * k: (s1 + 1) * k] = r0.d1_src[s0 * k: (s0 + 1) * k]
            twist_src[s1 * (k - 1): (s1 + 1) * (k - 1)] = r0.ref_twist_src[s0 * (k - 1): (s0 + 1) * (k - 1)]
        # the old joints' frames as they stand (ω folded in), then each new joint's from its beams' tangents
        xj0 = x0[: L0.num_joint_vars].reshape(-1, 9)[joint0]
        b_old = _rotate(xj0[:, 3:6], L0.joint_b0[joint0])
        n_old = _rotate(xj0[:, 3:6], L0.joint_n0[joint0])
        u = np.cross(n_old, b_old)
        c, sn = np.cos(0.5 * xj0[:, 6])[:, None], np.sin(0.5 * xj0[:, 6])[:, None]
        t_old = np.stack([c * b_old - sn * u, c * b_old + sn * u], axis=1)  # (nj, 2, 3)
        rows = np.arange(g1.num_joints)
        tA = source[:, 0, 1][:, None] * t_old[rows, source[:, 0, 0]]
        tB = source[:, 1, 1][:, None] * t_old[rows, source[:, 1, 0]]
        b0 = tA + tB
        b0 /= np.linalg.norm(b0, axis=1)[:, None]
        n = np.cross(tA, tB)
        n /= np.linalg.norm(n, axis=1)[:, None]
        xj1 = np.zeros((g1.num_joints, 9))
        xj1[:, 0:3] = xj0[:, 0:3]
        xj1[:, 6] = np.arccos(np.clip(np.sum(tA * tB, axis=1), -1.0, 1.0))
        xj1[:, 7] = xj0[rows, 7 + source[:, 0, 0]]
        xj1[:, 8] = xj0[rows, 7 + source[:, 1, 0]]
        tangents = (tA, tB)
        # where a joint's normal turned over, its segments' material frames turn by π about their edges
        flipped = np.sum(n * n_old, axis=1) < 0
        for s1 in range(len(E1)):
            ends = [int(j) for j in g1.segment_joints[s1] if j >= 0]
            if len({bool(flipped[j]) for j in ends}) > 1:
                return None  # turned at one end only: the rod would need half a turn of twist
            if ends and flipped[ends[0]] and match[s1] >= 0:
                th1[s1 * k: (s1 + 1) * k] += np.pi
        p1 = L1.rest_lengths
        p_start = np.where(match >= 0, L0.rest_lengths[np.maximum(match, 0)], p1)
        for s1 in np.flatnonzero(match < 0).tolist():  # a new segment: straight out of its joint(s), twist-free
            ends = [(e, int(g1.segment_joints[s1, e])) for e in (0, 1) if g1.segment_joints[s1, e] >= 0]
            if not ends:
                return None
            e, j1 = ends[0]
            beam = int(g1.segment_labels[s1, e])
            slot = int(np.argwhere(g1.joint_segments[j1, beam] == s1)[0, 0])
            t = tangents[beam][j1] * (1.0 if slot == 1 else -1.0)  # out of the joint: along t on the outgoing side
            step = p1[s1] / k
            start = xj1[j1, 0:3]
            pts = start + np.outer(np.arange(k + 1) - 0.5, t) * step
            if e == 1:
                pts = pts[::-1]
            if len(ends) == 2:  # between two joints: a straight chord between them
                other = xj1[ends[1][1], 0:3]
                pts = start + np.outer(np.linspace(0.0, 1.0, k + 1), other - start) if e == 0 else \
                    other + np.outer(np.linspace(0.0, 1.0, k + 1), start - other)
            P1[s1 * (k + 1): (s1 + 1) * (k + 1)] = pts
            te = np.diff(pts, axis=0)
            te /= np.linalg.norm(te, axis=1)[:, None]
            m1 = np.cross(n[j1], te)
            m1 /= np.linalg.norm(m1, axis=1)[:, None]
            t_src[s1 * k: (s1 + 1) * k], d1_src[s1 * k: (s1 + 1) * k] = te, m1
            twist_src[s1 * (k - 1): (s1 + 1) * (k - 1)] = 0.0
        L1.joint_b0, L1.joint_n0 = b0, n
        L1.rods.t_src, L1.rods.d1_src, L1.rods.ref_twist_src = t_src, d1_src, twist_src
        L1.rods.set_vars(np.concatenate([P1.ravel(), th1]))
        L1._refresh_instance_sources(theta_prev=L1.rods.thetas[L1._inst_edge].copy())
        x1 = np.zeros(L1.num_vars)
        x1[: L1.num_joint_vars] = xj1.ravel()
        x1[L1._free_reduced] = np.concatenate([P1.ravel(), th1])[L1._free_rod]
        try:
            L1.set_rest_lengths(p_start)
            L1.set_vars(x1)
            L1.update_source_frame()
            report = minimize(L1, fixed=self._pins, constraint=(self._a, angle), options=newton, callback=stop,
                              saddle_hint=self._hint)
        except Cancelled:
            raise
        except Exception:  # noqa: BLE001  (a degenerate transferred state: deploy from flat instead)
            return None
        if not report.converged or folded_joint(L1):
            return None
        return snapshot(L1), p_start

    def warm_start(self, previous: "Simulation", angle_deg: float, cancel: threading.Event | None = None,
                   options: WarmOptions | None = None) -> WarmReport:
        """Re-equilibrate ``previous``'s deployed state for this layout, without deploying again from the flat state.

        The deployed equilibrium at a given angle depends on the layout only
        through the rest lengths (the rods are straight at rest), so the state
        of ``previous`` nearest ``angle_deg`` is continued from its rest
        lengths to this layout's: steps along the straight path between them,
        each a first-order predictor (:func:`xshells.solve.continuation.rest_length_predictor`)
        and a Newton correction at that state's angle. A large edit takes
        several steps (each changes no rest length by more than
        ``options.max_relative_step``), and a step that fails is halved.
        Then the state is carried to ``angle_deg`` as a slider move would be.

        Returns a :class:`WarmReport`; when it did not succeed, the caller
        deploys from the flat state.
        """
        from ..solve.continuation import rest_length_predictor

        opts = options or WarmOptions()
        t0 = time.perf_counter()
        target = np.radians(float(angle_deg))
        angle, snap, before = previous.nearest_state(target)
        if abs(angle - previous.flat_angle) < 1e-12:
            return WarmReport(False, "the previous layout had no deployed state", time_s=time.perf_counter() - t0)
        L = self.linkage
        stop = self._stopper(cancel)
        before_x = snap["x"]
        transferred = not self._same_variables(previous)
        if transferred:  # a topology edit: carry over what the layouts share
            moved = self._transfer(previous, snap, angle, NewtonOptions(**{**self._newton.__dict__, "sigma_factor": opts.sigma_factor}), stop)
            if moved is None:
                restore(L, self.flat)
                return WarmReport(False, "the topology changed where no state carries over", time_s=time.perf_counter() - t0)
            snap, _ = moved
        p0, p1 = np.asarray(snap["rest_lengths"], float), np.asarray(self.flat["rest_lengths"], float)
        change = float(np.max(np.abs(p1 / p0 - 1.0)))
        step = 1.0 / max(1, int(np.ceil(change / opts.max_relative_step)))
        # a small first Hessian shift: from a predicted state the shift search finds the least one that
        # factors, where the deployment's (1e-3) took ~20 halvings on the manta ray (benchmarks/app.py --edit)
        settings = {"sigma_factor": opts.sigma_factor}
        if opts.preview:
            settings.update(gradient_tolerance=self._newton.gradient_tolerance * opts.preview_tolerance_factor,
                            max_iterations=opts.max_iterations)
        newton = NewtonOptions(**{**self._newton.__dict__, **settings})
        t, steps, iterations, good = 0.0, 0, 0, snap
        while t < 1.0:
            if cancel is not None and cancel.is_set():
                raise Cancelled()
            t_next = min(1.0, t + step)
            restore(L, good)
            try:
                rest_length_predictor(L, p0 + t_next * (p1 - p0), fixed=self._pins, constraint_direction=self._a)
                report = minimize(L, fixed=self._pins, constraint=(self._a, angle), options=newton, callback=stop,
                                  saddle_hint=self._hint)
            except Cancelled:
                raise
            except Exception as exc:  # noqa: BLE001  (a step too far: a degenerate state; halve it)
                report = NewtonReport(message=f"{type(exc).__name__}: {exc}", iterations=0)
            iterations += report.iterations
            ok = (report.converged or (opts.preview and report.message.startswith("stopped after"))) \
                and report.iterations <= opts.max_iterations and np.isfinite(L.energy()) and not folded_joint(L)
            if ok:
                good, t, steps = snapshot(L), t_next, steps + 1
                continue
            step /= 2
            if step < opts.min_step:
                restore(L, self.flat)
                return WarmReport(False, f"the warm start did not converge ({report.message})", steps, iterations,
                                  time.perf_counter() - t0)
        if transferred and not opts.preview:
            # the new segment's soft modes: at the deployment's tolerance the state can lie 1e-6 of the span
            # from a cold deployment's (the same equilibrium, each inside the tolerance); a tighter polish
            polish = NewtonOptions(**{**newton.__dict__, "gradient_tolerance": 0.03 * newton.gradient_tolerance,
                                      "max_iterations": 12})
            iterations += minimize(L, fixed=self._pins, constraint=(self._a, angle), options=polish, callback=stop,
                                   saddle_hint=self._hint).iterations
        self._match_pinned_joint()
        info = self._info(not opts.preview, iterations, "preview" if opts.preview else "")
        self._store(angle, info)
        self.current_angle = angle
        # the same branch? the out-of-plane shape keeps its direction and the energy changes smoothly
        z_prev = previous.linkage.height_selector() @ before_x
        z_new = L.height_selector() @ L.get_vars()
        z_prev, z_new = z_prev - np.median(z_prev), z_new - np.median(z_new)
        flipped = bool(len(z_prev) == len(z_new) and z_prev @ z_new < 0)  # (joints added or removed: the energy says)
        energy_change = (info.energy - before.energy) / max(abs(before.energy), 1e-300)
        if abs(np.degrees(angle) - float(angle_deg)) > 1e-9:
            self.solve_to(angle_deg, cancel=cancel)
        return WarmReport(True, "warm start across a topology edit" if transferred else "warm start", steps, iterations,
                          time.perf_counter() - t0, flipped, float(energy_change))

    def _match_pinned_joint(self) -> None:
        """Move the state rigidly so that the pinned joint sits where this layout's flat state holds it.

        A deployment from the flat state pins the central joint's position and
        frame at their flat values; a state continued from another layout has
        them from that layout's flat state (they differ slightly: the flat
        frames come out of the rest-length solve). The rigid motion puts it in
        the same place as a cold deployment would.
        """
        from ..linkage.linkage import _rotate

        L = self.linkage
        j = int(self._pins[0]) // 9

        def frame(x, b0, n0):
            w = x[9 * j + 3: 9 * j + 6][None, :]
            b, n = _rotate(w, b0[j][None, :])[0], _rotate(w, n0[j][None, :])[0]
            return np.column_stack([b, n, np.cross(b, n)]), x[9 * j: 9 * j + 3]

        F1, c1 = frame(self.flat["x"], self.flat["joint_b0"], self.flat["joint_n0"])
        F0, c0 = frame(L.get_vars(), L.joint_b0, L.joint_n0)
        R = F1 @ F0.T
        L.apply_rigid_motion(R, c1 - R @ c0)

    def show_state(self, angle_rad: float) -> StateInfo:
        """Restore the stored state nearest ``angle_rad`` (for the animation) and return its info."""
        a, snap, info = self.nearest_state(angle_rad)
        restore(self.linkage, snap)
        self.current_angle = a
        return info

    def stability(self) -> tuple[float, float, float | None]:
        """At the current state: the smallest generalized eigenvalue of the free Hessian, the gap λ₂/λ₁, and the
        smallest eigenvalue with the average angle held (as ``xshells deploy``'s ``min_eigenvalue_at_fixed_angle``;
        None where the free one is positive: it is then no smaller, and the state stable either way).

        The deployment holds the angle: past the torque's limit point the free
        Hessian's lowest (opening) mode turns negative while the state is
        stable with the angle held (the boat at 62°: −3.6e-8 against +4.7e-8).
        """
        import scipy.sparse as sp

        L = self.linkage
        free = np.setdiff1d(np.arange(L.num_vars), self._pins)
        H = L.hessian()[free][:, free]
        M = L.mass_matrix()[free][:, free]
        lam, shift = smallest_eigenvalues(H, M, k=2, return_shift=True)
        if lam[0] > 0:  # H + ρ a aᵀ ≥ H: stable with the angle held too, no second solve (the slider path's cost)
            return float(lam[0]), float(lam[1] / lam[0]), None
        af = self._a[free]
        nz = np.flatnonzero(af)
        rho = 100.0 * float(np.abs(H.diagonal()).max()) / float(af @ af)
        A = sp.csr_matrix((np.full(len(nz) ** 2, rho * af[nz[0]] ** 2), (np.repeat(nz, len(nz)), np.tile(nz, len(nz)))),
                          shape=H.shape)
        held = float(smallest_eigenvalues((H + A).tocsr(), M, k=1, shift=shift or None)[0])
        return float(lam[0]), float(lam[1] / lam[0]) if lam[0] != 0 else float("inf"), held
