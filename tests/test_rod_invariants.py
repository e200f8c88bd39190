"""Physical invariants of the rod energy (validation.md §7)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rod_helpers import random_rod, straight_rod


@pytest.mark.parametrize("variant", ["2008", "2010"])
def test_energy_unchanged_by_rigid_motion(variant):
    rod = random_rod(seed=11, variant=variant, curved_rest=True)
    parts = rod.energy_parts()
    R = Rotation.from_rotvec([0.4, -1.1, 0.7]).as_matrix()
    rod.points = rod.points @ R.T + np.array([3.0, -2.0, 5.0])
    rod.t_src = rod.t_src @ R.T
    rod.d1_src = rod.d1_src @ R.T
    moved = rod.energy_parts()
    for a, b in zip(parts.as_dict().values(), moved.as_dict().values()):
        assert abs(a - b) <= 1e-12 * max(abs(parts.total), 1.0)


def rigid_modes(rod):
    """Translations and infinitesimal rotations, (6, num_vars), at the source frame."""
    modes = []
    V = rod.num_vertices
    t = rod.t_src
    for k in range(3):
        m = np.zeros(rod.num_vars)
        m[k : 3 * V : 3] = 1.0
        modes.append(m)
    for k in range(3):
        w = np.eye(3)[k]
        m = np.zeros(rod.num_vars)
        m[: 3 * V] = np.cross(w, rod.points).ravel()
        m[3 * V :] = t @ w  # the material frame turns with the body about each tangent
        modes.append(m)
    return np.array(modes)


@pytest.mark.parametrize("variant", ["2008", "2010"])
def test_gradient_orthogonal_to_rigid_modes(variant):
    rod = random_rod(seed=12, variant=variant, curved_rest=True)
    g = rod.gradient()
    for m in rigid_modes(rod):
        assert abs(g @ m) <= 1e-10 * np.linalg.norm(g) * np.linalg.norm(m)


@pytest.mark.parametrize("variant", ["2008", "2010"])
def test_free_straight_rod_has_six_dimensional_null_space(variant):
    rod = straight_rod(8, EA=100.0, GJ=0.7, bending_energy=variant)
    rod = type(rod)([rod.points], stretching=100.0, bending=(1.0, 2.5), twisting=0.7, bending_energy=variant)
    H = rod.hessian().toarray()
    lam = np.linalg.eigvalsh(H)
    null = np.sum(np.abs(lam) <= 1e-9 * lam.max())
    assert null == 6
    assert lam.min() > -1e-9 * lam.max()
    for m in rigid_modes(rod):
        assert np.linalg.norm(H @ m) <= 1e-9 * lam.max() * np.linalg.norm(m)


def test_rest_shape_has_zero_energy_and_gradient():
    from xshells.rod import ElasticRod

    pts = np.array([[0, 0, 0], [1, 0.2, 0], [2, 0.1, 0.3], [3, -0.2, 0.5], [3.5, 0.4, 1.0]], float)
    th = np.array([0.1, -0.2, 0.3, 0.05])
    rod = ElasticRod(pts, stretching=10.0, bending=(1.0, 3.0), twisting=2.0, rest_shape=pts, rest_thetas=th, thetas=th)
    assert abs(rod.energy()) < 1e-24
    assert np.abs(rod.gradient()).max() < 1e-12
    rod.set_vars(rod.get_vars() + 1e-3)  # and any move away from it costs energy
    assert rod.energy() > 0


def test_symmetric_hessian_and_lower_triangle():
    rod = random_rod(seed=14)
    H = rod.hessian()
    L = rod.hessian(triangle="lower")
    assert abs(H - H.T).max() <= 1e-12 * abs(H).max()
    assert abs((L + L.T - np.diag(L.diagonal())) - H).max() <= 1e-12 * abs(H).max()


def test_mass_matrix_and_gravity():
    rod = straight_rod(4, length=2.0, density=3.0, area=0.5)
    M = rod.mass_matrix().diagonal()
    assert np.isclose(M[: 3 * rod.num_vertices].sum() / 3, 3.0 * 0.5 * 2.0)  # total mass ρAL
    f = rod.gravity_force((0, 0, -9.81))
    assert np.isclose(f[2::3][: rod.num_vertices].sum(), -9.81 * 3.0)
    assert (M > 0).all()


def test_stress_measures_shapes_and_signs():
    rod = random_rod(seed=15)
    s = rod.stress_measures(young=1e3, shear=4e2, fibre=(0.01, 0.02))
    for name in ("bending_energy_density", "twisting_energy_density", "stretching_energy_density",
                 "bending_stress", "twisting_stress", "stretching_stress"):
        assert s[name].shape == (rod.num_vertices,)
        assert (s[name] >= 0).all()
    assert s["bending_energy_density"][0] == 0.0  # an end vertex has no bending stencil
    assert s["bending_stress"][1:-1].min() > 0


def test_rods_from_section_materials():
    from xshells.rod import rods_with_materials
    from xshells.section import Material

    m = Material.uniform("rectangle", [10, 7], E=20000, nu=0.3)
    pts = np.c_[np.linspace(0, 100, 11), np.zeros(11), np.zeros(11)]
    rods = rods_with_materials([pts, pts + 50], m)
    assert np.allclose(rods.bending_stiffness[0], (20000 * 10**3 * 7 / 12, 20000 * 7**3 * 10 / 12))
    assert np.allclose(rods.ks, 20000 * 70)
    assert np.allclose(rods.polar_moment, (10**3 * 7 + 7**3 * 10) / 12)
