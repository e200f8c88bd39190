"""The design optimizer (trust-region Newton-CG and its BFGS baseline) on a real design, coarse."""
import copy

import numpy as np
import pytest

from xshells.design.objective import DesignProblem, DesignWeights
from xshells.design.optimize import OptimizeOptions, optimize
from xshells.errors import InputError

from test_design_objective import PointFit, banana_states

_BASE = {}


def banana_problem():
    """The wiggly banana before optimization at k = 4: flat, and deployed to 80°, fitting its own deployed joints."""
    if not _BASE:
        _BASE["L"], _BASE["D"] = banana_states()
    L, D = copy.deepcopy(_BASE["L"]), copy.deepcopy(_BASE["D"])
    fit = PointFit(D.joint_positions(), np.full(L.num_joints, 1.0 / L.num_joints))
    return DesignProblem(L, np.radians(80), DesignWeights(gamma=0.5, beta=1000.0), fitting=fit, deployed=D)


@pytest.fixture(scope="module")
def runs():
    out = {}
    for method, iters in (("newton-cg", 8), ("bfgs", 24)):
        prob = banana_problem()
        J0 = prob.objective(prob._q)
        res = optimize(prob, OptimizeOptions(method=method, max_iterations=iters))
        out[method] = (prob, res, J0)
    return out


def test_newton_cg_lowers_the_deployed_energy_and_keeps_the_flat_state_planar(runs):
    prob, res, J0 = runs["newton-cg"]
    first, last = res.history[0], res.history[-1]
    assert last.J < 0.5 * J0, [r.J for r in res.history]
    assert last.deployed_energy < 0.5 * first.deployed_energy
    # every accepted iterate is feasible: a planar flat state (c/l₀² ≤ 1e-12: |z| within 1e-6 of l₀), minimum angle kept
    assert max(r.planarity for r in res.history) <= 1e-12
    eps = first.min_angle_deg - 0.5  # the default ε
    assert min(r.min_angle_deg for r in res.history) >= eps - 1e-9
    # the problem is left at the best feasible design
    assert prob.objective(res.q) == pytest.approx(min(r.J for r in res.history), rel=1e-9)


def test_newton_cg_needs_fewer_iterations_than_bfgs(runs):
    J_n = [r.J for r in runs["newton-cg"][1].history]
    J_b = [r.J for r in runs["bfgs"][1].history]
    J0 = J_n[0]
    target = J0 - 0.8 * (J0 - min(J_n))  # 80 % of the decrease Newton-CG achieves
    it_n = next(i for i, J in enumerate(J_n) if J <= target)
    it_b = next((i for i, J in enumerate(J_b) if J <= target), len(J_b) + 1)
    assert it_b >= 3 * it_n, (it_n, it_b, J_n, J_b)


def test_infeasible_minimum_angle_is_refused():
    prob = banana_problem()
    with pytest.raises(InputError, match="infeasible"):
        optimize(prob, OptimizeOptions(min_angle=np.radians(30.0), max_iterations=1))
