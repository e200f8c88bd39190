"""Re-seating (xshells.inverse.reseat): the optimization goes on from the design's own deployment from flat."""
import copy
import json

import numpy as np
import pytest

from data_paths import EXAMPLES
from xshells.deploy.simulate import DeployOptions, deploy
from xshells.inverse.metrics import apply, kabsch
from xshells.inverse.reseat import ReseatOptions, optimize_reseated, seat, seat_direction, wants_reseat

from test_design_optimize import banana_problem

CAP = EXAMPLES / "targets" / "spherical_cap_R2000_30deg.obj"
DIAG = float(np.linalg.norm([1918.0, 1918.0, 266.0]))


def _loaded_banana():
    """The banana's design problem with its deployed state pushed off its own equilibrium by a dead load (as the
    guided optimization holds it), and the rigid motion onto that tracked state."""
    problem = banana_problem()
    L = problem.deployed.L
    span = float(np.linalg.norm(np.ptp(L.joint_positions(), axis=0)))
    load = np.zeros(L.num_vars)
    rows = (9 * np.arange(L.num_joints))[:, None] + np.arange(3)[None, :]
    load[rows[:, 2]] = 1e-1 * float(np.max(L.rods.bending_stiffness)) / span**2  # everything pushed one way
    problem.set_deployed_load(load)
    tracked = problem.deployed.L.joint_positions().copy()
    return problem, tracked, span


def test_seating_puts_the_deployment_from_flat_where_the_optimization_tracks_with_no_load():
    problem, tracked, span = _loaded_banana()
    own = copy.deepcopy(problem.flat.L)
    assert deploy(own, problem.deployed.angle, DeployOptions(steps=10)).converged
    Y = own.joint_positions()
    assert np.abs(Y - apply(kabsch(Y, tracked), Y)).max() > 1e-2 * span  # the load moved the tracked state off it

    assert seat(problem, lambda P: kabsch(P, tracked), 10, "up") == ""
    seated = problem.deployed
    assert seated.load is None and seated.tether is None
    # the deployment's own state, moved rigidly onto the tracked one
    np.testing.assert_allclose(seated.L.joint_positions(), apply(kabsch(Y, tracked), Y), atol=1e-8 * span)
    # an equilibrium at the deployed angle, and the design's rest lengths
    assert np.isclose(seated.a @ seated.L.get_vars(), problem.deployed.angle, atol=1e-12)
    np.testing.assert_array_equal(seated.L.rest_lengths, problem.flat.L.rest_lengths)


def test_after_seating_the_design_gradient_is_that_of_the_seated_state():
    problem, tracked, span = _loaded_banana()
    assert seat(problem, lambda P: kabsch(P, tracked), 10, "up") == ""
    q = problem._q.copy()
    v = np.random.default_rng(1).standard_normal(len(q))
    g = problem.gradient(q) @ v
    errors = []
    for h in (1e-4, 1e-5):
        fd = (problem.objective(q + h * v) - problem.objective(q - h * v)) / (2 * h)
        errors.append(abs(fd - g) / abs(g))
    problem.set_q(q)
    assert min(errors) < 1e-4, errors
    assert errors[1] < errors[0]  # the central difference's error falls with h (second order)


def test_a_design_that_does_not_deploy_is_not_seated_and_the_problem_is_left_as_it_was(monkeypatch):
    import xshells.deploy.simulate as simulate

    problem, tracked, _ = _loaded_banana()
    before = problem.deployed
    monkeypatch.setattr(simulate, "deploy", lambda L, angle, options: type("R", (), {
        "converged": False, "message": "stopped at 40° of 80°: the linkage inverts"})())
    why = seat(problem, lambda P: kabsch(P, tracked), 10, "up")
    assert why == "its deployment from flat stopped: stopped at 40° of 80°: the linkage inverts"
    assert problem.deployed is before
    assert optimize_reseated(problem, lambda P: kabsch(P, tracked), 10, "up", ReseatOptions()) == {"why": why}


def test_a_round_checks_every_few_iterations_and_at_its_end():
    problem, tracked, _ = _loaded_banana()
    seen, iterations = [], []
    r = optimize_reseated(problem, lambda P: kabsch(P, tracked), 10, "up",
                          ReseatOptions(iterations=5, checkpoint_every=2),
                          check=lambda: seen.append(problem._q.copy()), callback=lambda rec: iterations.append(rec.iteration))
    assert r["iterations"] <= 5 and np.isfinite(r["J"]) and r["message"]
    # at iterations 2 and 4 where reached (not at the limit, which the end's check covers), and at the end
    assert len(seen) == 1 + len([i for i in iterations if i and i % 2 == 0 and i < 5])


def test_which_designs_are_seated_and_which_way():
    close = {"design": 1, "fit": 0.4, "top": 1.9}
    assert not wants_reseat(close, 100.0)
    assert wants_reseat({**close, "fit": 0.6}, 100.0) and wants_reseat({**close, "top": 2.1}, 100.0)
    assert wants_reseat({"fit": np.inf}, 100.0)  # no design kept at all
    checked = [(0.5, {"direction": "down"}), (0.0, {"direction": "up"}), (0.0, {"why": "overlaps"})]
    assert seat_direction(checked, "down") == "up"
    assert seat_direction([(0.0, {"why": "stopped"})], "down") == "down"


def _short_design(monkeypatch):
    import dataclasses

    import xshells.inverse.guide as guide

    real = guide.guided_optimization
    monkeypatch.setattr(guide, "guided_optimization", lambda problem, hold, options, **kw: real(
        problem, hold, dataclasses.replace(options, schedule=(0.5, 0.0), iterations=2, final_iterations=4,
                                           checkpoint_every=0, polish=0.0), **kw))


@pytest.mark.parametrize("rounds", [0, 1])
def test_a_design_that_is_not_close_is_re_seated_and_says_so(tmp_path, monkeypatch, rounds):
    import xshells.inverse.reseat as reseat
    import xshells.inverse.run as run

    _short_design(monkeypatch)
    monkeypatch.setattr(reseat, "wants_reseat", lambda best, diagonal: True)  # whatever the fit
    out = tmp_path / "out"
    r = run.run_inverse(str(CAP), str(out), {}, run.InverseOptions(
        spacing=DIAG / 6, beams="even", heavier=False, refine=False, buckling=0.0, workers=1,
        reseat=ReseatOptions(rounds=rounds, iterations=4, checkpoint_every=2)), progress=False)
    saved = json.loads((out / "result.json").read_text())
    assert saved["reseated"] == r["reseated"]
    marks = [c.get("reseat") for c in r["checked_stages"]]
    if rounds == 0:
        assert r["reseated"] == [] and set(marks) == {None}
        return
    (one,) = r["reseated"]
    assert one["round"] == 1 and one["direction"] in ("up", "down") and 0 < one["iterations"] <= 4
    assert 0 <= one["tracked_fit_mean"] <= one["tracked_fit_max"]
    assert marks[:2] == [None, None] and set(marks[2:]) == {1} and len(marks) >= 3
    assert r["stages"][-1]["message"].startswith("re-seated on its own deployment from flat")
    assert r["load_released"] and r["status"] in ("complete", "missed")


def test_the_command_says_when_the_kept_design_was_re_seated_and_never_re_seats_when_told(tmp_path, monkeypatch, capsys):
    import xshells.inverse.reseat as reseat
    import xshells.inverse.run as run
    from xshells.cli import main

    _short_design(monkeypatch)
    monkeypatch.setattr(reseat, "wants_reseat", lambda best, diagonal: True)
    real = run._best_stage
    # plumbing: the best of the re-seated designs is kept, whatever the others' fit
    monkeypatch.setattr(run, "_best_stage", lambda checked, surface: real(
        [c for c in checked if "reseat" in c[1]] or checked, surface))
    args = ["inverse", str(CAP), "--spacing", f"{DIAG / 6:.3f}", "--beams", "even", "--no-heavier", "--no-refine",
            "--buckling", "0", "--workers", "1", "--no-progress"]
    main(args + ["--out", str(tmp_path / "a")])
    said = capsys.readouterr().out
    r = json.loads((tmp_path / "a" / "result.json").read_text())
    assert [d["round"] for d in r["reseated"]] == [1, 2] and r["chosen_stage_reseat"] in (1, 2)
    assert f"re-seated: the kept design comes from re-seating round {r['chosen_stage_reseat']}, optimized from its " \
        "own deployment from flat (the state it tracked then fitted" in said
    main(args + ["--no-reseat", "--out", str(tmp_path / "b")])
    assert "re-seated" not in capsys.readouterr().out
    r = json.loads((tmp_path / "b" / "result.json").read_text())
    assert r["reseated"] == [] and r["chosen_stage_reseat"] is None


def test_ctrl_c_while_re_seating_keeps_the_best_design_checked_so_far(tmp_path, monkeypatch):
    import xshells.inverse.reseat as reseat
    import xshells.inverse.run as run

    _short_design(monkeypatch)
    monkeypatch.setattr(reseat, "wants_reseat", lambda best, diagonal: True)

    def interrupted(problem, onto_tracked, steps, direction, options, min_angle=None, check=None, callback=None,
                    min_clearance=None):
        assert reseat.seat(problem, onto_tracked, steps, direction) == ""
        check()  # one design checked in the round, then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(reseat, "optimize_reseated", interrupted)
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        run.run_inverse(str(CAP), str(out), {}, run.InverseOptions(
            spacing=DIAG / 6, beams="even", heavier=False, refine=False, buckling=0.0, workers=1), progress=False)
    r = json.loads((out / "result.json").read_text())
    assert r["status"] == "interrupted" and (out / "flat_design.obj").is_file() and (out / "case.json").is_file()
    # the check that ended before Ctrl-C counts; the round itself did not end
    assert [c.get("reseat") for c in r["checked_stages"]][-1] == 1 and r["reseated"] == []
