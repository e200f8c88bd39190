"""Deployment: buckling out of plane, direction, compatible grids, torque, bad input."""
import json

import numpy as np
import pytest

from xshells.cli import main
from xshells.deploy import DeployOptions, deploy, rest_length_solve
from xshells.errors import InputError
from xshells.io.export import write_design_obj
from xshells.linkage.grids import rhombic_grid
from xshells.linkage.linkage import Linkage
from xshells.section import Material

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


def test_unreachable_angle_is_refused():
    L = Linkage(warped_grid(3), FLAT_BEAM, subdivision=4)
    with pytest.raises(InputError, match="out of reach"):
        deploy(L, np.radians(185))


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


def test_cli_contradictory_options(tmp_path, capsys):
    (tmp_path / "case.json").write_text(json.dumps({"file": "x.obj"}))
    assert main(["deploy", str(tmp_path / "case.json"), "--material", "rectangle:1,1"]) == 2
    err = capsys.readouterr().err
    assert "contradicts" in err and len(err.strip().splitlines()) == 1
