"""The thin viser layer of ``xshells app``: GUI panels and the 3D scene, drawing what a :class:`Session` reports.

The scene shows the flat layout (left: editable lines and joints over the
swept flat assembly state) and the deployed state (right: swept beams with
the true cross-section, coloured by the chosen field) side by side, in scene
units where the layout's span is 2. All solving runs on the session's
worker; callbacks here only forward actions, so the page never freezes.
"""
from __future__ import annotations

import glob
import os
import threading
import time

import numpy as np

from ..errors import InputError
from . import adapters, core, hover
from .session import FIELDS, Session, View, material_summary, spec_summary, stability_text

EXAMPLES_DIR = os.path.join(os.path.dirname(__file__), "..", "data", "examples")
MODES = ("view / orbit", "move joint", "brush", "cage", "add joint", "add segment", "delete joint", "delete segment")
SYMMETRY = {"off": None, "mirror left–right": "x", "mirror top–bottom": "y"}
MODE_HINTS = {
    "view / orbit": "drag to orbit, scroll to zoom",
    "move joint": "click a joint on the flat layout (left), then drag its handle; the deployed view follows",
    "brush": "click where to brush, then drag the handle: joints within the radius follow, with a smooth falloff",
    "cage": "click a cage handle (grey), then drag it: the layout deforms smoothly",
    "add joint": "click on the flat layout to place a joint (joined to the last one added)",
    "add segment": "click the two joints to join",
    "delete joint": "click a joint to delete it and its segments",
    "delete segment": "click a segment to delete it",
}
SECTION_TYPES = ("rectangle", "ellipse", "I", "L", "+")
PLAN_FOV = np.radians(8.0)  # the plan view: a narrow field of view from far above, nearly orthographic
PLAN_HALF_HEIGHT = 1.15  # scene units from the view's centre to its top edge (the layout spans 2)
GAP = 1.25  # scene units between the centre of each half and the origin
PANEL_PX = 400  # viser's control panel with its margin, at its default width (it floats over the canvas's right side)


def plan_camera(width: float, height: float) -> tuple[float, float]:
    """The plan view's half-height at the layout (scene units) and how far right of the layout its centre lies.

    Fits the flat layout (2 units across, with the margin of
    ``PLAN_HALF_HEIGHT``) into the canvas left of the panel: centred on the
    whole canvas, the layout ran under the panel at 1400 × 800. A canvas
    under twice the panel's width is taken whole (viser then folds the panel away).
    """
    visible = width - PANEL_PX if width > 2 * PANEL_PX else width
    px = min(visible, height) / (2 * PLAN_HALF_HEIGHT)  # pixels per scene unit
    return height / (2 * px), (width - visible) / (2 * px)
FIRST_SOLVE_DELAY_S = 3.0  # after the first page connects (see App.__init__; measured in benchmarks/app.py)


def bundled_examples() -> dict[str, str]:
    """Bundled designs and cases by display name (package data only)."""
    out = {}
    for pattern in ("*.obj", "*/case.json", "*/flat_opt.msh"):
        for path in sorted(glob.glob(os.path.join(EXAMPLES_DIR, pattern))):
            name = os.path.relpath(path, EXAMPLES_DIR)
            if not name.startswith("cross_sections"):
                out[name] = os.path.abspath(path)
    return out


def _plot_image(xs, ys, title: str) -> np.ndarray:
    """A small RGB line plot (for the optimization progress panel)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(3.2, 1.8), dpi=80)
    ax = fig.add_subplot(111)
    if len(xs):
        ax.plot(xs, ys, "-o", ms=2)
    ax.set_title(title, fontsize=8)
    ax.tick_params(labelsize=6)
    fig.tight_layout()
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()


def serve(host: str = "127.0.0.1", port: int = 8080):
    """Start the viser server with the app's scene settings and nothing in it yet.

    :func:`.cli.start` calls this first, so that the browser loads the page's
    client (seconds of JavaScript) while the design is read and the panels are built.
    """
    import viser

    server = viser.ViserServer(host=host, port=port, label="xshells app", verbose=False)
    server.scene.set_up_direction("+z")
    server.gui.configure_theme(control_width="large")  # room for the five tabs and the result tables
    # look down on both halves (flat left, deployed right), both clear of the panel on the right
    server.initial_camera.position = (0.75, -2.8, 2.35)
    server.initial_camera.look_at = (0.75, 0.0, 0.15)
    return server


class App:
    """The viser server and its panels, bound to one :class:`Session`.

    Parameters
    ----------
    session : Session
    host, port : str, int
    server : viser.ViserServer, optional
        One already started by :func:`serve` (else started here).
    """

    def __init__(self, session: Session, host: str = "127.0.0.1", port: int = 8080, server=None):
        self.session = session
        self.server = server if server is not None else serve(host, port)
        self._selected: int | None = None
        self._pending_segment: int | None = None
        self._gizmo = None
        self._frame = (np.zeros(2), 1.0)  # layout centre, scene scale
        self._playing = threading.Event()
        self._opt_history: list[tuple[int, float]] = []
        self._opt_title = "objective J"
        self._shown_deployed: View | None = None
        self._hovered = None  # (index, label) of the joint labelled under the pointer
        self._extras: dict = {}  # removable scene nodes by name: the swept meshes, the "before" ghost, the actuators
        self._build_gui()
        self._limit_uploads()
        session.listeners.append(self._on_event)
        # draw the current state (the session was loaded before we listened)
        self._on_event("layout", session.layout)
        self._on_event("problems", session.problems())
        self._on_event("material", material_summary(session._material) if session._material is not None
                       else spec_summary(session.material_spec))
        self._draw_ground()
        # The solver (its imports included) starts only once the first page has
        # connected and had time to draw the panel and the flat layout (or after 5 s
        # without a page): on a small machine it would otherwise compete with the
        # browser and the server for the CPU and hold up the page.
        self._first_client, self._stopped = threading.Event(), threading.Event()
        self.server.on_client_connect(lambda _client: self._first_client.set())
        threading.Thread(target=self._initial_solve_when_ready, daemon=True, name="xshells-app-start").start()

    def _draw_ground(self, width: float = 6.0, height: float = 3.0, cell: float = 0.25) -> None:
        """A ground grid of thin lines under both halves.

        viser's own grid is a shader over the whole plane with a shadow pass,
        which in software WebGL (headless Chromium, machines without a GPU)
        costs about a second of page start-up (benchmarks/app.py --startup).
        """
        xs, ys = np.arange(-width / 2, width / 2 + 1e-9, cell), np.arange(-height / 2, height / 2 + 1e-9, cell)
        seg = [[(x, ys[0], 0.0), (x, ys[-1], 0.0)] for x in xs] + [[(xs[0], y, 0.0), (xs[-1], y, 0.0)] for y in ys]
        self.server.scene.add_line_segments("/ground", np.asarray(seg, np.float32) - [0, 0, 0.01], colors=(215, 215, 215),
                                            thickness=1.0, thickness_units="screen")

    def _initial_solve_when_ready(self) -> None:
        self._first_client.wait(5.0)
        self._stopped.wait(FIRST_SOLVE_DELAY_S)
        if not self._stopped.is_set():
            self._solve_initial()

    # ------------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        gui, s = self.server.gui, self.session
        self.status_md = gui.add_markdown(f"**xshells** — {s.name}: {s.layout.num_segments} segments; "
                                          "the solver starts when the page has loaded")
        self.progress = gui.add_progress_bar(0.0, animated=False)
        # joint labels on hover: the page relays the pointer into this hidden field (see hover.py)
        gui.add_html(hover.relay_html())
        self.pointer = gui.add_text("pointer", "")
        self.pointer.on_update(lambda ev: self._on_pointer(ev.client))
        tabs = gui.add_tab_group()

        with tabs.add_tab("Design"):
            with gui.add_folder("Open"):
                examples = bundled_examples()
                names = tuple(examples) or ("-",)
                opened = [n for n, p in examples.items() if s.project.name == os.path.splitext(os.path.basename(p))[0]]
                self.example = gui.add_dropdown("example", names, initial_value=opened[0] if opened else names[0])
                b = gui.add_button("Open example")
                b.on_click(lambda _: self._guard(lambda: (s.open_path(examples[self.example.value]), self._solve_initial())))
                self.upload = gui.add_upload_button("Upload OBJ / .msh / case JSON (≤ 5 MB)", icon=None)
                self.upload.on_upload(lambda ev: self._on_upload(ev))
                self.upload_md = gui.add_markdown("")  # the last upload's fate (a status line is soon overwritten)
                self.grid_n = gui.add_vector2("grid segments", (6, 6), step=1)
                self.grid_angle = gui.add_number("grid angle (°)", 90.0, min=5.0, max=175.0, step=1.0)
                b = gui.add_button("New grid")
                b.on_click(lambda _: self._guard(lambda: (s.new_grid(int(self.grid_n.value[0]), int(self.grid_n.value[1]),
                                                                     float(self.grid_angle.value)), self._solve_initial())))
            with gui.add_folder("Edit"):
                self.mode = gui.add_dropdown("click mode", MODES, initial_value=MODES[0])
                self.mode.on_update(lambda _: self._set_mode())
                self.mode_md = gui.add_markdown(f"*{MODE_HINTS[MODES[0]]}*")
                row = gui.add_button_group("history", ("Undo", "Redo"))
                row.on_click(lambda ev: (s.undo() if ev.target.value == "Undo" else s.redo()))
                self.symmetry = gui.add_dropdown("symmetry", tuple(SYMMETRY), initial_value="off")
                self.brush_radius = gui.add_slider("brush radius (% of span)", 2.0, 50.0, 1.0, 15.0)
                self.cage_shape = gui.add_vector2("cage handles", (4, 4), step=1, min=(2, 2), max=(8, 8))
                self.cage_shape.on_update(lambda _: self._set_mode())
                self.snap_step = gui.add_number("snap to grid (design units, 0: off)", 0.0, min=0.0)
                self.joint_labels = gui.add_checkbox("joint numbers", False)
                self.joint_labels.on_update(lambda _: self._joint_labels_toggled())
                row = gui.add_button_group("view", ("Plan", "3D"))
                row.on_click(lambda ev: self._set_camera(ev.target.value, ev.client))
                self.live = gui.add_checkbox("follow edits live", True)
                self.live.on_update(lambda _: setattr(s, "live", bool(self.live.value)))
                self.check_cold = gui.add_checkbox("compare with a cold deployment after each edit", True)
                self.check_cold.on_update(lambda _: setattr(s, "compare_cold", bool(self.check_cold.value)))
                self.branch_md = gui.add_markdown("")
                self.branch_row = gui.add_button_group("branch", ("keep shown", "use cold"), visible=False)
                self.branch_row.on_click(lambda ev: self._choose_branch(ev.target.value))
                self.warp_amount = gui.add_slider("warp amount", -0.5, 0.5, 0.01, 0.1)
                warps = gui.add_button_group("warp", ("Scale", "Bend", "Pinch"))
                warps.on_click(lambda ev: self._warp(ev.target.value))
                self.problems_md = gui.add_markdown("")
                b = gui.add_button("Simulate edited layout")
                b.on_click(lambda _: self._solve_initial())

        with tabs.add_tab("Deploy"):
            lo, hi = 5.0, 175.0
            self.angle = gui.add_slider("opening angle (°)", lo, hi, 0.1, 90.0)
            self._angle_range, self._angle_resetting = (lo, hi), False
            self.angle.on_update(lambda _: self._angle_changed())
            self.field = gui.add_dropdown("colour by", tuple(FIELDS), initial_value="bending energy")
            self.field.on_update(lambda _: s.set_field(self.field.value))
            row = gui.add_button_group("animation", ("Play", "Stop"))
            row.on_click(lambda ev: self._play() if ev.target.value == "Play" else self._stop())
            b = gui.add_button("Cancel solve")
            b.on_click(lambda _: s.cancel())
            self.info_md = gui.add_markdown("")

        with tabs.add_tab("Material"):
            spec = s.material_spec
            self.sec_type = gui.add_dropdown("cross-section", SECTION_TYPES,
                                             initial_value=spec.get("type", "rectangle") if spec.get("type") in SECTION_TYPES else "rectangle")
            self.sec_params = gui.add_text("dimensions", ", ".join(f"{v:g}" for v in spec.get("params", [10, 7])))
            # no min/max: the page would clamp a bad value to another one silently; the session refuses it, saying why
            self.young = gui.add_number("E", float(spec.get("E", 20000.0)))
            self.poisson = gui.add_number("ν", float(spec.get("nu", 0.3)), step=0.01)
            self.subdiv = gui.add_number("edges per segment", int(s.subdivision), step=1)
            b = gui.add_button("Apply material")
            b.on_click(lambda _: self._apply_material())
            self.material_md = gui.add_markdown("")

        with tabs.add_tab("Optimize"):
            self.opt_md = gui.add_markdown(self._availability())
            self.opt_iters = gui.add_number("max iterations", 10, min=1, max=500, step=1)
            row = gui.add_button_group("design optimization", ("Optimize", "Stop", "Resume"))
            row.on_click(lambda ev: self._optimize(ev.target.value))
            b = gui.add_button("Actuate (sparse torques)")
            b.on_click(lambda _: self._actuate())
            self.result_md = gui.add_markdown("")
            # a blank canvas: matplotlib is imported only when there is something to plot
            self.opt_plot = gui.add_image(np.full((144, 256, 3), 255, np.uint8), label="progress")

        with tabs.add_tab("Export"):
            row = gui.add_button_group("fabrication (flat, 1:1 mm)", ("SVG", "DXF"))
            row.on_click(lambda ev: self._export(ev.target.value.lower(), ev.client))
            row = gui.add_button_group("workshop (1:1 mm)", ("cut list", "strips"))
            row.on_click(lambda ev: self._export(ev.target.value.replace(" ", ""), ev.client))
            row = gui.add_button_group("deployed mesh", ("OBJ", "PLY", "glTF"))
            row.on_click(lambda ev: self._export(ev.target.value.lower(), ev.client))
            row = gui.add_button_group("other", ("case JSON", "PNG"))
            row.on_click(lambda ev: self._export("case" if ev.target.value == "case JSON" else "png", ev.client))
            self.export_md = gui.add_markdown(f"files go to `{os.path.abspath(s.out_dir)}` and are downloaded")

    def _limit_uploads(self) -> None:
        """Refuse an oversized upload as soon as its size is announced, before its parts are buffered.

        Relies on viser's upload bookkeeping (private); when that changes, the
        size check after receipt (:class:`~.loading.UploadStore`) still applies.
        """
        from viser import _messages

        gui, limit = self.server.gui, self.session.uploads.limit

        def check(_client_id, message) -> None:
            state = gui._current_file_upload_states.get(message.transfer_uuid)
            if message.size_bytes > limit and state is not None:
                # keep acknowledging parts (so the page finishes and re-enables the
                # button) but store none: viser then drops the short upload
                state["parts"] = _DiscardingParts()
                self.session.upload_refused(f"{os.path.basename(str(message.filename))}: {message.size_bytes / 2**20:.1f} MB "
                                            f"is over the {limit / 2**20:.0f} MB upload limit")

        try:
            gui._websock_interface.register_handler(_messages.FileTransferStartUpload, check)
        except AttributeError:
            pass

    def _availability(self) -> str:
        has_opt, has_act = adapters.modules_present()  # no import at start-up: the solver loads on first use
        o = "available" if has_opt else adapters.NOT_AVAILABLE
        a = "available" if has_act else adapters.NOT_AVAILABLE
        return f"design optimization: {o}  \nsparse actuation: {a}"

    def _guard(self, fn) -> None:
        """Run a UI action; user errors become a status line, never a crash."""
        try:
            fn()
        except InputError as exc:
            self.session.status(str(exc))
        except Exception as exc:  # noqa: BLE001
            self.session.status(f"error: {type(exc).__name__}: {exc}")

    def _on_upload(self, ev) -> None:
        f = ev.target.value
        if self.session.open_upload(f.name, f.content):
            self._solve_initial()

    def _solve_initial(self) -> None:
        """Assemble the current layout and deploy it to the project's angle (or flat + 30°)."""
        s = self.session
        if s.problems():
            return
        angle = s.target_angle_deg
        if angle is None:
            angle = self._flat_angle_guess() + 30.0
        angle = float(np.clip(angle, 5.0, 175.0))
        self.angle.value = angle
        s.request_angle(angle)  # a repeated request from the slider's own callback just replaces this one

    def _angle_changed(self) -> None:
        """Deploy to the slider's angle; one typed into its box outside the slider's range puts it back, with one line.

        The box takes any number (200, −5, 179.9) and the slider kept it: the
        page then showed an angle that was never solved, or one the linkage
        folds on the way to.
        """
        if self._angle_resetting:
            return
        v = float(self.angle.value)
        lo, hi = self._angle_range
        if np.isfinite(v) and lo <= v <= hi:
            self.session.request_angle(v)
            return
        back = self.session.angle_deg
        if back is None:  # nothing shown yet: the nearest end of the range
            back = float(np.clip(v, lo, hi)) if np.isfinite(v) else lo
        self._angle_resetting = True
        try:
            self.angle.value = back
        finally:
            self._angle_resetting = False
        self.session.status(f"opening angle {v:g}°: give one from {lo:g}° to {hi:g}° (back at {back:.1f}°)")

    def _flat_angle_guess(self) -> float:
        """Average opening angle of the layout's joints (what the assembly state keeps)."""
        try:
            from ..linkage.graph import analyze

            return float(np.degrees(np.mean(analyze(core.layout_to_design(self.session.layout)).joint_opening_angles)))
        except Exception:
            return 60.0

    def _apply_material(self) -> None:
        try:
            params = [float(v) for v in self.sec_params.value.replace(";", ",").split(",") if v.strip()]
        except ValueError:
            self.session.status("material: dimensions must be numbers separated by commas")
            return
        s = self.session
        if s.set_material(self.sec_type.value, params, float(self.young.value), float(self.poisson.value),
                          subdivision=float(self.subdiv.value)):
            s.request_angle(float(self.angle.value))
        else:  # refused (the status line says why): the fields show the values still in use
            spec = s.material_spec
            self.young.value, self.poisson.value = float(spec.get("E", 20000.0)), float(spec.get("nu", 0.3))
            self.subdiv.value = int(s.subdivision)

    def _warp(self, which: str) -> None:
        a = float(self.warp_amount.value)
        if which == "Scale":
            self.session.edit(core.warp_scale, 1.0 + a)
        elif which == "Bend":
            self.session.edit(core.warp_bend, a)
        else:
            self.session.edit(core.warp_pinch, a)

    # ------------------------------------------------------------------ editing by clicks
    def _set_mode(self) -> None:
        scene = self.server.scene
        scene.remove_click_callback("all")
        self._pending_segment = None
        self._drop_gizmo()
        self.mode_md.content = f"*{MODE_HINTS.get(self.mode.value, '')}*"
        self._cage_cache = None
        self._draw_layout(self.session.layout, keep_frame=True)
        if self.mode.value != MODES[0]:
            scene.on_click()(self._on_click)

    def _to_layout(self, ray_o, ray_d) -> np.ndarray | None:
        """Where a click ray meets the flat layout's plane, in layout coordinates."""
        o, d = np.asarray(ray_o, float), np.asarray(ray_d, float)
        if abs(d[2]) < 1e-12:
            return None
        p = o - o[2] / d[2] * d
        c, k = self._frame
        return (p[:2] - [-GAP, 0.0]) / k + c

    def _to_scene(self, xy: np.ndarray) -> np.ndarray:
        c, k = self._frame
        xy = (np.asarray(xy, float) - c) * k + [-GAP, 0.0]
        return np.c_[xy, np.zeros(len(xy))] if xy.ndim == 2 else np.r_[xy, 0.0]

    def _on_click(self, ev) -> None:
        s, mode = self.session, self.mode.value
        xy = self._to_layout(ev.ray_origin, ev.ray_direction)
        if xy is None:
            return
        radius = 0.05 / self._frame[1]  # 5 % of the half-span
        v = core.nearest_vertex(s.layout, xy, radius)
        if mode == "move joint":
            if v is not None:
                self._attach_gizmo(v)
        elif mode == "brush":
            self._attach_gizmo(None, at=xy)
        elif mode == "cage":
            H = self._cage().handles().reshape(-1, 2)
            k = int(np.argmin(np.sum((H - xy) ** 2, axis=1)))
            if np.sum((H[k] - xy) ** 2) <= radius ** 2:
                self._attach_gizmo(None, at=H[k], handle=divmod(k, self._cage().shape[1]))
        elif mode == "add joint":
            if s.edit(core.add_joint, xy, self._selected):
                self._selected = s.layout.num_vertices - 1
        elif mode == "add segment":
            if v is None:
                return
            if self._pending_segment is None or self._pending_segment == v:
                self._pending_segment = v
                s.status(f"segment from joint {v}: click its other end")
            else:
                s.edit(core.add_segment, self._pending_segment, v)
                self._pending_segment = None
        elif mode == "delete joint" and v is not None:
            s.edit(core.delete_joint, v)
        elif mode == "delete segment":
            seg = core.nearest_segment(s.layout, xy, radius)
            if seg is not None:
                s.edit(core.delete_segment, seg)

    def _hover_targets(self) -> tuple[np.ndarray, list[str]]:
        """Scene positions of the joints that can be hovered (flat layout, then the shown deployed state) and their labels."""
        layout = self.session.layout
        P = [self._to_scene(layout.vertices) + [0, 0, 0.025]] if layout.num_vertices else []
        span = layout.span()
        to_file = self.session.project.to_file  # the file's coordinates, where the app re-centred the design
        labels = [hover.flat_label(v, xy, span, to_file) for v, xy in enumerate(layout.vertices)]
        view = self._shown_deployed
        if view is not None and view.joint_vertices is not None and len(view.joints):
            P.append(self._deployed_to_scene(view.joints, view))
            labels += [hover.height_label(v, z, span) for v, z in
                       zip(view.joint_vertices.tolist(), view.joints[:, 2] - view.joints[:, 2].min())]
        return (np.vstack(P) if P else np.zeros((0, 3))), labels

    def _on_pointer(self, client) -> None:
        """Label the joint under the pointer (the page sends where it is; hover.py), or clear the label."""
        parsed = hover.parse_pointer(self.pointer.value)
        k = None
        if parsed is not None and client is not None:
            pointer, w, h = parsed
            cam = client.camera
            P, labels = self._hover_targets()
            k = hover.pick_on_screen(P, pointer, w, h, {"position": cam.position, "wxyz": cam.wxyz, "fov": cam.fov})
        # the label first, then the record of it: whoever sees a joint recorded as hovered finds its label (a test
        # read the two between the assignments and found no label)
        if k is None:
            self._remove("/hover")
            self._hovered = None
            return
        if self._hovered != (k, labels[k]):
            self._extras["/hover"] = self.server.scene.add_label("/hover", labels[k], position=tuple(P[k] + [0, 0, 0.03]))
            self._hovered = (k, labels[k])

    def _mirror(self):
        axis = SYMMETRY.get(self.symmetry.value)
        return None if axis is None else core.Mirror.through_centre(self.session.layout, axis)

    def _cage(self) -> core.Cage:
        if getattr(self, "_cage_cache", None) is None or self._cage_cache[0] is not self.session.layout:
            shape = tuple(int(v) for v in self.cage_shape.value)
            self._cage_cache = (self.session.layout, core.Cage.around(self.session.layout, shape))
        return self._cage_cache[1]

    def _edit_for(self, v, start, handle):
        """The edit a drag makes, as ``(function, args_of(dragged_xy))``, for the current mode and symmetry."""
        mirror, step = self._mirror(), float(self.snap_step.value or 0.0)
        if v is not None:  # move one joint (and its mirror partner)
            if mirror is not None:
                return core.move_joint_mirrored, lambda xy: (v, core.snap(xy, step), mirror)
            return core.move_joint, lambda xy: (v, core.snap(xy, step))
        if handle is not None:
            cage = self._cage()
            return core.cage_move, lambda xy: (cage, handle[0], handle[1], xy - start)
        radius = float(self.brush_radius.value) / 100.0 * self.session.layout.span()
        return core.brush, lambda xy: (start, radius, xy - start, mirror)

    def _attach_gizmo(self, v: int | None, at=None, handle=None) -> None:
        """A drag handle on joint ``v`` (move), or at ``at`` (a brush stroke, or cage handle ``handle``)."""
        self._drop_gizmo()
        self._selected = v
        start = np.asarray(self.session.layout.vertices[v] if v is not None else at, float)
        g = self.server.scene.add_transform_controls("/flat/gizmo", scale=0.25, disable_rotations=True,
                                                     active_axes=(True, True, False), position=self._to_scene(start))
        self._gizmo = g
        fn, args = self._edit_for(v, start, handle)
        if v is not None:
            self._draw_layout(self.session.layout, keep_frame=True)  # its number shows while it is selected

        def dragged_to() -> np.ndarray:
            c, k = self._frame
            return (np.asarray(g.position[:2]) - [-GAP, 0.0]) / k + c

        released, order = [False], threading.Lock()

        @g.on_update
        def _(ev) -> None:
            # viser runs these callbacks in a thread pool, out of order: an "update" (a preview) could run
            # after the "end" (the full solve) and was then shown as the final state. So one callback takes
            # every phase, the phases of one handle run one at a time, and an update after the release is
            # dropped: a preview asked for before the release is superseded by its full solve.
            phase = getattr(ev, "phase", "update")
            with order:
                if phase == "start":
                    released[0] = False
                elif phase == "end":
                    released[0] = True
                    if self.session.edit(fn, *args(dragged_to())) and handle is None and v is None:
                        self._drop_gizmo()  # a brush stroke is done; the next click starts another
                    if self.session.live and self.check_cold.value:
                        self.session.check_branch()
                elif not released[0]:
                    try:  # the lines and the deployed view follow; recorded for undo only on release
                        layout = fn(self.session.layout, *args(dragged_to()))
                    except InputError:
                        return
                    self._draw_layout(layout, keep_frame=True)
                    if self.session.live:
                        self.session.preview(layout)

    def _set_camera(self, which: str, client) -> None:
        """``Plan``: look straight down on the flat layout (a narrow field of view: nearly orthographic); ``3D``: as at start."""
        clients = [client] if client is not None else list(self.server.get_clients().values())
        for c in clients:
            if which == "Plan":  # from straight above, tilted by 1e-4 rad so that "up" (+z) stays well defined
                half, right = PLAN_HALF_HEIGHT, 0.0
                if c.camera.update_timestamp:  # the canvas size is known once the page has sent its camera
                    half, right = plan_camera(c.camera.image_width, c.camera.image_height)
                d = half / np.tan(0.5 * PLAN_FOV)
                c.camera.fov = PLAN_FOV
                c.camera.position = (-GAP + right, -1e-4 * d, d)  # position moves look_at along: set look_at after it
                c.camera.look_at = (-GAP + right, 0.0, 0.0)
            else:
                c.camera.fov = np.radians(75.0)
                c.camera.position = (0.75, -2.8, 2.35)
                c.camera.look_at = (0.75, 0.0, 0.15)

    def _draw_ghost(self, name: str, sim) -> None:
        """Another state of the shown layout (the other branch) as a grey, translucent mesh in the deployed half."""
        import time

        view = self.session._view(sim, time.perf_counter())
        V = self._deployed_to_scene(view.vertices, self._shown_deployed)
        self._extras[name] = self.server.scene.add_mesh_simple(name, V.astype(np.float32), view.triangles,
                                                               color=(150, 150, 150), opacity=0.35)

    def _choose_branch(self, which: str) -> None:
        self.branch_row.visible = False
        self.branch_md.content = ""
        self._remove("/deployed/alternative")
        self.session.choose_branch("cold" if which == "use cold" else "shown")

    def _drop_gizmo(self) -> None:
        if self._gizmo is not None:
            self._gizmo.remove()
            self._gizmo = None

    # ------------------------------------------------------------------ session events → view
    def _on_event(self, event: str, payload) -> None:
        if event == "project":  # the meshes of the design before would be drawn in the new one's frame
            for name in ("/flat/mesh", "/deployed/mesh"):
                self._remove(name)
            self._shown_deployed = None
            self.info_md.content = ""
            self.progress.value = 0.0
        elif event == "layout":
            self._remove("/deployed/before")
            self._remove("/deployed/alternative")
            self.branch_row.visible = False
            self.branch_md.content = ""
            self._remove("/deployed/actuators")
            if self._gizmo is not None and (self._selected is None or self._selected >= payload.num_vertices):
                self._drop_gizmo()  # its joint is gone (delete, undo, new design)
            self._draw_layout(payload)
        elif event == "problems":
            self.problems_md.content = ("**topology:** ok" if not payload else
                                        "**topology problems:**\n\n" + "\n".join(f"- {p}" for p in payload))
        elif event == "upload":
            self.upload_md.content = f"*{payload}*"
        elif event == "status":
            self.status_md.content = f"**xshells** — {payload}"
        elif event == "progress":
            fraction, text = payload
            self.progress.value = float(np.clip(100 * fraction, 0, 100))
            if text and text not in ("done", "stopped"):
                self.status_md.content = f"**xshells** — {text}"
        elif event == "material":
            self.material_md.content = payload
            self._show_material_spec(self.session.material_spec)
        elif event == "flat":
            self._draw_mesh("/flat/mesh", payload, -GAP, flat=True)
        elif event == "deployed":
            self._remove("/deployed/actuators")  # drawn again by "actuated" when this is the actuated state
            self._draw_mesh("/deployed/mesh", payload, GAP)
            self._shown_deployed = payload
            i = payload.info
            self.info_md.content = (f"angle **{i.angle_deg:.2f}°**  \nenergy {i.energy:.5g} "
                                    f"(bend {i.energy_bend:.3g}, twist {i.energy_twist:.3g}, stretch {i.energy_stretch:.3g})  \n"
                                    f"torque {i.torque:.4g}  \nmax |z| {i.max_abs_z:.4g}  \n"
                                    f"solve + mesh {payload.solve_time_s:.2f} s")
        elif event == "branch":
            if not payload["cold_converged"]:
                self.branch_md.content = f"*a cold deployment did not get there: {payload['cold_message']}*"
                self.branch_row.visible = False
            elif payload["same"]:
                self.branch_md.content = f"*a cold deployment agrees (joints within {payload['difference']:.1e} of the span)*"
                self.branch_row.visible = False
            else:
                alt = self.session.alternative
                self.branch_md.content = (f"**two branches** at {payload['angle_deg']:.1f}°: shown energy "
                                          f"{payload['energy_shown']:.6g}, cold deployment {payload['energy_cold']:.6g} "
                                          f"(grey ghost; joints up to {100 * payload['difference']:.2g} % of the span apart"
                                          f"{', shape flipped' if payload['flipped'] else ''})")
                self.branch_row.visible = True
                if alt is not None and self._shown_deployed is not None:
                    self._draw_ghost("/deployed/alternative", alt[0])
        elif event == "opt_progress":
            it, value, text = payload
            self._opt_history.append((len(self._opt_history), value))
            xs, ys = zip(*self._opt_history)
            self.opt_plot.image = _plot_image(xs, ys, f"{self._opt_title} — {text}")
        elif event == "optimized":
            before = self._shown_deployed
            if before is not None:  # the deployed state before, as a grey ghost behind the optimized one
                V = self._deployed_to_scene(before.vertices, before)
                self._extras["/deployed/before"] = self.server.scene.add_mesh_simple(
                    "/deployed/before", V.astype(np.float32), before.triangles, color=(150, 150, 150), opacity=0.35)
            self._show_optimized(payload)
        elif event == "actuated":
            self._show_actuated(*payload)
        elif event == "task_failed":
            self.result_md.content = f"**failed** — {payload}"
        elif event == "stability":
            self.info_md.content = self.info_md.content.split("  \nstability")[0] + "  \n" + stability_text(*payload)

    def _show_material_spec(self, spec: dict) -> None:
        """Put the current material into the Material panel (a newly opened design brings its own)."""
        if not hasattr(self, "sec_type"):
            return
        if spec.get("type") in SECTION_TYPES:
            self.sec_type.value = spec["type"]
        self.sec_params.value = ", ".join(f"{float(v):g}" for v in spec.get("params", []))
        self.young.value = float(spec.get("E", 20000.0))
        self.poisson.value = float(spec.get("nu", 0.3))
        self.subdiv.value = int(self.session.subdivision)

    def _draw_layout(self, layout: core.Layout, keep_frame: bool = False) -> None:
        scene = self.server.scene
        V = layout.vertices
        if len(V) and not (keep_frame or self._gizmo is not None):
            c = 0.5 * (V.min(axis=0) + V.max(axis=0))
            self._frame = (c, 2.0 / layout.span())
        P = self._to_scene(V) if len(V) else np.zeros((0, 3))
        if layout.num_segments:
            seg = P[layout.edges] + [0, 0, 0.02]
            scene.add_line_segments("/flat/lines", seg.astype(np.float32), colors=(40, 40, 40), thickness=1.5, thickness_units="screen")
        if len(P):
            # joints a quarter of a typical segment across, so dense layouts stay readable
            size = float(np.clip(0.15 * np.median(layout.segment_lengths()) * self._frame[1], 0.004, 0.02)) if layout.num_segments else 0.02
            scene.add_point_cloud("/flat/joints", (P + [0, 0, 0.025]).astype(np.float32),
                                  colors=(220, 40, 40), point_size=size, point_shape="circle")
        self._draw_labels(layout, P)
        if getattr(self, "mode", None) is not None and self.mode.value == "cage":
            H = self._to_scene(self._cage().handles().reshape(-1, 2)) + [0, 0, 0.03]
            self._extras["/flat/cage"] = scene.add_point_cloud("/flat/cage", H.astype(np.float32), colors=(120, 120, 120),
                                                                point_size=0.04, point_shape="square")
        else:
            self._remove("/flat/cage")

    def _joint_labels_toggled(self) -> None:
        self._draw_layout(self.session.layout, keep_frame=True)
        shown, total = self._labels_shown
        if self.joint_labels.value and shown < total:
            self.session.status(f"joint numbers: {shown} of {total} shown, the others would overlap at the default "
                                f"zoom (hover a joint for its number)")

    def _draw_labels(self, layout: core.Layout, P: np.ndarray) -> None:
        """Joint numbers (design vertex ids): all of them when asked (thinned where they would overlap), else the
        selected joint's."""
        for name in [n for n in self._extras if n.startswith("/flat/labels/")]:
            self._remove(name)
        if getattr(self, "joint_labels", None) is not None and self.joint_labels.value:
            show = list(thin_labels(P, LABEL_SPACING))
            if self._selected is not None and self._selected < len(P) and self._selected not in show:
                show.append(self._selected)
        else:
            show = [self._selected] if self._selected is not None and self._selected < len(P) else []
        self._labels_shown = (len(show), len(P))
        for v in show:
            name = f"/flat/labels/{v}"
            self._extras[name] = self.server.scene.add_label(name, str(v), position=tuple(P[v] + [0, 0, 0.04]))

    def _remove(self, name: str) -> None:
        handle = self._extras.pop(name, None)
        if handle is not None:
            handle.remove()

    def _to_view_scene(self, P: np.ndarray, view: View, offset: float) -> np.ndarray:
        """Design coordinates of one state's points → scene (its half of the view, resting on the ground grid)."""
        c, k = self._frame
        V = np.array(P, float)
        V[:, :2] = (V[:, :2] - c) * k
        V[:, 2] = (V[:, 2] - view.vertices[:, 2].min()) * k
        V[:, 0] += offset
        return V

    def _deployed_to_scene(self, P: np.ndarray, view: View | None = None) -> np.ndarray:
        return self._to_view_scene(P, view if view is not None else self._shown_deployed, GAP)

    def _draw_mesh(self, name: str, view: View, offset: float, flat: bool = False) -> None:
        import trimesh

        from .exports import field_colors

        V = self._to_view_scene(view.vertices, view, offset)
        if flat:
            colors = np.tile([180, 180, 200], (len(V), 1)).astype(np.uint8)
        else:
            colors = field_colors(view.field)
        tm = trimesh.Trimesh(V, view.triangles, vertex_colors=np.c_[colors, np.full(len(V), 255, np.uint8)], process=False)
        self._extras[name] = self.server.scene.add_mesh_trimesh(name, tm)

    # ------------------------------------------------------------------ animation
    def _play(self) -> None:
        frames = self.session.animation_frames()
        if len(frames) < 2:
            self.session.status("nothing to play yet: move the angle slider first")
            return
        self._playing.set()

        def run():
            for a in frames[1:]:
                if not self._playing.is_set():
                    break
                self.session.show_frame(a)
                self.session.worker.wait_idle(10)
                time.sleep(0.04)
            self._playing.clear()

        threading.Thread(target=run, daemon=True, name="xshells-app-animation").start()

    def _stop(self) -> None:
        self._playing.clear()

    # ------------------------------------------------------------------ optimize / actuate
    def _optimize(self, action: str) -> None:
        s = self.session
        if action == "Stop":
            s.stop_optimization()
            return
        if not adapters.optimize_available():
            self.opt_md.content = f"design optimization: {adapters.NOT_AVAILABLE}"
            return
        if action == "Optimize":  # Resume keeps the plot and goes on from the current rest lengths
            self._opt_history = []
        self._opt_title = "objective J"
        self.result_md.content = "optimizing…"
        s.optimize(float(self.angle.value), int(self.opt_iters.value))

    def _actuate(self) -> None:
        if not adapters.actuate_available():
            self.opt_md.content = f"sparse actuation: {adapters.NOT_AVAILABLE}"
            return
        self._opt_history = []
        self._opt_title = "mean deviation, % of span"
        if self.session.actuate(int(self.opt_iters.value)):
            self.result_md.content = "sparse actuation…"

    def _show_optimized(self, out) -> None:
        self.result_md.content = "  \n".join(optimization_summary(out))

    def _show_actuated(self, out, joints) -> None:
        n, idx = len(out.torques), np.asarray(out.actuated, int)
        order = idx[np.argsort(-np.abs(out.torques[idx]))] if idx.size else idx
        top = ", ".join(f"{int(j)}: {out.torques[j]:.3g}" for j in order[:8]) + (" …" if idx.size > 8 else "")
        self.result_md.content = (f"**actuation**: {idx.size} of {n} joints actuated (orange)  \n"
                                  f"torques (joint: τ) {top}  \n{out.message}")
        if idx.size:
            P = self._deployed_to_scene(joints[idx])
            self._extras["/deployed/actuators"] = self.server.scene.add_point_cloud(
                "/deployed/actuators", P.astype(np.float32), colors=(255, 140, 0), point_size=0.06, point_shape="circle")

    # ------------------------------------------------------------------ export
    def _export(self, kind: str, client) -> None:
        def job():
            try:
                paths = self.session.export(kind)
            except InputError as exc:
                self.session.status(str(exc))
                return
            except Exception as exc:  # noqa: BLE001
                self.session.status(f"export failed: {type(exc).__name__}: {exc}")
                return
            name, data = download(paths, kind)
            self.export_md.content = "written:\n\n" + "\n".join(f"- `{p}`" for p in paths)
            note = self.session.export_note
            self.session.status(f"exported {', '.join(os.path.basename(p) for p in paths)}"
                                + (f" (downloaded as {name})" if len(paths) > 1 else "") + (f"; {note}" if note else ""))
            if client is not None:
                client.send_file_download(name, data, save_immediately=True)

        # off the UI callback thread: mesh exports wait for the solver
        threading.Thread(target=job, daemon=True, name="xshells-app-export").start()

    def stop(self) -> None:
        self._stopped.set()
        self._first_client.set()
        self._playing.clear()
        # detach first: a job still finishing must not draw into a stopped server
        if self._on_event in self.session.listeners:
            self.session.listeners.remove(self._on_event)
        self.session.close()
        self.server.stop()


LABEL_SPACING = 0.07  # scene units between joint numbers (the flat half is 2 across): about a 3-digit label's width


def thin_labels(P: np.ndarray, spacing: float) -> np.ndarray:
    """Indices of the points to label so that no two labels are closer than ``spacing`` (greedy, in order)."""
    P = np.asarray(P, float)[:, :2] if len(P) else np.zeros((0, 2))
    cells: dict = {}
    keep = []
    for i, p in enumerate(P):
        c = tuple(np.floor(p / spacing).astype(int))
        near = (cells.get((c[0] + dx, c[1] + dy), ()) for dx in (-1, 0, 1) for dy in (-1, 0, 1))
        if any(np.sum((P[j] - p) ** 2) < spacing ** 2 for group in near for j in group):
            continue
        cells.setdefault(c, []).append(i)
        keep.append(i)
    return np.array(keep, int)


def optimization_summary(out) -> list[str]:
    """The optimization result's lines: J (dimensionless) and the energies themselves, in the input's units."""
    b, a = out.before or {}, out.after or {}
    rows = [f"**optimization** ({out.iterations} iterations): {out.message}"]
    if "J" in b and "J" in a:
        rows.append(f"J: {b['J']:.4g} → {a['J']:.4g}")
    scale = getattr(out, "energy_scale", None)
    known = scale is not None and np.isfinite(scale) and scale > 0
    for key, label in (("deployed_energy", "deployed energy"), ("flat_energy", "flat energy")):
        if key in b and key in a:  # the terms are divided by the deployed energy at the start
            rows.append(f"{label}: {b[key] * scale:.5g} → {a[key] * scale:.5g} N·mm" if known else
                        f"{label} (relative to the deployed energy at the start): {b[key]:.4g} → {a[key]:.4g}")
    if known:
        rows.append("(energies in N·mm for a design in mm and E in MPa: the input's units)")
    p0 = out.rest_lengths_before
    if p0 is not None and len(p0) == len(out.rest_lengths):
        change = float(np.max(np.abs(out.rest_lengths / p0 - 1)))
        rows.append(f"rest lengths changed by up to {change:.2%}" if change > 0 else
                    "rest lengths unchanged: no better feasible design in these iterations; the design stays as it was")
    rows.append("grey: the deployed state before")
    return rows


def download(paths: list[str], kind: str = "export") -> tuple[str, bytes]:
    """What the browser downloads for an export: its one file, or all its files in one zip (a remote user has no
    other way to reach them: the cut list's joints and bill of materials, the strips' DXF and assembly drawing)."""
    if len(paths) == 1:
        with open(paths[0], "rb") as fh:
            return os.path.basename(paths[0]), fh.read()
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for p in paths:
            zf.write(p, os.path.basename(p))
    stem = os.path.commonprefix([os.path.basename(p) for p in paths]).rstrip("_.-") or "xshell"
    return f"{stem}_{kind}.zip", buf.getvalue()


class _DiscardingParts(dict):
    """Upload parts of a refused upload: the part indices are kept, their bytes are not."""

    def __setitem__(self, key, value) -> None:
        super().__setitem__(key, b"")
