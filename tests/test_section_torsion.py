"""Torsion constant against closed forms (validation.md §5) and P2 convergence order."""
import numpy as np
import pytest
from skfem import MeshTri

from xshells.section import profiles
from xshells.section.properties import analyse
from xshells.section.torsion import solve_warping, torsion_constant


def rectangle_k(aspect: float, terms: int = 200) -> float:
    """Saint-Venant series k(b/t) for J = k b t³."""
    n = np.arange(1, 2 * terms, 2)
    return (1 - 192 / (np.pi ** 5 * aspect) * np.sum(np.tanh(n * np.pi * aspect / 2) / n ** 5)) / 3


@pytest.mark.parametrize("aspect, k", [(1, 0.140577), (1.5, 0.195761), (2, 0.228682), (3, 0.263317),
                                        (4, 0.280813), (5, 0.291317), (10, 0.312325)])
def test_series_reproduces_validation_table(aspect, k):
    assert rectangle_k(aspect) == pytest.approx(k, abs=1e-6)


@pytest.mark.parametrize("b, t", [(1, 1), (2, 1), (3, 1), (10, 1), (0.02, 0.002), (7, 10)])
def test_rectangle_torsion_constant(b, t):
    long, short = max(b, t), min(b, t)
    exact = rectangle_k(long / short) * long * short ** 3
    assert analyse(profiles.rectangle(b, t)).torsion_constant == pytest.approx(exact, rel=1e-4)


@pytest.mark.parametrize("a, b", [(2, 1), (1, 3), (0.02, 0.002), (5, 5)])
def test_ellipse_torsion_constant(a, b):
    exact = np.pi * a ** 3 * b ** 3 / (a ** 2 + b ** 2)
    assert analyse(profiles.ellipse(a, b)).torsion_constant == pytest.approx(exact, rel=1e-4)


def test_validation_value_for_ellipse_2_1():
    assert analyse(profiles.ellipse(2, 1)).torsion_constant == pytest.approx(5.0265, abs=1e-4)


def test_circle_torsion_constant_is_polar_moment():
    r = 0.7
    assert analyse(profiles.ellipse(r, r)).torsion_constant == pytest.approx(np.pi * r ** 4 / 2, rel=1e-5)


def test_torsion_is_independent_of_position_and_rotation():
    base = analyse(profiles.l_angle(3, 2, 0.4, 0.5))
    angle = 0.3
    R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    moved = profiles.polygon(base.profile.outer @ R.T + [10.0, -4.0])
    assert analyse(moved).torsion_constant == pytest.approx(base.torsion_constant, rel=2e-5)


def fitted_slope(x, y):
    return np.polyfit(np.log(x), np.log(y), 1)[0]


def test_p2_error_in_J_is_fourth_order_in_h():
    # structured meshes of a 2 x 1 rectangle, halving h each level
    exact = rectangle_k(2) * 2
    hs, errors = [], []
    for level in range(1, 5):
        mesh = MeshTri.init_tensor(np.linspace(-1, 1, 2 * 2 ** level + 1), np.linspace(-0.5, 0.5, 2 ** level + 1))
        J = solve_warping(mesh).torsion_constant
        assert J >= exact * (1 - 1e-12)  # Galerkin: J_h - J = |ψ - ψ_h|²_energy >= 0
        hs.append(1 / 2 ** level)
        errors.append(J - exact)
    # h⁴ up to a log factor from the r² log r terms at the right-angle corners
    slope = fitted_slope(hs, errors)
    assert 3.4 < slope < 4.2
    local = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.diff(local) > 0)  # the local order climbs towards 4


def test_curved_ellipse_converges_at_p2_rate():
    # isoparametric P2: error ~ N^-2 in the number of unknowns
    profile = profiles.ellipse(2, 1)
    exact = np.pi * 8 / 5
    result = torsion_constant(profile, np.zeros(2), rtol=0, max_levels=4)
    dofs, J = np.array(result.history).T
    errors = np.abs(J - exact) / exact
    keep = errors > 1e-10  # below this, round-off
    assert keep.sum() >= 3
    assert fitted_slope(dofs[keep], errors[keep]) < -1.7


def test_adaptive_refinement_keeps_p2_rate_at_reentrant_corner():
    # a uniform mesh would give only N^-2/3 at the 270° corner of an L
    section = analyse(profiles.l_angle(1, 1, 0.2, 0.2), rtol=1e-8)
    dofs, J = np.array(section.torsion.history).T
    errors = J[:-1] - J[-1]
    assert np.all(errors > 0)  # monotone from above
    tail = slice(len(errors) // 3, -1)  # skip the pre-asymptotic start and the reference level
    assert fitted_slope(dofs[:-1][tail], errors[tail]) < -1.6


@pytest.mark.parametrize("t", [0.1, 0.05, 0.025])
def test_thin_walled_L_and_I_agree_with_sum_b_t3_over_3(t):
    # thin-walled theory J ≈ Σ b t³/3 over centreline lengths b; its error is O(t/b)
    J_L = analyse(profiles.l_angle(1, 1, t, t)).torsion_constant
    assert abs(J_L / ((2 - t) * t ** 3 / 3) - 1) < 0.3 * t
    J_I = analyse(profiles.i_beam(0.5 - t / 2, t, 0.5 - t / 2, t, 1 - 2 * t, t)).torsion_constant
    thin_I = (2 * 1 * t ** 3 + (1 - t) * t ** 3) / 3
    assert abs(J_I / thin_I - 1) < 0.3 * t


def test_thin_walled_error_shrinks_linearly_with_thickness():
    relative = [analyse(profiles.l_angle(1, 1, t, t)).torsion_constant / ((2 - t) * t ** 3 / 3) - 1
                for t in (0.1, 0.05, 0.025)]
    ratios = np.array(relative[:-1]) / np.array(relative[1:])
    assert np.all((ratios > 1.8) & (ratios < 2.2))


def test_hollow_rectangle_matches_bredt_for_thin_walls():
    # closed thin-walled section: J ≈ 4 A_m² t / s (Bredt), error O(t/b)
    t = 0.05
    box = profiles.polygon([(0, 0), (1, 0), (1, 1), (0, 1)],
                           holes=[[(t, t), (1 - t, t), (1 - t, 1 - t), (t, 1 - t)]])
    section = analyse(box)
    bredt = 4 * (1 - t) ** 4 * t / (4 * (1 - t))
    assert section.area == pytest.approx(1 - (1 - 2 * t) ** 2)
    assert abs(section.torsion_constant / bredt - 1) < 0.6 * t
    # a closed tube is far stiffer in torsion than the same wall slit open
    assert section.torsion_constant > 50 * (4 * (1 - t)) * t ** 3 / 3


def test_annulus_torsion_constant_is_its_polar_moment():
    angles = 2 * np.pi * np.arange(200) / 200
    circle = np.column_stack((np.cos(angles), np.sin(angles)))
    section = analyse(profiles.polygon(circle, holes=[0.6 * circle]))
    assert section.torsion_constant == pytest.approx(section.polar_moment, rel=1e-5)
    assert section.torsion_constant == pytest.approx(np.pi * (1 - 0.6 ** 4) / 2, rel=1e-3)
