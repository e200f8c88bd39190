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


def test_ctrl_c_while_the_subcommands_import_is_one_line(capsys, monkeypatch):
    # the signal handler was installed after the parser imported the subcommands: Ctrl-C in the
    # first second printed the traceback of whatever module was loading
    import pytest

    import xshells.cli as cli

    def interrupted_import(name):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli.importlib, "import_module", interrupted_import)
    try:
        rc = main(["deploy", "x.obj"])
    except KeyboardInterrupt:
        pytest.fail("the interrupt escaped main")
    assert rc == 130
    assert capsys.readouterr().err == "xshells deploy: interrupted\n"


def test_a_stop_during_an_import_lands_when_the_import_has_ended(tmp_path, monkeypatch):
    # raised inside the import, it left the module half-initialised in sys.modules (an interrupted
    # deploy then failed on "module 'matplotlib' has no attribute 'get_data_path'")
    import signal
    import sys
    import time

    import pytest

    from xshells.errors import STOP

    (tmp_path / "slow_module_19.py").write_text(
        "import signal, sys\nfrom xshells.errors import STOP\n"
        "STOP.request(sys._getframe(), signal.SIGINT)  # as the handler would, mid-import\nDONE = True\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(STOP, "requested", False)
    previous = signal.signal(signal.SIGINT, lambda signum, frame: STOP.request(frame, signum))
    try:
        with pytest.raises(KeyboardInterrupt):
            import slow_module_19  # noqa: F401

            time.sleep(5)  # the stop arrives here, once the import is over
        assert sys.modules["slow_module_19"].DONE
    finally:
        signal.signal(signal.SIGINT, previous)
        sys.modules.pop("slow_module_19", None)


def test_an_early_ctrl_c_exits_quietly(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    from data_paths import EXAMPLES, REPO

    for delay in (0.25, 0.4, 0.6):  # while the subcommand, NumPy and the solver import (Python itself is up)
        out = tmp_path / f"out{delay}"
        env = dict(os.environ, PYTHONPATH=str(REPO))
        proc = subprocess.Popen([sys.executable, "-m", "xshells.cli", "deploy", str(EXAMPLES / "quad.obj"), "--out",
                                 str(out), "--no-progress"], stderr=subprocess.PIPE, text=True, env=env)
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        err = proc.communicate(timeout=120)[1]
        assert "Traceback" not in err and not (out / "error.log").exists(), err
        # landed in the run (a loaded machine), it also says what was kept: "interrupted; the 1 finished step ..."
        assert (proc.returncode, err) == (0, "") or (
            proc.returncode == 130 and err.startswith("xshells deploy: interrupted") and err.count("\n") == 1), \
            (proc.returncode, err)


SPECIAL_FILES_SCRIPT = r"""
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))  # reading /dev/zero whole must fail, not fill the machine
from xshells.cli import main
d = sys.argv[1]
for args in (["deploy", d + "/pipe.obj"], ["deploy", d + "/pipe.json"], ["deploy", d + "/folder.msh"],
             ["deploy", d + "/zero.obj"], ["sweep", d + "/pipe.yaml"], ["inverse", d + "/pipe.obj"]):
    main([*args, "--out", d + "/out"])
"""


def test_a_named_pipe_a_folder_or_a_device_is_refused_before_it_is_opened(tmp_path):
    # a named pipe blocked the command for ever, /dev/zero was read until the memory ran out, and a
    # named pipe given as a .msh was "no such file"
    import os
    import subprocess
    import sys

    from data_paths import REPO

    os.mkfifo(tmp_path / "pipe.obj")
    os.mkfifo(tmp_path / "pipe.json")
    os.mkfifo(tmp_path / "pipe.yaml")
    (tmp_path / "folder.msh").mkdir()
    (tmp_path / "zero.obj").symlink_to("/dev/zero")
    p = subprocess.run([sys.executable, "-c", SPECIAL_FILES_SCRIPT, str(tmp_path)], capture_output=True, text=True,
                       timeout=60, env=dict(os.environ, PYTHONPATH=str(REPO)))
    d = str(tmp_path)
    assert p.stderr.splitlines() == [
        f"xshells deploy: error: {d}/pipe.obj: cannot read file (a named pipe, not a regular file)",
        f"xshells deploy: error: {d}/pipe.json: cannot read case file (a named pipe, not a regular file)",
        f"xshells deploy: error: {d}/folder.msh: a folder, not a design file (.obj, .msh or .3dm)",
        f"xshells deploy: error: {d}/zero.obj: cannot read file (a device, not a regular file)",
        f"xshells sweep: error: {d}/pipe.yaml: cannot read sweep file (a named pipe, not a regular file)",
        f"xshells inverse: error: {d}/pipe.obj: cannot read the target surface (a named pipe, not a regular file)",
    ]
