"""Faults found by a re-check of ``xshells app`` (session level; the page's parts through their functions)."""
from __future__ import annotations

import json
import os
import threading
import time
import zipfile

import numpy as np
import pytest

from xshells.app import core
from xshells.app.loading import Project, grid_project, open_path

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLES = os.path.join(ROOT, "xshells", "data", "examples")


def _session(tmp_path, angle=40.0):
    from xshells.app.session import Session

    s = Session(open_path(os.path.join(EXAMPLES, "nonuniform_linkage.obj")), out_dir=str(tmp_path))
    events = []
    s.listeners.append(lambda e, p: events.append((e, p)))
    assert s.set_subdivision(4) is not False
    if angle is not None:
        s.request_angle(angle)
        assert s.worker.wait_idle(120) and s.last_deployed.info.converged
    return s, events


def _statuses(events):
    return [p for e, p in events if e == "status"]


def _fake_optimize(monkeypatch, factor=1.0):
    """adapters.run_optimize as a run that makes no progress (factor 1) or changes the rest lengths by ``factor``;
    it records the rest lengths of the linkage each run starts from."""
    from xshells.app import adapters

    starts = []

    def run(linkage, target, *, progress, cancel, max_iterations=None):
        p0 = np.array(linkage.rest_lengths, float)
        starts.append(p0)
        progress(0, 1.0, "J = 1")
        terms = {"J": 1.0, "flat_energy": 0.1, "deployed_energy": 10.0}
        return adapters.OptimizeOutcome(p0 * factor, "no progress possible (fake)" if factor == 1 else "fake", factor != 1,
                                        0, terms, terms, p0.copy())

    monkeypatch.setattr(adapters, "run_optimize", run)
    return starts


def test_an_optimization_that_changes_nothing_leaves_the_design_exactly_as_it_was(tmp_path, monkeypatch):
    """The boat at 62°: Optimize stopped with "no progress possible", yet the session then held rest lengths of its
    own: J at iteration 0 of the next run differed (0.2632 vs 0.2049) and the exported case deployed to a mirrored
    dome. Round trip: the case exported after such a run deploys to the joints shown."""
    from xshells.cli import main

    starts = _fake_optimize(monkeypatch)
    s, events = _session(tmp_path)
    try:
        sim, shown = s.sim, s.last_deployed.joints.copy()
        for _ in range(2):
            s.optimize(40.0, max_iterations=1)
            time.sleep(0.2)
            assert s.worker.wait_idle(120), s.worker.last_error
            assert s.rest_lengths is None and s.sim is sim
            assert "rest lengths unchanged" in _statuses(events)[-2] or "unchanged" in " ".join(_statuses(events)[-3:])
        assert np.array_equal(starts[0], starts[1])  # the second run starts from the same design
        assert np.abs(s.last_deployed.joints - shown).max() <= 1e-9 * s.layout.span()
        case = s.export("case")[0]
        assert json.load(open(case)).get("rest_lengths") is None
        assert main(["deploy", case, "--out", str(tmp_path / "cli"), "--no-progress"]) == 0
        with open(tmp_path / "cli" / "result.json") as fh:
            joints = np.array(json.load(fh)["deployed"]["joint_positions"])
        assert np.abs(joints - shown).max() <= 1e-8 * s.layout.span()
    finally:
        s.close()


def test_an_optimized_case_says_at_export_that_xshells_deploy_starts_from_flat(tmp_path, monkeypatch):
    _fake_optimize(monkeypatch, factor=1.001)
    s, events = _session(tmp_path)
    try:
        s.optimize(40.0, max_iterations=1)
        time.sleep(0.2)
        assert s.worker.wait_idle(120), s.worker.last_error
        assert s.rest_lengths is not None and s.last_warm is not None
        # compared with a cold deployment, as `xshells deploy` of the exported case does it
        assert [p for e, p in events if e == "branch"]
        s.export("case")
        assert "xshells deploy" in s.export_note and "flat state" in s.export_note
        s.export("svg")
        assert s.export_note == ""
    finally:
        s.close()


def test_bad_material_values_are_refused_by_name_and_change_nothing(tmp_path):
    """E = −5 or 0 became 1e-9 MPa, ν = 0.7 → 0.49, ν = −2 → −0.99, edges per segment 1 → 3, silently."""
    s, events = _session(tmp_path, angle=None)
    try:
        spec, k = dict(s.material_spec), s.subdivision
        for E, nu, sub, field in ((-5, 0.3, None, "E must"), (0, 0.3, None, "E must"), (20000, 0.7, None, "ν must"),
                                  (20000, -2, None, "ν must"), (20000, 0.3, 1, "edges per segment"),
                                  (20000, 0.3, 4.5, "edges per segment"), (float("nan"), 0.3, None, "E must")):
            assert not s.set_material("rectangle", [10, 7], E, nu, subdivision=sub)
            assert field in _statuses(events)[-1] and "kept" in _statuses(events)[-1]
            assert s.material_spec == spec and s.subdivision == k
        assert not s.set_subdivision(1) and s.subdivision == k and "3 to 30" in _statuses(events)[-1]
        assert s.set_material("rectangle", [10, 7], 30000, 0.35, subdivision=5) and s.subdivision == 5
    finally:
        s.close()


def test_the_simulation_cache_key_is_the_material_values_not_an_id(tmp_path):
    """An id is reused once its dict is freed: a changed material could find a stale simulation."""
    s, _ = _session(tmp_path, angle=None)
    try:
        key = s._key()
        s.material_spec.update(E=float(s.material_spec.get("E", 20000.0)) * 2)  # the same dict (same id), other values
        assert s._key() != key
        s.rest_lengths = np.ones(s.layout.num_segments)
        k1 = s._key()
        s.rest_lengths = s.rest_lengths * 2
        assert s._key() != k1
    finally:
        s.close()


def test_a_deployment_that_stopped_short_is_not_exported_as_deployed(tmp_path):
    """The swimming ray stopped before its first step; its OBJ and PNG were still written as `_deployed.*`."""
    from xshells.app.session import Session

    grid = grid_project(4, 4, 70)
    s = Session(Project("bent grid", core.warp_bend(grid.layout, 0.5), grid.material, subdivision=4), out_dir=str(tmp_path))
    try:
        s.request_angle(179.0)
        assert s.worker.wait_idle(120)
        info = s.last_deployed.info
        assert not info.converged
        (path,) = s.export("obj")
        assert "deployed" not in os.path.basename(path) and "stopped_at" in os.path.basename(path)
        assert "did not reach 179.0°" in s.export_note and f"{info.angle_deg:.1f}°" in s.export_note
        s.request_angle(150.0)
        assert s.worker.wait_idle(120) and s.last_deployed.info.converged
        (path,) = s.export("obj")
        assert os.path.basename(path) == "bent_grid_deployed.obj" and s.export_note == ""
    finally:
        s.close()


def test_a_design_that_is_not_flat_is_said_so_when_opened_and_uploaded(tmp_path):
    """The app said "opened nonplanar: 4 segments"; `xshells deploy` warns that it is not flat."""
    from xshells.app.session import Session

    obj = "v 0 0 0\nv 100 0 0\nv 100 100 45\nv 0 100 0\nv 50 50 0\nl 1 5\nl 2 5\nl 3 5\nl 4 5\n"
    path = tmp_path / "bumpy.obj"
    path.write_text(obj)
    assert "not flat" in (open_path(str(path)).note or "")
    s = Session(grid_project(2, 2), out_dir=str(tmp_path))
    events = []
    s.listeners.append(lambda e, p: events.append((e, p)))
    try:
        assert s.open_upload("bumpy.obj", obj.encode())
        assert "not flat" in _statuses(events)[-1] and "best-fit plane" in _statuses(events)[-1]
        assert "not flat" in [p for e, p in events if e == "upload"][-1]
        s.request_angle(80.0)
        assert s.worker.wait_idle(60)
        assert _statuses(events)[-1].endswith(
            "(the design is not flat (up to 14.03 off its best-fit plane): this is its projection onto that plane)")
        assert open_path(os.path.join(EXAMPLES, "manta_ray.obj")).note is None
    finally:
        s.close()


def test_stability_is_judged_with_the_angle_held_and_a_negative_gap_is_not_shown(tmp_path):
    """The boat at 62°: "λmin −3.61e-08, gap λ2/λ1 −1.31" with no word that it is stable with the angle held."""
    from xshells.app.session import stability_text

    text = stability_text(-3.61e-8, -1.31, 4.71e-8)
    assert text.startswith("stability: stable with the angle held") and "gap" not in text and "snap" in text
    assert "gap λ2/λ1 3" in stability_text(1e-3, 3.0, 2e-3)
    assert stability_text(1e-3, 3.0, None).startswith("stability: stable, with the angle held and under a fixed torque")
    assert "unstable" in stability_text(-1e-3, 2.0, -1e-4)
    s, events = _session(tmp_path)
    try:
        lam_free, gap, held = s.sim.stability()
        assert lam_free > 0 and held is None  # no second eigen-solve where the free Hessian says it already
        assert len([p for e, p in events if e == "stability"][-1]) == 3
        # past the torque's limit point (as the boat at 62°): the held one is computed, and no smaller
        from xshells.app import sim as sim_module

        real = sim_module.smallest_eigenvalues
        calls = []

        def shifted(H, M, k=2, shift=None, return_shift=False, **kw):
            calls.append(k)
            out = real(H, M, k=k, shift=shift, return_shift=return_shift, **kw)
            if len(calls) == 1:  # the free Hessian's: as if its lowest mode had turned negative
                lam, sh = out
                return np.array([-abs(lam[0]), lam[1]]), sh
            return out

        sim_module.smallest_eigenvalues = shifted
        try:
            lam_free, gap, held = s.sim.stability()
        finally:
            sim_module.smallest_eigenvalues = real
        assert lam_free < 0 and held is not None and held > 0 and calls == [2, 1]
    finally:
        s.close()


def test_the_status_line_follows_an_edit_and_names_the_problem_it_made():
    """After the second click added the segment, the status still said "segment from joint 159: click its other
    end", and the valence-5 problem showed only further down the panel."""
    from xshells.app.session import Session

    s = Session(grid_project(3, 3))
    events = []
    s.listeners.append(lambda e, p: events.append((e, p)))
    try:
        s.status("segment from joint 5: click its other end")
        lay = s.layout
        deg = np.bincount(lay.edges.ravel(), minlength=lay.num_vertices)
        inner = [int(v) for v in np.flatnonzero(deg == 4)]
        linked = {tuple(sorted(e)) for e in lay.edges.tolist()}
        a, b = next((a, b) for a in inner for b in inner if a < b and (a, b) not in linked)
        assert s.edit(core.add_segment, a, b)
        assert s.problems()
        status = _statuses(events)[-1]
        assert status.startswith("add segment: the layout cannot be simulated: ") and s.problems()[0] in status
        s.undo()
        assert s.edit(core.move_joint, 0, s.layout.vertices[0] + 1.0)
        assert _statuses(events)[-1].startswith("move joint: done")
    finally:
        s.close()


def test_a_workshop_export_downloads_all_its_files_in_one_zip(tmp_path):
    """Cut list downloaded `_cutlist.csv` only; `_joints.csv` and `_bom.json` stayed on the server."""
    from xshells.app.ui import download

    s, _ = _session(tmp_path)
    try:
        for kind in ("cutlist", "strips"):
            paths = s.export(kind)
            assert len(paths) == 3
            name, data = download(paths, kind)
            assert name == f"nonuniform_linkage_{kind}.zip"
            zf = zipfile.ZipFile(__import__("io").BytesIO(data))
            assert sorted(zf.namelist()) == sorted(os.path.basename(p) for p in paths)
            for p in paths:
                assert zf.read(os.path.basename(p)) == open(p, "rb").read()
        (svg,) = s.export("svg")
        assert download([svg], "svg") == (os.path.basename(svg), open(svg, "rb").read())
    finally:
        s.close()


def test_a_newer_angle_supersedes_the_running_solve_without_saying_cancelled(tmp_path):
    """A new angle during the first solve said "solve cancelled" with the bar at 0 while the work went on; the
    start relaxation of a deployment from flat reported nothing."""
    s, events = _session(tmp_path, angle=None)
    try:
        started = threading.Event()
        s.listeners.append(lambda e, p: started.set() if e == "progress" and "assembly" in p[1] else None)
        s.request_angle(30.0)
        assert started.wait(60)
        s.request_angle(35.0)
        assert s.worker.wait_idle(120)
        assert s.last_deployed is not None and s.last_deployed.info.angle_deg == pytest.approx(35.0)
        statuses = _statuses(events)
        assert "solve cancelled" not in statuses, statuses
        assert [p for e, p in events if e == "flat"].__len__() == 1  # the assembly state was built once
        assert any("relaxing the flat state" in p[1] for e, p in events if e == "progress")
        # Cancel still cancels
        s.request_angle(60.0)
        s.cancel()
        assert s.worker.wait_idle(60)
    finally:
        s.close()


def test_the_optimization_result_shows_the_energies_themselves_with_units():
    """It showed "deployed energy: 1 → 1" (the objective's terms, divided by the deployed energy at the start)."""
    from xshells.app.adapters import OptimizeOutcome
    from xshells.app.ui import optimization_summary

    p = np.ones(3)
    out = OptimizeOutcome(p, "done", True, 2, {"J": 0.3, "deployed_energy": 1.0, "flat_energy": 0.16},
                          {"J": 0.2, "deployed_energy": 0.9, "flat_energy": 0.1}, p, 14506.3)
    text = "\n".join(optimization_summary(out))
    assert "deployed energy: 14506 → 13056 N·mm" in text and "flat energy: 2321 → 1450.6 N·mm" in text
    assert "J: 0.3 → 0.2" in text
    bare = OptimizeOutcome(p, "done", True, 2, {"deployed_energy": 1.0}, {"deployed_energy": 0.9}, p)
    assert "relative to the deployed energy at the start" in "\n".join(optimization_summary(bare))


def test_joint_numbers_are_thinned_where_they_would_overlap():
    """With joint numbers on, a 274-joint design's labels overlapped into an unreadable band."""
    from xshells.app.ui import thin_labels

    rng = np.random.default_rng(0)
    P = np.c_[rng.uniform(-1, 1, (274, 2)), np.zeros(274)]
    keep = thin_labels(P, 0.07)
    assert 0 < len(keep) < 274
    d = np.linalg.norm(P[keep, None, :2] - P[None, keep, :2], axis=2) + np.eye(len(keep))
    assert d.min() >= 0.07
    # every point dropped has a label within the spacing: none left unlabelled for no reason
    rest = np.setdiff1d(np.arange(274), keep)
    assert (np.linalg.norm(P[rest, None, :2] - P[None, keep, :2], axis=2).min(axis=1) < 0.07).all()
    sparse = np.c_[np.arange(5) * 0.5, np.zeros(5), np.zeros(5)]
    assert list(thin_labels(sparse, 0.07)) == list(range(5))


def test_hover_shows_the_files_coordinates_of_a_re_centred_design(tmp_path):
    """The swimming ray (file z ≈ 1e-14) is laid out re-centred in its best-fit plane: the hover showed those."""
    from xshells.app import hover
    from xshells.io import read_design

    rng = np.random.default_rng(2)
    lines = [f"v {1000 + 100 * i} {-500 + 100 * j} {rng.normal() * 1e-14}" for i in range(3) for j in range(3)]
    lines += [f"l {3 * i + j + 1} {3 * i + j + 2}" for i in range(3) for j in range(2)]
    lines += [f"l {3 * i + j + 1} {3 * i + j + 4}" for i in range(2) for j in range(3)]
    path = tmp_path / "offset.obj"
    path.write_text("\n".join(lines) + "\n")
    project = open_path(str(path))
    V = read_design(str(path)).vertices
    assert project.to_file is not None
    assert not np.allclose(project.layout.vertices, V[:, :2])  # the layout is re-centred
    for v in range(len(V)):
        assert hover.flat_label(v, project.layout.vertices[v], project.layout.span(), project.to_file) == \
            f"joint {v}  ({V[v, 0]:.2f}, {V[v, 1]:.2f}, 0.00)"
    assert open_path(os.path.join(EXAMPLES, "manta_ray.obj")).to_file is None


def test_cancel_stops_an_assembly_solve_at_its_next_check_and_says_so(tmp_path, monkeypatch):
    """Cancel (unlike a newer angle for the same design) stops the assembly state being built: the rest-length
    solve takes no cancel callback yet, so the check comes right after it, not after a whole deployment."""
    from xshells.app import sim as sim_module

    inside = threading.Event()
    real = sim_module.rest_length_solve

    def slow(L, *a, **kw):
        inside.set()
        time.sleep(1.0)
        return real(L, *a, **kw)

    monkeypatch.setattr(sim_module, "rest_length_solve", slow)
    s, events = _session(tmp_path, angle=None)
    try:
        s.request_angle(40.0)
        assert inside.wait(60)
        s.cancel()
        assert s.worker.wait_idle(60)
        assert s.last_deployed is None and not [p for e, p in events if e == "flat"]
        assert _statuses(events)[-1] == "solve cancelled"
    finally:
        s.close()


def test_cancel_stops_a_deployment_from_flat_inside_its_step():
    """Cancel was checked only between deployment steps (40 s inside one step on the 1004-segment fans): the app now
    hands deploy a Newton callback, so a Cancel set during a step stops at its next iteration, at the flat state."""
    from xshells.app.session import Session
    from xshells.app.sim import Cancelled, Simulation

    g = grid_project(3, 3, 70)
    sim = Simulation(core.warp_bend(g.layout, 0.3), Session._build_material(g.material), 4)
    flat = sim.linkage.joint_positions().copy()
    cancel = threading.Event()
    seen = []

    def progress(fraction, text):
        seen.append(text)
        if "relaxing" in text:  # before the first step: the next Newton iteration must see it
            cancel.set()

    with pytest.raises(Cancelled):
        sim.solve_to(100.0, cancel=cancel, progress=progress)
    assert len(seen) == 1  # no step finished
    assert np.abs(sim.linkage.joint_positions() - flat).max() < 1e-9 * np.ptp(flat, axis=0).max()
