"""The command line: demo end to end, help, errors."""
import json

import numpy as np

from xshells.cli import main
from xshells.rod import demo as rod_demo


def test_demo_deploys_the_manta_ray(tmp_path):
    assert main(["demo", "--out", str(tmp_path), "--no-progress"]) == 0
    result = json.loads((tmp_path / "result.json").read_text())
    assert result["reached"]
    assert abs(result["deployed"]["average_angle_deg"] - 93.0) < 1e-6
    span = np.ptp(np.array(result["flat"]["joint_positions"]), axis=0).max()
    assert result["deployed"]["max_abs_z"] > 0.05 * span  # it left the plane
    assert result["deployed"]["min_hessian_eigenvalue"] > 0
    for name in ("flat.png", "deployed.png", "deployment.png", "deployment.csv", "flat.ply", "deployed.obj",
                 "flat_centerlines.obj", "deployed_centerlines.obj"):
        assert (tmp_path / name).stat().st_size > 100, name
    assert not list(tmp_path.glob("*.tmp*"))


def test_rod_elastica_demo(tmp_path):
    result = rod_demo.run(str(tmp_path))
    forty = [r for r in result["discrete"] if r["edges"] == 40][0]
    assert forty["force_error"] < 0.005
    assert (tmp_path / "elastica.png").stat().st_size > 1000


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "usage" in capsys.readouterr().out


def test_an_empty_out_folder_gets_one_line(capsys):
    from data_paths import EXAMPLES

    assert main(["deploy", str(EXAMPLES / "quad.obj"), "--out", "", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--out is empty" in err and "\n" not in err


def test_3dm_options_on_another_design_get_one_line(capsys, tmp_path):
    from data_paths import EXAMPLES

    # --layer on an .obj was ignored without a word
    assert main(["deploy", str(EXAMPLES / "quad.obj"), "--layer", "beams", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "--layer reads a .3dm design" in err and "\n" not in err


def test_an_option_of_the_wrong_type_gets_one_line(capsys):
    # argparse printed the whole usage block first
    import pytest

    with pytest.raises(SystemExit) as exit_:
        main(["deploy", "x.obj", "--steps", "2.5"])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and "--steps: invalid int value: '2.5'" in err and "\n" not in err
