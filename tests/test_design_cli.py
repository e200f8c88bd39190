"""``xshells optimize``: outputs, resume, bad input."""
import json
import re

import numpy as np
import pytest

from xshells.cli import main
from xshells.io.export import write_design_obj

from test_deploy import warped_grid
from data_paths import EXAMPLES


@pytest.fixture(scope="module")
def small_case(tmp_path_factory):
    folder = tmp_path_factory.mktemp("case")
    write_design_obj(folder / "grid.obj", warped_grid(4))
    spec = {"file": "grid.obj", "material": {"type": "rectangle", "params": [4.0, 1.5], "E": 2000, "nu": 0.3},
            "angle_deg": 60, "steps": 6, "subdivision": 4}
    (folder / "case.json").write_text(json.dumps(spec))
    return folder / "case.json"


def test_optimize_writes_its_outputs_and_resumes(small_case, tmp_path):
    out = tmp_path / "out"
    args = ["optimize", str(small_case), "--out", str(out), "--max-iters", "2", "--no-progress"]
    assert main(args) == 0
    r = json.loads((out / "result.json").read_text())
    for key in ("J", "terms", "energy_flat", "energy_deployed", "initial", "constraints", "iterations", "time_s", "rest_lengths"):
        assert key in r
    assert set(r["initial"]) == {"J", "energy_flat", "energy_deployed"}
    assert r["J"] <= r["initial"]["J"] + 1e-12  # the best feasible iterate is kept
    p = np.loadtxt(out / "design_parameters.txt")
    assert np.allclose(p, r["rest_lengths"])
    for name in ("flat_before.png", "deployed_before.png", "flat.png", "deployed.png", "convergence.png", "deployed.obj", "flat.ply"):
        assert (out / name).stat().st_size > 0, name
    assert r["bfgs_history"] and len(r["history"]) >= 1
    # fabrication drawings carry the optimized rest lengths
    svg = (out / "flat_layout.svg").read_text()
    drawn = [float(v) for v in re.findall(r'data-rest-length="([0-9.eE+-]+)"', svg)]
    assert np.allclose(drawn, p, rtol=1e-4)
    assert (out / "flat_layout.dxf").read_text().count("REST_LENGTHS") > len(p)
    from fabrication_checks import check_cutlist  # and so does the cut list

    from xshells.io import read_design

    check_cutlist(out / "cutlist.csv", read_design(small_case.parent / "grid.obj").edges, p, tol=1e-3)
    assert "deployed_angle_deg" in (out / "joints.csv").read_text().splitlines()[0]
    assert (out / "deployed.3dm").stat().st_size > 0
    # resume from the written rest lengths, at another angle
    assert main(args + ["--resume", "--angle", "55", "--no-baseline"]) == 0
    r2 = json.loads((out / "result.json").read_text())
    assert r2["target_angle_deg"] == pytest.approx(55.0)


@pytest.mark.parametrize("argv,match", [
    (["--gamma", "1.5"], "gamma must lie in"), (["--beta", "-2"], "beta must be"),
    (["--target-surface", "missing.obj"], "missing.obj"), (["--resume"], "does not exist"),
    (["--min-angle", "170", "--no-baseline"], "is infeasible"),
    (["--material", "rectangle:1,1"], "--material contradicts the case file"),
    (["--max-iters", "0"], "--max-iters must be at least 1, got 0"),  # was "max_iterations must be ..."
])
def test_bad_input_is_one_line(small_case, tmp_path, capsys, argv, match):
    assert main(["optimize", str(small_case), "--out", str(tmp_path / "o"), "--no-progress", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and len(err.splitlines()) == 1, err


def test_a_design_file_is_optimized_with_its_options_and_the_case_is_kept(small_case, tmp_path):
    out = tmp_path / "out"
    args = ["optimize", str(small_case.parent / "grid.obj"), "--material", "rectangle:4,1.5", "--young", "2000",
            "--subdivision", "4", "--steps", "6", "--angle", "60", "--max-iters", "1", "--no-baseline",
            "--out", str(out), "--no-progress"]
    assert main(args) == 0
    case = json.loads((out / "case.json").read_text())
    assert case["material"] == {"type": "rectangle", "params": [4.0, 1.5], "E": 2000.0, "nu": 0.3}
    assert case["subdivision"] == 4 and case["steps"] == 6
    r = json.loads((out / "result.json").read_text())
    assert r["warnings"] == []
    # the same problem as the case file's
    assert main(["optimize", str(small_case), "--max-iters", "1", "--no-baseline", "--out", str(tmp_path / "ref"),
                 "--no-progress"]) == 0
    ref = json.loads((tmp_path / "ref" / "result.json").read_text())
    assert r["initial"]["J"] == pytest.approx(ref["initial"]["J"], rel=1e-9)


def test_a_flat_state_that_folds_a_joint_is_opened_just_enough(tmp_path, capsys, monkeypatch):
    # the manta ray's drawn layout folds joint 36 (3.6° drawn) in its flat equilibrium at 16.01°
    import xshells.design.run as design_run
    from data_paths import EXAMPLES

    argv = ["optimize", str(EXAMPLES / "manta_ray.obj"), "--subdivision", "4", "--angle", "90", "--max-iters", "1",
            "--no-baseline", "--out", str(tmp_path / "o"), "--no-progress"]
    monkeypatch.setattr(design_run, "OPEN_LIMIT", 0.0)  # nothing to try: refused, naming the joint
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "manta_ray.obj: the flat equilibrium" in err and "joint 36" in err and len(err.splitlines()) == 1, err
    monkeypatch.undo()
    assert main(argv) == 0
    r = json.loads((tmp_path / "o" / "result.json").read_text())
    assert r["flat_angle_deg"] > 16.01 and "joint 36" in r["flat_angle_note"]
    assert r["constraints"]["planarity"] <= 1e-12
    # opened until the smooth minimum angle leaves room for a positive bound (KS ≤ every angle):
    # opened only until nothing folded (KS −0.10°), the optimization could fold a joint
    assert r["constraints"]["min_angle_deg"] > 0


def test_the_written_case_deploys_the_optimized_design_and_the_report_describes_that_deployment(small_case, tmp_path):
    from xshells.deploy.case import load_case

    out = tmp_path / "out"
    assert main(["optimize", str(small_case), "--out", str(out), "--max-iters", "2", "--no-baseline", "--no-progress"]) == 0
    case = load_case(out / "case.json")  # what `xshells deploy OUT/case.json` reads
    assert case.rest_lengths_path == str(out / "design_parameters.txt")
    assert np.allclose(np.loadtxt(case.rest_lengths_path), json.loads((out / "result.json").read_text())["rest_lengths"])
    r = json.loads((out / "result.json").read_text())
    assert r["fresh_deployment"]["reached"] and set(r["state_distance"]) == {"flat", "deployed"}
    for state in (r, r["optimizer_state"]):  # the weighted terms sum to J; the raw ratios are kept beside them
        assert sum(state["terms"].values()) == pytest.approx(state["J"], rel=1e-12)
        g = r["weights"]["gamma"]
        assert state["terms"]["J_flat_energy_term"] == pytest.approx(g * state["ratios"]["flat_energy_over_E0"])
    dep = json.loads((out / "deploy" / "result.json").read_text())  # the fresh deployment, as reported
    assert r["energy_deployed"] == pytest.approx(dep["deployed"]["energy"], rel=1e-9)


def test_a_degenerate_or_far_target_surface(small_case, tmp_path, capsys):
    flat = tmp_path / "degen.obj"
    flat.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    assert main(["optimize", str(small_case), "--out", str(tmp_path / "o"), "--no-progress", "--target-surface", str(flat)]) == 2
    err = capsys.readouterr().err.strip()
    assert "degen.obj: the target surface has zero area" in err and len(err.splitlines()) == 1, err
    far = tmp_path / "far.obj"
    far.write_text("v 1000 0 0\nv 1010 0 0\nv 1000 10 0\nf 1 2 3\n")
    assert main(["optimize", str(small_case), "--out", str(tmp_path / "f"), "--no-progress", "--max-iters", "1",
                 "--no-baseline", "--target-surface", str(far)]) == 0
    r = json.loads((tmp_path / "f" / "result.json").read_text())
    assert any("far.obj: the initially deployed joints lie" in w for w in r["warnings"]), r["warnings"]


def test_an_angle_below_the_flat_state_is_refused_before_optimizing(tmp_path, capsys):
    """The re-check's case: the nonuniform linkage (flat at 10.84°) optimized for --angle 5 "deployed" by closing
    into inverted joints, J 4.58 -> 4527, and ended "complete" with exit 0."""
    case = {"file": str(EXAMPLES / "nonuniform_linkage.obj"), "subdivision": 5, "steps": 10, "angle_deg": 70.0,
            "material": {"type": "rectangle", "params": [0.04, 0.03], "E": 20000.0, "nu": 0.3}}
    (tmp_path / "case.json").write_text(json.dumps(case))
    args = ["optimize", str(tmp_path / "case.json"), "--angle", "5", "--max-iters", "2", "--no-baseline",
            "--out", str(tmp_path / "o"), "--no-progress"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "the target angle 5.00° is not above the flat state's average angle 10.8" in err and len(err.splitlines()) == 1, err


