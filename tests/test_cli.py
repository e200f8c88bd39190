"""The command line: demo end to end, help, errors."""
import json

from xshells.cli import main


def test_demo_writes_its_outputs(tmp_path):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "elastica.json").read_text())
    assert (tmp_path / "elastica.png").stat().st_size > 1000
    forty = [r for r in result["discrete"] if r["edges"] == 40][0]
    assert forty["force_error"] < 0.005
    assert not list(tmp_path.glob("*.tmp*"))


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "usage" in capsys.readouterr().out
