"""Deployment: buckling out of plane, direction, compatible grids, torque, bad input."""
import json
import os

import numpy as np
import pytest

from xshells.cli import main
from xshells.deploy import DeployOptions, deploy, rest_length_solve
from xshells.errors import InputError
from xshells.io import read_design
from xshells.io.export import write_design_obj
from xshells.linkage.grids import rhombic_grid
from xshells.linkage.linkage import Linkage
from xshells.section import Material

from data_paths import DATA, needs_data

FLAT_BEAM = Material.uniform("rectangle", [4.0, 1.5], E=2000, nu=0.3)


def warped_grid(n=6):
    """Joint spacing shrinking towards the rim: incompatible, flat and mirror-symmetric."""
    def warp(p):
        r = np.linalg.norm(p, axis=1, keepdims=True)
        R = r.max()
        return p * (1.0 - 0.25 * (r / R) ** 2)

    return rhombic_grid(n, n, spacing=100.0, angle=np.radians(30), warp=warp)


def span(L):
    return np.ptp(L.joint_positions(), axis=0).max()


@pytest.mark.parametrize("direction", ["up", "down"])
def test_flat_symmetric_incompatible_grid_leaves_the_plane_on_the_requested_side(direction):
    L = Linkage(warped_grid(), FLAT_BEAM, subdivision=4)
    rest_length_solve(L)
    assert np.abs(L.height_selector() @ L.get_vars()).max() == 0.0  # exactly flat, no perturbation
    res = deploy(L, np.radians(80), DeployOptions(steps=12, direction=direction))
    assert res.converged, res.message
    z = L.height_selector() @ L.get_vars()
    assert np.ptp(z) > 0.05 * span(L)
    assert (np.mean(z - z.min() if direction == "up" else z - z.max())) * (1 if direction == "up" else -1) > 0
    centre = z[np.argmin(np.linalg.norm(L.joint_positions()[:, :2], axis=1))]
    rim = z[np.argmax(np.linalg.norm(L.joint_positions()[:, :2], axis=1))]
    assert (centre - rim) * (1 if direction == "up" else -1) > 0
    assert res.min_hessian_eigenvalue > 0


def test_uniform_grid_stays_flat_when_opened():
    L = Linkage(rhombic_grid(4, 4, spacing=100.0, angle=np.radians(30)), FLAT_BEAM, subdivision=4)
    rest_length_solve(L)
    res = deploy(L, np.radians(80), DeployOptions(steps=5))
    assert res.converged
    assert np.abs(L.height_selector() @ L.get_vars()).max() < 1e-8 * span(L)
    assert abs(np.degrees(L.average_angle()) - 80) < 1e-8


def test_reported_torque_is_the_angle_gradient():
    L = Linkage(warped_grid(4), FLAT_BEAM, subdivision=4)
    rest_length_solve(L)
    res = deploy(L, np.radians(60), DeployOptions(steps=4))
    g = L.gradient()[L.angle_indices()]
    assert np.isclose(res.torque, g.mean())
    assert np.allclose(g, g.mean(), rtol=1e-4, atol=1e-6 * np.abs(g).max())  # equal torque at every joint


def test_a_step_whose_angle_did_not_move_is_not_reported_as_reached():
    """A segment 1e-9 of the others' length (the file reader refuses it; built here from arrays) makes the
    gradient tolerance meaningless: the solver once took no step at all and reported the target reached,
    30° away from it (the constraint's residual was judged by the gradient's tolerance)."""
    from xshells.io.design import Design

    # a square 4 × 4 grid, segments of 100, with a free end 1e-9 long at a corner
    V = [[100.0 * i, 100.0 * j, 0.0] for i in range(4) for j in range(4)] + [[300.000000001, 300.0, 0.0]]
    E = [[4 * i + j, 4 * i + j + 1] for i in range(4) for j in range(3)] + [[4 * i + j, 4 * i + j + 4] for i in range(3) for j in range(4)]
    L = Linkage(Design(np.array(V), np.array(E + [[15, 16]])), Material.uniform("rectangle", [10, 7], E=20000, nu=0.3), subdivision=4)
    rest_length_solve(L)
    res = deploy(L, np.radians(60), DeployOptions(steps=5))
    assert not res.converged and abs(res.reached_angle_deg - 60.0) > 1.0, res.message


def test_unreachable_angle_is_refused():
    L = Linkage(warped_grid(3), FLAT_BEAM, subdivision=4)
    with pytest.raises(InputError, match="out of reach"):
        deploy(L, np.radians(185))


def test_an_interrupted_deploy_keeps_the_steps_it_finished(tmp_path, monkeypatch):
    """Ctrl-C at step 3 of 6: result.json and deployment.csv list the two finished steps (they were
    once empty: the deployment's own result never came back)."""
    import xshells.deploy.run as run

    real = run.deploy

    def stopped_at_step_3(L, angle, options, callback=None, **kw):
        def on_step(rec):
            if rec.step == 3:
                raise KeyboardInterrupt
            return callback(rec)
        return real(L, angle, options, callback=on_step, **kw)

    monkeypatch.setattr(run, "deploy", stopped_at_step_3)
    design = tmp_path / "grid.obj"
    write_design_obj(design, warped_grid(4))
    out = tmp_path / "out"
    assert main(["deploy", str(design), "--angle", "70", "--steps", "6", "--subdivision", "4", "--out", str(out),
                 "--no-progress"]) == 130
    result = json.loads((out / "result.json").read_text())
    assert result["status"] == "interrupted" and [s["step"] for s in result["steps"]] == [1, 2]
    assert result["newton_iterations"] == sum(s["iterations"] for s in result["steps"]) > 0
    rows = (out / "deployment.csv").read_text().splitlines()
    assert rows[0].startswith("step,") and len(rows) == 3


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_an_interrupt_inside_a_step_keeps_the_last_finished_equilibrium(tmp_path, monkeypatch, capsys, how):
    """A stop landing inside step 3's solve: result.json's deployed state and the deployed files are step 2's
    equilibrium (they once described the half-solved step 3: scary_face 44.93° and energy 204,902 against
    the last finished step's 43.13°). SIGTERM says "terminated" and exits 143; Ctrl-C "interrupted", 130."""
    import signal

    import xshells.deploy.run as run
    import xshells.deploy.simulate as simulate
    from xshells.errors import STOP

    real_deploy, real_minimize = run.deploy, simulate.minimize
    finished = {}
    monkeypatch.setattr(STOP, "requested", False)  # put back after the test: the stop below must not outlive it
    monkeypatch.setattr(STOP, "signum", None, raising=False)

    def deploy_recording(L, angle, options, callback=None, **kw):
        def on_step(rec):
            finished[rec.step] = (L.joint_positions().copy(), rec)
            return callback(rec)
        return real_deploy(L, angle, options, callback=on_step, **kw)

    def minimize_stopped_in_step_3(problem, **kw):
        if 2 in finished and 3 not in finished:  # step 3: one Newton iteration, then the stop
            opts = kw.pop("options")
            real_minimize(problem, options=type(opts)(**{**opts.__dict__, "max_iterations": 1}), **kw)
            if how == "sigterm":
                STOP.request(None, signal.SIGTERM)  # what the command line's handler does
            raise KeyboardInterrupt
        return real_minimize(problem, **kw)

    monkeypatch.setattr(run, "deploy", deploy_recording)
    monkeypatch.setattr(simulate, "minimize", minimize_stopped_in_step_3)
    design = tmp_path / "grid.obj"
    write_design_obj(design, warped_grid(4))
    out = tmp_path / "out"
    code = main(["deploy", str(design), "--angle", "70", "--steps", "6", "--subdivision", "4", "--out", str(out),
                 "--no-progress"])
    err = capsys.readouterr().err
    result = json.loads((out / "result.json").read_text())
    assert result["status"] == "interrupted" and [s["step"] for s in result["steps"]] == [1, 2]
    P2, rec2 = finished[2]
    d = result["deployed"]
    assert d["average_angle_deg"] == pytest.approx(rec2.average_angle_deg, abs=1e-9)
    assert d["energy"] == pytest.approx(rec2.energy, rel=1e-12)
    assert np.allclose(d["joint_positions"], P2, rtol=0, atol=1e-12 * span_of(P2))
    assert d["max_abs_z"] == pytest.approx(result["steps"][-1]["max_abs_z"], rel=1e-12)  # one definition
    assert "energy" in (out / "deployment.csv").read_text() and (out / "deployed.obj").exists()
    assert result["message"].startswith("terminated (SIGTERM)" if how == "sigterm" else "interrupted by the user")
    assert code == (143 if how == "sigterm" else 130)
    assert ("terminated" if how == "sigterm" else "interrupted") in err and "2 finished steps" in err, err


def span_of(P):
    return float(np.ptp(np.asarray(P), axis=0).max())


def test_an_opening_past_180_names_the_case_key_not_only_the_sum(tmp_path, capsys):
    design = tmp_path / "grid.obj"
    write_design_obj(design, rhombic_grid(3, 3, spacing=100.0))  # drawn at 90°
    (tmp_path / "case.json").write_text(json.dumps({"file": "grid.obj", "open_by_deg": 170, "subdivision": 3, "steps": 2}))
    assert main(["deploy", str(tmp_path / "case.json"), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "open_by_deg 170" in err and "opened by 170° is 260°" in err and len(err.strip().splitlines()) == 1, err


def test_cli_deploy_case_file(tmp_path):
    design = tmp_path / "grid.obj"
    write_design_obj(design, warped_grid(4))
    case = {"name": "grid", "file": "grid.obj", "subdivision": 4, "angle_deg": 70, "steps": 6,
            "material": {"type": "rectangle", "E": 2000, "nu": 0.3, "params": [4.0, 1.5]}}
    (tmp_path / "case.json").write_text(json.dumps(case))
    out = tmp_path / "out"
    assert main(["deploy", str(tmp_path / "case.json"), "--out", str(out), "--no-progress"]) == 0
    result = json.loads((out / "result.json").read_text())
    for key in ("segments", "joints", "dof", "subdivision", "rest_lengths", "flat", "deployed", "steps", "timings_s", "newton_iterations"):
        assert key in result
    assert len(result["deployed"]["joint_positions"]) == result["joints"]
    assert (out / "deployment.csv").read_text().count("\n") == 7
    # fabrication drawings of the flat layout with the solved rest lengths
    svg = (out / "flat_layout.svg").read_text()
    assert svg.count('class="beam"') == result["segments"]
    assert f'data-rest-length="{result["rest_lengths"][0]:.4f}"' in svg
    assert (out / "flat_layout.dxf").stat().st_size > 0
    # holding the angle adds a positive semi-definite term: it can only raise the lowest eigenvalue
    dep = result["deployed"]
    assert dep["min_eigenvalue_at_fixed_angle"] > 0
    assert dep["min_eigenvalue_at_fixed_angle"] >= dep["min_hessian_eigenvalue"] * (1 - 1e-6)


def test_cli_contradictory_options(tmp_path, capsys):
    (tmp_path / "case.json").write_text(json.dumps({"file": "x.obj"}))
    assert main(["deploy", str(tmp_path / "case.json"), "--material", "rectangle:1,1"]) == 2
    err = capsys.readouterr().err
    assert "contradicts" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("option", [["--young", "5"], ["--poisson", "0.2"]])
def test_cli_material_options_with_a_case_file_are_refused_not_ignored(tmp_path, capsys, option):
    from data_paths import EXAMPLES

    (tmp_path / "quad.obj").write_bytes((EXAMPLES / "quad.obj").read_bytes())
    (tmp_path / "case.json").write_text(json.dumps({"file": "quad.obj", "steps": 3, "material": {
        "type": "rectangle", "E": 20000, "nu": 0.3, "params": [10, 7]}}))
    assert main(["deploy", str(tmp_path / "case.json"), *option, "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{option[0]} contradicts the case file" in err and len(err.splitlines()) == 1, err


# ---------------------------------------------------------------- real designs
def _optimized(name):
    from xshells.io import read_design, read_rest_lengths

    from data_paths import EXAMPLES

    base = EXAMPLES / name
    flat, deployed = read_design(base / "flat_opt.msh"), read_design(base / "deployed_opt.msh")
    p = read_rest_lengths(base / "design_parameters.txt", flat.num_segments)
    material = Material.uniform("+", [5.0, 5.0, 0.2, 0.2], E=20000, nu=0.3, stiff_axis="D1")
    return Linkage(flat, material, subdivision=10, rest_lengths=p), deployed


def _kabsch_deviation(A, B):
    ca, cb = A.mean(0), B.mean(0)
    U, _, Vt = np.linalg.svd((A - ca).T @ (B - cb))
    D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return np.linalg.norm((A - ca) @ R.T + cb - B, axis=1)


@pytest.fixture(scope="module")
def banana_energies():
    from xshells.solve import NewtonOptions, minimize

    out = {}
    for name in ("wiggly_banana_5", "wiggly_banana_preopt"):
        L, reference = _optimized(name)
        minimize(L, fixed=L.rigid_pin_indices(), options=NewtonOptions(gradient_tolerance=1e-6, saddle_gradient_factor=float("inf")))
        # buckle to the same side as the reference ("up" = the middle rises along the layout normal)
        P, ref = L.joint_positions(), reference.vertices[L.graph.joint_vertex]
        r2 = np.sum((P - P.mean(0)) ** 2, axis=1)
        side = (r2.mean() - r2) @ ((ref - ref.mean(0)) @ L.graph.layout_normal)
        res = deploy(L, np.radians(80), DeployOptions(steps=20, direction="up" if side > 0 else "down"))
        assert res.converged, res.message
        ref = reference.vertices[L.graph.joint_vertex]
        dev = _kabsch_deviation(L.joint_positions(), ref) / np.linalg.norm(np.ptp(ref, axis=0))
        out[name] = (L.energy(), dev.max())
    return out


def test_a_real_design_deploys_from_its_files_unrelaxed_state():
    """The pre-optimization banana (k = 10) straight from its file, not relaxed first: Newton must not
    give up where the gradient sits at its rounding floor (it stopped at 43° once)."""
    L, _ = _optimized("wiggly_banana_preopt")
    res = deploy(L, np.radians(80), DeployOptions(steps=20))
    assert res.converged, res.message
    assert np.degrees(L.average_angle()) == pytest.approx(80.0, abs=1e-6)


def test_optimized_designs_redeploy_onto_the_reference_states(banana_energies):
    for name, (_, deviation) in banana_energies.items():
        assert deviation < 0.01, name  # within 1% of the bounding-box diagonal


@pytest.mark.parametrize("folder, material, angle_deg, direction, bound", [
    # the paper's wings at their case angle (2 rad): 1.5e-5 of the diagonal measured (2026-12-05)
    ("asymm_wings_pointy", ("rectangle", [12.0, 8.0], 20000), float(np.degrees(2.0)), "down", 1e-4),
    # the wooden prototype's files are at about 97° (its notebook deploys them to 76°, the angle of cases.json,
    # and a 3D file's joints read as 83°, the supplement): 0.39% max there, 7-10% at 76° or 83°; the last 0.4%
    # is not ours to explain (no angle brings it below 0.39%: another section or iterate wrote the file)
    ("simple_two_bumps_3", ("rectangle", [15.3, 8.1], 2000), 97.5, "up", 0.01),
])
def test_more_optimized_designs_redeploy_onto_their_files_at_the_files_angle(folder, material, angle_deg, direction, bound):
    from xshells.io import read_rest_lengths
    from xshells.solve import NewtonOptions, minimize

    from data_paths import DATA, EXAMPLES

    base = EXAMPLES / folder
    if not base.is_dir():
        base = DATA / "python" / "examples" / "optimized" / "data" / folder
        if not base.is_dir():
            pytest.skip(f"shared ElasticRods data not found at {base}")
    flat, reference = read_design(base / "flat_opt.msh"), read_design(base / "deployed_opt.msh")
    kind, params, E = material
    L = Linkage(flat, Material.uniform(kind, params, E=E, nu=0.3, stiff_axis="D1"), subdivision=10,
                rest_lengths=read_rest_lengths(base / "design_parameters.txt", flat.num_segments))
    minimize(L, fixed=L.rigid_pin_indices(), options=NewtonOptions(gradient_tolerance=1e-6, saddle_gradient_factor=float("inf")))
    res = deploy(L, np.radians(angle_deg), DeployOptions(steps=20, direction=direction))
    assert res.converged, res.message
    ref = reference.vertices[L.graph.joint_vertex]
    dev = _kabsch_deviation(L.joint_positions(), ref) / np.linalg.norm(np.ptp(ref, axis=0))
    assert dev.max() < bound, dev.max()


def test_optimization_lowers_the_deployed_energy_five_fold(banana_energies):
    assert banana_energies["wiggly_banana_preopt"][0] > 5 * banana_energies["wiggly_banana_5"][0]


def test_equilibrium_under_the_deployment_torques_reproduces_the_deployment():
    from xshells.deploy import solve_equilibrium

    L = Linkage(warped_grid(4), FLAT_BEAM, subdivision=4)
    rest_length_solve(L)
    deploy(L, np.radians(50), DeployOptions(steps=4))
    x50 = L.get_vars()
    res = deploy(L, np.radians(55), DeployOptions(steps=1))
    x55 = L.get_vars()
    L.set_vars(x50)
    report = solve_equilibrium(L, torques=np.full(L.num_joints, res.torque))
    assert report.converged, report.message
    assert abs(np.degrees(L.average_angle()) - 55) < 1e-3
    assert np.abs(L.get_vars() - x55)[L.angle_indices()].max() < 1e-4


def test_gravity_and_point_loads_have_the_right_resultant():
    L = Linkage(warped_grid(3), FLAT_BEAM, subdivision=4)
    g = L.gravity_force((0, 0, -9810.0))
    mass = float(np.sum(L.rods.vertex_masses()))
    # a uniform translation δx along z does work mass * g * δz
    dz = np.zeros(L.num_vars)
    dz[2 : L.num_joint_vars : 9] = 1.0
    free_z = (L._free_rod < 3 * L.rods.num_vertices) & (L._free_rod % 3 == 2)
    dz[L._free_reduced[free_z]] = 1.0
    assert np.isclose(g @ dz, -9810.0 * mass)
    F = np.zeros((L.num_joints, 3))
    F[0] = [1.0, 2.0, 3.0]
    assert np.allclose(L.joint_force(F)[:3], [1.0, 2.0, 3.0])


def test_deployment_is_reproducible():
    runs = []
    for _ in range(2):
        L = Linkage(warped_grid(4), FLAT_BEAM, subdivision=4)
        rest_length_solve(L)
        deploy(L, np.radians(70), DeployOptions(steps=5))
        runs.append(L.get_vars())
    assert np.array_equal(runs[0], runs[1])


def test_minima_reached_by_quadratic_convergence_save_hessians_not_accuracy(monkeypatch):
    """The default deployment takes a minimum reached by Newton's quadratic convergence on its last step's
    factor (NewtonOptions.minimum_from_last_step), which also gives the next step's tangent: the same
    equilibrium path, fewer Hessians."""
    from dataclasses import replace

    counts = []
    original = Linkage._hessian_parts

    def counted(self, c):
        if "hess_parts" not in c:
            counts[-1] += 1
        return original(self, c)

    monkeypatch.setattr(Linkage, "_hessian_parts", counted)
    joints = []
    for ratio in (0.0, DeployOptions().newton.minimum_from_last_step):
        counts.append(0)
        L = Linkage(warped_grid(), FLAT_BEAM, subdivision=4)
        rest_length_solve(L)
        opts = DeployOptions(steps=12)
        res = deploy(L, np.radians(80), replace(opts, newton=replace(opts.newton, minimum_from_last_step=ratio)))
        assert res.converged and res.min_hessian_eigenvalue > 0
        joints.append(L.joint_positions())
    assert DeployOptions().newton.minimum_from_last_step > 0
    assert np.abs(joints[1] - joints[0]).max() < 1e-9 * np.ptp(joints[0], axis=0).max()
    assert counts[0] - counts[1] >= 8, counts  # 108 → 97 when written


# ---------------------------------------------------------------- bounds and failures
def _joint_edge_vars(L):
    return (9 * np.arange(L.num_joints)[:, None] + np.array([7, 8])[None, :]).ravel()


def _solved_grid(n=4):
    L = Linkage(warped_grid(n), FLAT_BEAM, subdivision=4)
    rest_length_solve(L)
    return L


def test_joint_edge_lengths_stay_above_their_bound_with_an_active_set():
    L = _solved_grid()
    ev = _joint_edge_vars(L)
    eps = float(np.median(L.get_vars()[ev]))  # half of the joint edges start below: they must be held at ε
    res = deploy(L, np.radians(70), DeployOptions(steps=5, min_joint_edge_length=eps))
    assert res.converged, res.message
    x, g = L.get_vars(), L.gradient()
    assert x[ev].min() >= eps
    active = np.array(res.active_joint_edges)
    assert len(active) > 0 and np.all(x[active] == eps)
    assert np.all(g[active] > 0)  # KKT: each held edge pushes against its bound
    free_edges = np.setdiff1d(ev, active)
    assert np.abs(g[free_edges]).max() < 1e-6 * np.abs(g[active]).max()
    assert res.min_hessian_eigenvalue > 0


def test_default_joint_edge_bound_is_inactive_in_a_normal_deployment():
    L = _solved_grid()
    res = deploy(L, np.radians(60), DeployOptions(steps=4))
    assert res.converged and res.active_joint_edges == []


def test_stalled_solver_reports_the_angle_reached_and_keeps_the_last_equilibrium():
    from xshells.solve import NewtonOptions

    L = _solved_grid()
    x0, a0 = L.get_vars(), np.degrees(L.average_angle())
    newton = NewtonOptions(gradient_tolerance=1e-6, max_iterations=1, saddle_gradient_factor=float("inf"))
    res = deploy(L, np.radians(70), DeployOptions(steps=5, newton=newton))
    assert not res.converged
    assert res.message.startswith(f"stopped at {a0:.2f}° of 70.00°") and "stalled" in res.message
    assert "stopped after 1 iterations" in res.message  # the reason
    assert res.reached_angle_deg == pytest.approx(a0) and res.steps == []
    assert np.array_equal(L.get_vars(), x0)  # the last equilibrium, not the failed iterate


def test_joint_folding_past_180_degrees_stops_the_deployment_with_a_message():
    L = _solved_grid()
    res = deploy(L, np.radians(179), DeployOptions(steps=10))
    assert not res.converged
    assert "inverts" in res.message and "joint" in res.message and res.message.startswith(f"stopped at {res.reached_angle_deg:.2f}°")
    assert 60 < res.reached_angle_deg < 179
    assert len(res.steps) >= 1 and res.steps[-1].average_angle_deg == pytest.approx(res.reached_angle_deg)
    alpha = L.joint_angles()  # kept at the last equilibrium, which is not inverted
    assert np.all((alpha > 0) & (alpha < np.pi))
    assert abs(np.degrees(L.average_angle()) - res.reached_angle_deg) < 1e-9


def test_collapsing_edge_stops_the_deployment_with_a_message():
    L = _solved_grid()
    # any edge shorter than its rest length counts as collapsed here, so the check must fire
    res = deploy(L, np.radians(70), DeployOptions(steps=5, collapse_ratio=1.0 - 1e-9))
    assert not res.converged and "collapses" in res.message and "segment" in res.message


def test_cli_writes_the_partial_deployment(tmp_path):
    design = tmp_path / "grid.obj"
    write_design_obj(design, warped_grid(4))
    case = {"name": "grid", "file": "grid.obj", "subdivision": 4, "angle_deg": 179, "steps": 10,
            "material": {"type": "rectangle", "E": 2000, "nu": 0.3, "params": [4.0, 1.5]}}
    (tmp_path / "case.json").write_text(json.dumps(case))
    out = tmp_path / "out"
    assert main(["deploy", str(tmp_path / "case.json"), "--out", str(out), "--no-progress"]) == 1
    result = json.loads((out / "result.json").read_text())
    assert not result["reached"] and "inverts" in result["message"]
    assert result["steps"] and abs(result["deployed"]["average_angle_deg"] - result["steps"][-1]["average_angle_deg"]) < 1e-9


@needs_data
def test_an_assembly_state_that_folds_a_joint_starts_from_the_central_joint():
    """The reference's ``debug_propagation/fail.obj`` ('hole', Fig. 14): held at its drawn average angle
    (43.9°) its assembly state has no equilibrium, joint 28 folds flat at once; held by the central
    joint's angle alone it springs open (to 75°, out of plane), and the deployment to 2 rad goes on
    from there, as the authors' notebook drives it (by one joint)."""
    import copy

    from xshells.io import read_design

    L = Linkage(read_design(DATA / "examples" / "florin" / "debug_propagation" / "fail.obj"),
                Material.uniform("+", [3.0, 3.0, 0.6, 0.6], E=2000, nu=0.3), subdivision=5)
    rest_length_solve(L)
    held = copy.deepcopy(L)
    res = deploy(held, 2.0, DeployOptions(steps=25, start="average"))
    assert not res.converged
    assert 40 < res.reached_angle_deg < 50
    assert "joint 28" in res.message and ("folding" in res.message or "inverts" in res.message), res.message

    res = deploy(L, 2.0, DeployOptions(steps=25))
    assert res.converged, res.message
    assert res.start == "central-joint" and 70 < res.start_angle_deg < 80
    assert "joint 28" in res.start_note and "central joint" in res.message
    assert abs(res.reached_angle_deg - np.degrees(2.0)) < 1e-6
    assert res.min_hessian_eigenvalue > 0
    z = L.joint_positions()[:, 2]
    assert np.ptp(z) > 0.05 * np.linalg.norm(np.ptp(L.joint_positions(), axis=0))


@needs_data
def test_where_both_starts_fold_a_joint_a_longer_first_step_carries_it_open(tmp_path):
    """The swimming ray (Fig. 14's zoo) at the default 40 steps: held at its average angle, joint 118 (6.3° flat)
    folds on the first step of 1.8°, and held by the central joint it folds as well; the zoo's own 10 steps
    (7.3° each) deploy it. A first step of 4 increments (7.27°) reaches the 10-step deployment's equilibrium."""
    path = DATA / "examples" / "florin" / "20181227_203302_meshID_fbfa32b2-3ab2-4722-9678-b577ad1ccfb8.obj"
    assert main(["deploy", str(path), "--angle", "85", "--out", str(tmp_path), "--no-progress"]) == 0
    r = json.loads((tmp_path / "result.json").read_text())
    assert r["reached"] and abs(r["deployed"]["average_angle_deg"] - 85.0) < 1e-9
    assert "joint 118" in r["start"]["note"] and "first step of 4 increments (7.27°)" in r["start"]["note"]
    assert r["steps"][0]["step"] == 4 and len(r["steps"]) == 37
    # the energy of the zoo's own 10-step deployment (measured 2026-12-06): the same equilibrium
    assert r["deployed"]["energy"] == pytest.approx(1137916.2697664457, rel=1e-8)
    assert r["deployed"]["min_eigenvalue_at_fixed_angle"] > 0


def test_start_option_is_checked():
    with pytest.raises(InputError, match="start must be"):
        deploy(Linkage(warped_grid(3), Material.uniform("rectangle", [4.0, 1.5], E=2000, nu=0.3), subdivision=3), 1.0,
               DeployOptions(start="joint"))


EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "xshells", "data", "examples")


def test_rest_length_solve_keeps_the_rest_lengths_of_segments_that_end_free():
    # A free end's position and its segment's rest length slide together at zero energy;
    # left free, a 2-by-3 grid's end segments drifted from 141 to 1.7e7.
    from xshells.io.design import Design

    V = np.array([[0, 0, 0], [100, 0, 0], [200, 0, 0], [0, 100, 0], [100, 100, 0], [200, 100, 0.0]])
    E = np.array([[0, 4], [3, 1], [1, 5], [4, 2], [3, 4], [4, 5]])
    L = Linkage(Design(V, E), FLAT_BEAM, subdivision=6)
    free_end = np.flatnonzero((L.graph.segment_joints < 0).any(axis=1))
    assert len(free_end) == 2
    p0 = L.rest_lengths
    rest_length_solve(L)
    assert np.array_equal(L.rest_lengths[free_end], p0[free_end])
    assert np.abs(L.rods.points).max() < 300.0  # the free ends stay where they are drawn, give or take a rotation

    L = Linkage(read_design(os.path.join(EXAMPLES, "uniform_linkage.obj")),
                Material.uniform("rectangle", [0.01, 0.005], E=20000, nu=0.3), subdivision=5)
    free_end = np.flatnonzero((L.graph.segment_joints < 0).any(axis=1))
    p0 = L.rest_lengths
    report = rest_length_solve(L)
    assert np.array_equal(L.rest_lengths[free_end], p0[free_end])
    assert report.converged and report.saddle_escapes == 0 and report.iterations <= 5


def test_a_single_joint_deploys():
    # one joint has no span: the force scale of the tolerances comes from the rods
    L = Linkage(read_design(os.path.join(EXAMPLES, "single_linkage.obj")),
                Material.uniform("rectangle", [0.01, 0.005], E=20000, nu=0.3), subdivision=5)
    rest_length_solve(L)
    res = deploy(L, np.radians(60), DeployOptions(steps=5))
    assert res.converged, res.message
    assert abs(np.degrees(L.average_angle()) - 60) < 1e-8


def test_deploy_warns_about_a_section_wider_than_the_segments_and_a_design_that_is_not_flat(tmp_path):
    small = rhombic_grid(3, 3, spacing=1.0, angle=np.radians(30))  # drawn in metres, say
    write_design_obj(tmp_path / "small.obj", small)
    assert main(["deploy", str(tmp_path / "small.obj"), "--material", "rectangle:10,7", "--subdivision", "4",
                 "--steps", "2", "--out", str(tmp_path / "a"), "--no-progress"]) in (0, 1)
    warnings = json.loads((tmp_path / "a" / "result.json").read_text())["warnings"]
    assert len(warnings) == 2 and "slender" in warnings[0] and "same units" in warnings[0]
    # nor are drawings of strips whose holes overlap written
    assert warnings[1].startswith("fabrication files not written: strip ") and "closer than their diameter" in warnings[1]
    assert not (tmp_path / "a" / "cutlist.csv").exists()

    V = np.array(small.vertices, float)
    V[:, 2] = 0.01 * V[:, 0] ** 2  # a curved (deployed-looking) input
    from xshells.io.design import Design

    write_design_obj(tmp_path / "curved.obj", Design(V, np.array(small.edges)))
    main(["deploy", str(tmp_path / "curved.obj"), "--material", "rectangle:0.01,0.005", "--subdivision", "4",
          "--steps", "2", "--out", str(tmp_path / "b"), "--no-progress"])
    warnings = json.loads((tmp_path / "b" / "result.json").read_text())["warnings"]
    assert len(warnings) == 1 and "not flat" in warnings[0]


def test_material_option_keeps_a_section_files_own_moduli(tmp_path):
    # --material section.json without --young must not replace the file's E with the default
    from xshells.deploy.case import material_from_spec, material_spec_from_option

    section = json.loads(open(os.path.join(EXAMPLES, "cross_sections", "IBeam.json")).read())
    section["young"], section["poisson"] = 1234.0, 0.25
    (tmp_path / "s.json").write_text(json.dumps(section))
    m = material_from_spec(material_spec_from_option(str(tmp_path / "s.json")))
    assert (m.E, m.nu) == (1234.0, 0.25)
    m = material_from_spec(material_spec_from_option(str(tmp_path / "s.json"), young=5000.0))
    assert (m.E, m.nu) == (5000.0, 0.25)
    m = material_from_spec(material_spec_from_option("rectangle:10,7"))
    assert (m.E, m.nu) == (20000.0, 0.3)


@pytest.mark.parametrize("option, words", [
    (["--young", "0"], "--young must be a positive Young's modulus"), (["--poisson", "0.7"], "--poisson must lie in"),
    (["--material", "rectangle:1"], "--material rectangle:1: rectangle takes 2 parameters"),
    # recheck34: these said "profile: unknown cross-section type 'bogus'" and "must be positive, got inf"
    (["--material", "bogus:1,2"], "--material bogus:1,2: unknown cross-section type 'bogus'"),
    (["--material", "rectangle:inf,7"], "--material rectangle:inf,7: rectangle dimension width must be a positive finite number, got inf"),
    (["--material", "ellipse:3,0"], "--material ellipse:3,0: ellipse dimension b must be a positive finite number, got 0"),
    (["--material", "rectangle:1e-12,7"], "--material rectangle:1e-12,7: rectangle dimension width = 1e-12 is outside"),
])
def test_cli_material_errors_name_the_option(tmp_path, capsys, option, words):
    # they said "rectangle: Young's modulus must be positive", naming no option
    from data_paths import EXAMPLES

    assert main(["deploy", str(EXAMPLES / "quad.obj"), *option, "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err


def test_deploy_of_a_design_that_is_not_flat_removes_an_earlier_flat_layout_drawing(tmp_path):
    # a curved input has no flat layout drawing: an earlier, flat design's flat_layout.svg/.dxf stayed beside it
    small = rhombic_grid(3, 3, spacing=1.0, angle=np.radians(30))
    write_design_obj(tmp_path / "flat.obj", small)
    out = tmp_path / "o"
    args = ["--material", "rectangle:0.01,0.005", "--subdivision", "4", "--steps", "2", "--out", str(out), "--no-progress"]
    assert main(["deploy", str(tmp_path / "flat.obj")] + args) in (0, 1)
    assert (out / "flat_layout.svg").exists() and (out / "flat_layout.dxf").exists()
    from xshells.io.design import Design

    V = np.array(small.vertices, float)
    V[:, 2] = 0.01 * V[:, 0] ** 2
    write_design_obj(tmp_path / "curved.obj", Design(V, np.array(small.edges)))
    main(["deploy", str(tmp_path / "curved.obj")] + args)
    assert not (out / "flat_layout.svg").exists() and not (out / "flat_layout.dxf").exists()
    warnings = json.loads((out / "result.json").read_text())["warnings"]
    assert any("flat_layout.svg" in w and w.startswith("removed an earlier run's") for w in warnings), warnings


# ---------------------------------------------------------------- recheck31: heights, stale plot, rest lengths, density
def test_max_abs_z_is_one_definition_independent_of_the_shells_orientation(tmp_path):
    """result.json's deployed max_abs_z and its last step's were two measures of one state (30.86 and 52.33
    on a 7-ring radial design); and a shell tilted by its pinned joint measured taller than the same shell level."""
    from xshells.deploy.run import run_deployment

    r = run_deployment(_grid_file(tmp_path), FLAT_BEAM, out_dir=str(tmp_path / "out"), subdivision=4,
                       target_angle=np.radians(70), steps=6, progress=False)
    P = np.array(r["deployed"]["joint_positions"])
    assert r["deployed"]["max_abs_z"] == r["steps"][-1]["max_abs_z"] > 0.05 * span_of(P)
    from xshells.deploy.simulate import max_abs_z
    c, s = np.cos(0.3), np.sin(0.3)
    tilted = P @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T + [5.0, -3.0, 7.0]
    assert max_abs_z(tilted) == pytest.approx(max_abs_z(P), rel=1e-9)
    assert r["flat"]["max_abs_z"] < 1e-9 * span_of(P)


def _grid_file(tmp_path, n=4):
    design = tmp_path / "grid.obj"
    write_design_obj(design, warped_grid(n))
    return str(design)


def test_a_run_with_no_step_removes_an_earlier_runs_deployment_plot(tmp_path, monkeypatch):
    """deployment.png of an earlier run stayed beside a result that finished no step (and drew none)."""
    import xshells.deploy.run as run

    out = tmp_path / "out"
    out.mkdir()
    (out / "deployment.png").write_bytes(b"an earlier run's plot")
    real = run.deploy

    def stopped_at_step_1(L, angle, options, callback=None, **kw):
        def on_step(rec):
            raise KeyboardInterrupt
        return real(L, angle, options, callback=on_step, **kw)

    monkeypatch.setattr(run, "deploy", stopped_at_step_1)
    assert main(["deploy", _grid_file(tmp_path), "--angle", "70", "--steps", "4", "--subdivision", "4", "--out",
                 str(out), "--no-progress"]) == 130
    result = json.loads((out / "result.json").read_text())
    assert result["steps"] == [] and not (out / "deployment.png").exists()
    assert any("removed an earlier run's deployment.png" in w for w in result["warnings"]), result["warnings"]


def test_a_rest_length_solve_that_does_not_converge_is_a_warning(tmp_path, monkeypatch):
    """Its report was thrown away: single_linkage.json deployed from a flat state with a twist energy of 2e8."""
    import xshells.deploy.run as run
    from xshells.solve import NewtonOptions

    real = run.rest_length_solve
    monkeypatch.setattr(run, "rest_length_solve", lambda L: real(L, NewtonOptions(gradient_tolerance=1e-30, max_iterations=1)))
    r = run.run_deployment(_grid_file(tmp_path), FLAT_BEAM, out_dir=str(tmp_path / "out"), subdivision=4,
                           target_angle=np.radians(70), steps=2, progress=False)
    assert any(w.startswith("the rest-length solve did not converge") and "twist" in w for w in r["warnings"]), r["warnings"]


def test_density_is_refused_by_deploy_not_ignored(tmp_path, capsys):
    assert main(["deploy", _grid_file(tmp_path), "--density", "4.2e-10", "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "deploy applies no self-weight: --density is used by xshells analyze" in err and len(err.splitlines()) == 1


def test_one_coarse_step_that_buckles_the_flat_layout_is_redone_and_lands_on_the_deployments_branch(tmp_path):
    """--steps 1 landed silently on another branch (two_asymm_bumps: one bump down, energy 52,225, against
    46,046.5 with 2 to 50 steps); on this grid asked "up", a single step went down. The step is redone from
    the flat state in sub-steps, and said: in result.json (refined_steps) and in a warning."""
    from xshells.deploy.run import run_deployment

    fine = Linkage(warped_grid(), FLAT_BEAM, subdivision=4)
    rest_length_solve(fine)
    res = deploy(fine, np.radians(80), DeployOptions(steps=12))  # 3.75° steps: none redone
    assert res.converged
    states = {}
    r = run_deployment(_grid_file(tmp_path, 6), FLAT_BEAM, out_dir=str(tmp_path / "out"), subdivision=4,
                       target_angle=np.radians(80), steps=1, progress=False, states=states)
    P, Q = states["deployed"].joint_positions(), fine.joint_positions()
    assert np.abs(P - Q).max() < 1e-8 * span_of(Q)  # the same branch, the same side ("up")
    assert res.refined_steps == []
    (refined,) = r["refined_steps"]
    assert refined["step"] == 1 and refined["substeps"] == 3 and refined["to_deg"] == pytest.approx(80.0)
    assert any("buckled the flat layout in one step" in w for w in r["warnings"]), r["warnings"]


def test_units_are_stated_and_the_flat_layout_is_drawn_along_its_normal(tmp_path, capsys, monkeypatch):
    """flat.png was a 3D view at 28° elevation (the manta ray's nearly closed 2317 × 204 layout a sliver); the
    energy axis, result.json and the stress line gave no unit (units follow the input, never converted)."""
    from xshells.deploy.run import _flat_view

    grid = warped_grid(4)
    upright = type(grid)(grid.vertices[:, [0, 2, 1]], grid.edges)  # drawn in the xz plane: seen along y
    L = Linkage(upright, FLAT_BEAM, subdivision=4)
    xy, axes = _flat_view(L)
    # the layout's own extents, nothing foreshortened: a view along the layout normal
    assert set(axes) == {"x", "z"}
    assert np.allclose(sorted(np.ptp(xy, axis=0)), sorted(np.ptp(L.rods.points[:, [0, 2]], axis=0)))
    design = tmp_path / "grid.obj"
    write_design_obj(design, upright)
    out = tmp_path / "out"
    assert main(["deploy", str(design), "--angle", "60", "--steps", "3", "--subdivision", "4", "--strength", "100",
                 "--out", str(out), "--no-progress"]) in (0, 1)
    # flat.png's axes name their unit (they had none, where inverse's flat.png said "mm")
    import xshells.viz.render as render
    from xshells.deploy.run import _write_flat_outputs

    drawn, render_flat = [], render.render_flat
    monkeypatch.setattr(render, "render_flat", lambda *a, **k: drawn.append(render_flat(*a, **k)))
    (tmp_path / "again").mkdir()
    _write_flat_outputs(str(tmp_path / "again"), L, upright)
    (ax,) = [a for a in drawn[0].axes if a.get_title()]
    assert {ax.get_xlabel(), ax.get_ylabel()} == {"x (design units)", "z (design units)"}, (ax.get_xlabel(), ax.get_ylabel())
    stress = [x for x in capsys.readouterr().out.splitlines() if "largest von Mises" in x]
    assert stress and "MPa for mm and MPa" in stress[0], stress
    assert "never converted" in json.loads((out / "result.json").read_text())["units"]
    assert (out / "flat.png").stat().st_size > 0 and (out / "deployment.png").stat().st_size > 0


def test_a_newton_callback_stops_inside_a_step_and_keeps_the_last_finished_equilibrium():
    """A stop checked only between steps waited out a whole step (40 s in the app on the 1004-segment fans):
    deploy's newton_callback is called after every Newton iteration, and stopping there keeps the last step."""
    L = Linkage(warped_grid(4), FLAT_BEAM, subdivision=4)
    rest_length_solve(L)
    whole = Linkage(warped_grid(4), FLAT_BEAM, subdivision=4)
    rest_length_solve(whole)
    first = deploy(whole, np.radians(60), DeployOptions(steps=4), callback=lambda rec: rec.step == 2)
    assert len(first.steps) == 2
    calls, steps = [0], []

    def stop_in_step_3(it, report):
        calls[0] += 1
        return len(steps) == 2 and it >= 1

    res = deploy(L, np.radians(60), DeployOptions(steps=4), callback=lambda rec: steps.append(rec) and False,
                 newton_callback=stop_in_step_3)
    assert not res.converged and res.message.startswith("stopped by request at") and calls[0] > 0
    assert len(res.steps) == 2
    assert np.abs(L.joint_positions() - whole.joint_positions()).max() < 1e-12 * span_of(whole.joint_positions())

    class Stop(Exception):
        pass

    def raise_in_step_3(it, report):
        if len(steps) == 2 and it >= 1:
            raise Stop()
        return False

    L2 = Linkage(warped_grid(4), FLAT_BEAM, subdivision=4)
    rest_length_solve(L2)
    steps.clear()
    with pytest.raises(Stop):
        deploy(L2, np.radians(60), DeployOptions(steps=4), callback=lambda rec: steps.append(rec) and False,
               newton_callback=raise_in_step_3)
    assert np.abs(L2.joint_positions() - whole.joint_positions()).max() < 1e-12 * span_of(whole.joint_positions())


def test_the_rest_length_solve_calls_back_after_each_iteration_and_stops():
    L = Linkage(warped_grid(4), FLAT_BEAM, subdivision=4)
    seen = []
    report = rest_length_solve(L, callback=lambda it, rep: seen.append(it) or True)
    assert seen == [0] and not report.converged and report.message == "stopped by callback"


def test_the_deployment_plot_keeps_both_axis_labels_on_its_canvas(monkeypatch):
    """The picture is cropped to its artists but never beyond the canvas: with units in the labels, the energy
    label lost its first letter beside six-digit ticks and the torque label half its width."""
    from xshells.viz import render

    figures = []
    monkeypatch.setattr(render, "_save", lambda fig, path: figures.append(fig))
    a = np.linspace(23, 93, 10)
    render.plot_deployment("unused.png", a, 9e5 * (a / 93) ** 2, 1e4 * (a / 93), "manta_ray.obj")
    render.plot_deployment("unused.png", a, 9e5 * (a / 93) ** 2, 1e4 * (a / 93), "manta_ray.obj", utilization=a / 93)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    for fig in figures:
        agg = FigureCanvasAgg(fig)
        fig.set_dpi(render.DPI)  # as _save draws it
        agg.draw()
        renderer = agg.get_renderer()
        canvas = fig.bbox
        for ax in fig.axes:
            label = ax.yaxis.label.get_window_extent(renderer)
            assert canvas.x0 <= label.x0 and label.x1 <= canvas.x1, (ax.get_ylabel(), label, canvas)


def test_folded_joints_lists_every_joint_at_or_past_0_or_180_degrees_and_folded_joint_names_the_worst():
    from xshells.deploy.simulate import folded_joint, folded_joints

    L = Linkage(rhombic_grid(3, 3, spacing=100.0, angle=np.radians(30)),
                Material.uniform("rectangle", [10, 7], E=20000, nu=0.3), subdivision=4)
    assert folded_joints(L).size == 0 and folded_joint(L) == ""
    x = L.get_vars().copy()
    a = L.angle_indices()
    x[a[1]], x[a[4]], x[a[6]] = np.pi, -0.01, np.radians(179.0)
    assert folded_joints(L, x).tolist() == [1, 4]
    assert folded_joints(L, x, margin=np.radians(1.5)).tolist() == [1, 4, 6]
    L.set_vars(x)
    assert "joint 4 " in folded_joint(L)  # -0.57° is further out than 180° exactly
