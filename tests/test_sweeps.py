"""Design-space sweeps: Dask cluster vs serial, failures recorded, resume, spec errors."""
import csv
import json
import math
import os

import numpy as np
import pytest

from xshells.cli import main
from xshells.errors import InputError
from xshells.io.export import write_design_obj
from xshells.linkage.grids import rhombic_grid
from xshells.sweeps import SweepSettings, load_spec, run_sweep, spec_from_dict
from xshells.sweeps.summary import write_summary
from xshells.sweeps.tasks import REGISTRY, register_task

from data_paths import EXAMPLES

ANGLES = [60, 65, 70, 75, 80, 85, 90, 179.9]  # 179.9°: a joint inverts on the way, the task ends "diverged"
RESULTS = ("energy", "average_angle_deg", "max_abs_z", "torque", "flat_energy")


def small_grid(path):
    """A 3×3 grid whose joint spacing shrinks towards the rim: it buckles, in about a second."""
    def warp(p):
        r = np.linalg.norm(p, axis=1, keepdims=True)
        return p * (1.0 - 0.25 * (r / r.max()) ** 2)

    write_design_obj(path, rhombic_grid(3, 3, spacing=100.0, angle=np.radians(30), warp=warp))


@pytest.fixture(scope="module")
def sweep_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("spec")
    small_grid(d / "grid.obj")
    spec = {"name": "grid", "task": "deploy",
            "base": {"file": "grid.obj", "subdivision": 4, "steps": 4,
                     "material": {"type": "rectangle", "E": 2000, "nu": 0.3, "params": [4.0, 1.5]}},
            "axes": {"angle_deg": ANGLES}}
    path = d / "sweep.json"
    path.write_text(json.dumps(spec))
    return path


@pytest.fixture(scope="module")
def cluster_run(sweep_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("cluster")
    spec = load_spec(sweep_file)
    seen = []
    report = run_sweep(spec, str(out), SweepSettings(workers=2), progress=lambda p: seen.append(p) and False)
    return spec, out, report, seen


def test_two_worker_cluster_finishes_and_records_the_failure(cluster_run):
    spec, out, report, seen = cluster_run
    assert len(spec.tasks) == 8 and report.ran == 8 and not report.stopped
    by_angle = {r["params"]["angle_deg"]: r for r in report.records}
    assert by_angle[179.9]["status"] == "diverged"
    assert "inverts" in by_angle[179.9]["result"]["message"]
    for a in ANGLES[:-1]:
        assert by_angle[float(a)]["status"] == "ok", by_angle[float(a)]["error"]
        assert abs(by_angle[float(a)]["result"]["average_angle_deg"] - a) < 1e-6
    assert len({r["pid"] for r in report.records}) == 2  # really ran on both workers
    # streamed: a folder per task, its marker, the table in sweep order
    with open(out / "results.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["id"] for r in rows] == [t.id for t in spec.tasks]
    assert [r["status"] for r in rows].count("diverged") == 1
    for t in spec.tasks:
        assert (out / "tasks" / t.id / "task.json").is_file()
    assert (out / "tasks" / spec.tasks[0].id / "deployed.png").is_file()
    # progress reached the end with an ETA going to zero
    assert [p.done for p in seen] == list(range(1, 9)) and seen[-1].eta_s == 0.0 and seen[-1].failed == 1
    plots = write_summary(str(out), spec, {r["id"]: r for r in report.records})
    assert {os.path.basename(p) for p in plots} == {"contact_sheet.png", "energy_vs_angle.png"}
    again = run_sweep(spec, str(out), SweepSettings(workers=2))  # all finished: nothing runs, no cluster starts
    assert (again.ran, again.skipped) == (0, 8) and again.wall_s < 2


def test_serial_gives_the_same_numbers(cluster_run, tmp_path):
    spec, _, report, _ = cluster_run
    serial = run_sweep(spec, str(tmp_path), SweepSettings(workers=0, max_tasks=2))
    assert serial.ran == 2 and {r["pid"] for r in serial.records} == {os.getpid()}
    cluster = {r["id"]: r for r in report.records}
    for rec in serial.records:
        for k in RESULTS:
            assert rec["result"][k] == pytest.approx(cluster[rec["id"]]["result"][k], rel=1e-9, abs=1e-12), k


def test_shipped_files_give_the_same_numbers_and_outputs(cluster_run, tmp_path):
    spec, _, report, _ = cluster_run
    shipped = run_sweep(spec, str(tmp_path), SweepSettings(scheduler="serial", ship_files=True, max_tasks=1))
    rec = shipped.records[0]
    assert rec["params"] == spec.tasks[0].params  # recorded as given, not the scratch copy
    ref = next(r for r in report.records if r["id"] == rec["id"])
    assert rec["result"]["energy"] == pytest.approx(ref["result"]["energy"], rel=1e-9)
    assert (tmp_path / "tasks" / rec["id"] / "deployed.png").is_file()


def test_existing_scheduler_with_files_shipped_over_dask(cluster_run, tmp_path):
    from dask.distributed import LocalCluster

    spec, _, report, _ = cluster_run
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as lc:
        rep = run_sweep(spec, str(tmp_path), SweepSettings(scheduler=lc.scheduler_address, ship_files=True, max_tasks=1))
    rec = rep.records[0]
    assert rec["status"] == "ok" and rec["params"] == spec.tasks[0].params
    ref = next(r for r in report.records if r["id"] == rec["id"])
    assert rec["result"]["energy"] == pytest.approx(ref["result"]["energy"], rel=1e-9)
    assert (tmp_path / "tasks" / rec["id"] / "deployed.png").is_file()


def test_local_workers_run_numeric_libraries_on_one_thread(tmp_path, monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/nonexistent")  # a user's own flags are kept
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)  # Dask's default would make tasks 1.5x dearer
    spec = spec_from_dict({"task": "noop", "axes": {"sleep_s": [0.0]}}, str(tmp_path))
    (rec,) = run_sweep(spec, str(tmp_path), SweepSettings(workers=1)).records
    assert rec["pid"] != os.getpid() and rec["result"]["blas_threads"] == "1"
    assert rec["result"]["xla_flags"] == "--xla_dump_to=/nonexistent --xla_cpu_multi_thread_eigen=false"
    assert rec["result"]["malloc_trim_threshold"] == ""
    # this process's environment is left as it was
    assert os.environ["XLA_FLAGS"] == "--xla_dump_to=/nonexistent" and "OPENBLAS_NUM_THREADS" not in os.environ


def test_interrupted_sweep_resumes_without_recomputing(tmp_path):
    spec = spec_from_dict({"task": "noop", "axes": {"sleep_s": [0.0, 0.001, 0.002, 0.003, 0.004]}}, str(tmp_path))
    first = run_sweep(spec, str(tmp_path), SweepSettings(workers=0), progress=lambda p: p.done == 2)
    assert first.stopped and first.ran == 2
    marks = {t.id: os.stat(tmp_path / "tasks" / t.id / "task.json").st_mtime_ns
             for t in spec.tasks if (tmp_path / "tasks" / t.id / "task.json").exists()}
    assert len(marks) == 2
    again = run_sweep(spec, str(tmp_path), SweepSettings(workers=0))
    assert (again.ran, again.skipped, len(again.records)) == (3, 2, 5)
    for tid, mtime in marks.items():
        assert os.stat(tmp_path / "tasks" / tid / "task.json").st_mtime_ns == mtime
    assert run_sweep(spec, str(tmp_path), SweepSettings(workers=0)).ran == 0


def test_ctrl_c_on_a_local_cluster_is_one_line_and_keeps_the_finished_tasks(tmp_path):
    # The terminal sends Ctrl-C to the whole process group: each Dask worker printed its traceback
    # (asyncio's CancelledError, then KeyboardInterrupt) before the sweep's own line.
    import signal
    import subprocess
    import sys
    import time

    from data_paths import REPO

    (tmp_path / "s.yaml").write_text("task: noop\naxes:\n  sleep_s: [0.5, 2, 2.1, 2.2, 2.3]\n")
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "xshells.cli", "sweep", str(tmp_path / "s.yaml"), "--out", str(out),
                             "--workers", "1", "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, env=dict(os.environ, PYTHONPATH=str(REPO)))
    try:
        deadline = time.time() + 60
        while not list(out.glob("tasks/*/task.json")):
            assert proc.poll() is None and time.time() < deadline, proc.communicate()
            time.sleep(0.05)
        time.sleep(0.2)  # the next task is running
    finally:
        os.killpg(proc.pid, signal.SIGINT)  # as the terminal does
        err = proc.communicate(timeout=60)[1]
    assert (proc.returncode, err) == (130, "xshells sweep: interrupted\n")
    with open(out / "results.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["sleep_s"] for r in rows] == ["0.5"] and rows[0]["status"] == "ok"


def test_an_output_folder_of_another_sweep_is_refused_and_the_same_one_extended(tmp_path):
    a = spec_from_dict({"name": "a", "task": "noop", "axes": {"sleep_s": [0.0, 0.001]}}, str(tmp_path))
    assert run_sweep(a, str(tmp_path / "out"), SweepSettings(workers=0)).ran == 2
    b = spec_from_dict({"name": "b", "task": "noop", "axes": {"sleep_s": [0.0]}}, str(tmp_path))
    with pytest.raises(InputError, match=r"holds the sweep 'a' \(task noop\), not 'b'"):  # its manifest was replaced
        run_sweep(b, str(tmp_path / "out"), SweepSettings(workers=0))
    more = spec_from_dict({"name": "a", "task": "noop", "axes": {"sleep_s": [0.0, 0.001, 0.002]}}, str(tmp_path))
    rep = run_sweep(more, str(tmp_path / "out"), SweepSettings(workers=0))  # the same sweep, one value more
    assert (rep.ran, rep.skipped) == (1, 2)


def test_failed_tasks_are_kept_unless_retried(tmp_path):
    spec = spec_from_dict({"task": "noop", "axes": {"fail": [False, "boom"]}}, str(tmp_path))
    rep = run_sweep(spec, str(tmp_path), SweepSettings(workers=0))
    assert [r["status"] for r in rep.records] == ["ok", "failed"] and rep.records[1]["error"] == "RuntimeError: boom"
    assert run_sweep(spec, str(tmp_path), SweepSettings(workers=0)).ran == 0
    assert run_sweep(spec, str(tmp_path), SweepSettings(workers=0, retry_failed=True)).ran == 1


def test_task_ids_are_stable_and_follow_file_contents(tmp_path):
    small_grid(tmp_path / "grid.obj")
    d = {"base": {"file": "grid.obj", "angle_deg": 80}, "axes": {"E": [1000, 2000.0]}}
    a, b = spec_from_dict(d, str(tmp_path)), spec_from_dict(d, str(tmp_path))
    assert [t.id for t in a.tasks] == [t.id for t in b.tasks] and len({t.id for t in a.tasks}) == 2
    assert spec_from_dict({**d, "axes": {"E": [1000.0, 2000]}}, str(tmp_path)).tasks[0].id == a.tasks[0].id
    with open(tmp_path / "grid.obj", "a") as fh:
        fh.write("# edited\n")
    assert spec_from_dict(d, str(tmp_path)).tasks[0].id != a.tasks[0].id


def test_axes_combine_as_a_product_with_globs_and_cases(tmp_path):
    for n in ("a", "b"):
        small_grid(tmp_path / f"{n}.obj")
    spec = spec_from_dict({"base": {"angle_deg": 70}, "axes": {"file": ["*.obj"], "material.params": [[4, 1.5], [5, 2]]},
                           "cases": [{}, {"E": 1000, "angle_deg": 60}]}, str(tmp_path))
    assert len(spec.tasks) == 8 and spec.varying_keys[:2] == ("file", "material.params")  # axes first
    assert set(spec.varying_keys[2:]) == {"material.E", "angle_deg"}
    assert spec.tasks[0].varying["file"] == "a.obj" and spec.tasks[2].varying["file"] == "b.obj"
    assert spec.tasks[0].params["material"]["type"] == "rectangle"  # the case-file default material


@pytest.mark.parametrize("data, key", [
    ({"base": {"file": "grid.obj"}, "axis": {}}, "axis: unknown key"),
    ({"base": {"file": "grid.obj", "angel_deg": 70}}, "base.angel_deg: unknown key (did you mean 'angle_deg'?)"),
    ({"base": {"file": "grid.obj"}, "axes": {"angle_deg": []}}, "axes.angle_deg: empty axis"),
    ({"base": {"file": "missing.obj"}}, "base.file: no such file 'missing.obj'"),
    ({"base": {"file": "grid.obj"}, "axes": {"file": ["*.msh"]}}, "axes.file[0]: no file matches"),
    ({"base": {"file": "grid.obj", "steps": "ten"}}, "base.steps: Input should be a valid integer"),
    ({"base": {"file": "grid.obj"}, "axes": {"E": [2000, -1]}}, "axes.E[1]: Input should be greater than 0, got -1"),
    ({"base": {"file": "grid.obj"}, "axes": {"angle_deg": [60, 185]}}, "axes.angle_deg[1]: Input should be less than 180"),
    ({"base": {"file": "grid.obj", "angle_deg": 60, "open_by_deg": 10}}, "give one of angle_deg, angle_rad, open_by_deg"),
    ({"base": {"file": "grid.obj", "material": {"type": "rectangle", "parms": [1, 2]}}}, "base.material.parms: unknown key"),
    ({"base": {"file": "grid.obj"}, "axes": {"eta": [0.1]}}, "axes.eta: unknown key"),
    ({"task": "sparsify", "base": {"file": "grid.obj"}, "axes": {"p": [0.5, 2]}}, "axes.p[1]: Input should be less than or equal to 1, got 2"),
    ({"task": "explode", "base": {"file": "grid.obj"}}, "task: unknown task 'explode'"),
    ({"base": {"file": "grid.obj"}, "cases": [{"material": {"type": "recangle"}}]}, "'material': unknown cross-section type"),
    ({"base": {"file": "grid.obj"}, "axes": {"params": [[4, 1.5], [4]]}}, "key 'material': rectangle takes 2 parameters"),
    ({"axes": {"angle_deg": [70]}}, "base.file: missing"),
    ({"base": {"file": "grid.obj", "start": "joint"}}, "base.start: Input should be 'auto', 'average' or 'central-joint'"),
])
def test_spec_errors_name_the_key(tmp_path, data, key):
    small_grid(tmp_path / "grid.obj")
    with pytest.raises(InputError) as exc:
        spec_from_dict(data, str(tmp_path))
    assert key in str(exc.value) and "\n" not in str(exc.value)


def test_a_task_whose_module_is_missing_is_refused_before_anything_runs(tmp_path, capsys):
    register_task("later", "xshells.not_written_yet:sweep_task")
    try:
        (tmp_path / "s.yaml").write_text("task: later\nbase: {file: grid.obj}\n")
        small_grid(tmp_path / "grid.obj")
        assert main(["sweep", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip()
        assert err == "xshells sweep: error: task 'later' is not available yet"
        assert not (tmp_path / "out").exists()
    finally:
        del REGISTRY["later"]


def test_cli_serial_sweep_and_bad_yaml(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text("task: noop\naxes:\n  sleep_s: [0, 0.001]\n")
    assert main(["sweep", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out"), "--workers", "0", "--no-progress"]) == 0
    assert "2 tasks, 2 run now" in capsys.readouterr().out
    assert main(["sweep", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "o3"), "--max-tasks", "-1"]) == 2
    assert "--max-tasks must be at least 1" in capsys.readouterr().err
    (tmp_path / "bad.yaml").write_text("task: [noop\n")
    assert main(["sweep", str(tmp_path / "bad.yaml"), "--out", str(tmp_path / "o2")]) == 2
    assert "not valid YAML" in capsys.readouterr().err


def test_optimize_and_sparsify_are_registered_and_available():
    from xshells.sweeps.tasks import get_task

    assert {"deploy", "optimize", "sparsify", "noop"} <= set(REGISTRY)
    assert get_task("sparsify").params.keys() >= {"eta", "p"}
    assert get_task("optimize").params.keys() >= {"gamma", "beta"}


def _fake_sparsify(params, out_dir):
    n = max(1, round(8 * (1 - params["eta"]) * params["p"]))
    return {"num_actuators": n, "fit_mean": 0.01 / n}


def test_tradeoff_plot_from_the_column_names(tmp_path):
    from xshells.sweeps.tasks import number

    register_task("fake_sparsify", _fake_sparsify, case=False, params={"p": number(0), "eta": number(0)})
    try:
        spec = spec_from_dict({"task": "fake_sparsify", "axes": {"p": [1, 0.5], "eta": [0.1, 0.5, 0.9]}}, str(tmp_path))
        rep = run_sweep(spec, str(tmp_path), SweepSettings(workers=0))
        plots = write_summary(str(tmp_path), spec, {r["id"]: r for r in rep.records})
        assert [os.path.basename(p) for p in plots] == ["tradeoff.png"]
    finally:
        del REGISTRY["fake_sparsify"]


def test_a_real_sparsify_sweep_draws_the_tradeoff_with_default_p_and_yaml_exponents(tmp_path):
    # YAML 1.1 (PyYAML) reads 1e-4 as a string; η is naturally written that way
    small_grid(tmp_path / "grid.obj")
    (tmp_path / "s.yaml").write_text(
        "task: sparsify\nbase:\n  file: grid.obj\n  subdivision: 3\n  steps: 4\n  angle_deg: 60\n"
        "  material: {type: rectangle, E: 2e3, nu: 0.3, params: [4.0, 1.5]}\naxes:\n  eta: [1e-4, 1E-3]\n")
    spec = load_spec(tmp_path / "s.yaml")
    assert [t.params["eta"] for t in spec.tasks] == [1e-4, 1e-3]
    assert spec.tasks[0].params["material"]["E"] == 2000.0
    rep = run_sweep(spec, str(tmp_path / "out"), SweepSettings(workers=0))
    assert not rep.failed, [r["error"] for r in rep.records]
    plots = write_summary(str(tmp_path / "out"), spec, {r["id"]: r for r in rep.records})
    assert "tradeoff.png" in [os.path.basename(p) for p in plots]  # p is the default, not in the spec
    assert all(r["result"]["p"] == 0.5 for r in rep.records)


def test_bundled_example_spec_is_valid():
    spec = load_spec(EXAMPLES / "sweep_example.yaml")
    assert spec.task == "deploy" and len(spec.tasks) == 8


def test_dispatch_size_ranks_larger_designs_first(tmp_path):
    from xshells.sweeps.run import estimated_size

    small_grid(tmp_path / "grid.obj")
    spec = spec_from_dict({"base": {"file": "grid.obj", "subdivision": 4, "steps": 5},
                           "cases": [{}, {"subdivision": 8}, {"steps": 20}]}, str(tmp_path))
    sizes = [estimated_size(t.params) for t in spec.tasks]
    assert sizes[0] > 0 and sizes[1] == 2 * sizes[0] and sizes[2] == 4 * sizes[0]
    assert estimated_size({"file": str(tmp_path / "missing.obj")}) == 0  # the task itself reports the file
    # within a design, a wider deployment ranks first
    base = {"file": str(tmp_path / "grid.obj"), "subdivision": 4, "steps": 5}
    assert estimated_size({**base, "angle_deg": 75}) == 1.25 * estimated_size({**base, "angle_deg": 60})
    assert estimated_size({**base, "angle_rad": math.pi / 2}) == pytest.approx(estimated_size({**base, "angle_deg": 90}))


def test_a_sparsify_sweep_without_eta_runs_the_elimination_and_draws_its_curve(tmp_path):
    small_grid(tmp_path / "grid.obj")
    (tmp_path / "s.yaml").write_text(
        "task: sparsify\nbase:\n  file: grid.obj\n  subdivision: 3\n  steps: 4\n  angle_deg: 60\n"
        "  material: {type: rectangle, E: 2e3, nu: 0.3, params: [4.0, 1.5]}\naxes:\n  max_fit: [0.002, 0.01]\n")
    spec = load_spec(tmp_path / "s.yaml")
    rep = run_sweep(spec, str(tmp_path / "out"), SweepSettings(workers=0))
    assert not rep.failed, [r["error"] for r in rep.records]
    res = [r["result"] for r in rep.records]
    assert all(r["method"] == "elimination" and r["fit_mean"] <= r["max_fit"] for r in res)
    assert res[1]["num_actuators"] <= res[0]["num_actuators"]
    plots = write_summary(str(tmp_path / "out"), spec, {r["id"]: r for r in rep.records})
    assert "tradeoff.png" in [os.path.basename(p) for p in plots]


def test_a_sparsify_spec_mixing_the_two_methods_is_refused_before_anything_runs(tmp_path):
    # it was found only when the task ran (recorded as failed, exit 1), though docs/sweeps.md promised otherwise
    from xshells.errors import InputError

    small_grid(tmp_path / "grid.obj")
    with pytest.raises(InputError, match=r"^sweep task 0: .*not both"):
        spec_from_dict({"task": "sparsify", "base": {"file": "grid.obj", "subdivision": 3, "steps": 4, "angle_deg": 60,
                                                     "eta": 1e-3, "max_fit": 0.01}}, str(tmp_path))


def test_a_sweep_of_more_tasks_than_the_limit_is_refused_before_it_is_expanded(tmp_path, capsys):
    # 1.58 million tasks were expanded and checked (minutes, gigabytes) before the first one ran
    import time

    from xshells.sweeps.spec import MAX_TASKS

    spec = tmp_path / "huge.yaml"
    spec.write_text(f"task: noop\naxes:\n  sleep_s: {[i / 1000 for i in range(400)]}\ncases: {[{}] * 251}\n")
    t0 = time.perf_counter()
    assert main(["sweep", str(spec), "--out", str(tmp_path / "out"), "--workers", "0", "--no-progress"]) == 2
    assert time.perf_counter() - t0 < 5
    assert capsys.readouterr().err == ("xshells sweep: error: axes: 251 cases × sleep_s 400 make 100,400 tasks, more "
                                       f"than the limit of {MAX_TASKS:,}: give fewer values, or --force to run them all\n")
    assert not (tmp_path / "out").exists()
    data = {"task": "noop", "axes": {"sleep_s": [0, 1]}, "cases": [{}, {"fail": True}]}
    with pytest.raises(InputError, match=r"^axes: 2 cases × sleep_s 2 make 4 tasks, more than the limit of 3: "):
        spec_from_dict(data, str(tmp_path), max_tasks=3)
    assert len(spec_from_dict(data, str(tmp_path), max_tasks=None).tasks) == 4  # what --force passes


@pytest.mark.parametrize("task, module, runner", [("sparsify", "xshells.actuation.run", "run_selection"),
                                                  ("optimize", "xshells.design.run", "run_optimize")])
def test_sparsify_and_optimize_tasks_get_the_direction_in_their_case(tmp_path, monkeypatch, task, module, runner):
    # the case file a task wrote left direction out: a sparsify sweep over [up, down] ran "up" twice
    import importlib

    seen = []

    def fake(case, out_dir, *args, **kwargs):
        seen.append(json.loads(open(case).read()).get("direction"))
        raise RuntimeError("stop here")

    monkeypatch.setattr(importlib.import_module(module), runner, fake)
    small_grid(tmp_path / "grid.obj")
    spec = spec_from_dict({"task": task, "base": {"file": "grid.obj", "angle_deg": 60}, "axes": {"direction": ["up", "down"]}},
                          str(tmp_path))
    run_sweep(spec, str(tmp_path / "out"), SweepSettings(workers=0))
    assert seen == ["up", "down"]


@pytest.mark.parametrize("task", ["sparsify", "optimize"])
def test_start_is_refused_for_the_tasks_that_do_not_use_it(tmp_path, task):
    small_grid(tmp_path / "grid.obj")
    with pytest.raises(InputError, match=rf"^axes.start\[0\]: only the deploy task takes start .*the {task} task does not"):
        spec_from_dict({"task": task, "base": {"file": "grid.obj"}, "axes": {"start": ["average"]}}, str(tmp_path))
    assert spec_from_dict({"base": {"file": "grid.obj"}, "axes": {"start": ["average"]}}, str(tmp_path)).tasks


def curved_quad(path):
    """A .3dm of four arcs around a 80 × 314 rectangle: read only with --sample."""
    rhino3dm = pytest.importorskip("rhino3dm")
    f = rhino3dm.File3dm()
    f.Settings.ModelUnitSystem = rhino3dm.UnitSystem.Millimeters
    corners = [(-40, -157), (-40, 157), (40, 157), (40, -157)]
    for (x0, y0), (x1, y1) in zip(corners, corners[1:] + corners[:1]):
        mid = rhino3dm.Point3d(0.55 * (x0 + x1), 0.55 * (y0 + y1), 0)
        f.Objects.AddCurve(rhino3dm.Arc(rhino3dm.Point3d(x0, y0, 0), mid, rhino3dm.Point3d(x1, y1, 0)).ToNurbsCurve())
    assert f.Write(str(path), 7)
    return path


def test_layer_and_sample_are_task_parameters(tmp_path):
    # they were set in the client process only: workers refused the curved design ("give --sample N"), and a
    # re-run with another --sample took the earlier result for its own (the task id did not change)
    from xshells.io import read_design
    from xshells.rhino.read import set_defaults
    from xshells.sweeps.run import execute_task

    curved_quad(tmp_path / "c.3dm")
    small_grid(tmp_path / "grid.obj")
    data = {"base": {"file": "c.3dm", "subdivision": 3, "steps": 2}}
    s4, s8 = (spec_from_dict(data, str(tmp_path), design_options={"layer": None, "sample": n}) for n in (4, 8))
    assert s4.tasks[0].params["sample"] == 4 and s4.tasks[0].id != s8.tasks[0].id
    assert "sample" not in spec_from_dict(data, str(tmp_path)).tasks[0].params
    mixed = spec_from_dict({"base": {"subdivision": 3}, "axes": {"file": ["c.3dm", "grid.obj"]}}, str(tmp_path),
                           design_options={"sample": 4})
    assert [t.params.get("sample") for t in mixed.tasks] == [4, None]  # an .obj task's id is the same as without
    assert mixed.tasks[1].id == spec_from_dict({"base": {"file": "grid.obj", "subdivision": 3}}, str(tmp_path)).tasks[0].id
    with pytest.raises(InputError, match=r"^--sample reads a .3dm design: no task's file is one$"):
        spec_from_dict({"base": {"file": "grid.obj"}}, str(tmp_path), design_options={"sample": 4})
    with pytest.raises(InputError, match=r"^--sample must be from 1 to 1000 segments per curve, got 0$"):
        spec_from_dict(data, str(tmp_path), design_options={"sample": 0})
    set_defaults()  # as in a worker process: the command line's options never reached it
    rec = execute_task("count", lambda p, out: {"segments": read_design(p["file"]).num_segments}, s8.tasks[0].id,
                       s8.tasks[0].params, str(tmp_path / "t"), None)
    assert rec["status"] == "ok" and rec["result"]["segments"] == 32


def test_a_3dm_sweep_with_sample_runs_on_workers_and_reruns_for_another_sample(tmp_path, capsys, reset_3dm_options):
    curved_quad(tmp_path / "c.3dm")
    (tmp_path / "s.yaml").write_text("base: {file: c.3dm, subdivision: 3, steps: 2, material: {params: [4, 2]}}\n")
    out = str(tmp_path / "out")
    for workers, n in (("1", 4), ("0", 8)):
        main(["sweep", str(tmp_path / "s.yaml"), "--out", out, "--workers", workers, "--sample", str(n), "--no-progress"])
        assert "1 run now" in capsys.readouterr().out
        rec = [json.loads(p.read_text()) for p in (tmp_path / "out" / "tasks").glob("*/task.json")]
        assert sorted(r["result"].get("segments") for r in rec) == ([16] if n == 4 else [16, 32]), rec[-1]["error"]


@pytest.mark.parametrize("base", [{"E": 2e4}, {"material": {"E": 2e4}}, {"material": {"type": "rectangle"}}, {"nu": 0.3},
                                  {"material": {"type": "Rect", "params": []}}])
def test_a_partial_material_gets_the_case_file_default_for_each_missing_key(tmp_path, base):
    # only a base without any material key got the defaults: E alone was refused ("rectangle takes 2 parameters")
    small_grid(tmp_path / "grid.obj")
    spec = spec_from_dict({"base": {"file": "grid.obj", **base}}, str(tmp_path))
    material = spec.tasks[0].params["material"]
    assert {**material, "type": material["type"].lower()} in (
        {"type": t, "E": 20000, "nu": 0.3, "params": [10, 7]} for t in ("rectangle", "rect"))


@pytest.mark.parametrize("data, words", [
    # an ellipse axis ran with the default rectangle's 10 × 7, where a case file refuses it
    ({"axes": {"material.type": ["rectangle", "ellipse"]}}, "sweep task 1: key 'material': type 'ellipse' needs its "
                                                            "dimensions in 'params'"),
    ({"base": {"material": {"type": "contour"}}}, "sweep task 0: key 'material': type 'contour' needs contour_file"),
])
def test_a_material_is_refused_as_a_case_file_refuses_it(tmp_path, data, words):
    small_grid(tmp_path / "grid.obj")
    data["base"] = {"file": "grid.obj", **data.get("base", {})}
    with pytest.raises(InputError) as exc:
        spec_from_dict(data, str(tmp_path))
    assert str(exc.value).startswith(words)


@pytest.mark.parametrize("data, words", [
    # the later silently replaced the other: 1 rad ran, 60° did not
    ({"axes": {"angle_deg": [60], "angle_rad": [1]}}, "axes.angle_deg and axes.angle_rad: give one of"),
    # refused as "tasks 0 and 1 have identical parameters"
    ({"axes": {"open_by_deg": [30]}, "cases": [{"angle_deg": 60}, {"angle_deg": 70}]},
     "cases[0].angle_deg and axes.open_by_deg: give one of"),
    ({"cases": [{}, {"angle_deg": 60, "open_by_deg": 5}]}, "cases[1].angle_deg and cases[1].open_by_deg: give one of"),
])
def test_two_kinds_of_angle_together_are_refused_naming_both(tmp_path, data, words):
    small_grid(tmp_path / "grid.obj")
    with pytest.raises(InputError) as exc:
        spec_from_dict({"base": {"file": "grid.obj"}, **data}, str(tmp_path))
    assert str(exc.value).startswith(words) and str(exc.value).endswith("(they set the same angle)")
    # an axis of another kind replaces the base's angle
    spec = spec_from_dict({"base": {"file": "grid.obj", "angle_deg": 70}, "axes": {"open_by_deg": [20, 30]}}, str(tmp_path))
    assert [t.params.get("angle_deg") for t in spec.tasks] == [None, None]


def test_local_workers_are_at_most_one_per_task_and_core(tmp_path, capsys):
    # --workers 1000 for one task started 1000 worker processes on 2 cores and hung
    from xshells.sweeps.run import _cores, local_workers

    cores = _cores()
    assert local_workers(None, 100) == (cores, "") and local_workers(1, 100) == (1, "")
    assert local_workers(1000, 1) == (1, "--workers 1000: 1 local worker (1 task to run)" if cores > 1 else
                                      "--workers 1000: 1 local worker (1 core here)")
    assert local_workers(1000, 10**6)[0] == cores
    (tmp_path / "s.yaml").write_text("task: noop\nbase: {sleep_s: 0}\n")
    assert main(["sweep", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out"), "--workers", "1000", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("note: --workers 1000: 1 local worker (") and "1 tasks, 1 run now" in out


@pytest.mark.parametrize("data, words", [
    ({"base": {"file": "grid.obj", "E": 1e4, "material": {"E": 3e4}}}, "base: E and material.E name the same key"),
    ({"base": {"file": "grid.obj"}, "cases": [{"E": 1e4, "young": 2e4}]}, "cases[0]: E and young name the same key"),
    ({"base": {"file": "grid.obj", "material": {"E": 1e4, "young": 2e4}}}, "base: material.E and material.young name"),
    ({"base": {"file": "grid.obj"}, "axes": {"E": [1e4], "material.E": [2e4]}}, "axes: E and material.E name the same key"),
])
def test_one_key_given_twice_through_an_alias_is_refused_naming_both(tmp_path, data, words):
    # the later was kept without a word
    small_grid(tmp_path / "grid.obj")
    with pytest.raises(InputError) as exc:
        spec_from_dict(data, str(tmp_path))
    assert str(exc.value).startswith(words) and str(exc.value).endswith("(material.E): give it once")


def test_a_file_that_is_not_a_design_is_refused_before_anything_runs(tmp_path):
    # a glob's stray .txt was accepted and failed when its task ran
    small_grid(tmp_path / "grid.obj")
    (tmp_path / "notes.txt").write_text("not a design")
    with pytest.raises(InputError) as exc:
        spec_from_dict({"base": {"subdivision": 3}, "axes": {"file": ["*"]}}, str(tmp_path))
    assert str(exc.value) == ("axes.file[1]: 'notes.txt' is not a design file (unknown type '.txt': expected .obj, "
                              ".msh or .3dm)")


def test_the_errors_shown_in_the_docs_are_the_ones_given(tmp_path):
    # docs/sweeps.md showed "must be > 0, got -1" where pydantic's words came (as for a case file)
    from data_paths import REPO

    small_grid(tmp_path / "grid.obj")
    with pytest.raises(InputError) as exc:
        spec_from_dict({"base": {"file": "grid.obj"}, "axes": {"E": [20000, -1]}}, str(tmp_path))
    assert f"xshells sweep: error: {exc.value}\n" in (REPO / "docs" / "sweeps.md").read_text()
