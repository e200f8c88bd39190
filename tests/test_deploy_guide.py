"""A deployment guided into one of its equilibria (xshells.deploy.guide): held on a shape and let go."""
import copy
import json
import os

import numpy as np
import pytest

from xshells.cli import main
from xshells.deploy import DeployOptions, deploy, rest_length_solve
from xshells.deploy.guide import guide_text, read_guide, rigid_fit
from xshells.errors import InputError
from xshells.io import read_design
from xshells.linkage.linkage import Linkage
from xshells.section import Material

EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "xshells", "data", "examples")
DESIGN = os.path.join(EXAMPLES, "nonuniform_linkage.obj")  # 97 joints; buckles out of plane by 60°
SPEC = {"file": DESIGN, "material": {"type": "rectangle", "params": [0.1, 0.07]}, "angle_deg": 60, "steps": 4,
        "subdivision": 3}


def _linkage():
    L = Linkage(read_design(DESIGN), Material.uniform("rectangle", [0.1, 0.07], E=20000, nu=0.3), subdivision=3)
    rest_length_solve(L)
    return L


@pytest.fixture(scope="module")
def both_ways():
    L = _linkage()
    out = {}
    for direction in ("up", "down"):
        D = copy.deepcopy(L)
        assert deploy(D, np.radians(60), DeployOptions(steps=4, direction=direction)).converged
        out[direction] = D
    return L, out


def _turned(P):
    """``P`` moved rigidly: a guide may come in any placement."""
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return P @ R.T + np.array([3.0, -2.0, 5.0])


def test_guided_into_the_mirror_image_it_reaches_what_the_other_direction_reaches(both_ways):
    # a shell has (at least) two stable states at its angle, mirror images: deployed "up" and guided onto the "down"
    # state, it settles into that one, with no load left (the "down" deployment's joints, to round-off)
    L, out = both_ways
    up, down = out["up"].joint_positions(), out["down"].joint_positions()
    span = float(np.ptp(up, axis=0).max())
    assert np.abs(rigid_fit(up, down) - down).max() > 0.1 * span  # two different states, not one turned
    D = copy.deepcopy(L)
    res = deploy(D, np.radians(60), DeployOptions(steps=4, direction="up", guide=_turned(down)))
    assert res.converged and res.guide.held, res.message
    Y = D.joint_positions()
    assert np.abs(rigid_fit(down, Y) - Y).max() <= 1e-8 * span
    assert res.guide.moved > 0.1 and res.guide.released_rms <= 1e-8
    assert abs(np.degrees(D.average_angle()) - 60) < 1e-8  # at the target angle
    assert res.min_eigenvalue_at_fixed_angle > 0  # a stable equilibrium, as the deployment checks every end state
    assert res.gradient_norm <= 1e-6 * np.abs(D.gradient()).max() + 1e-9
    assert res.steps[-1].energy == pytest.approx(D.energy(), rel=1e-12)  # the last record is the guided state's
    assert "guided" in res.message


def test_a_guide_on_the_state_reached_changes_nothing(both_ways):
    L, out = both_ways
    up = out["up"].joint_positions()
    span = float(np.ptp(up, axis=0).max())
    D = copy.deepcopy(L)
    res = deploy(D, np.radians(60), DeployOptions(steps=4, direction="up", guide=_turned(up)))
    assert res.guide.held and res.guide.moved <= 1e-8
    assert np.abs(D.joint_positions() - up).max() <= 1e-8 * span


def test_a_shape_the_shell_cannot_be_held_on_is_not_followed_and_it_says_so(both_ways):
    # a guide is not a load: a dome far steeper than a 60° opening of this design reaches cannot be held within the
    # tolerance by the stiffest springs, so the state the deployment reached is kept, and the message says why
    L, out = both_ways
    P = L.joint_positions()
    r2 = np.sum((P[:, :2] - P[:, :2].mean(axis=0)) ** 2, axis=1)
    span = float(np.ptp(P, axis=0).max())
    dome = P.copy()
    dome[:, 2] = 0.6 * span * (1 - r2 / r2.max())
    D = copy.deepcopy(L)
    res = deploy(D, np.radians(60), DeployOptions(steps=4, direction="up", guide=dome))
    assert res.converged and not res.guide.held
    assert res.guide.held_rms > 0.01 and "the guide was not followed" in res.message
    assert np.array_equal(D.get_vars(), out["up"].get_vars())  # exactly the unguided state


def test_a_case_names_its_guide_and_the_command_follows_it(both_ways, tmp_path):
    L, out = both_ways
    (tmp_path / "guide.txt").write_text(guide_text(_turned(out["down"].joint_positions())))
    case = tmp_path / "case.json"
    case.write_text(json.dumps({**SPEC, "direction": "up", "guide": "guide.txt"}))
    assert main(["deploy", str(case), "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    r = json.loads((tmp_path / "o" / "result.json").read_text())
    assert r["guide"]["held"] and r["guide"]["moved"] > 0.1 and r["guide"]["released_rms"] <= 1e-8
    assert r["guide"]["file"] == str(tmp_path / "guide.txt")
    assert r["deployed"]["energy"] == pytest.approx(out["down"].energy(), rel=1e-9)
    # the same from a bare design with --guide
    assert main(["deploy", DESIGN, "--material", "rectangle:0.1,0.07", "--subdivision", "3", "--steps", "4",
                 "--angle", "60", "--guide", str(tmp_path / "guide.txt"), "--out", str(tmp_path / "b"),
                 "--no-progress"]) == 0
    b = json.loads((tmp_path / "b" / "result.json").read_text())
    assert b["guide"]["held"] and b["deployed"]["energy"] == pytest.approx(r["deployed"]["energy"], rel=1e-9)


def test_the_guide_file_keeps_full_precision(tmp_path):
    G = np.random.default_rng(1).normal(size=(5, 3)) * 1e3
    (tmp_path / "g.txt").write_text(guide_text(G))
    assert np.array_equal(read_guide(tmp_path / "g.txt", 5), G)


@pytest.mark.parametrize("text,match", [
    ("1 2 3\n4 5 6\n", "2 joint positions for a design with 97 joints"),
    ("1 2 3\n4 5\n", "line 2: expected 3 numbers"),
    ("1 2 3\n4 x 6\n", "line 2: not a number"),
    ("".join("1 2 3\n" for _ in range(96)) + "1 nan 3\n", "joint 96 (row 97) is not finite"),
    ("".join("1 2 3\n" for _ in range(97)), "every joint is at the same point"),
])
def test_a_bad_guide_is_one_line_naming_the_file(tmp_path, capsys, text, match):
    (tmp_path / "g.txt").write_text(text)
    case = tmp_path / "case.json"
    case.write_text(json.dumps({**SPEC, "guide": "g.txt"}))
    assert main(["deploy", str(case), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and "g.txt" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "o" / "result.json").exists()  # refused before the deployment


def test_a_missing_guide_file_is_named(tmp_path, capsys):
    case = tmp_path / "case.json"
    case.write_text(json.dumps({**SPEC, "guide": "nowhere.txt"}))
    assert main(["deploy", str(case), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "nowhere.txt" in err and len(err.splitlines()) == 1, err


def test_a_guide_of_the_wrong_shape_is_refused_by_the_api_before_deploying():
    L = _linkage()
    x0 = L.get_vars().copy()
    with pytest.raises(InputError, match="2 joint positions for a design with 97 joints"):
        deploy(L, np.radians(60), DeployOptions(steps=4, guide=np.zeros((2, 3))))
    assert np.array_equal(L.get_vars(), x0)


# ------------------------------------------------------------------ the commands and the app follow a case's guide
@pytest.fixture
def guided_case(both_ways, tmp_path):
    """A case deployed "up" whose guide is the "down" state: it ends in the "down" state wherever it is deployed."""
    L, out = both_ways
    (tmp_path / "guide.txt").write_text(guide_text(_turned(out["down"].joint_positions())))
    case = tmp_path / "case.json"
    case.write_text(json.dumps({**SPEC, "direction": "up", "guide": "guide.txt"}))
    return case, out


def test_optimize_starts_from_the_guided_state_and_writes_its_own_guide(tmp_path):
    # the small warped grid of the design tests, deployed "up" and guided into its "down" state
    from test_deploy import warped_grid

    from xshells.deploy.case import load_case
    from xshells.io.export import write_design_obj

    write_design_obj(tmp_path / "grid.obj", warped_grid(4))
    L = Linkage(read_design(tmp_path / "grid.obj"), Material.uniform("rectangle", [4.0, 1.5], E=2000, nu=0.3),
                subdivision=4)
    rest_length_solve(L)
    states = {}
    for direction in ("up", "down"):
        D = copy.deepcopy(L)
        assert deploy(D, np.radians(60), DeployOptions(steps=6, direction=direction)).converged
        states[direction] = D.joint_positions()
    (tmp_path / "guide.txt").write_text(guide_text(_turned(states["down"])))
    (tmp_path / "case.json").write_text(json.dumps({
        "file": "grid.obj", "material": {"type": "rectangle", "params": [4.0, 1.5], "E": 2000, "nu": 0.3},
        "angle_deg": 60, "steps": 6, "subdivision": 4, "direction": "up", "guide": "guide.txt"}))
    o = tmp_path / "opt"
    assert main(["optimize", str(tmp_path / "case.json"), "--out", str(o), "--max-iters", "2", "--no-baseline",
                 "--no-progress"]) == 0
    written = load_case(o / "case.json")
    assert written.guide_path == str(o / "deploy_guide.txt")
    r = json.loads((o / "result.json").read_text())
    assert r["state_distance"]["deployed"] <= 1e-6  # `xshells deploy OUT/case.json` reaches the optimizer's state
    assert json.loads((o / "deploy" / "result.json").read_text())["guide"]["held"]
    # the optimizer's state is the "down" one it was guided into, moved a little by two iterations, not the "up" one
    G = read_guide(written.guide_path, None)
    near = lambda P: np.abs(rigid_fit(P, G) - G).max()  # noqa: E731
    assert near(states["down"]) < 0.2 * near(states["up"])


def test_the_app_deploys_a_case_with_its_guide_and_exports_it(guided_case, tmp_path):
    from xshells.app.exports import write_case
    from xshells.app.loading import open_path
    from xshells.app.session import Session
    from xshells.app.sim import SimSettings, Simulation

    case, out = guided_case
    project = open_path(str(case))
    assert project.guide is not None and project.guide.shape == (97, 3)
    sim = Simulation(project.layout, Session._build_material(project.material), project.subdivision,
                     settings=SimSettings(direction="up", steps=4, guide=project.guide))
    info = sim.solve_to(60.0)
    assert info.converged
    Y, down = sim.linkage.joint_positions(), out["down"].joint_positions()
    assert np.abs(rigid_fit(down, Y) - Y).max() <= 1e-6 * float(np.ptp(down, axis=0).max())
    written = write_case(tmp_path / "app.json", "app", project.layout, project.material, project.subdivision, 60.0,
                         direction="up", steps=4, guide=project.guide)
    assert str(tmp_path / "app_guide.txt") in written
    assert np.array_equal(read_guide(tmp_path / "app_guide.txt", 97), project.guide)


def test_an_uploaded_case_with_a_guide_is_refused_in_one_line():
    from xshells.app.loading import UploadStore

    store = UploadStore()
    with open(DESIGN, "rb") as fh:
        store.open_upload("nonuniform_linkage.obj", fh.read())
    with pytest.raises(InputError, match="guide files are not read from uploads"):
        store.open_upload("case.json", json.dumps({"file": "nonuniform_linkage.obj", "guide": "g.txt"}).encode())


def test_analyze_puts_the_guided_state_on_its_supports(guided_case, tmp_path):
    case, out = guided_case
    assert main(["analyze", str(case), "--supports", "lowest:4", "--load", "point:3:0,0,-1e-9", "--no-critical",
                 "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    dep = json.loads((tmp_path / "a" / "deploy" / "result.json").read_text())
    assert dep["guide"]["held"] and dep["deployed"]["energy"] == pytest.approx(out["down"].energy(), rel=1e-9)


def test_ctrl_c_while_held_on_the_guide_keeps_the_state_reached(both_ways, monkeypatch):
    import xshells.deploy.guide as guide

    L, out = both_ways

    def interrupted(linkage, *args, **kw):
        x = linkage.get_vars()
        linkage.set_vars(x + 1e-3)  # half-way somewhere: must not be what is left
        raise KeyboardInterrupt

    monkeypatch.setattr(guide, "settle_into", interrupted)
    D = copy.deepcopy(L)
    with pytest.raises(KeyboardInterrupt):
        deploy(D, np.radians(60), DeployOptions(steps=4, direction="up", guide=out["down"].joint_positions()))
    assert np.array_equal(D.get_vars(), out["up"].get_vars())  # the last finished equilibrium: the state reached
