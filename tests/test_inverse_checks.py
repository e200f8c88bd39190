"""Stage checks (xshells.inverse.checks): beside the optimization or here, the same designs, in the order asked."""
import json
import os
import signal
import time
from concurrent.futures import Future

import numpy as np
import pytest

from data_paths import EXAMPLES
from xshells.cli import main

CAP = EXAMPLES / "targets" / "spherical_cap_R2000_30deg.obj"
DIAG = float(np.linalg.norm([1918.0, 1918.0, 266.0]))


def _short_design(monkeypatch):
    """Two short stages, the last checked every 2 iterations: four checks in seconds."""
    import dataclasses

    import xshells.inverse.guide as guide

    real = guide.guided_optimization
    monkeypatch.setattr(guide, "guided_optimization", lambda problem, hold, options, **kw: real(
        problem, hold, dataclasses.replace(options, schedule=(0.5, 0.0), iterations=2, final_iterations=5,
                                           checkpoint_every=2, polish=0.0), **kw))


def test_checks_beside_the_optimization_keep_the_same_design_to_the_last_bit(tmp_path, monkeypatch):
    import xshells.inverse.run as run

    _short_design(monkeypatch)
    monkeypatch.setattr(run, "CHECKS_BESIDE_SEGMENTS", 0)
    seen = []
    import xshells.inverse.checks as checks

    class Spy(checks.StageChecks):
        def __init__(self, ctx, beside=False):
            super().__init__(ctx, beside)
            seen.append(self.beside)

    monkeypatch.setattr(checks, "StageChecks", Spy)
    for workers in (1, 2):
        main(["inverse", str(CAP), "--spacing", f"{DIAG / 6:.3f}", "--beams", "even", "--no-heavier", "--no-refine",
              "--buckling", "0", "--workers", str(workers), "--out", str(tmp_path / str(workers)), "--no-progress"])
    # one checker per design, and one per re-seating round (:mod:`xshells.inverse.reseat`), all here or all beside
    assert set(seen[:len(seen) // 2]) == {False} and set(seen[len(seen) // 2:]) == {True}
    here, beside = (json.loads((tmp_path / w / "result.json").read_text()) for w in "12")
    assert len(seen) == 2 * (1 + len(here["reseated"]))
    assert len([c for c in here["checked_stages"] if "reseat" not in c]) == 4
    assert here["checked_stages"] == beside["checked_stages"]
    for key in ("fit_mean", "fit_max", "coverage", "chosen_stage_load", "placement", "free_ends", "status"):
        assert here[key] == beside[key], key
    assert [{k: v for k, v in r.items() if k != "time_s"} for r in here["reseated"]] == \
        [{k: v for k, v in r.items() if k != "time_s"} for r in beside["reseated"]]
    for name in ("flat_design.obj", "design_parameters.txt", "case.json"):
        assert (tmp_path / "1" / name).read_bytes() == (tmp_path / "2" / name).read_bytes(), name


def test_after_ctrl_c_only_the_checks_that_ended_count():
    from xshells.inverse.checks import CheckContext, StageChecks

    checks = StageChecks(CheckContext(None, None, 8, 30, "up", 1.0, 0.0, np.zeros((0, 2), np.int64)))
    done, failed, running = Future(), Future(), Future()
    done.set_result({"why": "a"})
    failed.set_exception(RuntimeError("b"))
    arrays = (np.zeros((1, 3)), np.zeros(1), np.zeros((1, 3)))
    checks._asked = [(0.5, arrays, done), (0.25, arrays, running), (0.0, arrays, failed), (0.0, arrays, {"why": "c"})]
    assert checks.results(wait=False) == [(0.5, {"why": "a"}), (0.0, {"why": "c"})]


def test_a_check_whose_process_died_is_run_here(monkeypatch):
    import xshells.inverse.checks as checks

    monkeypatch.setattr(checks, "check_stage", lambda ctx, Pv, p, guess, try_guide=True: {"why": f"here {len(p)}"})
    stage = checks.StageChecks(checks.CheckContext(None, None, 8, 30, "up", 1.0, 0.0, np.zeros((0, 2), np.int64)),
                               beside=True)
    pool = stage._pool
    deadline = time.time() + 60
    while not pool._processes and time.time() < deadline:
        time.sleep(0.05)
    for proc in list(pool._processes.values()):
        os.kill(proc.pid, signal.SIGKILL)
    while not pool._broken and time.time() < deadline:
        time.sleep(0.05)
    stage.ask(0.0, np.zeros((2, 3)), np.ones(3), np.zeros((2, 3)))
    assert stage.results() == [(0.0, {"why": "here 3"})]
    assert stage._pool is None


def test_the_best_stage_is_the_first_of_equals_within_the_bar_and_the_last_refusal_is_said():
    from types import SimpleNamespace

    from xshells.inverse.run import _best_stage

    S = SimpleNamespace(diagonal=100.0)
    r = lambda fit, top, tag, way="up": {"fit": fit, "top": top, "design": tag, "free_ends": 0, "tracked": tag,  # noqa: E731
                                         "direction": way}
    best = _best_stage([(0.5, r(0.4, 5.0, "a")), (0.25, {"why": "overlaps"}), (0.0, r(0.6, 1.0, "b", "down")),
                        (0.0, r(0.6, 1.0, "c")), (0.0, {"why": "stopped"})], S)
    # 0.4 % mean but 5 % max misses the bar: the first of the two within it is kept, with its direction
    assert best["design"] == "b" and best["mu"] == 0.0 and best["why"] == "stopped" and best["direction"] == "down"
    assert [c["fit_mean"] for c in best["checked"]] == [0.004, 0.006, 0.006]
    assert [c["direction"] for c in best["checked"]] == ["up", "down", "up"]
    # every design that could not be kept says why, not only the last (result.json's refused_stages)
    assert best["refused"] == [{"load_factor": 0.25, "why": "overlaps"}, {"load_factor": 0.0, "why": "stopped"}]


@pytest.mark.parametrize("workers, segments, beside", [(1, 500, False), (2, 99, False), (2, 100, True)])
def test_checks_go_beside_with_two_workers_on_a_net_large_enough(workers, segments, beside):
    from xshells.inverse.run import InverseOptions, _checks_beside

    assert _checks_beside(InverseOptions(workers=workers), segments) is beside


@pytest.mark.parametrize("errors", ["ignore", "warn"])
def test_the_checking_process_handles_numpys_floating_point_errors_as_the_optimizing_one(errors):
    from xshells.inverse.checks import CheckContext, StageChecks

    with np.errstate(all=errors):
        checks = StageChecks(CheckContext(None, None, 8, 30, "up", 1.0, 0.0, np.zeros((0, 2), np.int64)), beside=True)
    try:
        assert set(checks._pool.submit(np.geterr).result(timeout=60).values()) == {errors}
    finally:
        checks.close()


def _wings_both_ways(steps=10):
    """The bundled pointy wings (rest lengths, in-plane curved beams, a 12 × 8 section stiff along d1), its
    settled flat linkage, and its deployments asked "up" and "down"."""
    import copy

    from xshells.deploy.case import load_case, material_from_spec, target_angle
    from xshells.deploy.simulate import DeployOptions, deploy
    from xshells.io import read_design, read_rest_lengths
    from xshells.linkage.linkage import Linkage

    c = load_case(EXAMPLES / "asymm_wings_pointy" / "case.json")
    d = read_design(c.design_path)
    material = material_from_spec(c.material)
    L = Linkage(d, material, subdivision=c.subdivision, rest_lengths=read_rest_lengths(c.rest_lengths_path, d.num_segments))
    theta = target_angle(c, L)
    deployed = {}
    for direction in ("up", "down"):
        D = copy.deepcopy(L)
        assert deploy(D, theta, DeployOptions(steps=steps, direction=direction)).converged
        deployed[direction] = D
    return d, material, L, theta, deployed


@pytest.fixture(scope="module")
def wings_both_ways():
    return _wings_both_ways()


def test_the_other_direction_deploys_the_mirror_image(wings_both_ways):
    # what check_stage relies on to score the other direction without deploying it
    from xshells.inverse.metrics import apply, kabsch

    _, _, _, _, deployed = wings_both_ways
    up, down = deployed["up"].joint_positions(), deployed["down"].joint_positions()
    span = np.ptp(up, axis=0).max()
    assert np.ptp(up[:, 2]) > 0.05 * span  # it buckled
    mirror = up * np.array([1.0, 1.0, -1.0])
    assert np.abs(apply(kabsch(mirror, down), mirror) - down).max() <= 1e-9 * span
    assert np.abs(apply(kabsch(up, down), up) - down).max() > 0.01 * span  # not merely the same state turned


@pytest.mark.parametrize("asked", ["up", "down"])
def test_a_check_asks_for_the_direction_that_deploys_the_design_onto_the_surface(wings_both_ways, asked):
    from xshells.design.fitting import target_surface
    from xshells.inverse.checks import CheckContext, check_stage
    from xshells.inverse.surface import check_target

    d, material, L, theta, deployed = wings_both_ways
    surface = check_target(*target_surface(deployed["down"]))  # the surface the design reaches when asked "down"
    ctx = CheckContext(surface, material, L.subdivision, 10, asked, theta, 0.0, np.asarray(d.edges, np.int64))
    r = check_stage(ctx, L.vertex_positions(), L.rest_lengths, deployed["down"].joint_positions())
    assert r["direction"] == "down"
    # where the surface's own joints lie (a Loop-subdivided surface passes near its joints, not through them)
    from xshells.inverse.metrics import apply, place, surface_distances

    on = surface_distances(surface, deployed["down"].joint_positions())
    assert r["fit"] == pytest.approx(np.mean(on), rel=0.05) and r["fit"] <= 0.005 * surface.diagonal
    assert np.abs(r["tracked"] - deployed["down"].joint_positions()).max() <= 0.01 * surface.diagonal
    up = deployed["up"].joint_positions()  # the state asked "up" reaches, placed as well as it goes: far off
    assert np.mean(surface_distances(surface, apply(place(surface, up, deployed["down"].joint_positions()), up))) \
        > 0.02 * surface.diagonal


def test_the_kept_stages_direction_is_the_cases_and_the_verifications(tmp_path, monkeypatch, capsys):
    # plumbing: a kept stage that asks "down" (as check_stage answers where the mirror image fits) is written
    # into the case, reported, and verified by deploying it so, as `xshells deploy case.json` then does
    import xshells.inverse.run as run

    _short_design(monkeypatch)
    real = run._best_stage
    monkeypatch.setattr(run, "_best_stage", lambda checked, surface: {**real(checked, surface), "direction": "down"})
    out = tmp_path / "out"
    main(["inverse", str(CAP), "--spacing", f"{DIAG / 6:.3f}", "--beams", "even", "--no-heavier", "--no-refine",
          "--buckling", "0", "--workers", "1", "--out", str(out), "--no-progress"])
    assert "direction: down (asked up; buckling up, this design deploys to the mirror image of the surface); the case " \
        "says down" in capsys.readouterr().out
    r = json.loads((out / "result.json").read_text())
    assert json.loads((out / "case.json").read_text())["direction"] == "down"
    assert (r["direction"], r["direction_asked"]) == ("down", "up")
    assert main(["deploy", str(out / "case.json"), "--out", str(tmp_path / "again"), "--no-progress"]) in (0, 1)
    Y = np.array(json.loads((tmp_path / "again" / "result.json").read_text())["deployed"]["joint_positions"])
    T = np.array(r["placement"])
    assert np.abs(Y @ T[:3, :3].T + T[:3, 3] - np.array(r["deployed_joints"])).max() <= 1e-6 * DIAG


# ------------------------------------------------------------------ guided deployments (xshells.deploy.guide)
def test_a_guided_check_settles_into_the_tracked_equilibrium(wings_both_ways, monkeypatch):
    # deployed "up", the wings reach the mirror image of the "down" state the surface was made from; guided into the
    # tracked ("down") state, the same design settles there with no load: onto the surface. The guide is chosen once
    # the target is reached, and the state is the one a case naming it deploys to from flat, to the last bit.
    import copy

    import xshells.inverse.checks as checks
    from xshells.deploy.guide import rigid_fit
    from xshells.deploy.simulate import DeployOptions, deploy
    from xshells.design.fitting import target_surface
    from xshells.inverse.surface import check_target

    d, material, L, theta, deployed = wings_both_ways
    surface = check_target(*target_surface(deployed["down"]))
    ctx = checks.CheckContext(surface, material, L.subdivision, 10, "up", theta, 0.0, np.asarray(d.edges, np.int64),
                              guide=True)
    down = deployed["down"].joint_positions()
    monkeypatch.setattr(checks, "wants_guide", lambda surface, d, guess: True)  # the mirror image would fit as well
    lin = copy.deepcopy(L)
    res, unguided, guided = checks.deployed_fits(ctx, lin, down, True)
    assert res.converged and res.guide.held and unguided[0] == "down"  # unguided: the mirror image, asked down
    direction, placed, dist, rise = guided
    Y, span = lin.joint_positions(), float(np.ptp(down, axis=0).max())
    assert direction == "up" and rise > 0.05
    assert np.abs(rigid_fit(down, Y) - Y).max() <= 1e-7 * span
    assert np.mean(dist) <= 0.005 * surface.diagonal and np.abs(placed - down).max() <= 0.01 * surface.diagonal
    case = copy.deepcopy(L)  # as `xshells deploy case.json` with the guide deploys it
    assert deploy(case, theta, DeployOptions(steps=10, direction="up", guide=down)).converged
    assert np.array_equal(case.get_vars(), lin.get_vars())
    # guided into the state the deployment reaches anyway, it goes back there: nothing to keep, no guide to write
    assert checks.deployed_fits(ctx, copy.deepcopy(L), deployed["up"].joint_positions(), True)[2] is None
    res, unguided, guided = checks.deployed_fits(ctx, copy.deepcopy(L), down, False)  # none where not asked
    assert res.converged and res.guide is None and guided is None and unguided[0] == "down"


def test_a_guide_is_tried_only_where_the_deployment_is_not_close_and_the_tracked_state_fits_better(wings_both_ways):
    from xshells.design.fitting import target_surface
    from xshells.inverse.checks import wants_guide
    from xshells.inverse.surface import check_target

    _, _, _, _, deployed = wings_both_ways
    surface = check_target(*target_surface(deployed["down"]))
    down, diag = deployed["down"].joint_positions(), surface.diagonal
    n = len(down)
    far = np.full(n, 0.03 * diag)  # a deployment 3 % off: not close
    assert wants_guide(surface, far, down)  # the tracked state lies on the surface
    assert not wants_guide(surface, np.full(n, 0.001 * diag), down)  # close already
    assert not wants_guide(surface, far, down + np.array([0.0, 0.0, 0.2 * diag]))  # the tracked state fits worse


def test_a_kept_guided_stage_writes_its_guide_and_the_case_deploys_it(tmp_path, monkeypatch, capsys):
    # plumbing: a kept stage with a guide (as check_stage answers where the guided deployment fits better) is written
    # with deploy_guide.txt, which the case names, the verification follows and `xshells deploy case.json` reproduces
    import xshells.inverse.run as run

    _short_design(monkeypatch)
    real = run._best_stage

    def guided(checked, surface):
        best = real(checked, surface)
        return {**best, "guide": best["tracked"]} if "tracked" in best else best

    monkeypatch.setattr(run, "_best_stage", guided)
    out = tmp_path / "out"
    main(["inverse", str(CAP), "--spacing", f"{DIAG / 6:.3f}", "--beams", "even", "--no-heavier", "--no-refine",
          "--buckling", "0", "--workers", "1", "--out", str(out), "--no-progress"])
    assert "guided: case.json names deploy_guide.txt" in capsys.readouterr().out
    r = json.loads((out / "result.json").read_text())
    assert json.loads((out / "case.json").read_text())["guide"] == "deploy_guide.txt"
    assert r["chosen_stage_guided"] and r["deploy_guide"]["held"]
    assert r["deploy_guide"]["moved"] <= 1e-6  # guided into the state it reaches anyway: the same equilibrium
    assert main(["deploy", str(out / "case.json"), "--out", str(tmp_path / "again"), "--no-progress"]) in (0, 1)
    again = json.loads((tmp_path / "again" / "result.json").read_text())
    assert again["guide"]["held"]
    Y = np.array(again["deployed"]["joint_positions"])
    T = np.array(r["placement"])
    assert np.abs(Y @ T[:3, :3].T + T[:3, 3] - np.array(r["deployed_joints"])).max() <= 1e-6 * DIAG


def test_an_adopted_design_without_a_guide_leaves_no_guide_file_behind(tmp_path):
    from xshells.inverse.run import GUIDE_FILE, _copy_outputs, _write_guide

    src, dst = tmp_path / "src", tmp_path / "dst"
    src.mkdir()
    dst.mkdir()
    assert _write_guide(str(dst), np.ones((3, 3)) * np.arange(3)[:, None]) == str(dst / GUIDE_FILE)
    (src / "case.json").write_text("{}")
    _copy_outputs(str(src), str(dst))
    assert not (dst / GUIDE_FILE).exists() and (dst / "case.json").exists()
    _write_guide(str(dst), np.ones((3, 3)) * np.arange(3)[:, None])
    assert _write_guide(str(dst), None) is None and not (dst / GUIDE_FILE).exists()


@pytest.mark.parametrize("mu, tried", [(0.5, False), (0.0, True)])
def test_a_guide_is_tried_only_at_the_stages_without_load(monkeypatch, mu, tried):
    # under a load the tracked state is held there by it: no equilibrium of the design alone for a guide to find
    import xshells.inverse.checks as checks

    seen = []
    monkeypatch.setattr(checks, "check_stage", lambda ctx, Pv, p, guess, try_guide=True: seen.append(try_guide) or {})
    stage = checks.StageChecks(checks.CheckContext(None, None, 8, 30, "up", 1.0, 0.0, np.zeros((0, 2), np.int64),
                                                   guide=True))
    stage.ask(mu, np.zeros((1, 3)), np.zeros(1), np.zeros((1, 3)))
    assert seen == [tried]


@pytest.mark.parametrize("flag", [[], ["--no-clearance"]])
def test_the_optimization_keeps_the_flat_beams_a_width_apart_unless_told_not_to(tmp_path, monkeypatch, flag):
    # plumbing: every design optimization of the run (stages, polish, re-seating) gets the beams' width as its
    # min_clearance (stage designs whose flat beams overlap are refused by their checks), or None when told
    import xshells.design.optimize as opt

    _short_design(monkeypatch)
    real, seen = opt.optimize, []
    monkeypatch.setattr(opt, "optimize", lambda problem, options, **kw: seen.append(options.min_clearance)
                        or real(problem, options, **kw))
    main(["inverse", str(CAP), "--spacing", f"{DIAG / 6:.3f}", "--beams", "even", "--no-heavier", "--no-refine",
          "--buckling", "0", "--workers", "1", "--out", str(tmp_path / "out"), "--no-progress", *flag])
    material = json.loads((tmp_path / "out" / "case.json").read_text())["material"]
    assert material["type"] == "rectangle" and len(seen) >= 2
    assert set(seen) == ({None} if flag else {max(material["params"])})  # the default section: 10 mm wide


def test_the_clearance_is_measured_where_the_checks_settle_the_stage_designs(tmp_path, monkeypatch):
    # the barrier's state is the flat layout let go where it pushes to close (DesignProblem.released_flat), which
    # is where a stage check settles the design (checks.settled_flat, from its flat joints and rest lengths):
    # the same angle and the same nearest beams. Where it pushes to open, the held state's beams are the nearer.
    # Held at the flat angle only (the barrier's first form, 2026-12-07), the swimming ray's stage designs closed
    # from 20.1° to 17.5° when let go, their nearest beams from 21.9 to 18.1 mm apart
    from types import SimpleNamespace

    import xshells.design.optimize as opt
    import xshells.deploy.case as case
    from xshells.inverse import checks
    from xshells.linkage.clearance import family_clearance

    _short_design(monkeypatch)
    real, compared = opt.optimize, []
    material = case.material_from_spec(dict(case.DEFAULT_MATERIAL))

    def spy(problem, options, **kw):
        res = real(problem, options, **kw)
        L = problem.flat.L
        made = checks.stage_arrays(L.vertex_positions(), L.rest_lengths, np.asarray(L.design.edges))
        settled = checks.settled_flat(SimpleNamespace(material=material, subdivision=L.subdivision), *made)
        eq = problem.released_flat()
        compared.append((eq is not None, np.degrees(L.average_angle()),
                         np.degrees((L if eq is None else eq.L).average_angle()), np.degrees(settled.average_angle()),
                         family_clearance(L if eq is None else eq.L, np.inf)[0], family_clearance(settled, np.inf)[0],
                         np.ptp(settled.joint_positions(), axis=0).max()))
        return res

    monkeypatch.setattr(opt, "optimize", spy)
    main(["inverse", str(CAP), "--spacing", f"{DIAG / 6:.3f}", "--beams", "even", "--no-heavier", "--no-refine",
          "--buckling", "0", "--workers", "1", "--out", str(tmp_path / "out"), "--no-progress"])
    assert len(compared) >= 2, compared  # (on this short run every stage design pushes to open: the released
    # state, where one pushes to close, is compared with the settled one in test_design_objective)
    for released, held, measured, settled, gap, gap_settled, span in compared:
        if released:  # the same state: the check's
            assert measured < held and abs(measured - settled) < 1e-6, compared
            assert abs(gap - gap_settled) < 1e-6 * span, compared
        else:  # the check's opens, its beams no nearer than those the barrier holds apart
            assert measured == held and settled > held and gap_settled > gap, compared


def test_a_stage_design_whose_flat_state_leaves_the_plane_is_refused(wings_both_ways, monkeypatch):
    # the verification finds a flat state off its plane by more than 1e-6 of the span invalid, so the stage
    # check refuses it too (the boat's fanned net, 2026-12-07: its last stage design was kept and then found
    # 0.0014 of the span off the plane, status invalid, where an earlier stage could have been kept)
    import copy

    from xshells.design.fitting import target_surface
    from xshells.inverse import checks
    from xshells.inverse.surface import check_target

    d, material, L, theta, deployed = wings_both_ways
    surface = check_target(*target_surface(deployed["up"]))
    ctx = checks.CheckContext(surface, material, L.subdivision, 10, "up", theta, 0.0, np.asarray(d.edges, np.int64))
    assert checks.flat_planarity(L) < checks.PLANAR
    assert "fit" in checks.check_stage(ctx, L.vertex_positions(), L.rest_lengths, deployed["up"].joint_positions())
    real = checks.settled_flat

    def buckled(*args):  # the settled flat state with one joint lifted by 1e-5 of the span
        fwd = real(*args)
        lifted = copy.deepcopy(fwd)
        x = lifted.get_vars()
        x[2] += 1e-5 * np.ptp(fwd.rods.points, axis=0).max()
        lifted.set_vars(x)
        return lifted

    monkeypatch.setattr(checks, "settled_flat", buckled)
    r = checks.check_stage(ctx, L.vertex_positions(), L.rest_lengths, deployed["up"].joint_positions())
    assert list(r) == ["why"] and r["why"].startswith("its flat state leaves the plane by "), r
    assert r["why"].endswith(" of its span") and 1e-6 < float(r["why"].split()[-4]) < 1e-4, r
