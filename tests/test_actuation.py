"""Sparse actuation (paper §6): derivatives, sparsity, torque limit, the pointy wings, bad input."""
import json

import numpy as np
import pytest

from xshells.actuation import SparsifyOptions, TorqueFit, sparsify
from xshells.cli import main
from xshells.deploy import DeployOptions, deploy, rest_length_solve
from xshells.errors import InputError
from xshells.linkage.linkage import Linkage
from xshells.linkage.state import restore, snapshot

from data_paths import EXAMPLES
from test_deploy import FLAT_BEAM, warped_grid


@pytest.fixture(scope="module")
def dense():
    """A small incompatible grid deployed to 60° by uniform actuation: (linkage, τ_ref, state, flat energy)."""
    L = Linkage(warped_grid(5), FLAT_BEAM, subdivision=4)
    rest_length_solve(L)
    flat = L.energy()
    res = deploy(L, np.radians(60), DeployOptions(steps=6))
    assert res.converged and res.torque > 0
    return L, res.torque, snapshot(L), flat


def test_dense_torques_reproduce_the_dense_deployment(dense):
    L, tau, state, _ = dense
    restore(L, state)
    fit = TorqueFit(L, tau)
    P0 = L.joint_positions()
    assert fit.evaluate(np.full(L.num_joints, 1.0)) == pytest.approx(1e-4, rel=1e-9)  # only η·mean(t) is left
    assert np.abs(L.joint_positions() - P0).max() < 1e-6 * fit.l0


@pytest.mark.parametrize("p", [1.0, 0.5, 0.25])
def test_adjoint_gradient_and_hessian_vector_product_match_finite_differences(dense, p):
    L, tau, state, _ = dense
    restore(L, state)
    fit = TorqueFit(L, tau, p=p, eta=1e-3)
    rng = np.random.default_rng(0)
    t = np.clip(1 + 0.3 * rng.standard_normal(L.num_joints), 0.3, 2.0)
    g, v = fit.gradient(t), rng.standard_normal(L.num_joints)
    Hv = fit.hessp(t, v)
    ge, he = [], []
    for h in (2e-3, 1e-3, 5e-4):
        fp, gp = fit.evaluate(t + h * v), fit.gradient(t + h * v)
        fm, gm = fit.evaluate(t - h * v), fit.gradient(t - h * v)
        ge.append(abs((fp - fm) / (2 * h) - g @ v) / abs(g @ v))
        he.append(np.linalg.norm((gp - gm) / (2 * h) - Hv) / np.linalg.norm(Hv))
    assert ge[-1] < 1e-4 and he[-1] < 1e-4, (ge, he)
    # central differences converge at second order onto our derivatives
    assert ge[0] / ge[1] > 3 and he[0] / he[1] > 3, (ge, he)
    # the Hessian is symmetric (up to the equilibrium's and the Hessian derivative's accuracy)
    w = rng.standard_normal(L.num_joints)
    assert w @ fit.hessp(t, v) == pytest.approx(v @ fit.hessp(t, w), rel=1e-5)


def test_fold_penalty_derivatives_match_finite_differences(dense):
    # narrow the angle window so that half the joints are penalized
    L, tau, state, _ = dense
    restore(L, state)
    fit = TorqueFit(L, tau, p=0.5, eta=1e-3)
    rng = np.random.default_rng(1)
    t = np.clip(1 + 0.3 * rng.standard_normal(L.num_joints), 0.3, 2.0)
    fit.evaluate(t)
    alpha = L.joint_angles()
    fit.angle_window = (float(np.quantile(alpha, 0.25)), float(np.quantile(alpha, 0.75)))
    fit._t = None
    fit.evaluate(t)
    assert np.count_nonzero(fit.fold_excess()) >= L.num_joints // 3
    g, v = fit.gradient(t), rng.standard_normal(L.num_joints)
    Hv = fit.hessp(t, v)
    h = 5e-4
    gd = (fit.evaluate(t + h * v) - fit.evaluate(t - h * v)) / (2 * h)
    Hd = (fit.gradient(t + h * v) - fit.gradient(t - h * v)) / (2 * h)
    assert abs(gd - g @ v) < 1e-4 * abs(g @ v)
    assert np.linalg.norm(Hd - Hv) < 1e-3 * np.linalg.norm(Hv)


def test_sparse_torques_do_not_fold_a_joint(tmp_path):
    # Unpenalized, the pointy wings' 3-actuator answer at η = 3e-4 opened joint 18 to 190°
    out = tmp_path / "out"
    main(["sparsify", str(EXAMPLES / "asymm_wings_pointy" / "case.json"), "--eta", "3e-4", "--out", str(out), "--no-progress"])
    r = json.loads((out / "result.json").read_text())
    assert "not valid" not in r["message"], r["message"]
    assert r["num_actuators"] <= 6 and r["fit_mean"] <= 0.01


def _tradeoff(L, tau, state, p, etas):
    out = []
    for eta in etas:
        restore(L, state)
        r = sparsify(L, tau, SparsifyOptions(eta=eta, p=p))
        assert r.converged, r.message
        out.append((len(r.actuated), r.fit_mean))
    return out


def test_p_one_half_needs_fewer_actuators_than_p_one(dense):
    L, tau, state, _ = dense
    etas = (1e-4, 2e-4)
    l1 = _tradeoff(L, tau, state, 1.0, etas)
    lh = _tradeoff(L, tau, state, 0.5, etas)
    # every p = 1 point is matched by a p = 1/2 point with no more actuators and no worse fit, one with fewer
    for k1, f1 in l1:
        assert any(kh <= k1 and fh <= f1 * 1.05 for kh, fh in lh), (l1, lh)
    assert any(kh < k1 and fh <= f1 * 1.05 for kh, fh in lh for k1, f1 in l1), (l1, lh)


def test_sparse_torques_keep_the_work_and_deploy_close(dense):
    L, tau, state, flat = dense
    restore(L, state)
    dense_work = L.energy() - flat
    r = sparsify(L, tau, SparsifyOptions(eta=1e-3, p=0.5), flat_energy=flat)
    assert 1 <= len(r.actuated) <= 4
    assert r.fit_mean < 0.02
    # the same shape takes about the same work, so each of few actuators pushes harder
    assert r.work == pytest.approx(dense_work, rel=0.25)
    assert r.torques.max() > 3 * tau


def test_torque_limit_stops_the_sparsification(dense):
    L, tau, state, _ = dense
    restore(L, state)
    free = sparsify(L, tau, SparsifyOptions(eta=1e-3, p=0.5))
    limit = free.torques.max() / 3
    restore(L, state)
    capped = sparsify(L, tau, SparsifyOptions(eta=1e-3, p=0.5, tau_max=limit))
    assert capped.torques.max() <= limit * (1 + 1e-9)
    assert len(capped.actuated) > len(free.actuated)


def test_candidates_restrict_the_actuated_joints(dense):
    L, tau, state, _ = dense
    restore(L, state)
    allowed = np.zeros(L.num_joints, bool)
    allowed[::3] = True
    r = sparsify(L, tau, SparsifyOptions(eta=1e-3, p=0.5), allowed=allowed)
    assert len(r.actuated) and allowed[r.actuated].all()


@pytest.mark.parametrize("kwargs,match", [
    (dict(eta=-1.0), "eta"), (dict(p=0.0), "p must"), (dict(p=1.5), "p must"), (dict(tau_max=0.0), "tau_max"),
])
def test_bad_options(kwargs, match):
    with pytest.raises(InputError, match=match):
        SparsifyOptions(**kwargs)


@pytest.mark.parametrize("argv,match", [
    (["--eta", "-1"], "eta must be"), (["--p", "2"], "p must lie"), (["--tau-max", "-3"], "--tau-max must be positive"), (["--tau-max", "-inf"], "--tau-max must be positive"),
    (["--candidates", "5,99999"], "candidate joint 99999 is out of range"),
])
def test_cli_bad_input_is_one_line(tmp_path, capsys, argv, match):
    case = EXAMPLES / "asymm_wings_pointy" / "case.json"
    if "--candidates" in argv:  # needs the dense deployment first: use a small case
        spec = {"file": str(EXAMPLES / "nonuniform_linkage.obj"), "material": {"type": "rectangle", "params": [0.1, 0.07]},
                "angle_deg": 60, "steps": 4, "subdivision": 3}
        case = tmp_path / "small.json"
        case.write_text(json.dumps(spec))
    assert main(["sparsify", str(case), "--out", str(tmp_path / "o"), "--no-progress", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and len(err.splitlines()) == 1, err


def test_cli_takes_a_bare_design_with_its_options(tmp_path):
    from xshells.io.export import write_design_obj

    write_design_obj(tmp_path / "grid.obj", warped_grid(4))
    out = tmp_path / "out"
    assert main(["sparsify", str(tmp_path / "grid.obj"), "--material", "rectangle:4,1.5", "--young", "2000",
                 "--subdivision", "3", "--steps", "4", "--angle", "60", "--eta", "1e-3", "--out", str(out), "--no-progress"]) == 0
    case = json.loads((out / "case.json").read_text())
    assert case["material"]["params"] == [4.0, 1.5]
    assert case["angle_deg"] == 60.0  # re-run from the case, it deploys where this run did (it once opened 60°)
    r = json.loads((out / "result.json").read_text())
    assert r["num_actuators"] >= 1 and "not valid" not in r["message"] and r["warnings"] == []
    assert r["target_angle_deg"] == pytest.approx(60.0)
    assert main(["sparsify", str(tmp_path / "grid.txt"), "--out", str(out)]) == 2


def test_an_interrupted_sparsification_exits_as_interrupted(tmp_path, monkeypatch, capsys):
    """It kept its best answer (status 'interrupted' in result.json) but exited 1 with no word of the stop;
    `xshells deploy` exits 130 and says 'interrupted'."""
    import xshells.actuation.run as run
    from xshells.io.export import write_design_obj

    def interrupted(case_path, out, opts, **kw):
        return {"name": "grid", "num_actuators": 2, "actuated_joints": [1, 2], "torques": [1.0, 2.0], "dense_torque": 0.5,
                "fit_mean": 0.02, "fit_max": 0.05, "work": 1.0, "dense_work": 1.0, "time_s": 1.0, "dense_deployment_time_s": 1.0,
                "converged": False, "status": "interrupted", "message": "interrupted by the user", "warnings": []}

    monkeypatch.setattr(run, "run_selection", interrupted)
    write_design_obj(tmp_path / "grid.obj", warped_grid(3))
    code = main(["sparsify", str(tmp_path / "grid.obj"), "--material", "rectangle:4,1.5", "--subdivision", "3",
                 "--steps", "3", "--out", str(tmp_path / "out"), "--no-progress"])
    assert code == 130 and "interrupted" in capsys.readouterr().err
