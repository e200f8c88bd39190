"""Saving and reloading a linkage state reproduces it bit for bit."""
import numpy as np
import pytest

from xshells.errors import InputError
from xshells.io import read_design
from xshells.linkage.linkage import Linkage
from xshells.linkage.state import load_linkage, save_linkage
from xshells.section import Material

from data_paths import EXAMPLES


def test_round_trip_is_bit_exact(tmp_path):
    L = Linkage(read_design(EXAMPLES / "nonuniform_linkage.obj"), Material.uniform("rectangle", [0.1, 0.07], E=20000, nu=0.3), subdivision=4)
    rng = np.random.default_rng(0)
    L.set_vars(L.get_vars() + 1e-3 * rng.standard_normal(L.num_vars))
    L.update_source_frame()
    L.set_vars(L.get_vars() + 1e-3 * rng.standard_normal(L.num_vars))  # away from the source frame
    path = tmp_path / "state.npz"
    save_linkage(path, L)
    R = load_linkage(path)
    assert np.array_equal(R.get_vars(), L.get_vars())
    assert np.array_equal(R.rest_lengths, L.rest_lengths)
    assert R.energy() == L.energy()
    assert np.array_equal(R.gradient(True), L.gradient(True))
    assert not list(tmp_path.glob("*.tmp"))


def test_bad_state_file(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(InputError, match="not a saved linkage state"):
        load_linkage(bad)


def test_move_checkpoint_rolls_back_bit_for_bit():
    L = Linkage(read_design(EXAMPLES / "nonuniform_linkage.obj"), Material.uniform("rectangle", [0.1, 0.07], E=20000, nu=0.3), subdivision=4)
    rng = np.random.default_rng(1)
    L.set_vars(L.get_vars() + 1e-3 * rng.standard_normal(L.num_vars))
    x, p, E, g = L.get_vars(), L.rest_lengths, L.energy(), L.gradient(True)
    cp = L.move_checkpoint()
    L.set_vars(x + 1e-2 * rng.standard_normal(L.num_vars))
    L.set_rest_lengths(1.1 * p)
    assert L.energy() != E
    L.move_rollback(cp)
    assert np.array_equal(L.get_vars(), x) and np.array_equal(L.rest_lengths, p)
    assert L.energy() == E and np.array_equal(L.gradient(True), g)
    assert np.array_equal(L.rods.points.ravel(), L.rod_vars()[: L.rods.points.size])
