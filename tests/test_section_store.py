"""The cross-section disk cache (``xshells.section.store``): a second run reads the same numbers bit for bit,
solves nothing, and a cache that cannot be read or written never fails a command."""
import json
import subprocess
import sys

import pytest

from xshells.section import properties, store
from xshells.section import material as material_module
from xshells.section.material import Material


def _fresh(monkeypatch, folder):
    monkeypatch.setenv("XSHELLS_CACHE", str(folder))
    monkeypatch.setattr(properties, "_CACHE", {})
    monkeypatch.setattr(material_module, "_SHEAR_FACTORS", {})


def _no_solve(*args, **kwargs):
    raise AssertionError("solved although the cache holds the result")


def test_second_run_reads_the_same_numbers_and_solves_nothing(tmp_path, monkeypatch):
    _fresh(monkeypatch, tmp_path)
    first = Material.uniform("rectangle", [10, 7], E=20000, nu=0.3)
    J, k = first.torsion_constant, first.shear_stress_factor
    history = list(first.section.torsion.history)
    assert len(list((tmp_path / "sections").glob("*.json"))) == 2

    _fresh(monkeypatch, tmp_path)
    import xshells.section.torsion as torsion

    monkeypatch.setattr(torsion, "torsion_constant", _no_solve)
    monkeypatch.setattr(torsion, "shear_stress_factor", _no_solve)
    again = Material.uniform("rectangle", [10, 7], E=20000, nu=0.3)
    assert again.torsion_constant == J and again.shear_stress_factor == k  # bit for bit
    assert isinstance(again.section.torsion, properties.StoredTorsion)
    assert again.section.torsion.history == history and again.section.torsion.converged
    assert again.section.torsion.relative_change == first.section.torsion.relative_change


def test_the_solution_is_solved_again_on_first_use(tmp_path, monkeypatch):
    _fresh(monkeypatch, tmp_path)
    solved = Material.uniform("rectangle", [6, 4], E=1.0, nu=0.3).section.torsion
    _fresh(monkeypatch, tmp_path)
    stored = Material.uniform("rectangle", [6, 4], E=1.0, nu=0.3).section.torsion
    assert isinstance(stored, properties.StoredTorsion)
    assert stored.solution.n_dofs == solved.solution.n_dofs
    assert stored.solution.torsion_constant == solved.torsion_constant


def test_another_profile_or_tolerance_is_another_entry(tmp_path, monkeypatch):
    _fresh(monkeypatch, tmp_path)
    a = properties.analyse(Material.uniform("rectangle", [10, 7], E=1.0, nu=0.3).profile)
    b = properties.analyse(Material.uniform("rectangle", [10, 6], E=1.0, nu=0.3).profile)
    c = properties.analyse(a.profile, rtol=1e-4)
    assert len({a.torsion_constant, b.torsion_constant}) == 2
    assert len(list((tmp_path / "sections").glob("torsion-*.json"))) == 3
    assert c.torsion_constant >= a.torsion_constant  # coarser: J converges from above


@pytest.mark.parametrize("content", ["{not json", "[1, 2]", '{"torsion_constant": "x"}', '{"value": null}',
                                     '{"torsion_constant": NaN, "history": [[10, NaN]], "converged": true, "value": NaN}',
                                     '{"torsion_constant": -1.0, "history": [[10, -1.0]], "converged": true, "value": -1.0}',
                                     '{"torsion_constant": 2.0, "history": [], "converged": true}'])
def test_a_damaged_entry_is_solved_again_and_rewritten(tmp_path, monkeypatch, content):
    _fresh(monkeypatch, tmp_path)
    m = Material.uniform("rectangle", [10, 7], E=1.0, nu=0.3)
    J, k = m.torsion_constant, m.shear_stress_factor
    for path in (tmp_path / "sections").glob("*.json"):
        path.write_text(content)
    _fresh(monkeypatch, tmp_path)
    again = Material.uniform("rectangle", [10, 7], E=1.0, nu=0.3)
    assert again.torsion_constant == J and again.shear_stress_factor == k
    for path in (tmp_path / "sections").glob("*.json"):
        assert isinstance(json.loads(path.read_text()), dict)


def test_off_or_unwritable_costs_only_the_solve(tmp_path, monkeypatch):
    for value in ("off", "0", ""):
        _fresh(monkeypatch, value)
        assert store.cache_dir() is None
        Material.uniform("rectangle", [10, 7], E=1.0, nu=0.3)
    blocked = tmp_path / "a_file"
    blocked.write_text("not a folder")
    _fresh(monkeypatch, blocked)
    m = Material.uniform("rectangle", [10, 7], E=1.0, nu=0.3)
    assert m.torsion_constant > 0 and m.shear_stress_factor > 0
    assert blocked.read_text() == "not a folder"


def test_the_default_folder_follows_xdg(tmp_path, monkeypatch):
    monkeypatch.delenv("XSHELLS_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert store.cache_dir() == tmp_path / "xshells"


def test_a_cached_run_does_not_import_scikit_fem(tmp_path):
    code = ("import sys; from xshells.section.material import Material; "
            "m = Material.uniform('rectangle', [10, 7], E=1.0, nu=0.3); m.shear_stress_factor; "
            "print('skfem' in sys.modules)")
    env = {"XSHELLS_CACHE": str(tmp_path), "PATH": "/usr/bin:/bin"}
    runs = [subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout.strip()
            for _ in range(2)]
    assert runs == ["True", "False"]
