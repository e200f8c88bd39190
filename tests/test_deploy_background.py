"""Output files written by forked writers (xshells.deploy.background): the same files as inline, errors reported."""
import json
import os

import pytest

from data_paths import EXAMPLES
from xshells.deploy.background import Background
from xshells.errors import InputError

fork_only = pytest.mark.skipif(not hasattr(os, "fork"), reason="no os.fork here: the jobs run inline")


def _append(path, text):
    with open(path, "a") as f:
        f.write(text)


def _fail(message):
    raise InputError(message)


@fork_only
def test_jobs_run_in_a_child_in_order(tmp_path):
    log = tmp_path / "log"
    w = Background(lambda: _append(log, f"first {os.getpid()}\n"), imports=["json"])
    assert w.forked
    for i in range(3):
        w.submit(_append, str(log), f"{i}\n")
    w.join()
    assert not w.forked
    first, *rest = log.read_text().splitlines()
    assert first != f"first {os.getpid()}" and rest == ["0", "1", "2"]


@fork_only
def test_an_error_in_the_child_is_raised_by_join_with_its_traceback(tmp_path):
    w = Background()
    w.submit(_fail, "no such material")
    w.submit(_append, str(tmp_path / "never"), "x")  # after the error: not run
    with pytest.raises(InputError, match="no such material") as info:
        w.join()
    assert "in the background writer" in "".join(getattr(info.value, "__notes__", []))
    assert not (tmp_path / "never").exists()


def test_inline_jobs_run_at_once(tmp_path):
    w = Background(lambda: _append(tmp_path / "a", "1"), inline=True)
    assert not w.forked and (tmp_path / "a").read_text() == "1"
    w.submit(_append, tmp_path / "a", "2")
    assert (tmp_path / "a").read_text() == "12"
    w.join()


@fork_only
def test_a_deployment_writes_the_same_files_in_the_background_as_inline(tmp_path, monkeypatch):
    import xshells.deploy.background as bg
    from xshells.deploy.case import material_from_spec
    from xshells.deploy.run import run_deployment

    started = []
    monkeypatch.setattr(bg.IdleCores, "idle", lambda self: 2.0)  # a spare core, however busy the machine is
    monkeypatch.setattr(bg, "_fork", lambda f=bg._fork: started.append(1) or f())

    material = material_from_spec({"type": "rectangle", "params": [10, 7], "E": 20000, "nu": 0.3})
    results = {}
    for background in (False, True):
        out = tmp_path / str(background)
        results[background] = run_deployment(str(EXAMPLES / "quad.obj"), material, out_dir=str(out), steps=3,
                                              progress=False, background=background)
    assert started  # the second run forked its writers
    inline, forked = tmp_path / "False", tmp_path / "True"
    names = sorted(os.listdir(inline))
    assert names == sorted(os.listdir(forked))
    assert "deployed.3dm" in names and "deployed.png" in names and "flat_layout.dxf" in names
    for name in names:  # the .3dm and .dxf carry a time stamp; the .3dm's state is restored, equal to 1e-12
        if name.endswith((".obj", ".ply", ".csv", ".svg", ".png")) or name == "bom.json":
            assert (inline / name).read_bytes() == (forked / name).read_bytes(), name
    a, b = (json.loads((d / "result.json").read_text()) for d in (inline, forked))
    a.pop("timings_s"), b.pop("timings_s")
    assert a == b


def _record_pid(path):
    _append(path, f"{os.getpid()}\n")


@fork_only
def test_a_second_lane_runs_beside_the_first_and_reports_its_errors(tmp_path):
    w = Background(lambda: _append(tmp_path / "first", "x"), lanes=2)
    w.submit(_record_pid, str(tmp_path / "lane0"))
    w.submit(_record_pid, str(tmp_path / "lane1"), lane=1)
    w.join()
    pids = {(tmp_path / f"lane{i}").read_text() for i in (0, 1)}
    assert len(pids) == 2 and str(os.getpid()) + "\n" not in pids
    assert (tmp_path / "first").read_text() == "x"  # run once, before the lanes split
    w = Background(lanes=2)
    w.submit(_fail, "lane one failed", lane=1)
    with pytest.raises(InputError, match="lane one failed"):
        w.join()


def test_idle_cores_counts_a_busy_interval_as_busy():
    import time

    from xshells.deploy.background import IdleCores

    c = IdleCores()
    t = time.perf_counter()
    while time.perf_counter() - t < 0.3:
        pass
    assert 0.0 <= c.idle() <= (os.cpu_count() or 1) - 0.5
