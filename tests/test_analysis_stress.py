"""Beam stresses against closed forms: bending (both principal axes), stretching, Saint-Venant torsion."""
import numpy as np
import pytest

from xshells.analysis.stress import stresses_of
from xshells.errors import InputError
from xshells.rod.rods import rods_with_materials
from xshells.section import Material
from xshells.section.profiles import make_profile
from xshells.section.properties import analyse
from xshells.section.torsion import shear_stress_factor

N, LENGTH = 81, 400.0


def straight_rod(material):
    s = np.linspace(0, LENGTH, N)
    return rods_with_materials([np.c_[s, np.zeros(N), np.zeros(N)]], material)


def set_points(rods, pts, thetas=None):
    x = rods.get_vars().copy()
    x[: 3 * N] = pts.ravel()
    if thetas is not None:
        x[3 * N:] = thetas
    rods.set_vars(x)


def arc(R, plane):
    a = np.linspace(0, LENGTH, N) / R
    u, v = R * np.sin(a), R * (1 - np.cos(a))
    return np.c_[u, v, np.zeros(N)] if plane == "xy" else np.c_[u, np.zeros(N), v]


@pytest.mark.parametrize("plane", ["xy", "xz"])
def test_bending_stress_is_E_c_over_R_about_either_principal_axis(plane):
    m = Material.uniform("rectangle", [10, 4], E=1000.0, nu=0.3)
    rods = straight_rod(m)
    _, d1, d2 = rods.material_frames()
    normal = np.array([0, 1.0, 0]) if plane == "xy" else np.array([0, 0, 1.0])
    c = 5.0 if abs(normal @ d1[0]) > 0.5 else 2.0  # the half-width along the bending direction
    R = 800.0
    set_points(rods, arc(R, plane))
    st = stresses_of(rods, m)
    mid = slice(5, N - 5)
    # the chords of the arc shorten each edge by 1 − sinc: that axial strain is part of the state
    strain = np.abs(np.sinc((LENGTH / (N - 1)) / R / 2 / np.pi) - 1)
    assert st.normal[mid] == pytest.approx(1000.0 * (c / R + strain), rel=1e-3)
    assert st.normal[mid] == pytest.approx(1000.0 * c / R, rel=1e-2)


def test_stretching_stress_is_E_strain_and_adds_to_bending_on_the_tension_side():
    m = Material.uniform("rectangle", [6, 6], E=2000.0, nu=0.3)
    rods = straight_rod(m)
    s = np.linspace(0, LENGTH, N) * 1.001
    set_points(rods, np.c_[s, np.zeros(N), np.zeros(N)])
    assert stresses_of(rods, m).normal == pytest.approx(2.0, rel=1e-9)  # E ε = 2000 × 0.001


def test_torsion_shear_stress_is_G_twist_rate_k():
    m = Material.uniform("rectangle", [10, 10], E=1000.0, nu=0.25)
    rods = straight_rod(m)
    rate = 1e-3  # radians per length
    thetas = rate * np.linspace(0, LENGTH, N)[:-1] + 0.5 * rate * LENGTH / (N - 1)
    set_points(rods, np.c_[np.linspace(0, LENGTH, N), np.zeros(N), np.zeros(N)], thetas)
    st = stresses_of(rods, m)
    mid = slice(2, N - 2)
    assert st.shear[mid] == pytest.approx(m.G * rate * m.shear_stress_factor, rel=1e-6)
    assert st.normal[mid] == pytest.approx(0.0, abs=1e-9)
    assert st.von_mises[mid] == pytest.approx(np.sqrt(3) * st.shear[mid], rel=1e-12)


# Saint-Venant (Timoshenko & Goodier §109, Roark Table 10.1): τ_max = T / (α b t²), T = G J θ′
@pytest.mark.parametrize("b, t, alpha", [(10, 10, 0.208), (20, 10, 0.246), (100, 10, 0.312)])
def test_rectangle_shear_factor_against_saint_venant_tables(b, t, alpha):
    p = make_profile("rectangle", [b, t])
    s = analyse(p)
    k, converged = shear_stress_factor(p, s.centroid)
    assert converged
    assert k == pytest.approx(s.torsion_constant / (alpha * b * t * t), rel=0.01)


def test_circle_shear_factor_is_the_radius():
    p = make_profile("ellipse", [5, 5])
    k, converged = shear_stress_factor(p, analyse(p).centroid)
    assert converged and k == pytest.approx(5.0, rel=0.01)  # τ = T r / J


def test_a_bad_strength_is_one_line():
    m = Material.uniform("rectangle", [6, 6], E=2000.0, nu=0.3)
    with pytest.raises(InputError, match="positive stress"):
        stresses_of(straight_rod(m), m, strength=-3)
    st = stresses_of(straight_rod(m), m, strength=10.0)
    assert st.max_utilization == pytest.approx(0.0, abs=1e-12)
