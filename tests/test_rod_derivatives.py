"""Finite-difference and second-method checks of the rod's derivatives."""
import numpy as np
import pytest

from xshells.rod import rods as rods_module
from rod_helpers import random_rod


def _set(rod, x, with_L=False):
    nv = rod.num_vars
    rod.set_vars(x[:nv])
    if with_L:
        rod.set_rest_lengths(x[nv:])
    return rod


def _energy_at(rod, x, with_L=False):
    return _set(rod, x, with_L).energy()


def _gradient_at(rod, x, with_L=False):
    return _set(rod, x, with_L).gradient(with_L)


def _state(rod, with_L):
    x = rod.get_vars()
    return np.concatenate([x, rod.rest_lengths]) if with_L else x


@pytest.mark.parametrize("variant", ["2008", "2010"])
@pytest.mark.parametrize("with_L", [False, True])
@pytest.mark.parametrize("curved", [False, True])
def test_gradient_matches_finite_differences_at_second_order(variant, with_L, curved):
    rod = random_rod(seed=1, variant=variant, curved_rest=curved)
    x = _state(rod, with_L)
    g = rod.gradient(with_L)
    d = np.random.default_rng(2).standard_normal(len(x))
    errors = []
    for h in (2e-5, 1e-5):
        fd = (_energy_at(rod, x + h * d, with_L) - _energy_at(rod, x - h * d, with_L)) / (2 * h)
        errors.append(abs(fd - g @ d))
    assert errors[1] < 1e-6 * abs(g @ d)
    assert 3.0 < errors[0] / errors[1] < 5.0  # central differences: second order


@pytest.mark.parametrize("variant", ["2008", "2010"])
@pytest.mark.parametrize("with_L", [False, True])
@pytest.mark.parametrize("curved", [False, True])
def test_hessian_matches_finite_differences_at_second_order(variant, with_L, curved):
    rod = random_rod(seed=3, variant=variant, curved_rest=curved)
    x = _state(rod, with_L)
    H = rod.hessian(with_L)
    assert abs(H - H.T).max() <= 1e-12 * abs(H).max()
    d = np.random.default_rng(4).standard_normal(len(x))
    Hd = H @ d
    errors = []
    for h in (2e-5, 1e-5):
        fd = (_gradient_at(rod, x + h * d, with_L) - _gradient_at(rod, x - h * d, with_L)) / (2 * h)
        errors.append(np.linalg.norm(fd - Hd))
    _gradient_at(rod, x, with_L)
    assert errors[1] < 1e-6 * np.linalg.norm(Hd)
    assert 3.0 < errors[0] / errors[1] < 5.0


@pytest.mark.parametrize("variant", ["2008", "2010"])
def test_analytic_and_automatic_derivatives_agree(variant, monkeypatch):
    rod = random_rod(seed=5, variant=variant, curved_rest=True)
    g_fast, H_fast = rod.gradient(True), rod.hessian(True)
    monkeypatch.setattr(rods_module, "_analytic", None)
    g_ad, H_ad = rod.gradient(True), rod.hessian(True)
    assert np.allclose(g_fast, g_ad, rtol=1e-10, atol=1e-10 * abs(g_ad).max())
    assert abs(H_fast - H_ad).max() <= 1e-9 * abs(H_ad).max()


def test_gradient_is_exact_away_from_the_source_frame():
    rod = random_rod(seed=6)
    rng = np.random.default_rng(7)
    x = rod.get_vars() + 0.02 * rng.standard_normal(rod.num_vars)  # away from the source frame
    rod.set_vars(x)
    g = rod.gradient()
    d = rng.standard_normal(len(x))
    h = 1e-6
    fd = (_energy_at(rod, x + h * d) - _energy_at(rod, x - h * d)) / (2 * h)
    assert abs(fd - g @ d) < 1e-6 * abs(g @ d)


def test_hessian_away_from_the_source_frame():
    rod = random_rod(seed=8)
    rng = np.random.default_rng(9)
    x = rod.get_vars() + 0.05 * rng.standard_normal(rod.num_vars)
    rod.set_vars(x)
    H = rod.hessian()
    d = rng.standard_normal(len(x))
    h = 1e-5
    fd = (_gradient_at(rod, x + h * d) - _gradient_at(rod, x - h * d)) / (2 * h)
    assert np.linalg.norm(fd - H @ d) < 1e-6 * np.linalg.norm(fd)
