"""Sparse actuation, faults of the re-check (issue 44): Ctrl-C in an eq. 8 sweep, a second API call on the
same linkage, options the sweep ignored, eq. 8 answers far from the shape, free ends, stale files, options."""
import csv
import json

import numpy as np
import pytest

from xshells.actuation import SelectionOptions, SparsifyOptions, select_actuators, sparsify
from xshells.cli import main
from xshells.errors import InputError
from xshells.linkage.state import restore

from data_paths import EXAMPLES
from test_actuation import dense  # noqa: F401  (the small deployed grid, shared fixture)
from test_actuation_selection import _small_case


# ------------------------------------------------------------------ F2: the API, called twice
def test_a_second_selection_on_the_same_linkage_measures_against_the_same_targets(dense):
    """Both calls left the linkage at the sparse state, and the second took it as its targets: 1 actuator at 2e-15."""
    L, tau, state, flat = dense
    restore(L, state)
    P0 = L.joint_positions()
    r1 = select_actuators(L, tau, SelectionOptions(max_fit=0.01), flat_energy=flat)
    assert np.array_equal(L.joint_positions(), P0)  # handed back at the dense state
    r2 = select_actuators(L, tau, SelectionOptions(max_fit=0.01), flat_energy=flat)
    assert list(r2.actuated) == list(r1.actuated) and r2.fit_mean == pytest.approx(r1.fit_mean, rel=1e-6)
    assert r1.fit_mean > 1e-4  # a real deviation, not the sparse state against itself
    # the answer's state is in the result; the vertices are named beside the joint numbers
    restore(L, r1.state)
    assert np.linalg.norm(L.joint_positions() - P0, axis=1).mean() > 0
    restore(L, state)
    assert list(r1.actuated_vertices) == [int(L.graph.joint_vertex[j]) for j in r1.actuated]
    # explicit targets: the same answer
    r3 = select_actuators(L, tau, SelectionOptions(max_fit=0.01), flat_energy=flat, targets=P0)
    assert list(r3.actuated) == list(r1.actuated)
    with pytest.raises(InputError, match="targets"):
        select_actuators(L, tau, SelectionOptions(max_fit=0.01), targets=P0[:3])


def test_sparsify_twice_and_the_work_needs_the_flat_energy(dense):
    L, tau, state, flat = dense
    restore(L, state)
    P0 = L.joint_positions()
    a = sparsify(L, tau, SparsifyOptions(eta=1e-3, max_iterations=15), flat_energy=flat)
    assert np.array_equal(L.joint_positions(), P0)
    b = sparsify(L, tau, SparsifyOptions(eta=1e-3, max_iterations=15))
    assert b.fit_mean == pytest.approx(a.fit_mean, rel=1e-6) and list(b.actuated) == list(a.actuated)
    assert np.isfinite(a.work) and np.isnan(b.work)  # the absolute energy was reported as the work


# ------------------------------------------------------------------ F8: options checked where they are made
@pytest.mark.parametrize("cls,kwargs,match", [
    (SelectionOptions, dict(max_fit=5.0), "max_fit must be a fraction of the span below 1"),
    (SelectionOptions, dict(tau_max="3"), "tau_max must be a number"),
    (SelectionOptions, dict(full_curve="yes"), "full_curve must be true or false"),
    (SparsifyOptions, dict(max_iterations=-5), "max_iterations must be a whole number of at least 1"),
    (SparsifyOptions, dict(tau_max="3"), "tau_max must be a number"),
    (SparsifyOptions, dict(eta=float("nan")), "eta must be a finite number"),
    (SparsifyOptions, dict(tolerance=0.0), "tolerance must be positive"),
])
def test_bad_options_are_named(cls, kwargs, match):
    with pytest.raises(InputError, match=match):
        cls(**kwargs)


# ------------------------------------------------------------------ the command line
def _run(tmp_path, case, *argv):
    return main(["sparsify", str(case), "--out", str(tmp_path / "out"), "--no-progress", *argv])


@pytest.mark.parametrize("argv,match", [
    (["--candidates", "99"], "candidate joint 99 is out of range"),  # was ignored, exit 0
    (["--actuators", "3"], "--actuators does not apply to --sweep --etas"),
    (["--eta", "1e-3"], "--eta does not apply to --sweep --etas"),
])
def test_an_eta_sweep_refuses_or_applies_the_options_it_ignored(tmp_path, capsys, argv, match):
    case = _small_case(tmp_path)
    assert _run(tmp_path, case, "--sweep", "--etas", "1e-3", "--ps", "0.5", *argv) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and len(err.splitlines()) == 1, err


def test_an_eta_sweep_keeps_to_the_candidates_and_says_which_runs_converged(tmp_path, capsys):
    case = _small_case(tmp_path)
    assert _run(tmp_path, case, "--sweep", "--etas", "1e-3,3e-3", "--ps", "0.5", "--candidates", "7,12,17",
                "--max-iters", "2") == 0
    rows = list(csv.DictReader((tmp_path / "out" / "sweep.csv").open()))
    assert len(rows) == 2 and {"converged", "message"} <= set(rows[0])
    for r in rows:
        assert set(r["actuated_joints"].split()) <= {"7", "12", "17"}
        assert r["converged"] == "False" and "iteration limit" in r["message"]  # two iterations are not enough
    assert "NOT CONVERGED" in capsys.readouterr().out


def test_ctrl_c_stops_an_eta_sweep_and_keeps_only_the_finished_runs(tmp_path, capsys, monkeypatch):
    """It ran on through every run, and saved the cut-short one as a normal row (38 actuators after 28 iterations
    where the full run gives 8 after 64), exiting 0."""
    import xshells.actuation.run as run

    real, calls = run.sparsify, []

    def stop_in_the_second(*args, **kw):
        calls.append(1)
        if len(calls) == 2:  # Ctrl-C in its second iteration: sparsify keeps its iterate and returns
            kw["callback"] = lambda rec: (_ for _ in ()).throw(KeyboardInterrupt)
        return real(*args, **kw)

    monkeypatch.setattr(run, "sparsify", stop_in_the_second)
    case = _small_case(tmp_path)
    assert _run(tmp_path, case, "--sweep", "--etas", "1e-3,3e-3,1e-2", "--ps", "0.5", "--max-iters", "3") == 130
    assert len(calls) == 2  # the third run did not start
    rows = list(csv.DictReader((tmp_path / "out" / "sweep.csv").open()))
    assert len(rows) == 1 and float(rows[0]["eta"]) == 1e-3
    out, err = capsys.readouterr()
    assert "1 of 3 runs finished" in out and "interrupted" in err


def test_an_eta_answer_far_from_the_shape_is_not_converged(tmp_path, capsys):
    """--eta 1e6 gave 0 actuators at 11.9 % mean, 'finished', exit 0."""
    case = _small_case(tmp_path)
    assert _run(tmp_path, case, "--eta", "1e6") == 1
    text = capsys.readouterr().out
    r = json.loads((tmp_path / "out" / "result.json").read_text())
    assert r["converged"] is False and "is above 1% of the span" in r["message"] and r["fit_mean"] > 0.01
    assert "NOT CONVERGED" in text and "suggestion: a smaller --eta" in text
    # the same answer is accepted where the user says a larger deviation will do
    assert _run(tmp_path, case, "--eta", "1e6", "--max-fit", f"{100 * r['fit_mean'] + 1}%") == 0


def test_free_ends_are_reported_and_stale_files_removed(tmp_path, capsys):
    spec = {"file": str(EXAMPLES / "nonuniform_linkage.obj"), "material": {"type": "rectangle", "params": [0.1, 0.07]},
            "angle_deg": 60, "steps": 4, "subdivision": 3}
    case = tmp_path / "small.json"
    case.write_text(json.dumps(spec))
    out = tmp_path / "out"
    assert _run(tmp_path, case, "--actuators", "1") in (0, 1)
    r = json.loads((out / "result.json").read_text())
    assert r["num_free_ends"] == 2 and r["free_end_fit_mean"] > 0 and r["free_end_fit_max"] >= r["free_end_fit_mean"]
    assert "free ends' distance (not fitted)" in capsys.readouterr().out
    assert (out / "sweep.csv").exists()
    # an --eta run into the same folder writes no curve: the earlier one's is removed, and it says so
    _run(tmp_path, case, "--eta", "1e-3", "--max-iters", "2")
    assert not (out / "sweep.csv").exists() and not (out / "sweep.png").exists()
    assert "removed an earlier run's" in capsys.readouterr().err
    # a run that fails leaves no result of an earlier one
    assert _run(tmp_path, case, "--candidates", "0,1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16,17,18,19,20,21,999") == 2
    assert not (out / "result.json").exists()


# ------------------------------------------------------------------ F4: --actuators N, exchanges after the elimination
def _grid_with_free_ends(tmp_path):
    """A 5×5 warped grid with free stubs (13 free ends), asymmetric: the re-check's grid_free."""
    n, s, th = 2, 100.0, np.radians(22)
    idx, V, E = {}, [], []

    def pos(u, v):
        p = np.array([(u + v) * s * np.cos(th), (u - v) * s * np.sin(th)])
        return p * (1 - 0.25 * (np.linalg.norm(p) / (2 * n * s * np.cos(th))) ** 2)

    def vert(p):
        V.append(p)
        return len(V) - 1

    for i in range(-n, n + 1):
        for j in range(-n, n + 1):
            idx[i, j] = vert(pos(i, j))
    for i in range(-n, n + 1):
        chain = [vert(pos(i, -n - 0.45))] + [idx[i, j] for j in range(-n, n + 1)] + [vert(pos(i, n + 0.45))]
        E += list(zip(chain[:-1], chain[1:]))
    for j in range(-n, n + 1):
        chain = [idx[i, j] for i in range(-n, n + 1)] + ([vert(pos(n + 0.5, j))] if j % 2 == 0 else [])
        E += list(zip(chain[:-1], chain[1:]))
    (tmp_path / "grid_free.obj").write_text("".join(f"v {x:.6f} {y:.6f} 0\n" for x, y in V)
                                            + "".join(f"l {a + 1} {b + 1}\n" for a, b in E))
    spec = {"name": "grid_free", "file": "grid_free.obj", "subdivision": 4,
            "material": {"type": "rectangle", "E": 2000, "nu": 0.3, "params": [4.0, 1.5]}, "angle_deg": 70, "steps": 10}
    (tmp_path / "grid_free.json").write_text(json.dumps(spec))
    return tmp_path / "grid_free.json"


def test_one_actuator_is_the_best_single_joint(tmp_path, capsys, monkeypatch):
    """Greedy elimination ended at joint 24 (0.80 % mean); joint 12 alone gives 0.215 % (brute force over all 25)."""
    import xshells.actuation.run as run

    titles = []
    real = run._write_outputs
    monkeypatch.setattr(run, "_write_outputs", lambda *a: (titles.append(a[-1]), real(*a)))
    case = _grid_with_free_ends(tmp_path)
    assert _run(tmp_path, case, "--actuators", "1") == 0
    r = json.loads((tmp_path / "out" / "result.json").read_text())
    assert r["actuated_joints"] == [12] and r["fit_mean"] < 0.0025
    assert "exchange" in r["message"]
    assert ": 1 actuator (" in titles[0]  # was "1 actuators"
    # --sweep: the curve goes on to one actuator; the message names the answer's count, not the curve's end
    assert _run(tmp_path, case, "--sweep", "--max-fit", "0.15%") == 0
    r = json.loads((tmp_path / "out" / "result.json").read_text())
    assert r["num_actuators"] > 1 and f"the answer is the fewest within the limit, {r['num_actuators']} actuators" in r["message"]


def test_an_interrupted_eta_run_is_told_to_run_again():
    from xshells.actuation.run import suggestion

    text = suggestion({"converged": False, "message": "interrupted by the user", "method": "eta"})
    assert text.startswith("run again")  # was "try the default mode (no --eta)"


def test_the_plots_mark_runs_that_did_not_converge(tmp_path, monkeypatch):
    import matplotlib.axes

    from xshells.viz.render import plot_actuation_curve, plot_actuation_tradeoff

    labels = []
    real = matplotlib.axes.Axes.plot
    monkeypatch.setattr(matplotlib.axes.Axes, "plot", lambda self, *a, **kw: (labels.append(kw.get("label")), real(self, *a, **kw))[1])
    rows = [{"p": 0.5, "eta": e, "num_actuators": k, "fit_mean": f, "converged": c}
            for e, k, f, c in ((1e-4, 9, 0.002, "True"), (1e-3, 4, 0.004, "False"))]
    plot_actuation_tradeoff(tmp_path / "s.png", rows)
    assert "not converged" in labels
    labels.clear()
    plot_actuation_curve(tmp_path / "c.png", [{"num_actuators": 2, "fit_mean": 0.002, "fit_max": 0.005}], max_fit=0.001,
                         chosen=2, chosen_failed=True)
    assert any(lab and lab.startswith("NOT CONVERGED") for lab in labels)


def test_another_commands_result_is_not_removed(tmp_path):
    from xshells.actuation.run import remove_stale_outputs

    (tmp_path / "result.json").write_text('{"name": "an inverse design"}')
    (tmp_path / "sweep.csv").write_text("gamma,beta,J\n1,2,3\n")
    (tmp_path / "torques.txt").write_text("1\n")
    assert remove_stale_outputs(tmp_path) == ["torques.txt"]
    assert (tmp_path / "result.json").exists() and (tmp_path / "sweep.csv").exists()
