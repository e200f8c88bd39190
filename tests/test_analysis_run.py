"""``xshells analyze`` end to end on a small design, and its one-line errors."""
import json
import os

import numpy as np
import pytest

from data_paths import EXAMPLES
from xshells.cli import main

DESIGN = str(EXAMPLES / "nonuniform_linkage.obj")  # unit-sized: a section to match
BASE = [DESIGN, "--material", "rectangle:0.05,0.035", "--angle", "60", "--steps", "6", "--subdivision", "5",
        "--no-progress"]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("an")
    code = main(["analyze", *BASE, "--density", "1.9e-9", "--supports", "lowest:4", "--load", "self-weight",
                 "--load", "point:3:0,0,-1e-3", "--strength", "200", "--out", str(out)])
    return code, out, json.loads((out / "result.json").read_text())


def test_the_analysis_reports_and_writes_what_it_should(run):
    code, out, r = run
    assert code == 0 and r["status"] == "complete"
    for key in ("max_displacement", "max_utilization", "reactions", "reactions_total", "total_load", "stable",
                "critical_load_factor", "critical_method", "buckled"):
        assert key in r, key
    assert len(r["reactions"]) == 4
    assert r["equilibrium_error"] <= 1e-8
    assert r["stable"] and not r["buckled"]
    # this shell snaps through at 1.87x its load (tests/test_analysis_run.py::test_the_snap_through_is_found);
    # the search sampled 1x, 2x, 4x ... from the requested load, landed past the fold, and said "no
    # instability up to 50x"
    assert r["critical_kind"] == "limit point" and 1.8 < r["critical_load_factor"] < 1.95
    # informative for a squeeze too, where critical_total_load is 0: the factor times the loads' magnitude
    assert r["critical_load_magnitude"] == pytest.approx(r["critical_load_factor"] * abs(r["total_load"][2]), rel=1e-12)
    assert r["state"] == "loaded" and r["load_factor_reached"] == 1.0
    for name in ("analysis.png", "beams.csv", "loaded.ply", "loaded.3dm", "deploy/result.json", "deploy/deployed.3dm"):
        assert (out / name).is_file(), name
    assert "utilization" in (out / "loaded.ply").read_bytes()[:2000].decode("latin-1")


def test_the_snap_through_is_found(run):
    """Past the critical factor the equilibrium jumps: followed in small load steps, the largest displacement
    grows smoothly up to 0.99x the reported factor, then leaps at 1.01x (and the lowest eigenvalue, near 0
    before, is back up after: a limit point, not a bifurcation)."""
    import copy

    import numpy as np

    from xshells.analysis.run import parse_load
    from xshells.analysis.static import (Load, StaticOptions, Support, held_variables, load_vector, lowest_supports,
                                         smallest_eigenvalue, solve_loaded, translate)
    from xshells.deploy.case import material_from_spec
    from xshells.deploy.run import run_deployment

    _, out, r = run
    crit = r["critical_load_factor"]
    states = {}
    spec = {"type": "rectangle", "E": 20000, "nu": 0.3, "params": [0.05, 0.035], "density": 1.9e-9}
    run_deployment(DESIGN, material_from_spec(spec), out_dir=str(out / "again"), subdivision=5, target_angle=np.radians(60),
                   steps=6, progress=False, states=states)
    L = states["deployed"]
    translate(L, -L.vertex_positions().mean(axis=0))
    held = held_variables(L, [Support(v) for v in lowest_supports(L, 4)], "locked")
    f, _ = load_vector(L, [Load("self-weight"), parse_load("point:3:0,0,-1e-3")])
    P0 = L.vertex_positions()
    lam, d, mu = 0.0, [], []
    for target in (0.9, 0.95, 0.99, 1.01):
        assert solve_loaded(L, f, held, target * crit, StaticOptions(load_steps=4), escape=False, start_factor=lam).converged
        lam = target * crit
        d.append(float(np.linalg.norm(L.vertex_positions() - P0, axis=1).max()))
        mu.append(smallest_eigenvalue(L, held))
    smooth = (d[2] - d[1]) / 0.04  # growth per unit of the factor just before
    assert d[3] - d[2] > 3 * smooth * 0.02  # the leap: several times what the path's own slope would give
    assert 0 < mu[2] < 0.6 * mu[0] and mu[3] > 2 * mu[2]  # μ falls toward the fold (as its square root), then is back


@pytest.mark.parametrize("args, words", [
    (["--supports", "joints:0,999", "--load", "point:3:0,0,-1"], "vertex 999 does not exist"),
    (["--supports", "lowest:4", "--load", "point:999:0,0,-1"], "point load at vertex 999"),
    (["--supports", "lowest:4", "--load", "self-weight"], "needs a density"),
    (["--supports", "lowest:4", "--load", "point:3:0,0,-1", "--strength=-5"], "--strength must be a positive"),
    (["--supports", "lowest:4", "--load", "point:3:0,0,-1", "--density=-1"], "--density must be a positive"),
    (["--supports", "lowest:1", "--load", "point:3:0,0,-1"], "rigid motion(s) free"),
    (["--supports", "under:3", "--load", "point:3:0,0,-1"], "use lowest:N or joints:"),
    (["--supports", "lowest:4", "--load", "wind:3"], "use self-weight, point:"),
    (["--supports", "lowest:4", "--load", "point:3:0,0,0"], "a point load of zero"),  # equilibrium_error 1.7e291
    (["--supports", "lowest:4", "--load", "area:0"], "an area load of zero"),
    (["--supports", "joints:0,0,1,2", "--load", "point:3:0,0,-1"], "--supports joints:0,0,1,2: vertex 0 is listed twice"),
    (["--supports", "lowest:4", "--density", "1e-9", "--load", "self-weight", "--load", "self-weight"],
     "--load self-weight is given twice"),
])
def test_bad_inputs_get_one_line(tmp_path, capsys, args, words):
    assert main(["analyze", *BASE, "--out", str(tmp_path / "o"), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err and "Traceback" not in err


def test_free_joints_keep_the_deployed_state_with_its_actuation_torque(tmp_path):
    # with the joints free, the actuation torque stays: a vanishing load leaves the deployed state where it is
    code = main(["analyze", *BASE, "--supports", "lowest:4", "--joints", "free", "--load", "point:3:0,0,-1e-12",
                 "--no-critical", "--out", str(tmp_path)])
    assert code == 0
    r = json.loads((tmp_path / "result.json").read_text())
    assert r["joint_mode"] == "free" and r["max_displacement"] < 1e-6


@pytest.fixture
def quad_case(tmp_path):
    (tmp_path / "quad.obj").write_bytes((EXAMPLES / "quad.obj").read_bytes())
    (tmp_path / "case.json").write_text(json.dumps({"file": "quad.obj", "steps": 3, "material": {
        "type": "rectangle", "E": 20000, "nu": 0.3, "params": [10, 7]}}))
    return tmp_path / "case.json"


@pytest.mark.parametrize("option", [["--young", "5"], ["--poisson", "0.2"], ["--material", "rectangle:10,7"]])
def test_material_options_with_a_case_file_are_refused_not_ignored(quad_case, tmp_path, capsys, option):
    code = main(["analyze", str(quad_case), *option, "--supports", "lowest:3", "--load", "point:3:0,0,-1",
                 "--no-critical", "--out", str(tmp_path / "o"), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and f"{option[0]} contradicts the case file" in err and len(err.splitlines()) == 1, err


def test_an_analysis_that_stops_says_so_and_why(quad_case, tmp_path, capsys, monkeypatch):
    # Every loaded equilibrium is given no Newton iterations, so none converges: the path from zero load stops
    # at once, short of the full load, and result.json and the summary say so and why. (Until 2026-12-06 this
    # took a real case, three pinned corners and a load on the fourth, whose equilibrium stalled at round-off;
    # with NumPy 2.4.6 it converges, as it should: a stiff quad moves 1.7e-10 under that load.)
    from dataclasses import replace

    import xshells.solve as solve

    real, steps = solve.minimize, []

    def no_iterations_under_load(problem, **kw):
        if kw.get("force") is not None:  # a loaded equilibrium (the deployment before it has no force)
            steps.append(1)
            kw["options"] = replace(kw["options"], max_iterations=0)
        return real(problem, **kw)

    monkeypatch.setattr(solve, "minimize", no_iterations_under_load)
    out = tmp_path / "o"
    code = main(["analyze", str(quad_case), "--supports", "joints:0,1,2", "--load", "point:3:0,0,-1", "--no-critical",
                 "--out", str(out), "--no-progress"])
    r = json.loads((out / "result.json").read_text())
    assert code == 1 and r["status"] == "stopped"
    assert steps and r["load_factor_reached"] == 0 and "stopped at load factor 0" in r["message"]
    line = f"  stopped at load factor {r['load_factor_reached']:.4g} of 1: {r['message']}"
    assert line in capsys.readouterr().out.splitlines()


@pytest.fixture(scope="module")
def snapping(tmp_path_factory):
    """The shell of ``run`` on its supports, with its load: (deployed linkage, held variables, load vector)."""
    import numpy as np

    from xshells.analysis.run import parse_load
    from xshells.analysis.static import Load, Support, held_variables, load_vector, lowest_supports, translate
    from xshells.deploy.case import material_from_spec
    from xshells.deploy.run import run_deployment

    states = {}
    spec = {"type": "rectangle", "E": 20000, "nu": 0.3, "params": [0.05, 0.035], "density": 1.9e-9}
    run_deployment(DESIGN, material_from_spec(spec), out_dir=str(tmp_path_factory.mktemp("dep")), subdivision=5,
                   target_angle=np.radians(60), steps=6, progress=False, states=states)
    L = states["deployed"]
    translate(L, -L.vertex_positions().mean(axis=0))
    held = held_variables(L, [Support(v) for v in lowest_supports(L, 4)], "locked")
    f, _ = load_vector(L, [Load("self-weight"), parse_load("point:3:0,0,-1e-3")])
    return L, held, f


def test_the_critical_load_does_not_depend_on_how_the_load_is_split(snapping):
    # The same total load at the snap, whatever the reference load (1x, 1.5x, 3x) and the factor applied (1, or
    # past the snap): the search once started from the requested factor and let the snap through a long step
    # (the boat: 40.2 N found from 30 N, 2.83x30 N from 1.47x30 N, 0.5x100 N at its first sample)
    from xshells.analysis.static import critical_load_factor

    L, held, f = snapping
    ref = critical_load_factor(L, f, held)
    assert ref.kind == "limit point" and 1.8 < ref.factor < 1.95
    splits = ((1.5, 1.0), (3.0, 1.0), (1.0, 1.1 * ref.factor), (1.0, 0.5))
    found = {split: critical_load_factor(L, split[0] * f, held, start=split[1]) for split in splits}
    assert [cr.factor * scale for (scale, _), cr in found.items()] == pytest.approx([ref.factor] * 4, rel=2e-3)
    for (scale, start), cr in found.items():
        assert cr.bracket[1] - cr.bracket[0] <= 1e-3 * cr.bracket[1]
        assert (cr.target_state is None) == (start * scale > ref.factor)  # past the snap: no state on the path there


@pytest.mark.parametrize("fraction", [0.9, 1.1])
def test_past_the_snap_the_shell_is_reported_buckled(run, tmp_path, capsys, fraction):
    # At 1.1x the critical factor the shell has snapped through: buckled, and not "stable" (it said "stable,
    # critical load factor 2.83" for the boat at 1.1x its snap load); at 0.9x it stands
    _, _, r0 = run
    crit = r0["critical_load_factor"]
    out = tmp_path / "o"
    code = main(["analyze", *BASE, "--density", "1.9e-9", "--supports", "lowest:4", "--load", "self-weight",
                 "--load", "point:3:0,0,-1e-3", "--load-factor", str(fraction * crit), "--out", str(out)])
    r = json.loads((out / "result.json").read_text())
    line = capsys.readouterr().out.splitlines()[1]
    assert code == 0 and r["critical_load_factor"] == pytest.approx(crit, rel=2e-3)
    if fraction > 1:
        assert r["buckled"] and "BUCKLED" in line and "snaps through" in line and "stable," not in line
    else:
        assert not r["buckled"] and "stable, critical load factor" in line and "BUCKLED" not in line
    assert r["critical_load_ratio"] == pytest.approx(1 / fraction, rel=2e-3)


def strict(text):
    """``json.loads`` that refuses Infinity and NaN, as JavaScript's JSON.parse does."""
    def refuse(name):
        raise ValueError(f"not JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def test_result_json_is_strict_json():
    # the open bracket [lo, inf] of a search without a critical factor was written [50.0, Infinity]
    from xshells.io.export import finite_json

    value = {"a": [1.0, float("inf")], "b": (float("nan"), -float("inf")), "c": {"d": 2}}
    with pytest.raises(ValueError):
        strict(json.dumps(value))
    assert strict(finite_json(value)) == {"a": [1.0, None], "b": [None, None], "c": {"d": 2}}


def test_an_interrupted_critical_search_keeps_the_loaded_state(tmp_path, monkeypatch):
    # Ctrl-C during the critical load search (past the requested load, 1x): result.json says so and the
    # loaded state's files are written (an interrupt lost everything before)
    import xshells.analysis.static as S

    real = S.critical_load_factor

    def interrupted_at_1_2(*a, callback=None, **k):
        def on_step(lam):
            if lam > 1.2:
                raise KeyboardInterrupt
            return callback(lam)

        return real(*a, callback=on_step, **k)

    monkeypatch.setattr(S, "critical_load_factor", interrupted_at_1_2)
    out = tmp_path / "o"
    code = main(["analyze", *BASE, "--density", "1.9e-9", "--supports", "lowest:4", "--load", "self-weight",
                 "--load", "point:3:0,0,-1e-3", "--out", str(out)])
    r = strict((out / "result.json").read_text())  # its open bracket was written [1.2, Infinity]
    assert code == 130 and r["status"] == "interrupted" and r["critical_bracket"][1] is None
    assert r["message"].startswith("interrupted during the critical load search")
    assert r["load_factor_reached"] == 1.0 and r["equilibrium_error"] <= 1e-8 and r["critical_load_factor"] is None
    for name in ("analysis.png", "beams.csv", "loaded.ply"):
        assert (out / name).is_file(), name


def test_the_buckling_mode_is_drawn_at_the_amplitude_its_title_states(tmp_path, monkeypatch):
    # the mode was passed scaled by s2 and scaled by s2 again when drawn
    import numpy as np

    import xshells.viz.render as render

    drawn = {}

    def capture(path, points0, points, edges, values, scale, label="", title="", **kw):
        drawn[os.path.basename(path)] = (np.linalg.norm(scale * (points - points0), axis=1).max(), title)
        drawn[path] = kw

    monkeypatch.setattr(render, "render_analysis", capture)
    assert main(["analyze", *BASE, "--supports", "lowest:4", "--support-type", "clamped", "--load",
                 "point:3:0,0,-1e-3", "--no-critical", "--out", str(tmp_path)]) == 0
    amplitude, title = drawn["buckling_mode.png"]
    assert f"largest amplitude shown {amplitude:.3g} (" in title
    # the supports' kind goes with them (clamped: squares)
    assert drawn[str(tmp_path / "analysis.png")]["support_kinds"] == ["clamped"] * 4


def test_a_load_too_small_to_balance_to_1e8_gets_a_warning(run, tmp_path, capsys):
    # the equilibrium stops at the stiffness forces' round-off: a load near it balances to 3e-5 of itself, said
    # in one line (it was reported silently beside the 1e-8 that the docs promise)
    assert not any("round-off" in w for w in run[2]["warnings"])
    code = main(["analyze", *BASE, "--supports", "lowest:4", "--load", "point:3:0,0,-1e-9", "--no-critical",
                 "--out", str(tmp_path)])
    r = json.loads((tmp_path / "result.json").read_text())
    assert code == 0 and r["equilibrium_error"] > 1e-8
    lines = [line for line in capsys.readouterr().out.splitlines() if "warning:" in line and "balance" in line]
    assert len(lines) == 1 and "round-off" in lines[0] and f"{r['equilibrium_error']:.1e}" in lines[0]


@pytest.mark.parametrize("supports, words", [
    ("joints:21,26,22", ["the 3 supports lie within", "it stands on one end", "vertex 21 ("]),
    ("joints:11,36,20", ["outside its supports' footprint", "vertex 36 ("]),
])
def test_supports_at_one_end_and_supports_that_pull_get_a_warning(tmp_path, capsys, supports, words):
    # three joints near one edge of the shell (or a footprint beside its centre): it cantilevers from them and
    # one support pulls it down; lowest:N on a shell deployed tilted picked such supports without a word
    code = main(["analyze", *BASE, "--supports", supports, "--load", "point:3:0,0,-1e-5", "--no-critical",
                 "--out", str(tmp_path)])
    lines = [line for line in capsys.readouterr().out.splitlines() if "warning:" in line]
    assert code == 0 and len(lines) == 2
    assert all(any(w in line for line in lines) for w in words)
    assert "would lift off a support that can only push" in lines[1]


@pytest.mark.parametrize("fraction", [0.9, 1.1])
def test_an_arm_that_buckles_sideways_is_a_bifurcation_not_a_snap(tmp_path, capsys, fraction):
    # The plus deployed to 150 deg, clamped at its joint, one arm pushed in its plane along x (30 deg off its
    # axis): the arm bends in plane until it buckles out of it, at 34.1x the load, the in-plane path going on as
    # a saddle. It was a "limit point: it snaps through" (Newton does not converge to the saddle), and at 1.1x
    # "stable, critical load factor ...; BUCKLED"
    (tmp_path / "plus.obj").write_text("v 0 0 0\nv 500 0 0\nv 0 500 0\nv -500 0 0\nv 0 -500 0\nl 1 2\nl 1 3\nl 1 4\nl 1 5\n")
    code = main(["analyze", str(tmp_path / "plus.obj"), "--supports", "joints:0", "--support-type", "clamped",
                 "--load", "point:1:-2,0,0", "--load-factor", str(fraction * 34.14), "--no-progress",
                 "--out", str(tmp_path / "o")])
    r = json.loads((tmp_path / "o" / "result.json").read_text())
    line = capsys.readouterr().out.splitlines()[1]
    assert code == 0 and r["critical_kind"] == "bifurcation" and r["critical_load_factor"] == pytest.approx(34.14, rel=2e-3)
    assert "(a bifurcation: it buckles)" in line and r["buckled"] == (fraction > 1)
    assert ("BUCKLED" in line and "stable," not in line) if fraction > 1 else line.endswith("x the load applied (a bifurcation: it buckles)")


def test_analysis_png_states_units_marks_supports_and_loads_and_keeps_round_off_unscaled(tmp_path, monkeypatch):
    # a vanishing load with free joints: 1e-8 of displacement was blown up x8e7 into a shape; the title had no
    # unit, the supports and loads were not drawn
    import numpy as np

    import xshells.viz.render as render

    drawn = {}
    monkeypatch.setattr(render, "render_analysis", lambda path, *a, **kw: drawn.setdefault(os.path.basename(path), (a, kw)))
    assert main(["analyze", *BASE, "--supports", "lowest:4", "--joints", "free", "--load", "point:3:0,0,-1e-12",
                 "--strength", "200", "--no-critical", "--out", str(tmp_path)]) == 0
    (points0, points, edges, values, scale), kw = drawn["analysis.png"]
    assert scale == 1.0 and "drawn unscaled" in kw["title"] and "(the design's length unit)" in kw["title"]
    assert kw["label"].startswith("utilization (") and len(kw["supports"]) == 4
    at, F = kw["loads"]
    assert at.shape == (1, 3) and np.allclose(F, [[0, 0, -1e-12]])


def test_the_colour_bar_reaches_the_largest_vertex_value(tmp_path, monkeypatch):
    # the edges are coloured by their vertices' means: the bar stopped short of the maximum reported
    import numpy as np

    import xshells.viz.render as render

    figs = []
    monkeypatch.setattr(render, "_save", lambda fig, path: figs.append(fig))
    P = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]])
    render.render_analysis(str(tmp_path / "a.png"), P, P, np.array([[0, 1], [1, 2]]), np.array([0.1, 0.2, 0.9]), 1.0,
                           supports=P[:1], loads=(P[2:], np.array([[0, 0, -1.0]])))
    assert figs[0].axes[1].get_ylim()[1] == pytest.approx(0.9)


def test_the_snap_through_mode_is_the_direction_the_path_moves_in(snapping):
    # near a limit point the shell moves along the critical mode: the picture shows the path's tangent there
    # (the lowest eigenvector drawn before can be another, soft mode: on the boat, cosine 0.02 with the motion)
    import copy

    import numpy as np

    from xshells.analysis.run import _buckling_mode
    from xshells.analysis.static import StaticOptions, critical_load_factor, solve_loaded
    from xshells.linkage.state import restore

    L, held, f = snapping
    cr = critical_load_factor(L, f, held)
    near = copy.deepcopy(L)
    restore(near, cr.last_stable)
    before = copy.deepcopy(L)
    assert solve_loaded(before, f, held, 0.98 * cr.bracket[0], StaticOptions(load_steps=10), escape=False).converged
    motion = (near.rods.points - before.rods.points).ravel()  # the path's secant over the last 2 %
    mode = _buckling_mode(near, held, f)
    assert abs(mode @ motion) >= 0.9 * np.linalg.norm(mode) * np.linalg.norm(motion)


class _Flat:
    """A stand-in for a linkage in _support_warnings: a 200 x 100 shell, its vertices at (x, y, 0)."""

    def __init__(self, xy):
        self.xy = np.c_[np.asarray(xy, float), np.zeros(len(xy))]
        self.rods = type("R", (), {"points": self.xy})

    def vertex_positions(self):
        return self.xy


GRID = [(x, y) for x in np.linspace(-100, 100, 9) for y in np.linspace(-50, 50, 5)]


@pytest.mark.parametrize("supports, outside", [
    ([0, 4], True),  # both at x = -100, the centre at 0: held at one side (no warning with two supports)
    ([0, 44], False),  # the diagonal passes through the centre
    ([0, 2, 4], True),  # three in a line at one side
    ([2, 42], False),  # a line through the centre
    ([0, 4, 40, 44], False),
    ([0, 4, 9, 13], True),  # a footprint beside the centre
])
def test_the_centre_outside_the_supports_footprint_is_said_for_any_number_of_supports(supports, outside):
    from xshells.analysis.run import _support_warnings
    from xshells.analysis.static import Support

    reac = [{"vertex": v, "force": [0.0, 0.0, 1.0]} for v in supports]
    out = _support_warnings(_Flat(GRID), [Support(v) for v in supports], reac, [0, 0, -len(supports)], len(supports))
    assert any("outside its supports' footprint" in w for w in out) == outside, out


@pytest.mark.parametrize("pulls, resultant, magnitude, said, words", [
    ([-6.5e-6, -3e-7], [0, 0, -1e-3], 1e-3, False, ""),  # round-off leftovers on a 1 mN load
    ([-0.036], [0, 0, -5.47], 5.47, False, ""),  # 0.65 % of the load: negligible
    ([-0.2], [0, 0, -5.47], 5.47, True, "against the load, more than 2% of the load"),
    ([-3.76], [0, 0, 0], 10.0, True, "down (-z; the loads cancel)"),  # a squeeze: no "against the load"
])
def test_a_pulling_support_is_said_relative_to_the_load_applied(pulls, resultant, magnitude, said, words):
    from xshells.analysis.run import _support_warnings
    from xshells.analysis.static import Support

    supports = [0, 4, 40, 44]
    reac = [{"vertex": v, "force": [0.0, 0.0, 1.0 if i >= len(pulls) else pulls[i]]} for i, v in enumerate(supports)]
    out = [w for w in _support_warnings(_Flat(GRID), [Support(v) for v in supports], reac, resultant, magnitude)
           if "pull" in w]
    assert bool(out) == said and (not said or words in out[0]), out


def test_the_search_is_reported_in_multiples_of_the_load_applied():
    # with --load-factor 2 the path went to 100x the --load: "no instability up to 100x the load" was 50x the
    # load applied
    from xshells.analysis.cli import _stability_line

    r = {"critical_load_factor": None, "stable": True, "buckled": False, "critical_searched_to": 100.0,
         "load_factor": 2.0, "status": "complete"}
    assert _stability_line(r) == "stable, no instability up to 50x the load applied (100x --load)"
    assert _stability_line({**r, "load_factor": 1.0, "critical_searched_to": 50.0}).endswith("up to 50x the load applied")


def test_past_the_snap_a_state_not_found_is_not_called_the_state_it_goes_to(run, tmp_path, capsys, monkeypatch):
    # Newton past the snap failing (max_iterations 2): the last equilibrium before the snap was shown, the line
    # saying "the state it goes to is stable"
    import xshells.analysis.static as S

    real = S.solve_loaded

    def failing_past_the_snap(linkage, f, held, load_factor=1.0, *a, start_factor=0.0, **k):
        if start_factor not in (0.0, load_factor):  # the buckled branch: Newton from the last stable state
            k["max_iterations"] = 2
        return real(linkage, f, held, load_factor, *a, start_factor=start_factor, **k)

    monkeypatch.setattr(S, "solve_loaded", failing_past_the_snap)
    crit = run[2]["critical_load_factor"]
    out = tmp_path / "o"
    main(["analyze", *BASE, "--density", "1.9e-9", "--supports", "lowest:4", "--load", "self-weight",
          "--load", "point:3:0,0,-1e-3", "--load-factor", str(1.1 * crit), "--out", str(out)])
    r = strict((out / "result.json").read_text())
    line = capsys.readouterr().out.splitlines()[1]
    assert r["buckled"] and r["state"] == "pre-snap" and "the state it goes to" not in line
    assert "the state past it was not found; shown: the last equilibrium before it, at load factor " in line
    assert r["load_factor_reached"] == pytest.approx(r["critical_bracket"][0])
