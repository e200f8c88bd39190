"""One editing session of the app, independent of the browser: project, edits, material, solves, exports.

The UI layer (:mod:`.ui`) only forwards user actions to a :class:`Session`
and draws what the session reports through its listeners:

* ``"project"`` — a design was opened (payload: its name); what was solved for the last one is gone;
* ``"layout"`` — the flat layout changed (payload: the :class:`Layout`);
* ``"problems"`` — topology problems (list of one-line messages);
* ``"material"`` — the material summary text;
* ``"flat"`` / ``"deployed"`` — a :class:`View` of the flat assembly state / the deployed state;
* ``"stability"`` — ``(λ_min, gap)`` at the shown deployed state;
* ``"status"`` — a one-line message (errors included);
* ``"upload"`` — what became of the last upload (opened, or why it was refused);
* ``"progress"`` — ``(fraction, text)`` of the running job;
* ``"opt_progress"`` — ``(iteration, value, text)`` of a running optimization or actuation;
* ``"optimized"`` / ``"actuated"`` — their outcomes; ``"task_failed"`` — why one of them failed.

Solves run on the session's :class:`~.worker.Worker`; a newer angle request
cancels the solve still running for an older one.
"""
from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from . import core, exports
from .loading import Project, UploadStore, grid_project, open_path
from .worker import Worker

FIELDS = {
    "bending energy": "bending_energy_density",
    "bending stress": "bending_stress",
    "twisting energy": "twisting_energy_density",
    "stretching stress": "stretching_stress",
}


@dataclass(frozen=True)
class View:
    """What the 3D view draws for one state: the swept beam mesh and a scalar field on it."""

    vertices: np.ndarray
    triangles: np.ndarray
    field: np.ndarray
    field_name: str
    joints: np.ndarray
    info: object  # .sim.StateInfo
    solve_time_s: float = 0.0
    joint_vertices: np.ndarray | None = None  # (n_joints,) the layout vertex of each row of ``joints``


class _BuildCancel:
    """The cancel check of an assembly solve: the job's cancel event, honoured only while ``applies()`` says so."""

    def __init__(self, cancel: threading.Event, applies):
        self._cancel, self._applies = cancel, applies

    def is_set(self) -> bool:
        return self._cancel.is_set() and self._applies()


SIM_CACHE = 4  # simulations kept for undo/redo (each holds its deployed states)


def spec_summary(spec: dict) -> str:
    """A material spec as one line, before its stiffnesses are computed (that needs the section's torsion solve)."""
    params = ", ".join(f"{float(v):g}" for v in spec.get("params", []))
    return (f"{spec.get('type', 'rectangle')} {params}, E = {float(spec.get('E', 20000.0)):.4g}, "
            f"ν = {float(spec.get('nu', 0.3)):.3g}  \nstiffnesses: computed with the first solve")


def stability_text(lam_free: float, gap: float, lam_held: float | None) -> str:
    """The stability readout, as ``xshells deploy`` judges it: with the average angle held (the deployment's control).

    The free Hessian's smallest eigenvalue says whether the state also holds
    under a fixed torque; its gap λ₂/λ₁ means something only when λ₁ > 0.
    ``lam_held`` None: not computed, the free one being positive (the held one is no smaller).
    """
    if lam_held is None:
        return (f"stability: stable, with the angle held and under a fixed torque "
                f"(λmin {lam_free:.3g}, gap λ2/λ1 {gap:.3g})")
    held = "stable" if lam_held > 0 else "unstable"
    text = f"stability: {held} with the angle held (λmin {lam_held:.3g})"
    if lam_free > 0:
        return text + f"; under a fixed torque too (λmin {lam_free:.3g}, gap λ2/λ1 {gap:.3g})"
    return text + f"; under a fixed torque it would snap (free λmin {lam_free:.3g}: past the torque's limit point)"


def material_summary(material) -> str:
    """Stiffnesses of a material as one short Markdown block."""
    B1, B2 = material.bending_stiffness
    return (f"A = {material.area:.4g}, E = {material.E:.4g}, ν = {material.nu:.3g}, G = {material.G:.4g}  \n"
            f"stretching EA = {material.stretching_stiffness:.4g}  \n"
            f"bending EI = {B1:.4g}, {B2:.4g}  \n"
            f"twisting GJ = {material.twisting_stiffness:.4g}")


class Session:
    """State and actions of the design tool.

    Parameters
    ----------
    project : Project
    out_dir : str
        Folder that exports are written into.
    """

    def __init__(self, project: Project, out_dir: str = "xshells_app_out"):
        self.out_dir = out_dir
        self.uploads = UploadStore()
        self.listeners: list = []
        self.worker = Worker(on_progress=lambda f, t: self._emit("progress", (f, t)))
        self._lock = threading.RLock()
        self.field_name = "bending energy"
        self.sim = None  # a .sim.Simulation, built on the worker (the solver is imported there)
        self._sim_key = None
        self.last_deployed: View | None = None
        self.angle_deg: float | None = None
        self.live = True  # re-solve the deployed state after every edit (warm-started where the topology is kept)
        self.last_warm = None  # the .sim.WarmReport of the last edit, or None after a cold deployment
        self.alternative = None  # a cold deployment on another branch than the shown one (check_branch)
        self._pending_solve = None  # ((layout key, angle), token) of the solve queued or running
        self._sims: list = []  # recent simulations [(key, layout, sim)], so that an undo finds its state again
        self._opt_stop = threading.Event()
        self.export_note = ""
        self.compare_cold = True  # compare an optimized design's state with a cold deployment (as `xshells deploy`'s)
        self._cancel_generation = 0  # counts the user's Cancels (and loads): they stop an assembly solve too
        self.load(project)

    # ------------------------------------------------------------------ events
    def _emit(self, event: str, payload=None) -> None:
        for fn in list(self.listeners):
            try:
                fn(event, payload)
            except Exception as exc:  # a drawing error must not break the session
                if event != "status":
                    self._emit("status", f"display error: {exc}")

    def status(self, text: str) -> None:
        self._emit("status", text)

    # ------------------------------------------------------------------ project
    def load(self, project: Project) -> None:
        """Make ``project`` current (resets undo history and the simulation)."""
        self._cancel_generation += 1
        self.worker.cancel_all()
        with self._lock:
            self.project = project
            self.name = project.name
            self.history = core.History(project.layout)
            # a design opened with beams of one family crossing is layered by intent: its edits may keep them
            self._layered = any(p.endswith(core.FAMILY_CROSSING) for p in core.topology_problems(project.layout))
            self._pairing = {}  # how the beams pass through each joint, as drawn: edits must keep it (core.repairings)
            self.subdivision = project.subdivision
            self.rest_lengths = project.rest_lengths
            self._optimized = False  # the rest lengths came from an optimization (its state was continued, not deployed cold)
            # a design that is not flat: every deployed status keeps saying so (the opening line is soon replaced)
            self._not_flat = next((part.removeprefix("warning: ").split(":")[0] for part in (project.note or "").split("; ")
                                   if "not flat" in part), None)
            self.target_angle_deg = project.target_angle_deg
            self.material_spec = dict(project.material)
            self._material = None  # built on the worker, with the first solve
            self.sim, self._sim_key, self.last_deployed, self.angle_deg = None, None, None, None
            self._sims, self._pending_solve = [], None
        self._emit("project", project.name)
        self._emit("material", spec_summary(self.material_spec))
        self._layout_changed()
        # a .3dm's layer and units (converted to mm) are said, as the command line says them
        self.status(f"opened {project.name}: {project.layout.num_segments} segments"
                    + (f" ({project.note})" if project.note else ""))

    def open_path(self, path: str) -> None:
        self.load(open_path(path))

    def open_upload(self, name: str, content: bytes) -> bool:
        """Open an uploaded file; a bad upload only produces a message (``"upload"`` and status). Returns success."""
        try:
            self.load(self.uploads.open_upload(name, content))
            note = self.project.note
            self._emit("upload", f"opened {os.path.basename(str(name))}" + (f" ({note})" if note else ""))
            return True
        except InputError as exc:
            self.upload_refused(str(exc))
        except Exception as exc:  # noqa: BLE001  (malformed input must never crash the app)
            self.upload_refused(f"{os.path.basename(str(name))}: cannot read it ({type(exc).__name__})")
        return False

    def upload_refused(self, why: str) -> None:
        """Report a refused upload: in the status line and as the ``"upload"`` event (kept beside the upload button)."""
        self._emit("upload", f"upload refused: {why}")
        self.status(f"upload refused: {why}")

    def new_grid(self, nx: int, ny: int, angle_deg: float) -> None:
        self.load(grid_project(int(nx), int(ny), float(angle_deg)))

    @property
    def layout(self) -> core.Layout:
        return self.history.current

    # ------------------------------------------------------------------ edits
    def edit(self, fn, *args) -> bool:
        """Apply ``fn(layout, *args)`` and record it for undo; an invalid edit shows a message. Returns success."""
        try:
            new = fn(self.layout, *args)
        except InputError as exc:
            self.status(str(exc))
            return False
        with self._lock:
            before = self.history.current
            self.history.push(new)
            if new.num_segments != before.num_segments:
                self.rest_lengths = None  # per-segment data no longer matches
        self._layout_changed()
        # the status line follows every edit (a click's "click its other end" must not stay), and a problem the
        # edit made is said there, where it is seen, not only in the Edit panel below
        what = getattr(fn, "__name__", "edit").replace("_", " ")
        what = "edit" if what.startswith("<") else what
        problems = self.problems()
        if problems:
            more = f" (and {len(problems) - 1} more, listed under Edit)" if len(problems) > 1 else ""
            self.status(f"{what}: the layout cannot be simulated: {problems[0]}{more}")
        else:
            self.status(f"{what}: done ({new.num_vertices} joints, {new.num_segments} segments)")
        self._follow_edit()
        return True

    def undo(self) -> None:
        self.history.undo()
        self._layout_changed()
        self._follow_edit()

    def redo(self) -> None:
        self.history.redo()
        self._layout_changed()
        self._follow_edit()

    def _follow_edit(self) -> None:
        """Live editing: bring the deployed view back for the edited layout (warm-started when it can be)."""
        if self.live and self.angle_deg is not None and not self.problems():
            self.request_angle(self.angle_deg)

    def preview(self, layout: core.Layout) -> None:
        """While a joint is dragged: the deployed view of ``layout`` (not recorded for undo), the latest position winning.

        Solved warm from the last state with a looser tolerance. A preview
        is not interrupted by the next drag position (it would never finish
        while the mouse moves): the latest position waits and is solved next.
        The edit on release (:meth:`edit`) solves to full accuracy from it.
        """
        self._preview(layout)

    def _preview(self, layout: core.Layout, since: int | None = None) -> None:
        """:meth:`preview`; ``since``: the full-solve count a finished preview saw when it asked for the next one."""
        if self.angle_deg is None or self._problems(layout):
            return
        with self._lock:
            current = self.layout
            if np.array_equal(layout.vertices, current.vertices) and np.array_equal(layout.edges, current.edges):
                # the layout recorded (a drag's release): the full-accuracy solve shows it. A drag update that
                # viser runs after the release (its callbacks run in a thread pool) reads the released position
                # and asked for this; its preview, shown after the full solve, was the final state (CI, 2026-12-07)
                return
            generation = getattr(self, "_full_solves", 0)
            if since is not None and since != generation:
                # a full-accuracy solve was asked for after that preview's check and before this call (another
                # thread): the waiting position is superseded, and a preview queued behind the full solve would
                # be shown after it as the final state (CI, 2026-12-07)
                return
            self._preview_next = layout
            if getattr(self, "_preview_busy", False):
                return
            self._preview_busy = True
        angle = self.angle_deg

        def job(cancel, progress):
            with self._lock:
                lay, self._preview_next = self._preview_next, None
            if lay is None:
                return None
            t0 = time.perf_counter()
            sim = self._sim_for(lay, ("preview", id(lay)), cancel, angle, preview=True)
            if sim is None:
                return None
            info = sim.solve_to(angle, cancel=cancel)
            return self._view(sim, t0, info)

        def done(view):
            with self._lock:
                self._preview_busy = False
                # a preview that finishes after a full-accuracy solve began (its cancel came too late) is stale
                stale = getattr(self, "_full_solves", 0) != generation
                waiting = None if stale else self._preview_next
            if view is not None and not stale:
                self._deployed(view, stability=False)
            if waiting is not None:
                self._preview(waiting, since=generation)

        def failed(exc):
            with self._lock:
                self._preview_busy = False
            self._job_error(exc)

        self.worker.submit(job, key="preview", on_done=done, on_error=failed)

    def problems(self) -> list[str]:
        return self._problems(self.layout)

    def _problems(self, layout) -> list[str]:
        return core.topology_problems(layout, allow_crossings=getattr(self, "_layered", False),
                                      pairing=getattr(self, "_pairing", None))

    def _layout_changed(self) -> None:
        self._emit("layout", self.layout)
        problems = self.problems()
        if not problems:
            # a sound layout's joints (new ones, or with other neighbours) join the pairing that edits must keep;
            # a joint deleted renumbers the vertices, and the pairing starts again from this layout
            layout = self.layout
            kept = getattr(self, "_pairing", {})
            if getattr(self, "_pairing_size", None) != layout.num_vertices:
                kept = {}
            self._pairing = {**kept, **core.beam_pairing(layout, core.analyzed(layout))}
            self._pairing_size = layout.num_vertices
        self._emit("problems", problems)

    # ------------------------------------------------------------------ material
    @staticmethod
    def _build_material(spec: dict):
        """As :func:`xshells.deploy.case.material_from_spec`, without importing the solver at start-up."""
        from ..section import Material

        kind = spec.get("type", "rectangle")
        E, nu = float(spec.get("E", 20000.0)), float(spec.get("nu", 0.3))
        if kind == "contour":
            return Material.from_file(spec["contour_file"], young=E, poisson=nu, stiff_axis=spec.get("stiff_axis"))
        return Material.uniform(kind, spec.get("params", []), E=E, nu=nu, stiff_axis=spec.get("stiff_axis"))

    @property
    def material(self):
        """The current :class:`~xshells.section.Material`, built on first use.

        Building it runs the section's torsion solve (and imports SciPy and
        scikit-fem), so the session does it on the worker, not at start-up.
        """
        with self._lock:
            spec, m = self.material_spec, self._material
        if m is not None:
            return m
        m = self._build_material(spec)
        with self._lock:
            if self.material_spec is not spec:  # changed meanwhile: that one wins
                return self._material if self._material is not None else m
            fresh = self._material is None
            if fresh:
                self._material = m
            m = self._material
        if fresh:
            self._emit("material", material_summary(m))
        return m

    def set_material(self, kind: str, params, E: float, nu: float, subdivision: int | None = None) -> bool:
        """Change the cross-section, elastic constants (and edges per segment); a bad value only shows a message.

        A value out of range is refused, naming the field and its range, and
        nothing changes (the page's fields do not clamp it to another value).
        """
        E, nu = float(E), float(nu)
        why = None
        if not (np.isfinite(E) and E > 0):
            why = f"E must be a positive number (MPa), got {E:g}"
        elif not (np.isfinite(nu) and -1.0 < nu < 0.5):
            why = f"ν must lie strictly between -1 and 0.5, got {nu:g}"
        elif subdivision is not None:
            why = self._subdivision_problem(subdivision)
        if why:
            self.status(f"material: {why}; the previous material is kept")
            return False
        spec = {"type": kind, "params": [float(v) for v in params], "E": E, "nu": nu}
        try:
            material = self._build_material(spec)
        except (InputError, ValueError) as exc:
            self.status(f"material: {exc}")
            return False
        with self._lock:
            self.material_spec, self._material = spec, material
            if subdivision is not None:
                self.subdivision = int(subdivision)
        self._emit("material", material_summary(material))
        return True

    MAX_SUBDIVISION = 30

    @classmethod
    def _subdivision_problem(cls, k) -> str | None:
        kf = float(k)
        if not (np.isfinite(kf) and kf == int(kf) and 3 <= kf <= cls.MAX_SUBDIVISION):
            return f"edges per segment must be a whole number from 3 to {cls.MAX_SUBDIVISION}, got {kf:g}"
        return None

    def set_subdivision(self, k: int) -> bool:
        """Set the edges per segment (3 to 30); a bad value is refused with a message and changes nothing."""
        why = self._subdivision_problem(k)
        if why:
            self.status(f"material: {why}; the previous value ({self.subdivision}) is kept")
            return False
        self.subdivision = int(k)
        return True

    # ------------------------------------------------------------------ simulation
    def _key(self):
        # values, not ids: an id is reused once its object is freed, and a changed material (or rest lengths)
        # would then find a stale simulation. The layout's id is safe: the cached simulation holds its layout.
        spec = self.material_spec
        material = (spec.get("type"), tuple(float(v) for v in spec.get("params", [])), float(spec.get("E", 20000.0)),
                    float(spec.get("nu", 0.3)), str(spec.get("stiff_axis")), str(spec.get("contour_file")))
        return (id(self.layout), material, self.subdivision,
                None if self.rest_lengths is None else np.asarray(self.rest_lengths, float).tobytes())

    def _ensure_sim(self, cancel, angle_deg: float | None = None):
        """The simulation of the current layout and material, building it if stale (warm-started at ``angle_deg``)."""
        with self._lock:
            key, layout = self._key(), self.layout
            if self.sim is not None and self._sim_key == key:
                return self.sim
        return self._sim_for(layout, key, cancel, angle_deg)

    def _sim_for(self, layout, key, cancel, angle_deg: float | None = None, preview: bool = False):
        """Build the simulation of ``layout``: its assembly state, then, when the last simulation has the same
        segments and material and a deployed state, that state continued to this layout at ``angle_deg``
        (:meth:`.sim.Simulation.warm_start`). Otherwise, or if that fails, the deployment starts from the flat
        state, and the status line says why."""
        with self._lock:
            k, p, previous = self.subdivision, self.rest_lengths, self.sim
            if previous is not None and self._sim_key == key:
                return previous
            cached = next((sim for kk, lay, sim in self._sims if kk == key and lay is layout), None)
            if cached is not None:  # an undo or redo back to a layout solved before
                self.sim, self._sim_key, self.last_warm, self.alternative = cached, key, None, None
                return cached
        problems = self._problems(layout)
        if problems:
            raise InputError("cannot simulate: " + problems[0])
        self._emit("progress", (0.02, "loading the solver…"))
        from .sim import Simulation, WarmOptions  # the first time: SciPy and the solver (about a second)

        self._emit("progress", (0.05, "cross-section stiffnesses…"))
        material = self.material
        if cancel is not None and cancel.is_set():
            from .sim import Cancelled
            raise Cancelled()
        self._emit("progress", (0.1, f"assembly state ({layout.num_segments} segments)…"))
        sim = Simulation(layout, material, k, rest_lengths=p, settings=self._settings(), cancel=cancel)
        self._emit("flat", self._view(sim, time.perf_counter()))  # the flat assembly state of the edited layout
        warm = None
        if angle_deg is not None and previous is not None and previous.states[1:]:
            if sim.can_warm_start_from(previous):
                self._emit("progress", (0.5, "continuing the deployed state to the edited layout…"))
                warm = sim.warm_start(previous, angle_deg, cancel=cancel, options=WarmOptions(preview=preview))
                if not warm.ok:
                    self.status(f"{warm.message}: deploying from the flat state")
            else:
                self.status("the material or subdivision changed: deploying from the flat state")
        if preview and (warm is None or not warm.ok):
            return None  # no preview for this position: never a deployment from flat while dragging
        with self._lock:
            self.sim, self._sim_key = sim, key
            self.last_warm = warm if warm is not None and warm.ok else None
            self.alternative = None
            if key[0] != "preview":
                self._sims = [e for e in self._sims if e[0] != key][-(SIM_CACHE - 1):] + [(key, layout, sim)]
        return sim

    def _guide_for(self, layout):
        """The project's guide where ``layout`` has as many joints as it has rows (an edit that adds or removes
        joints leaves it out), else None."""
        guide = self.project.guide
        if guide is None:
            return None
        from ..linkage.graph import analyze
        from .core import layout_to_design

        return guide if analyze(layout_to_design(layout)).num_joints == len(guide) else None

    def _settings(self):
        """The simulation settings of the project: its buckling direction and deployment steps, as ``xshells deploy``'s."""
        from .sim import SimSettings

        return SimSettings(direction=self.project.direction, steps=self.project.steps, guide=self.project.guide)

    def _view(self, sim, t0: float, info=None) -> View:
        from ..linkage.export import scalar_fields, swept_mesh

        fields = scalar_fields(sim.linkage)
        mesh = swept_mesh(sim.linkage, fields)
        name = FIELDS.get(self.field_name, "bending_energy_density")
        f = mesh.fields.get(name, np.zeros(len(mesh.vertices)))
        return View(mesh.vertices, mesh.triangles, np.sqrt(np.maximum(f, 0)) if "energy" in name else f, self.field_name,
                    sim.linkage.joint_positions(), info or sim.flat_info, time.perf_counter() - t0,
                    np.asarray(sim.linkage.graph.joint_vertex))

    def prepare(self) -> None:
        """Build the simulation in the background (assembly state and flat view)."""
        self.worker.submit(lambda cancel, progress: self._ensure_sim(cancel), key="solve", on_error=self._job_error)

    def request_angle(self, angle_deg: float) -> None:
        """Re-solve the deployed equilibrium at ``angle_deg`` in the background (latest request wins)."""
        self.angle_deg = float(angle_deg)

        request = (self._key(), float(angle_deg))
        generation = self._cancel_generation

        def job(cancel, progress):
            t0 = time.perf_counter()
            # a newer angle for the same design does not stop the assembly state being built (the newer
            # request needs it too); Cancel, another design, material or rest lengths do
            build_cancel = _BuildCancel(cancel, lambda: self._cancel_generation != generation or self._key() != request[0])
            sim = self._ensure_sim(build_cancel, angle_deg)
            info = sim.solve_to(angle_deg, cancel=cancel,
                                progress=lambda f, text: progress(f, f"deploying to {angle_deg:.1f}°: at {text}"))
            view = self._view(sim, t0, info)
            return view

        with self._lock:
            if self._pending_solve is not None and self._pending_solve[0] == request:
                return  # the same layout and angle is being solved already (an edit follows itself, then asks again)
        self.worker.cancel("branch")  # a comparison of the state before is moot
        with self._lock:  # and so is a drag's preview
            self._preview_next, self._preview_busy = None, False
            self._full_solves = getattr(self, "_full_solves", 0) + 1
        self.worker.cancel("preview")
        token = object()

        def finished(view=None):
            with self._lock:
                if self._pending_solve is not None and self._pending_solve[1] is token:
                    self._pending_solve = None

        def done(view):
            finished()
            self._deployed(view)

        def failed(exc):
            from .sim import Cancelled

            with self._lock:
                newer = self._pending_solve
            finished()
            if isinstance(exc, Cancelled) and newer is not None and newer[1] is not token:
                # superseded, not cancelled: the newer request runs next, and the bar goes on with it
                self.status(f"the solve for {angle_deg:.1f}° was superseded: solving for {newer[0][1]:.1f}° instead")
                self._emit("progress", (0.05, f"restarting for {newer[0][1]:.1f}°…"))
                return
            self._job_error(exc)

        with self._lock:
            self._pending_solve = (request, token)
        self.worker.submit(job, key="solve", on_done=done, on_error=failed)

    def _deployed(self, view: View, stability: bool = True) -> None:
        self.last_deployed = view
        self._emit("deployed", view)
        msg = view.info.message or f"deployed to {view.info.angle_deg:.1f}° in {view.solve_time_s:.2f} s"
        warm = self.last_warm
        if warm is not None and not view.info.message:
            msg += f" ({warm.message} from the last layout: {warm.steps} step{'s' * (warm.steps != 1)}, {warm.iterations} iterations)"
            if warm.flipped or abs(warm.energy_change) > 0.5:
                msg += ("; the shape flipped" if warm.flipped else f"; the energy changed by {100 * warm.energy_change:+.0f} %") \
                    + ": another branch? Compare with a cold deployment"
        if self._not_flat:
            msg += f" ({self._not_flat}: this is its projection onto that plane)"
        self._emit("progress", (1.0, "done"))
        self.status(msg)
        if stability:
            self.worker.submit(self._stability_job, key="stability", on_error=lambda e: None)

    def check_branch(self) -> None:
        """Deploy the current layout from its flat state (as a cold start would) and compare with the shown state.

        Emits ``"branch"`` with ``{"same": bool, "difference": max joint distance / span, "energy_shown",
        "energy_cold", "flipped", "cold_converged", "cold_message"}``; when they differ, the cold state is
        kept as :attr:`alternative` and :meth:`choose_branch` switches to it.

        Only a converged shown state is compared, and only with a converged
        cold one: a deployment that stopped short was "agreed" with by a cold
        one stopped at the same flat state (joints 0 apart), and that line
        replaced the status line's reason why it stopped. A cold deployment
        that stops is reported as such, with its reason, and is no branch to switch to.
        """
        angle = self.angle_deg
        if angle is None:
            return

        def job(cancel, progress):
            from .sim import Simulation

            with self._lock:
                shown, key, layout, k, p = self.sim, self._sim_key, self.layout, self.subdivision, self.rest_lengths
                view = self.last_deployed
            if shown is None or key != self._key() or view is None or not view.info.converged:
                return None  # nothing solved, or a state that stopped short: its status line stays
            cold = Simulation(layout, self.material, k, rest_lengths=p, settings=self._settings(),
                              cancel=cancel)
            info = cold.solve_to(angle, cancel=cancel,
                                 progress=lambda f, text: progress(f, f"cold deployment for comparison: at {text}"))
            P, Q = shown.linkage.joint_positions(), cold.linkage.joint_positions()
            span = float(np.ptp(layout.vertices, axis=0).max())
            diff = float(np.abs(P - Q).max()) / span
            zs, zc = (L.height_selector() @ L.get_vars() for L in (shown.linkage, cold.linkage))
            result = {"same": info.converged and diff <= 1e-6, "difference": diff, "energy_shown": shown.linkage.energy(),
                      "energy_cold": info.energy, "flipped": bool((zs - np.median(zs)) @ (zc - np.median(zc)) < 0),
                      "angle_deg": angle, "cold_converged": info.converged, "cold_message": info.message}
            with self._lock:
                if self.sim is not shown or self.last_deployed is not view:
                    return None  # edited or re-solved meanwhile: the comparison is stale
                self.alternative = None if result["same"] or not info.converged else (cold, key)
            return result

        def done(result):
            if result is None:
                return
            self._emit("branch", result)
            if not result["cold_converged"]:
                self.status(f"a cold deployment to {angle:.1f}° did not get there, no comparison: {result['cold_message']}")
            elif result["same"]:
                self.status(f"a cold deployment agrees (joints within {result['difference']:.1e} of the span)")
            else:
                self.status(f"two branches: shown energy {result['energy_shown']:.6g}, cold deployment "
                            f"{result['energy_cold']:.6g} (joints up to {100 * result['difference']:.2g} % of the span apart)")

        self.worker.submit(job, key="branch", on_done=done, on_error=self._job_error)

    def choose_branch(self, which: str) -> None:
        """``"cold"``: show the cold deployment found by :meth:`check_branch` instead; ``"shown"``: keep the current one."""
        with self._lock:
            alt = self.alternative
            if which == "shown" or alt is None:
                self.alternative = None
                return
            cold, key = alt
            if key != self._key():
                self.alternative = None
                return
            previous = self.sim
            self.sim, self.alternative = cold, (previous, key)  # the other one stays available to switch back
            self.last_warm = None
        self.request_angle(self.angle_deg)

    def _stability_job(self, cancel, progress):
        sim = self.sim
        if sim is None or cancel.is_set():
            return
        self._emit("stability", sim.stability())

    def _job_error(self, exc: BaseException) -> None:
        from .sim import Cancelled

        if isinstance(exc, Cancelled):
            self.status("solve cancelled")
        elif isinstance(exc, InputError):
            self.status(str(exc))
        else:
            self.status(f"solve failed: {type(exc).__name__}: {exc}")
        self._emit("progress", (0.0, "stopped"))

    def cancel(self) -> None:
        with self._lock:
            self._cancel_generation += 1
            self._pending_solve = None
        self._opt_stop.set()
        self.worker.cancel_all()

    # ------------------------------------------------------------------ optimize / actuate
    def optimize(self, angle_deg: float, max_iterations: int = 10) -> None:
        """Design optimization on the worker (:func:`.adapters.run_optimize`) for a deployment at ``angle_deg``.

        Starts from the current rest lengths, so running it again resumes.
        Emits ``"opt_progress"`` ``(iteration, J, text)`` per iteration and
        ``"optimized"`` (:class:`~.adapters.OptimizeOutcome`) at the end;
        the new rest lengths then become the design's and it is re-deployed
        to ``angle_deg``. :meth:`stop_optimization` stops after the current iteration.
        """
        from . import adapters

        self._opt_stop = stop = threading.Event()

        def job(cancel, progress):
            sim = self._ensure_sim(cancel)
            sim.show_state(sim.flat_angle)

            def step(it, value, text):
                if cancel.is_set():
                    stop.set()
                self._emit("opt_progress", (it, value, text))
                progress(min(1.0, it / max(1, max_iterations)), f"optimizing: iteration {it}, {text}")

            return adapters.run_optimize(sim.linkage, np.radians(float(angle_deg)), progress=step, cancel=stop,
                                         max_iterations=max_iterations)

        def done(out) -> None:
            before = out.rest_lengths_before
            if before is not None and np.array_equal(np.asarray(out.rest_lengths), np.asarray(before)):
                # nothing changed: the design stays exactly as it was (rest lengths "of its own" would hold the
                # flat state differently, and the next run, the exported case and its deployment would differ)
                self._emit("optimized", out)
                self.status(f"optimization: {out.message}; rest lengths unchanged, the design stays as it was")
                self.request_angle(angle_deg)
                return
            with self._lock:
                self.rest_lengths = out.rest_lengths
                self._optimized = True
            self._emit("optimized", out)
            self.status(f"optimization: {out.message}; deploying the optimized design")
            self.request_angle(angle_deg)
            if self.compare_cold:
                # the optimized design's state is continued from the one before; `xshells deploy` of its case
                # deploys it from flat (the boat's came out a mirrored dome): compare, and say so if they differ
                self.check_branch()

        self.worker.submit(job, key="optimize", on_done=done, on_error=lambda e: self._task_error("optimization", e))

    def stop_optimization(self) -> None:
        self._opt_stop.set()

    def actuate(self, max_iterations: int = 20) -> bool:
        """Sparse actuation on the worker (:func:`.adapters.run_actuate`) at the shown deployed state.

        Emits ``"opt_progress"`` per iteration, then ``"deployed"`` with the
        sparsely actuated equilibrium and ``"actuated"`` ``(outcome, joints)``
        (joint positions there). Returns False when nothing is deployed yet.
        """
        from . import adapters

        view, sim = self.last_deployed, self.sim
        if view is None or sim is None:
            self.status("deploy first (move the angle slider), then actuate")
            return False
        self._opt_stop = stop = threading.Event()

        def job(cancel, progress):
            sim.show_state(np.radians(view.info.angle_deg))

            def step(it, value, text):
                if cancel.is_set():
                    stop.set()
                self._emit("opt_progress", (it, value, text))
                progress(min(1.0, it / max(1, max_iterations)), f"actuation: iteration {it}, {text}")

            t0 = time.perf_counter()
            out = adapters.run_actuate(sim.linkage, view.info.torque, progress=step, cancel=stop,
                                       max_iterations=max_iterations)
            if out.state is not None:  # shown: the sparse equilibrium (the selection hands the linkage back dense;
                from ..linkage.state import restore  # the next actuation starts from show_state's dense one again)

                restore(sim.linkage, out.state)
            info = sim._info(out.success, 0, f"sparse actuation: {len(out.actuated)} actuated joints")
            return out, self._view(sim, t0, info)

        def done(res) -> None:
            out, shown = res
            self._emit("deployed", shown)
            self._emit("actuated", (out, shown.joints))
            self.status(f"actuation: {len(out.actuated)} of {len(out.torques)} joints actuated; {out.message}")

        self.worker.submit(job, key="optimize", on_done=done, on_error=lambda e: self._task_error("actuation", e))
        return True

    def _task_error(self, what: str, exc: BaseException) -> None:
        text = f"{what}: {exc}" if isinstance(exc, (InputError, NotImplementedError)) else f"{what}: {type(exc).__name__}: {exc}"
        self._emit("task_failed", text)
        self.status(text)
        self._emit("progress", (0.0, "stopped"))

    def animation_frames(self) -> list[float]:
        """Angles (radians) of the stored deployed states, for the deployment animation."""
        return [] if self.sim is None else [a for a, _, _ in self.sim.states]

    def show_frame(self, angle_rad: float) -> None:
        """Show the stored state nearest ``angle_rad`` (runs on the worker)."""
        def job(cancel, progress):
            sim = self.sim
            t0 = time.perf_counter()
            info = sim.show_state(angle_rad)
            return self._view(sim, t0, info)

        if self.sim is not None:
            self.worker.submit(job, key="solve", on_done=lambda v: self._emit("deployed", v), on_error=self._job_error)

    def set_field(self, name: str) -> None:
        self.field_name = name
        if self.angle_deg is not None:
            self.request_angle(self.angle_deg)

    # ------------------------------------------------------------------ exports
    def _path(self, suffix: str) -> str:
        os.makedirs(self.out_dir, exist_ok=True)
        safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in self.name) or "xshell"
        return os.path.join(self.out_dir, safe + suffix)

    def _rest_lengths(self):
        with self._lock:
            if self.sim is not None and self._sim_key == self._key():
                return self.sim.linkage.rest_lengths.copy()
            return self.rest_lengths

    def export(self, kind: str) -> list[str]:
        """Write one export into ``out_dir``: ``svg``, ``dxf``, ``cutlist``, ``strips``, ``obj``, ``ply``, ``gltf``, ``glb``,
        ``case`` or ``png``.

        Mesh and PNG exports need a solved state (the last shown deployed
        state, else the flat assembly state). Returns the paths written.
        """
        layout, p = self.layout, self._rest_lengths()
        self.export_note = ""  # what the status line adds about the files written (the state they hold)
        if kind in ("svg", "dxf"):
            path = self._path(f"_flat.{kind}")
            (exports.write_svg if kind == "svg" else exports.write_dxf)(path, layout, p)
            return [path]
        if kind in ("cutlist", "strips"):
            path = self._path("")
            return exports.write_fabrication_files(os.path.dirname(path), os.path.basename(path), layout, self.material,
                                                   p, kind)
        if kind == "case":
            # Rest lengths only where the design has its own (opened with it, or optimized): those from the
            # rest-length solve are left to `xshells deploy` to solve again. Given instead, they hold the flat
            # state differently (the pinned joint's frame as drawn, not as solved), and the deployed joints
            # came out rotated against the shown ones by 3.2e-3 of the span (manta ray at 90°).
            with self._lock:
                given, optimized, warm = self.rest_lengths, self._optimized, self.last_warm
            if given is not None and optimized and warm is not None:
                self.export_note = ("the case holds the optimized rest lengths: the shown state was continued from the "
                                    "design before, while `xshells deploy` deploys it from its flat state and may reach "
                                    "another branch (*Compare with a cold deployment* shows which)")
            return exports.write_case(self._path(".json"), self.name, layout, self.material_spec, self.subdivision,
                                      self.angle_deg if self.angle_deg is not None else self.target_angle_deg, given,
                                      direction=self.project.direction, steps=self.project.steps,
                                      guide=self._guide_for(layout))
        if kind in ("obj", "ply", "gltf", "glb", "png"):
            sim = self.sim
            if sim is None:
                raise InputError("nothing solved yet: move the angle slider first")
            # the files are named after the state they hold: a deployment that stopped short is no "deployed" shape
            view = self.last_deployed
            if view is None or self.angle_deg is None:
                path = self._path(f"_flat_state.{kind}")
                self.export_note = "nothing deployed yet: the files hold the flat assembly state"
            elif not view.info.converged or abs(view.info.angle_deg - self.angle_deg) > 0.05:
                path = self._path(f"_stopped_at_{view.info.angle_deg:.1f}deg.{kind}")
                self.export_note = (f"the deployment did not reach {self.angle_deg:.1f}°: the files hold the state "
                                    f"where it stopped ({view.info.angle_deg:.1f}°)"
                                    + (f": {view.info.message}" if view.info.message else ""))
            else:
                path = self._path(f"_deployed.{kind}")
            done = threading.Event()
            err: list = []

            def job(cancel, progress):  # the linkage belongs to the worker thread
                try:
                    if kind == "png":
                        exports.write_png(path, sim.linkage, title=f"{self.name}: {np.degrees(sim.linkage.average_angle()):.1f}°")
                    else:
                        from ..linkage.export import swept_mesh
                        exports.write_mesh(path, swept_mesh(sim.linkage), field="bending_energy_density")
                except BaseException as exc:  # noqa: BLE001
                    err.append(exc)
                finally:
                    done.set()

            self.worker.submit(job, key="export")
            done.wait(120)
            if err:
                raise err[0]
            return [path]
        raise InputError(f"unknown export {kind!r}")

    def close(self) -> None:
        self.worker.close()
