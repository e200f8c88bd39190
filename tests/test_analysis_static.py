"""Supports, loads and stability against closed forms, on a plus-shaped linkage: four cantilever arms
clamped at the joint (arm length L = 500, rectangle 10 × 7, E = 20000)."""
import copy

import numpy as np
import pytest

from xshells.analysis.static import (Load, StaticOptions, Support, critical_load_factor, free_rigid_modes, held_variables,
                                     load_vector, reactions, smallest_eigenvalue, solve_loaded)
from xshells.analysis.stress import rod_stresses
from xshells.errors import InputError
from xshells.io.design import design_from_arrays
from xshells.linkage.linkage import Linkage
from xshells.section import Material

ARM = 500.0
MAT = Material.uniform("rectangle", [10, 7], E=20000.0, nu=0.3, density=1.9e-9)
B1, B2 = MAT.bending_stiffness  # B2: bending out of the layout plane (about m1), B1: in plane


def plus(k):
    V = np.array([[0, 0, 0], [ARM, 0, 0], [-ARM, 0, 0], [0, ARM, 0], [0, -ARM, 0.0]])
    E = np.array([[0, 1], [2, 0], [0, 3], [4, 0]])
    L = Linkage(design_from_arrays(V, E), MAT, subdivision=k)
    sup = [Support(0, "clamped")]
    return L, sup, held_variables(L, sup, "locked")


def tip(L, f, held, factor=1.0):
    st = solve_loaded(L, f, held, factor)
    assert st.converged, st.message
    return st.displacement[1]


@pytest.mark.parametrize("axis, B", [(2, B2), (1, B1)])
def test_cantilever_tip_load_converges_to_PL3_over_3EI(axis, B):
    P = 0.05
    errs = []
    for k in (10, 20):
        L, sup, held = plus(k)
        F = np.zeros(3)
        F[axis] = -P
        f, _ = load_vector(L, [Load("point", vertex=1, vector=tuple(F))])
        errs.append(abs(tip(L, f, held)[axis] / (-P * ARM**3 / (3 * B)) - 1))
    assert errs[1] < 0.01 and errs[1] < errs[0]


def test_cantilever_self_weight_converges_to_wL4_over_8EI():
    w = MAT.area * MAT.density * 9810.0
    errs = []
    for k in (10, 20):
        L, sup, held = plus(k)
        f, total = load_vector(L, [Load("self-weight")])
        assert total[2] == pytest.approx(-w * 4 * ARM, rel=1e-6)  # four arms' weight
        errs.append(abs(tip(L, f, held)[2] / (-w * ARM**4 / (8 * B2)) - 1))
    assert errs[1] < 0.01 and errs[1] < errs[0]


# Bisshopp & Drucker (1945), tip-loaded cantilever: α = P L² / EI → (v/L, u/L)
@pytest.mark.parametrize("alpha, v_ref, u_ref", [(1, 0.30172, 0.05643), (5, 0.71379, 0.38763)])
def test_cantilever_large_deflection_against_the_elastica_table(alpha, v_ref, u_ref):
    L, sup, held = plus(20)
    P = alpha * B2 / ARM**2
    f, _ = load_vector(L, [Load("point", vertex=1, vector=(0, 0, -P))])
    st = solve_loaded(L, f, held, 1.0, StaticOptions(load_steps=20))
    d = st.displacement[1]
    assert -d[2] / ARM == pytest.approx(v_ref, rel=0.01)
    assert -d[0] / ARM == pytest.approx(u_ref, rel=0.02)


@pytest.mark.parametrize("axis, B, c", [(2, B2, 3.5), (1, B1, 5.0)])
def test_bending_stress_along_the_cantilever_is_M_c_over_I(axis, B, c):
    L, sup, held = plus(20)
    P = 1.0
    F = np.zeros(3)
    F[axis] = -P
    f, _ = load_vector(L, [Load("point", vertex=1, vector=tuple(F))])
    L0 = copy.deepcopy(L)
    solve_loaded(L, f, held)
    a, b = L.rods.vertex_offsets[0], L.rods.vertex_offsets[1]  # the arm from the joint to vertex 1
    s = L0.rods.points[a:b, 0]
    sigma = rod_stresses(L).normal[a:b]
    ref = P * (ARM - s) * c / (B / MAT.E)
    assert sigma[2:-2] == pytest.approx(ref[2:-2], rel=0.01)


def test_reactions_balance_the_load():
    L, sup, held = plus(10)
    f, total = load_vector(L, [Load("point", vertex=1, vector=(0.3, -0.5, -2.0)), Load("self-weight")])
    solve_loaded(L, f, held)
    _, R = reactions(L, sup, f, held)
    assert np.linalg.norm(R + total) <= 1e-8 * np.linalg.norm(total)


def test_clamped_free_ends_balance_the_load_in_force_and_moment():
    # A clamped free end holds its end vertex, the next rod vertex and the end edge's twist: its reaction
    # is theirs together (the end vertex's alone was 30x the load, and no moment was reported)
    for clamped, loaded in (((1, 2, 3, 4), (0,)), ((1, 3), (2, 4))):  # the second twists the arms it holds
        L, _, _ = plus(10)
        sup = [Support(v, "clamped") for v in clamped]
        held = held_variables(L, sup, "locked")
        F = np.array([0.2, -0.1, -1.0])
        f, total = load_vector(L, [Load("point", vertex=v, vector=tuple(F)) for v in loaded])
        assert solve_loaded(L, f, held).converged
        R, R_total = reactions(L, sup, f, held)
        assert np.linalg.norm(R_total + total) <= 1e-8 * np.linalg.norm(total)
        P = L.vertex_positions()
        moment = sum(np.cross(P[v], F) for v in loaded)
        moment = moment + sum(np.cross(P[r["vertex"]], r["force"]) + np.array(r["moment"]) for r in R)
        assert np.linalg.norm(moment) <= 1e-8 * np.linalg.norm(F) * ARM, (clamped, moment)


def test_a_load_step_that_fails_leaves_the_last_equilibrium(monkeypatch):
    # the third load step "fails" after moving the state: what is reported is the second step's equilibrium
    # (its displacement and load factor), not the failed iterate (3252 mm of displacement at factor 0 before)
    import xshells.solve as solve

    L, sup, held = plus(5)
    f, _ = load_vector(L, [Load("point", vertex=1, vector=(0, 0, -0.05))])
    ref = copy.deepcopy(L)
    solve_loaded(ref, f, held, 0.2)  # the equilibrium at two steps of ten
    real, calls = solve.minimize, []

    def failing(problem, **kw):
        calls.append(1)
        rep = real(problem, **kw)
        if len(calls) == 3:
            problem.set_vars(problem.get_vars() + 1.0)  # wherever a failed Newton run leaves it
            rep.converged, rep.message = False, "stopped after 200 iterations"
        return rep

    monkeypatch.setattr(solve, "minimize", failing)
    st = solve_loaded(L, f, held, 1.0)
    assert not st.converged and st.load_factor == pytest.approx(0.2) and "0.3" in st.message
    np.testing.assert_allclose(L.vertex_positions(), ref.vertex_positions(), atol=1e-9 * ARM)


def test_a_small_load_doubled_doubles_the_displacement():
    L, sup, held = plus(10)
    f, _ = load_vector(L, [Load("point", vertex=1, vector=(0, 0, -0.01))])
    d1 = tip(copy.deepcopy(L), f, held, 1.0)
    d2 = tip(copy.deepcopy(L), f, held, 2.0)
    assert d2[2] == pytest.approx(2 * d1[2], rel=0.01)


@pytest.fixture(scope="module")
def column():
    L, sup, held = plus(20)
    f, _ = load_vector(L, [Load("point", vertex=1, vector=(-10.0, 0, 0))])  # axial compression of one arm
    return L, held, f, critical_load_factor(L, f, held)


def test_the_critical_load_of_a_cantilever_column_is_eulers(column):
    _, _, _, cr = column
    euler = np.pi**2 * B2 / (4 * ARM**2)
    assert cr.factor * 10.0 == pytest.approx(euler, rel=0.01)
    assert cr.bracket[0] <= cr.factor <= cr.bracket[1]
    assert cr.kind == "bifurcation"  # the straight column goes on straight past it, as a saddle: no snap


def test_stable_below_the_critical_factor_and_not_above(column):
    L, held, f, cr = column
    M = copy.deepcopy(L)
    st = solve_loaded(M, f, held, 0.9 * cr.factor, escape=False)
    assert st.converged and smallest_eigenvalue(M, held) >= 0
    # past it the straight column is unstable: no equilibrium on its branch, or one with a negative eigenvalue
    M = copy.deepcopy(L)
    st = solve_loaded(M, f, held, 1.1 * cr.factor, escape=False)
    assert not st.converged or smallest_eigenvalue(M, held) < 0


def test_supports_that_leave_a_mechanism_are_counted():
    L, _, _ = plus(5)
    assert free_rigid_modes(L, []) == 6
    assert free_rigid_modes(L, [Support(1)]) == 3
    assert free_rigid_modes(L, [Support(1), Support(2)]) == 1  # rotation about the line through them
    assert free_rigid_modes(L, [Support(1), Support(2), Support(3)]) == 0
    assert free_rigid_modes(L, [Support(0, "clamped")]) == 0


def test_bad_supports_and_loads_are_one_line():
    L, _, _ = plus(5)
    with pytest.raises(InputError, match="vertex 9"):
        held_variables(L, [Support(9)])
    with pytest.raises(InputError, match="point load at vertex 7"):
        load_vector(L, [Load("point", vertex=7, vector=(0, 0, 1.0))])
    with pytest.raises(InputError, match="pinned or clamped"):
        Support(1, "welded")


@pytest.mark.parametrize("section_angle, c", [(0.0, 3.5), (np.pi / 2, 5.0)])
def test_simply_supported_beams_under_a_midspan_load_against_M_c_over_I(section_angle, c):
    """The plus pinned at its four ends, loaded at the joint: by symmetry each beam is simply supported over
    2L with P/2 at midspan (no torsion: both slopes vanish there), M(x) = P/4 (L − |x|). A quarter turn of
    the section (section_angle) makes the other principal axis bend."""
    V = np.array([[0, 0, 0], [ARM, 0, 0], [-ARM, 0, 0], [0, ARM, 0], [0, -ARM, 0.0]])
    E = np.array([[0, 1], [2, 0], [0, 3], [4, 0]])
    L = Linkage(design_from_arrays(V, E), MAT, subdivision=20, section_angle=section_angle)
    sup = [Support(v) for v in (1, 2, 3, 4)]
    held = held_variables(L, sup, "locked")
    P = 0.01  # small: pinned ends also stretch a deflected beam (membrane stress ∝ P², 1.3 % of the bending at P = 0.5)
    f, total = load_vector(L, [Load("point", vertex=0, vector=(0, 0, -P))])
    L0 = copy.deepcopy(L)
    solve_loaded(L, f, held)
    R, _ = reactions(L, sup, f, held)
    for r in R:
        assert r["force"][2] == pytest.approx(P / 4, rel=1e-6)
    sigma = rod_stresses(L).normal
    I = (B2 if section_angle == 0.0 else B1) / MAT.E
    for s in range(4):
        a, b = L.rods.vertex_offsets[s], L.rods.vertex_offsets[s + 1]
        x = np.linalg.norm(L0.rods.points[a:b, :2], axis=1)
        ref = P / 4 * (ARM - x) * c / I
        peak = P / 4 * ARM * c / I
        assert np.abs(sigma[a:b][1:-1] - ref[1:-1]).max() <= 0.01 * peak
    assert sigma.max() == pytest.approx(P / 4 * ARM * c / I, rel=0.05)  # the peak, sampled half an edge off


def test_a_clamped_joint_reports_the_cantilever_moment():
    L, sup, held = plus(10)
    P = 0.2
    f, _ = load_vector(L, [Load("point", vertex=1, vector=(0, 0, -P))])
    solve_loaded(L, f, held)
    R, _ = reactions(L, sup, f, held)
    M = np.array(R[0]["moment"])
    # the arm along +x carries P at x = L: the clamp holds it with a moment of magnitude P·L about y
    assert np.linalg.norm(M) == pytest.approx(P * ARM, rel=0.01)
    assert abs(M[1]) == pytest.approx(P * ARM, rel=0.01)
