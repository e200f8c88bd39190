"""The planar branch (xshells.design.planar) and the planar-buckling penalty of the design objective."""
import copy

import numpy as np
import pytest

from xshells.design.objective import DesignProblem, DesignWeights
from xshells.design.planar import buckling_block, out_of_plane_indices, out_of_plane_modes, planar_equilibrium
from xshells.errors import InputError

from test_design_objective import PointFit, assert_gradient_converges, banana_states, perturbed_design


@pytest.fixture(scope="module")
def problem():
    """The coarse wiggly banana's design problem with the penalty on (its planar opening to 80° buckles)."""
    L, D = banana_states()
    fit = PointFit(D.joint_positions(), np.full(L.num_joints, 1.0 / L.num_joints))
    return DesignProblem(L, np.radians(80), DesignWeights(gamma=0.3, beta=100.0, buckling=1.0, buckling_target=-10.0),
                         fitting=fit, deployed=D)


def test_the_planar_state_stays_in_its_plane_and_is_an_equilibrium_of_the_whole_problem():
    L, _ = banana_states()
    eq = planar_equilibrium(L, np.radians(60), steps=6)
    P = eq.L
    assert abs(P.average_angle() - np.radians(60)) < 1e-9
    z = P.rods.points[:, 2]
    assert np.ptp(z) <= 1e-9 * np.ptp(P.rods.points, axis=0).max()
    # mirror symmetry: the gradient has no out-of-plane part, so the planar state is an equilibrium
    # of the unconstrained problem too (up to the angle's multiplier)
    g = P.gradient()
    oop = out_of_plane_indices(P)
    assert np.abs(g[oop]).max() <= 1e-8 * np.abs(g).max()


def test_a_tilted_layout_is_refused_with_one_line():
    L, _ = banana_states()
    L.apply_rigid_motion(np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), np.zeros(3))
    object.__setattr__(L.graph, "layout_normal", np.array([0.0, -1.0, 0.0]))  # as a layout drawn in the xz plane
    with pytest.raises(InputError, match="plane z = const"):
        out_of_plane_indices(L)


def test_the_wiggly_bananas_planar_opening_buckles_soon_after_it_starts():
    """Its flat state (1.8°) is stable; opened in the plane by 1° still, by 13° no longer."""
    L, _ = banana_states()
    a0 = np.degrees(L.average_angle())
    for angle, unstable in ((a0 + 1.0, False), (15.0, True), (80.0, True)):
        eq = planar_equilibrium(L, np.radians(angle), steps=6)
        B = buckling_block(eq)
        lam, vecs = out_of_plane_modes(eq, B, eq.L.mass_matrix()[B][:, B].tocsc())
        assert (lam[0] < 0) == unstable, (angle, lam)
        assert np.all(np.diff(lam) >= 0)


def test_planar_buckling_gradient_matches_finite_differences(problem):
    prob = problem
    q, v = perturbed_design(prob, 5)
    sigma, g = prob.planar_buckling(q)
    assert sigma < 0  # the banana's planar opening buckles: σ ≈ −1 relative to its start
    assert_gradient_converges(lambda x: prob.planar_buckling(x)[0], g, q, v)


def test_the_penalty_enters_J_and_its_gradient(problem):
    """Target −10, below σ (−1 to −5 here): the penalty is active, and J's gradient includes it (finite differences)."""
    prob = problem
    q, v = perturbed_design(prob, 6)
    t = prob.terms(q)
    assert t["planar_buckling"] > 0 and t["J"] > t["planar_buckling"]
    g = prob.gradient(q)
    h = 2.5e-5
    fd = (prob.objective(q + h * v) - prob.objective(q - h * v)) / (2 * h)
    assert abs(fd - g @ v) <= 2e-3 * abs(g @ v), (fd, g @ v)


def test_without_the_weight_nothing_changes():
    L, D = banana_states()
    fit = PointFit(D.joint_positions(), np.full(L.num_joints, 1.0 / L.num_joints))
    prob = DesignProblem(copy.deepcopy(L), np.radians(80), DesignWeights(gamma=0.3, beta=100.0), fitting=fit, deployed=copy.deepcopy(D))
    assert prob.planar is None and len(prob.equilibria) == 2
    assert set(prob.terms(prob._q)) == {"J", "flat_energy", "deployed_energy", "fit"}
    with pytest.raises(InputError, match="weights.buckling"):
        prob.planar_buckling(prob._q)
    with pytest.raises(InputError, match="buckling weight"):
        DesignWeights(buckling=-1.0)


def test_a_planar_opening_that_fails_gets_one_line(monkeypatch):
    import xshells.design.planar as planar

    def fail(*args, **kwargs):
        raise ArithmeticError("equilibrium at 80.00° did not converge (stalled)")

    monkeypatch.setattr(planar, "planar_equilibrium", fail)
    L, D = banana_states()
    fit = PointFit(D.joint_positions(), np.full(L.num_joints, 1.0 / L.num_joints))
    with pytest.raises(InputError, match="cannot follow this layout: its planar opening to 80.00° fails") as exc:
        DesignProblem(L, np.radians(80), DesignWeights(buckling=1.0), fitting=fit, deployed=D)
    assert "\n" not in str(exc.value)
