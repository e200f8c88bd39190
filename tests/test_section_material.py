"""Material: frame convention, stiff axis, per-rod and per-edge expansion, and the CLI."""
import json

import numpy as np
import pytest

from xshells.cli import main
from xshells.errors import InputError
from xshells.section.material import Material, expand_materials
from xshells.section import profiles

E, NU = 20000.0, 0.3


@pytest.fixture(scope="module")
def ribbon():
    return Material.uniform("rectangle", [10, 7], E=E, nu=NU, density=2.0)


def test_rectangle_width_along_d1_by_default(ribbon):
    # B1 = E ∫x² dA with x along d1: the width w = 10 is along d1
    B1, B2 = ribbon.bending_stiffness
    assert B1 == pytest.approx(E * 10 ** 3 * 7 / 12)
    assert B2 == pytest.approx(E * 10 * 7 ** 3 / 12)
    assert ribbon.stretching_stiffness == pytest.approx(E * 70)
    assert ribbon.G == pytest.approx(E / 2.6)
    assert ribbon.twisting_stiffness == pytest.approx(ribbon.G * ribbon.torsion_constant)
    assert ribbon.mass_per_length == pytest.approx(140)


def test_stiff_axis_chooses_which_bending_stiffness_is_larger():
    tall = profiles.rectangle(3, 8)
    d1 = Material(tall, E, NU, stiff_axis="D1")
    d2 = Material(tall, E, NU, stiff_axis="D2")
    default = Material(tall, E, NU)
    assert d1.bending_stiffness[0] > d1.bending_stiffness[1]
    assert d2.bending_stiffness[1] > d2.bending_stiffness[0]
    assert default.bending_stiffness == pytest.approx(d2.bending_stiffness)
    assert d1.bending_stiffness == pytest.approx(d2.bending_stiffness[::-1])
    assert d1.twisting_stiffness == pytest.approx(d2.twisting_stiffness)


def test_outline_and_fibres_follow_the_frame():
    tall = profiles.rectangle(3, 8)
    d1 = Material(tall, E, NU, stiff_axis="D1")
    assert d1.extreme_fibre_distances == pytest.approx([4, 1.5])
    assert d1.fibre_extents == pytest.approx(np.array([[-4, 4], [-1.5, 1.5]]))
    assert np.ptp(d1.outline[0], axis=0) == pytest.approx([8, 3])


def test_non_principal_profile_is_rotated_to_principal_axes():
    L = Material.uniform("L", [20, 20, 2, 2], E=E, nu=NU)
    assert abs(L.bending_coupling) < 1e-9 * sum(L.bending_stiffness)
    moments, _ = L.section.principal_axes()
    assert sorted(L.bending_stiffness) == pytest.approx(sorted(E * moments))
    assert L.bending_stiffness[0] >= L.bending_stiffness[1]
    # centroid of an equal-leg L with legs a and thickness t
    a, t = 20, 2
    c = (a * t * a / 2 + (a - t) * t * t / 2) / (a * t + (a - t) * t)
    assert L.section.centroid == pytest.approx([c, c])


def test_angle_orientation_gives_coupling():
    rect = profiles.rectangle(4, 1)
    tilted = Material(rect, E, NU, stiff_axis=np.pi / 6)
    B1, B2 = tilted.bending_stiffness
    assert B1 + B2 == pytest.approx(E * (4 ** 3 + 4) / 12)
    assert tilted.bending_coupling != pytest.approx(0)


def test_paper_inertia_tensor_and_principal_axes(ribbon):
    inertia = np.array(ribbon.summary()["inertia"])
    assert inertia == pytest.approx(np.diag([10 * 7 ** 3 / 12, 10 ** 3 * 7 / 12]))


def test_expand_uniform_per_rod_and_per_edge(ribbon):
    other = Material.uniform("ellipse", [2, 1], E=E, nu=NU)
    uniform = expand_materials(ribbon, [3, 2])
    assert set(uniform) == {"ks", "B1", "B2", "kt", "area", "density"}
    assert uniform["B1"].shape == (5,) and np.all(uniform["B1"] == ribbon.bending_stiffness[0])
    per_rod = expand_materials([ribbon, other], [3, 2])
    assert per_rod["area"] == pytest.approx([70, 70, 70, 2 * np.pi, 2 * np.pi])
    per_edge = expand_materials([other, ribbon, other], 3)
    assert per_edge["kt"] == pytest.approx([other.twisting_stiffness, ribbon.twisting_stiffness,
                                            other.twisting_stiffness])
    with pytest.raises(InputError, match="one per rod or one per edge"):
        expand_materials([ribbon, other, ribbon], [3, 2])


def test_stiff_axis_rejects_nonsense():
    with pytest.raises(InputError, match="stiff_axis"):
        Material.uniform("rectangle", [1, 2], E=E, nu=NU, stiff_axis="D3")


# ---- CLI -----------------------------------------------------------------------

CLI_KEYS = {"area", "centroid", "inertia", "principal_axes", "stretching_stiffness", "bending_stiffness",
            "torsion_constant", "twisting_stiffness", "E", "nu", "G"}


def test_cli_with_type_and_params(capsys):
    assert main(["section", "rectangle", "10", "7", "--young", str(E), "--poisson", str(NU)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert CLI_KEYS <= set(data)
    assert data["bending_stiffness"] == pytest.approx([E * 10 ** 3 * 7 / 12, E * 10 * 7 ** 3 / 12])
    assert data["G"] == pytest.approx(E / 2.6)


def test_cli_with_json_file_and_plot(tmp_path, capsys):
    spec = tmp_path / "L.json"
    spec.write_text(json.dumps({"type": "L", "young": E, "poisson": NU, "params": [20, 20, 2, 2]}))
    picture = tmp_path / "psi.png"
    output = tmp_path / "out.json"
    assert main(["section", str(spec), "--plot", str(picture), "-o", str(output)]) == 0
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    data = json.loads(output.read_text())
    assert data["area"] == pytest.approx(76)
    assert data["twisting_stiffness"] == pytest.approx(data["G"] * data["torsion_constant"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["L.json", "out.json", "psi.png"]


def test_cli_output_onto_a_device_or_folder_is_refused_and_a_link_written_through(tmp_path, capsys):
    import os

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)  # as /dev/null or /dev/full: the rename replaced the device node with a file
    base = ["section", "rectangle", "10", "7", "--young", "1", "--poisson", "0.3", "-o"]
    for out, words in ((fifo, "not a regular file"), (tmp_path, "a folder"), ("/proc/x.json", "cannot write there")):
        assert main(base + [str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert words in err and "\n" not in err
    (tmp_path / "t.json").write_text("{}")
    os.symlink(tmp_path / "t.json", tmp_path / "link.json")
    assert main(base + [str(tmp_path / "link.json")]) == 0
    assert os.path.islink(tmp_path / "link.json") and "area" in json.loads((tmp_path / "t.json").read_text())


@pytest.mark.parametrize("option, name", [("--plot", "x.png"), ("-o", "x.json")])
def test_cli_unwritable_output_is_refused_before_the_computation(tmp_path, capsys, monkeypatch, option, name):
    # --plot /nonexist/x.png printed the whole JSON, then exited 2
    import xshells.section.cli as section_cli

    monkeypatch.setattr(section_cli, "material_from_args", lambda args: pytest.fail("computed first"))
    out = tmp_path / "missing" / name
    assert main(["section", "rectangle", "10", "7", "--young", "1", "--poisson", "0.3", option, str(out)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.strip() == f"xshells section: error: {option} {out}: folder {out.parent} does not exist"
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("argv, fragment", [
    (["section", "hexagon", "1", "2", "--young", "1", "--poisson", "0.3"], "unknown cross-section type"),
    (["section", "rectangle", "1", "-2", "--young", "1", "--poisson", "0.3"], "must be positive"),
    (["section", "rectangle", "1", "2", "--young", "1", "--poisson", "0.6"], "Poisson"),
    (["section", "rectangle", "1", "2"], "--young"),
])
def test_cli_bad_input_is_one_line(argv, fragment, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert fragment in err and "\n" not in err and err.startswith("xshells section: error:")


@pytest.mark.parametrize("kind, params", [("ellipse", ["2", "1"]), ("rectangle", ["3", "1"]), ("L", ["2", "2", "0.4", "0.4"])])
def test_cli_plot_every_mesh_kind(tmp_path, kind, params):
    """Curved (ellipse) and straight-sided meshes both plot."""
    picture = tmp_path / "psi.png"
    assert main(["section", kind, *params, "--young", "1000", "--poisson", "0.3", "--plot", str(picture)]) == 0
    assert picture.stat().st_size > 1000
