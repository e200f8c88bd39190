"""Named materials, strength and density: in case files, on the command line, in the deployment's report."""
import csv
import json

import numpy as np
import pytest

from data_paths import EXAMPLES
from xshells.analysis.materials import LIBRARY, named_material
from xshells.cli import main
from xshells.deploy.case import material_from_spec, material_strength
from xshells.errors import InputError


def test_the_library_has_the_four_materials_with_sources():
    for name in ("gfrp-e23", "softwood-c24", "aluminium-6063-t6", "birch-plywood"):
        m = LIBRARY[name]
        assert m.E > 0 and 0 < m.strength < m.E and 0 < m.density < 1e-8 and m.source
    assert named_material("Softwood-C24").strength == 24.0  # EN 338 C24: f_m,k = 24 MPa


def test_an_unknown_grade_suggests_the_closest():
    with pytest.raises(InputError, match="did you mean 'softwood-c24'"):
        named_material("softwood-c42")


def test_a_grade_fills_in_what_the_material_object_does_not_give():
    spec = {"type": "rectangle", "params": [15.7, 8.1], "grade": "softwood-c24"}
    m = material_from_spec(spec)
    assert m.E == 11000.0 and m.density == pytest.approx(4.2e-10)
    assert material_strength(spec) == 24.0
    assert material_strength({**spec, "strength": 18.0}) == 18.0
    assert material_from_spec({**spec, "E": 9000.0}).E == 9000.0


def test_deploy_reports_utilization_and_the_first_break(tmp_path):
    design = EXAMPLES / "nonuniform_linkage.obj"  # unit-sized: a section to match
    code = main(["deploy", str(design), "--material", "rectangle:0.05,0.035", "--angle", "70", "--steps", "8",
                 "--subdivision", "5", "--strength", "200", "--out", str(tmp_path), "--no-progress"])
    assert code == 0
    r = json.loads((tmp_path / "result.json").read_text())
    st = r["stress"]
    rows = list(csv.DictReader(open(tmp_path / "deployment.csv")))
    util = np.array([float(row["utilization_max"]) for row in rows])
    assert r["utilization_max"] == pytest.approx(util.max())
    ff = st["first_failure"]
    first = int(np.flatnonzero(util >= 1.0)[0])
    assert ff["angle_deg"] == pytest.approx(float(rows[first]["average_angle_deg"]))
    assert 0 <= ff["nearest_joint"] < r["joints"] and ff["beam"] >= 0
    assert len(st["deployed_beams"]) > 0


@pytest.mark.parametrize("args, words", [
    (["--strength", "-2"], "--strength must be a positive stress"),
    (["--density=-1e-9"], "--density must be a positive"),
    (["--density", "-1e-9"], "--density must be a positive"),  # argparse took -1e-9 for an option
    (["--density", "0"], "--density must be a positive"),  # "density must be positive and finite: edge 0 has 0.0"
    (["--grade", "oak"], "unknown material grade 'oak'"),
])
def test_bad_material_options_are_one_line(tmp_path, capsys, args, words):
    code = main(["deploy", str(EXAMPLES / "uniform_linkage.obj"), "--out", str(tmp_path), "--no-progress", *args])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err


def test_case_files_check_strength_density_and_grade(tmp_path, capsys):
    for material, words in (({"strength": -1}, "strength"), ({"density": -1.0}, "density"),
                            ({"density": 0}, "key 'material.density' = 0"), ({"grade": "teak"}, "teak")):
        case = tmp_path / "c.json"
        case.write_text(json.dumps({"file": str(EXAMPLES / "uniform_linkage.obj"), "material": material}))
        assert main(["deploy", str(case), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip()
        assert words in err and "\n" not in err


def test_an_interrupt_inside_a_steps_stresses_keeps_the_steps_before(tmp_path, monkeypatch):
    # Ctrl-C while a step's stresses are computed: that step is dropped whole, the ones before keep their
    # utilization (the step was recorded before its stresses: KeyError 'utilization_max', rc 3, no result.json)
    import xshells.deploy.run as R

    real, calls = R._stress_row, []

    def interrupted(*a, **k):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(R, "_stress_row", interrupted)
    code = main(["deploy", str(EXAMPLES / "nonuniform_linkage.obj"), "--material", "rectangle:0.05,0.035", "--angle", "60",
                 "--steps", "6", "--subdivision", "5", "--strength", "200", "--out", str(tmp_path), "--no-progress"])
    assert code == 130
    r = json.loads((tmp_path / "result.json").read_text())
    assert r["status"] == "interrupted" and len(r["steps"]) == 2
    assert all(s["utilization_max"] > 0 for s in r["steps"])
