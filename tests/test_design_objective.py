"""Design objective (eq. 5) and flat-state constraints: adjoint gradients and Hessian-vector products."""
import copy

import numpy as np
import pytest

from xshells.deploy import DeployOptions, deploy
from xshells.design.objective import DesignProblem, DesignWeights, ks_min
from xshells.errors import InputError
from xshells.io import read_design, read_rest_lengths
from xshells.linkage.linkage import Linkage
from xshells.section import Material
from xshells.solve import NewtonOptions, minimize

from data_paths import EXAMPLES

PLUS = Material.uniform("+", [5.0, 5.0, 0.2, 0.2], E=20000, nu=0.3, stiff_axis="D1")


class PointFit:
    """Point-to-point fitting only (the surface term has its own tests)."""

    def __init__(self, targets, weights):
        self.targets, self.weights = targets, weights

    def value(self, P):
        return 0.5 * np.sum(self.weights[:, None] * (P - self.targets) ** 2)

    def gradient(self, P):
        return self.weights[:, None] * (P - self.targets)

    def hessian_vector(self, P, dP):
        return self.weights[:, None] * dP


def banana_states(k: int = 4):
    """The wiggly banana before optimization (a real design), coarse: its flat state and a copy deployed to 80°."""
    folder = EXAMPLES / "wiggly_banana_preopt"
    d = read_design(folder / "flat_opt.msh")
    L = Linkage(d, PLUS, subdivision=k, rest_lengths=read_rest_lengths(folder / "design_parameters.txt", d.num_segments))
    minimize(L, fixed=L.rigid_pin_indices(), options=NewtonOptions(gradient_tolerance=1e-9, max_iterations=100))
    D = copy.deepcopy(L)
    assert deploy(D, np.radians(80), DeployOptions(steps=10)).converged
    return L, D


@pytest.fixture(scope="module")
def banana():
    """The banana's design problem with noisy point targets (k = 4)."""
    L, D = banana_states()
    rng = np.random.default_rng(0)
    span = np.linalg.norm(np.ptp(D.joint_positions(), axis=0))
    fit = PointFit(D.joint_positions() + 0.01 * span * rng.standard_normal((L.num_joints, 3)), np.full(L.num_joints, 1.0 / L.num_joints))
    return DesignProblem(L, np.radians(80), DesignWeights(gamma=0.3, beta=100.0), fitting=fit, deployed=D)


def _fd(f, g, hp, q, v, steps):
    g0, H0 = g(q) @ v, hp(q, v)
    ge, he = [], []
    for h in steps:
        ge.append(abs((f(q + h * v) - f(q - h * v)) / (2 * h) - g0) / abs(g0))
        he.append(np.linalg.norm((g(q + h * v) - g(q - h * v)) / (2 * h) - H0) / np.linalg.norm(H0))
    return ge, he


@pytest.fixture(scope="module")
def buckled_grid():
    """A small incompatible grid whose flat state leaves the plane once its rest lengths change."""
    from xshells.deploy import rest_length_solve
    from test_deploy import FLAT_BEAM, warped_grid

    L = Linkage(warped_grid(4), FLAT_BEAM, subdivision=4)
    rest_length_solve(L)
    D = copy.deepcopy(L)
    assert deploy(D, np.radians(60), DeployOptions(steps=6)).converged
    fit = PointFit(D.joint_positions(), np.full(L.num_joints, 1.0 / L.num_joints))
    return DesignProblem(L, np.radians(60), DesignWeights(gamma=0.3, beta=100.0), fitting=fit, deployed=D)


def test_planarity_derivatives_match_finite_differences(buckled_grid):
    prob = buckled_grid
    rng = np.random.default_rng(0)
    q = 1 + 0.01 * rng.standard_normal(len(prob.p0))
    v = rng.standard_normal(len(q))
    assert prob.planarity(q) > 1e-4  # the flat state has left the plane: c and its derivatives are not trivially 0
    ge, he = _fd(prob.planarity, prob.planarity_gradient, prob.planarity_hessp, q, v, (2.5e-4, 1.25e-4, 6.25e-5))
    assert ge[-1] < 2e-3 and he[-1] < 5e-3, (ge, he)
    assert ge[0] / ge[1] > 3 and he[0] / he[1] > 3, (ge, he)


def test_planar_flat_state_has_zero_planarity(banana):
    assert banana.planarity(banana._q) < 1e-20
    assert np.abs(banana.planarity_gradient(banana._q)).max() < 1e-8


@pytest.mark.parametrize("which", ["J", "min_angle"])
def test_adjoint_derivatives_match_finite_differences(banana, which):
    prob = banana
    f, g, hp = {"J": (prob.objective, prob.gradient, prob.hessp),
                "planarity": (prob.planarity, prob.planarity_gradient, prob.planarity_hessp),
                "min_angle": (prob.min_angle, prob.min_angle_gradient, prob.min_angle_hessp)}[which]
    rng = np.random.default_rng(1)
    # away from the initial design, but not so far that the nearly closed flat state inverts
    q = 1 + 1e-3 * rng.standard_normal(len(prob.p0))
    v = rng.standard_normal(len(q))
    ge, he = _fd(f, g, hp, q, v, (1e-4, 5e-5, 2.5e-5))
    assert ge[-1] < 1e-3 and he[-1] < 3e-3, (ge, he)
    # second-order convergence onto our derivatives
    assert ge[0] / ge[1] > 3 and he[0] / he[1] > 3, (ge, he)
    assert ge[1] / ge[2] > 3 and he[1] / he[2] > 3, (ge, he)


def test_hessian_vector_product_is_symmetric(banana):
    prob = banana
    rng = np.random.default_rng(2)
    q = 1 + 1e-3 * rng.standard_normal(len(prob.p0))
    u, v = rng.standard_normal(len(q)), rng.standard_normal(len(q))
    assert u @ prob.hessp(q, v) == pytest.approx(v @ prob.hessp(q, u), rel=1e-5)


def test_product_at_a_deployed_equilibrium(banana):
    """The matrix-free ``dH·w`` against the differenced matrix on the vectors the objective uses
    (a state sensitivity and an adjoint), at the deployed equilibrium (80°, stressed)."""
    from xshells.linkage.derivatives import hessian_derivative

    prob = banana
    rng = np.random.default_rng(5)
    q = 1 + 1e-3 * rng.standard_normal(len(prob.p0))
    prob.set_q(q)
    eq = prob.deployed
    dp = rng.standard_normal(len(q)) * prob.p0
    dx = eq.state_derivative(dp)
    w = np.concatenate([prob._adjoint("fit", eq, prob._fit_term()), np.zeros(len(dp))])
    ref = hessian_derivative(eq.L, dx, dp, with_rest_lengths=True) @ w
    got = eq.hessian_derivative_product(dx, dp, w)
    err = np.linalg.norm(got - ref) / np.linalg.norm(ref)
    assert err < 2e-6, err


def perturbed_design(prob, seed):
    """A design 0.1 % off the problem's start, and a direction (both (S,)), for finite-difference checks."""
    rng = np.random.default_rng(seed)
    q = 1 + 1e-3 * rng.standard_normal(len(prob.p0))
    return q, rng.standard_normal(len(q))


def test_flat_stability_gradient_matches_finite_differences(banana):
    prob = banana
    q, v = perturbed_design(prob, 4)
    sigma, g = prob.flat_stability(q)
    assert sigma > 0  # the planar flat state is stable
    lam, grads = prob.flat_stability_modes(q)
    assert np.all(np.diff(lam) >= 0) and np.allclose(grads.shape, (4, len(q)))
    assert_gradient_converges(lambda x: prob.flat_stability(x)[0], g, q, v)


def assert_gradient_converges(f, g, q, v, steps=(1e-4, 5e-5, 2.5e-5)):
    """Central differences of the scalar ``f`` along ``v`` approach ``g @ v``: within 2e-3 at the last step,
    and at second order (the error falls more than 3-fold as the step halves)."""
    errs = [abs((f(q + h * v) - f(q - h * v)) / (2 * h) - g @ v) / abs(g @ v) for h in steps]
    assert errs[-1] < 2e-3, errs
    assert errs[0] / errs[1] > 3, errs


def test_dense_hessian_is_the_exact_energy_hessian(banana):
    """With β = 0 the dense model is exact: it must match the Hessian-vector products."""
    prob = banana
    q = prob._q.copy()
    w = prob.w
    try:
        prob.w = DesignWeights(gamma=w.gamma, beta=0.0)
        prob._cache = {}
        H = prob.dense_hessian(q)
        rng = np.random.default_rng(5)
        for _ in range(2):
            v = rng.standard_normal(len(q))
            hv = prob.hessp(q, v)
            assert np.linalg.norm(H @ v - hv) / np.linalg.norm(hv) < 1e-6
        assert np.allclose(H, H.T)
    finally:
        prob.w = w
        prob._cache = {}
    # with the fitting term the model leaves out only the adjoint's third-derivative term
    H = prob.dense_hessian(q)
    v = np.random.default_rng(6).standard_normal(len(q))
    hv = prob.hessp(q, v)
    assert np.linalg.norm(H @ v - hv) / np.linalg.norm(hv) < 0.2


def test_multi_column_kkt_solve_matches_single(banana):
    eq = banana.deployed
    R = np.random.default_rng(7).standard_normal((eq.nx, 3))
    W = eq.kkt_solve_many(R)
    for j in range(3):
        assert np.allclose(W[:, j], eq.kkt_solve(R[:, j]), rtol=1e-12, atol=1e-14 * np.abs(W).max())


def test_energy_terms_are_normalized_at_the_start(banana):
    t = banana.terms(banana._q)
    assert t["J"] == pytest.approx(0.3 * t["flat_energy"] + 0.7 * t["deployed_energy"] + 50.0 * t["fit"])


def test_ks_minimum_is_overflow_safe_and_conservative():
    a = np.array([1000.0, 1000.5, 1001.0])
    v, w, curv = ks_min(a, 0.01)
    assert np.isfinite(v) and v <= a.min() and v > a.min() - 0.01 * np.log(3) - 1e-12
    assert w.sum() == pytest.approx(1.0)
    h = 1e-6
    d = np.array([0.3, -0.2, 0.5])
    fd = (ks_min(a + h * d, 0.01)[1] - ks_min(a - h * d, 0.01)[1]) / (2 * h)
    assert np.allclose(curv(d), fd, atol=1e-6)


@pytest.mark.parametrize("kw,match", [(dict(gamma=1.5), "gamma"), (dict(gamma=-0.1), "gamma"), (dict(beta=-1), "beta")])
def test_bad_weights(kw, match):
    with pytest.raises(InputError, match=match):
        DesignWeights(**kw)



def test_a_predicted_start_that_goes_non_finite_falls_back_quietly(banana, monkeypatch):
    """A long prediction can turn a joint half a turn from its source frame, where the frame transport
    divides by zero (seen in ``xshells inverse`` on the manta ray). The solve stops on the non-finite
    state, the design is re-solved from where it was, and NumPy's warnings on the way do not reach the
    user. The solve is stood in for here: its first call divides by zero in NumPy and fails as the real
    one does; the second is the real re-solve."""
    import warnings

    from xshells.errors import InvalidState

    eq = banana.equilibria[-1]
    real, calls = eq.solve, []

    def solve(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            np.array([1.0]) / np.array([0.0])  # what the transport's 1 / (1 + ts·te) does at a half turn
            raise InvalidState("state: the material angle of edge 3 of rod 100 is not finite: nan")
        return real(*args, **kwargs)

    monkeypatch.setattr(eq, "solve", solve)
    q = banana._q.copy()
    q[0] *= 1.0 + 1e-4
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        banana.objective(q)
    assert len(calls) == 2  # the predicted start, then the re-solve from the last state
    assert not [w for w in seen if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in seen]
    assert np.isfinite(eq.L.get_vars()).all()


def _banana_problem_held_at(offset_deg: float = 0.0):
    """The banana's design problem with its flat state held ``offset_deg`` more open than it settles (0: where it
    settles, the problem's default), and the settled flat linkage."""
    L, D = banana_states()
    settled = copy.deepcopy(L)
    prob = DesignProblem(L, np.radians(80), DesignWeights(gamma=0.3, beta=100.0),
                         fitting=PointFit(D.joint_positions(), np.full(L.num_joints, 1.0 / L.num_joints)), deployed=D,
                         flat_angle=L.average_angle() + np.radians(offset_deg))
    return prob, settled


@pytest.mark.parametrize("offset, spread, steps", [(0.0, 1e-3, (2e-6, 1e-6, 5e-7)), (0.5, 1e-4, (8e-5, 4e-5, 2e-5))])
def test_flat_clearance_is_a_smooth_minimum_with_adjoint_derivatives(offset, spread, steps):
    # the flat beams of one family: a smooth minimum of their in-plane distances, below the smallest one by at
    # most s·log(pairs)·width, and its gradient in q (adjoint) converging at second order. Measured on the held
    # flat state where it pushes to open (offset 0, at these designs), on the released one where it pushes to
    # close (held 0.5° more open than it settles; at designs nearer the start, since a change of 1e-3 to the
    # rest lengths turns that torque round). A problem of its own: the banana's flat beams are 0.04 mm
    # apart, and the equilibria reached from the designs other tests visited differ by more than these steps
    from xshells.design.objective import CLEARANCE_REACH, CLEARANCE_SHARPNESS
    from xshells.linkage.clearance import family_clearance, same_family_pairs

    prob, _ = _banana_problem_held_at(offset)
    rng = np.random.default_rng(3)
    q = 1 + spread * rng.standard_normal(len(prob.p0))
    v = rng.standard_normal(len(q))
    v /= np.linalg.norm(v)  # the banana's flat beams are 0.04 of 885 mm apart: tiny steps stay linear
    prob.set_q(q)
    released = prob.released_flat()
    assert (released is not None) == (offset > 0)
    measured = prob.flat.L if released is None else released.L
    gap = family_clearance(measured, np.inf)[0]
    width = 0.8 * gap
    value, grad = prob.flat_clearance(q, width)
    n = len(same_family_pairs(measured, CLEARANCE_REACH * width)[0])
    assert gap - CLEARANCE_SHARPNESS * np.log(n) * width <= value <= gap and n > 1
    errors = []
    for h in steps:  # (the released state's differences are at round-off, 4e-7, below 1e-5)
        fd = (prob.flat_clearance(q + h * v, width)[0] - prob.flat_clearance(q - h * v, width)[0]) / (2 * h)
        errors.append(abs(fd - grad @ v) / abs(grad @ v))
    assert errors[-1] < 1e-4 and errors[0] / errors[1] > 3 and errors[1] / errors[2] > 3, errors
    # no pair within reach: the value is the reach, and nothing moves it
    value, grad = prob.flat_clearance(q, 1e-3 * gap)
    assert value == CLEARANCE_REACH * 1e-3 * gap and not grad.any()


def test_the_released_flat_state_is_where_the_layout_settles_let_go():
    # held more open than it settles, the flat state pushes to close: let go (released_flat) it settles back to
    # the state a linkage built from the design and settled reaches (banana_states settles it so, as the inverse
    # design's checks and `xshells deploy` do); an unconstrained minimum, and a function of the design alone.
    # Held more closed, it pushes to open: nothing is released (the held beams are the nearer)
    prob, settled = _banana_problem_held_at(0.5)
    eq = prob.released_flat()
    assert eq is not None and eq.L is not prob.flat.L
    span = np.ptp(settled.joint_positions(), axis=0).max()
    assert np.degrees(prob.flat.L.average_angle() - eq.L.average_angle()) == pytest.approx(0.5, abs=1e-6)
    assert np.abs(eq.L.joint_positions() - settled.joint_positions()).max() < 1e-6 * span
    g = eq.L.gradient()
    g[eq.pins] = 0.0
    assert np.abs(g).max() <= eq.newton.gradient_tolerance
    rng = np.random.default_rng(5)
    q = 1 + 1e-4 * rng.standard_normal(len(prob.p0))  # (1e-3 turns the banana's closing torque round)
    prob.set_q(q)
    first = prob.released_flat().L.get_vars().copy()
    assert np.array_equal(prob.released_flat().L.rest_lengths, q * prob.p0)
    prob.set_q(q * (1 + 1e-4 * rng.standard_normal(len(q))))
    assert prob.released_flat() is not None
    prob.set_q(q)
    assert np.abs(prob.released_flat().L.get_vars() - first).max() < 1e-6 * span
    closed, _ = _banana_problem_held_at(-0.5)
    assert closed.released_flat() is None
