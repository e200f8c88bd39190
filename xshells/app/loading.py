"""Opening designs in the app: files named on the command line, browser uploads, generated grids.

Uploads are size-limited and only *parsed* (OBJ/``.msh`` through the design
readers, case JSON with :mod:`json`); nothing in them is executed. An
uploaded case may name its design only as a file uploaded earlier in the
same session, never as a path, so an upload cannot make the app read files
the user did not open. Every problem is an :class:`InputError` with one line.
"""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, check_input_file
from .core import Layout, layout_from_design

MAX_UPLOAD_BYTES = 5 * 1024 * 1024
# the paper's section, as xshells deploy uses by default (copied here so that
# opening the app does not import the solver; test_app_core checks they agree)
DEFAULT_MATERIAL = {"type": "rectangle", "E": 20000.0, "nu": 0.3, "params": [10.0, 7.0]}
DESIGN_SUFFIXES = (".obj", ".msh", ".3dm")
DEFAULT_STEPS = 40  # xshells deploy's (DeployOptions.steps), copied for the same reason


@dataclass(frozen=True)
class Project:
    """What the app starts from: a layout and its simulation settings.

    Attributes
    ----------
    name : str
    layout : Layout
    material : dict
        A case's material object (``type``, ``params``, ``E``, ``nu``).
    subdivision : int
    target_angle_deg : float or None
        Deployed average opening angle (None: flat + 60°, as ``xshells deploy``).
    rest_lengths : ndarray or None
    direction : {"up", "down"}
        Which way the flat state buckles (a case's ``direction``).
    note : str or None
        How the design file was read where that says more than its name (a ``.3dm``'s layer and units,
        converted to mm): the status line says it when the project opens.
    to_file : tuple or None
        ``(A, b)``: the file's coordinates of a layout point ``xy`` are ``xy @ A + b`` (a design off z = 0, or
        with round-off out of it, is laid out in its best-fit plane, re-centred); None where they are the same.
    steps : int
        Angle increments of a deployment from the flat state (a case's ``steps``); the branch it
        buckles into can depend on them, so the app deploys with the command line's.
    guide : (nj, 3) float or None
        A case's guide (:mod:`xshells.deploy.guide`), for the deployments from the flat state.
    """

    name: str
    layout: Layout
    material: dict = field(default_factory=lambda: dict(DEFAULT_MATERIAL))
    subdivision: int = 8
    target_angle_deg: float | None = None
    rest_lengths: np.ndarray | None = None
    direction: str = "up"
    note: str | None = None
    steps: int = DEFAULT_STEPS
    to_file: tuple | None = None  # (A (2, 3), b (3,)): layout xy → the file's coordinates, xy @ A + b; None: the same
    guide: np.ndarray | None = field(default=None, repr=False, compare=False)


def open_path(path: str) -> Project:
    """A project from a design (``.obj``, ``.msh``) or a case (``.json``) the user named."""
    from ..io import read_design, read_rest_lengths

    ext = os.path.splitext(path)[1].lower()
    check_input_file(path)
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such file")
    if ext == ".json":
        from ..deploy.case import load_case

        case = load_case(path)
        if case.open_by_rad is not None:
            raise InputError(f"{path}: the app deploys to an angle, not by one: give angle_deg instead of open_by_deg")
        design = read_design(case.design_path)
        p = read_rest_lengths(case.rest_lengths_path, design.num_segments, design) if case.rest_lengths_path else None
        angle = np.degrees(case.angle_rad) if case.angle_rad is not None else None
        from ..deploy.case import case_guide

        guide = case_guide(case, None)  # counted against the linkage's joints when it deploys
        return Project(case.name, layout_from_design(design), dict(case.material), case.subdivision, angle, p, case.direction,
                       note=design_note(design), to_file=file_frame(design), steps=case.steps, guide=guide)
    if ext in DESIGN_SUFFIXES:
        design = read_design(path)
        layout = layout_from_design(design)
        return Project(os.path.splitext(os.path.basename(path))[0], layout, default_material(layout), note=design_note(design), to_file=file_frame(design))
    raise InputError(f"{path}: open a design (.obj, .msh, .3dm) or a case file (.json)")


def file_frame(design) -> tuple | None:
    """The affine map from the app's layout coordinates back to the file's (for the hover labels), or None."""
    V = np.asarray(design.vertices, float)
    xy = layout_from_design(design).vertices
    if len(V) < 3 or (np.all(V[:, 2] == 0) and np.array_equal(xy, V[:, :2])):
        return None
    M, *_ = np.linalg.lstsq(np.c_[xy, np.ones(len(xy))], V, rcond=None)
    return M[:2], M[2]


def design_note(design) -> str | None:
    """What the status line says about an opened design: its reader's note (a .3dm's layer and units), and a design
    that is not flat, as ``xshells deploy`` warns (the app edits and deploys its projection onto the best-fit plane)."""
    from ..linkage.graph import _layout_plane

    notes = [design.note] if design.note else []
    V, E = np.asarray(design.vertices, float), np.asarray(design.edges, int)
    used = V[np.unique(E)] if len(E) else V
    if len(used) >= 3:
        normal, planar = _layout_plane(used)
        if not planar:
            off = float(np.abs((used - used.mean(axis=0)) @ normal).max())
            notes.append(f"warning: the design is not flat (up to {off:.4g} off its best-fit plane): the app uses its "
                         f"projection onto that plane, while `xshells deploy` deploys it from the state as drawn")
    return "; ".join(notes) or None


def default_material(layout: Layout) -> dict:
    """The paper's 10 × 7 mm rectangle, scaled down for designs drawn in larger units.

    Bundled designs in mm have segments of ~50–150; a design whose mean
    segment is below 80 units gets a section scaled by ``mean / 80`` so the
    beams stay slender (a 10 mm wide beam on a 1-unit segment cannot be simulated).
    """
    mean = float(layout.segment_lengths().mean()) if layout.num_segments else 80.0
    s = min(1.0, mean / 80.0)
    m = dict(DEFAULT_MATERIAL)
    m["params"] = [float(f"{v * s:.4g}") for v in DEFAULT_MATERIAL["params"]]
    return m


def _safe_name(name: str) -> str:
    base = os.path.basename(str(name).replace("\\", "/")) or "upload"
    return "".join(c if c.isalnum() or c in "._-" else "_" for c in base)[:100]


def parse_design_bytes(name: str, content: bytes):
    """A Design from uploaded bytes, parsed from a private temporary file (the readers take paths)."""
    from ..io import read_design

    ext = os.path.splitext(name)[1].lower()
    with tempfile.TemporaryDirectory(prefix="xshells-upload-") as tmp:
        path = os.path.join(tmp, _safe_name(name))
        with open(path, "wb") as fh:
            fh.write(content)
        try:
            design = read_design(path)
        except InputError as exc:
            # name the upload, not the temporary path
            raise InputError(str(exc).replace(path, _safe_name(name))) from None
        except (ValueError, KeyError, IndexError, UnicodeDecodeError, RuntimeError) as exc:  # meshio's own errors
            raise InputError(f"{_safe_name(name)}: cannot read this {ext} file ({type(exc).__name__})") from None
    return design


class UploadStore:
    """Designs uploaded in this session, by file name, so that an uploaded case can refer to one."""

    def __init__(self, limit: int = MAX_UPLOAD_BYTES):
        self.limit = limit
        self._designs: dict[str, object] = {}

    def open_upload(self, name: str, content: bytes) -> Project:
        """A project from an uploaded file; raises InputError (one line) on anything wrong."""
        name = _safe_name(name)
        if len(content) > self.limit:
            raise InputError(f"{name}: {len(content) / 2**20:.1f} MB is over the {self.limit / 2**20:.0f} MB upload limit")
        ext = os.path.splitext(name)[1].lower()
        if ext in DESIGN_SUFFIXES:
            design = parse_design_bytes(name, content)
            self._designs[name] = design
            layout = layout_from_design(design)
            return Project(os.path.splitext(name)[0], layout, default_material(layout), note=design_note(design), to_file=file_frame(design))
        if ext == ".json":
            return self._case_from_bytes(name, content)
        raise InputError(f"{name}: upload a design (.obj, .msh, .3dm) or a case file (.json)")

    def _case_from_bytes(self, name: str, content: bytes) -> Project:
        from ..io.strict_json import loads

        try:
            spec = loads(content.decode("utf-8"), name)
        except UnicodeDecodeError:
            raise InputError(f"{name}: not valid JSON (not UTF-8)") from None
        from ..io.case_schema import validate_case

        case = validate_case(spec, name)  # the case files' one schema, as for every command
        ref = _safe_name(case.flat_file or case.file)
        design = self._designs.get(ref)
        if design is None:
            raise InputError(f"{name}: upload its design file '{ref}' first (an uploaded case cannot read files by path)")
        material = case.material.model_dump(exclude_none=True) if case.material is not None else dict(DEFAULT_MATERIAL)
        if material.get("type") == "contour":
            raise InputError(f"{name}: uploaded cases support parametric materials only (type, params, E, nu)")
        if case.rest_lengths:
            raise InputError(f"{name}: rest-length files are not read from uploads; remove 'rest_lengths'")
        if case.guide:
            raise InputError(f"{name}: guide files are not read from uploads; remove 'guide' (open the case by path)")
        if case.open_by_deg is not None:
            raise InputError(f"{name}: the app deploys to an angle, not by one: give angle_deg instead of open_by_deg")
        angle = case.angle_deg if case.angle_deg is not None else (
            float(np.degrees(case.angle_rad)) if case.angle_rad is not None else None)
        # an uploaded case without a subdivision keeps the app's own default (8), not the case files' (10)
        sub = case.subdivision if "subdivision" in spec else 8
        return Project(case.name or os.path.splitext(name)[0], layout_from_design(design), material, sub, angle,
                       direction=case.direction or "up", note=design_note(design), to_file=file_frame(design), steps=case.steps)


def grid_project(nx: int, ny: int, angle_deg: float = 90.0, spacing: float = 100.0) -> Project:
    """A regular rhombic grid of ``nx`` × ``ny`` segments crossing at ``angle_deg``."""
    from ..linkage.grids import rhombic_grid

    if not (1 <= nx <= 60 and 1 <= ny <= 60):
        raise InputError(f"grid size must be 1 to 60 segments per side, got {nx} × {ny}")
    if not 5 <= angle_deg <= 175:
        raise InputError(f"grid angle must lie between 5° and 175°, got {angle_deg}")
    if not spacing > 0:
        raise InputError(f"grid spacing must be positive, got {spacing}")
    d = rhombic_grid(nx, ny, spacing=spacing, angle=np.radians(angle_deg))
    layout = layout_from_design(d)
    return Project(f"grid_{nx}x{ny}", layout, default_material(layout))
