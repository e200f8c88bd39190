"""Directional derivatives of the linkage Hessian (third derivatives of E)."""
import numpy as np
import pytest

from xshells.errors import InputError
from xshells.linkage.derivatives import hessian_derivative, hessian_derivative_product

from test_linkage import banana, nonuniform, perturbed


def scaled_direction(L, rng, with_p):
    """A random direction with lengths in the design's units and angles in radians."""
    ell = 0.1 * np.mean(L.rest_lengths)
    d = rng.standard_normal(L.num_vars)
    d[: L.num_joint_vars] *= np.tile([ell, ell, ell, 1e-2, 1e-2, 1e-2, 1e-2, 0.1 * ell, 0.1 * ell], L.num_joints)
    is_angle = L._free_rod >= 3 * L.rods.num_vertices
    d[L._free_reduced] *= np.where(is_angle, 1e-2, ell)
    dp = 0.1 * ell * rng.standard_normal(L.num_segments) if with_p else None
    return d, dp


def mixed_difference(L, dx, dp, u, a, with_p):
    """Second method: ``dH[δ] u`` from four gradients, ``∂²g/∂s∂t`` at ``z + sδ + tu``."""
    x0, p0 = L.get_vars(), L.rest_lengths
    nx = L.num_vars
    out = 0.0
    for s, t, sign in ((a, a, 1), (a, -a, -1), (-a, a, -1), (-a, -a, 1)):
        L.set_vars(x0 + s * dx + t * u[:nx])
        p = p0 + (s * dp if dp is not None else 0.0) + (t * u[nx:] if with_p else 0.0)
        L.set_rest_lengths(p)
        out = out + sign * L.gradient(with_p)
    L.set_vars(x0)
    L.set_rest_lengths(p0)
    return out / (4 * a * a)


@pytest.mark.parametrize("make,with_p,at_source", [
    (nonuniform, False, True), (nonuniform, True, False), (banana, False, False), (banana, True, True),
])
def test_matches_mixed_gradient_differences(make, with_p, at_source):
    L = perturbed(make(k=4), seed=3)
    if not at_source:  # a state away from the stored source frame
        rng = np.random.default_rng(9)
        d, _ = scaled_direction(L, rng, False)
        L.set_vars(L.get_vars() + 0.3 * d)
    rng = np.random.default_rng(1)
    dx, dp = scaled_direction(L, rng, with_p)
    ux, up = scaled_direction(L, rng, with_p)
    u = np.concatenate([ux, up]) if with_p else ux
    x0 = L.get_vars()
    dH = hessian_derivative(L, dx, dp, with_rest_lengths=with_p)
    assert np.array_equal(L.get_vars(), x0)  # state restored exactly
    ref = dH @ u
    fd = [mixed_difference(L, dx, dp, u, a, with_p) for a in (1e-3, 5e-4, 2.5e-4)]
    errs = [np.linalg.norm(f - ref) / np.linalg.norm(ref) for f in fd]
    # second-order convergence of the reference towards ours: our value is the limit
    assert errs[0] / errs[1] > 3.5 and errs[1] / errs[2] > 3.5, errs
    richardson = (4 * fd[2] - fd[1]) / 3
    assert np.linalg.norm(richardson - ref) / np.linalg.norm(ref) < 1e-6, errs
    # the matrix-free product (a second, independent method) and the forward scheme agree
    got = hessian_derivative_product(L, dx, dp, u, with_rest_lengths=with_p)
    assert np.array_equal(L.get_vars(), x0)
    # measured 5e-8 to 2e-5: these states are strongly twisted (material angles perturbed by up to
    # about 1 rad per edge), where the differences' truncation error is large; 2e-8 to 5e-7 at
    # equilibria (test_product_at_a_deployed_equilibrium, test_design_objective)
    assert np.linalg.norm(got - ref) / np.linalg.norm(ref) < 5e-5
    assert np.linalg.norm(got - richardson) / np.linalg.norm(ref) < 5e-5
    fwd = hessian_derivative(L, dx, dp, with_rest_lengths=with_p, scheme="forward") @ u
    assert np.linalg.norm(fwd - ref) / np.linalg.norm(ref) < 1e-5


def test_symmetric_and_linear_in_direction():
    L = perturbed(banana(k=4), seed=5)
    rng = np.random.default_rng(2)
    d1, p1 = scaled_direction(L, rng, True)
    d2, p2 = scaled_direction(L, rng, True)
    A = hessian_derivative(L, d1, p1, with_rest_lengths=True)
    B = hessian_derivative(L, d2, p2, with_rest_lengths=True)
    C = hessian_derivative(L, 2 * d1 - d2, 2 * p1 - p2, with_rest_lengths=True)
    scale = abs(A).max()
    assert abs(A - A.T).max() < 1e-12 * scale
    assert abs(C - (2 * A - B)).max() < 1e-7 * scale


def test_rigid_translation_leaves_hessian_unchanged():
    L = perturbed(nonuniform(k=4), seed=4)
    rng = np.random.default_rng(0)
    d, _ = scaled_direction(L, rng, False)
    t = np.zeros(L.num_vars)
    t[: L.num_joint_vars] = np.tile([1.0, -2.0, 0.5, 0, 0, 0, 0, 0, 0], L.num_joints)
    is_pos = L._free_rod < 3 * L.rods.num_vertices
    t[L._free_reduced[is_pos]] = np.tile([1.0, -2.0, 0.5], is_pos.sum() // 3)
    ref = abs(hessian_derivative(L, d)).max()
    assert abs(hessian_derivative(L, t)).max() < 1e-6 * ref


def test_zero_direction_and_bad_input():
    L = nonuniform(k=3)
    assert hessian_derivative(L, np.zeros(L.num_vars)).nnz == 0
    with pytest.raises(InputError, match="expected"):
        hessian_derivative(L, np.zeros(3))
    with pytest.raises(InputError, match="scheme"):
        hessian_derivative(L, np.ones(L.num_vars), scheme="complex")


def test_third_derivative_product_agrees_with_the_hessian_derivative():
    from xshells.linkage.derivatives import third_derivative_product

    L = perturbed(banana(k=4), seed=7)
    rng = np.random.default_rng(3)
    dx, _ = scaled_direction(L, rng, False)
    u, _ = scaled_direction(L, rng, False)
    x0 = L.get_vars()
    ref = hessian_derivative(L, dx) @ u
    got = third_derivative_product(L, dx, u)
    assert np.array_equal(L.get_vars(), x0)
    assert np.linalg.norm(got - ref) / np.linalg.norm(ref) < 1e-5
    assert not third_derivative_product(L, np.zeros(L.num_vars), u).any()
    assert not third_derivative_product(L, dx, np.zeros(L.num_vars)).any()


def test_product_is_linear_in_the_vector_and_direction():
    L = perturbed(nonuniform(k=4), seed=6)
    rng = np.random.default_rng(4)
    d1, p1 = scaled_direction(L, rng, True)
    d2, p2 = scaled_direction(L, rng, True)
    w1 = np.concatenate(scaled_direction(L, rng, True))
    w2 = np.concatenate(scaled_direction(L, rng, True))
    f = lambda d, p, w: hessian_derivative_product(L, d, p, w, with_rest_lengths=True)  # noqa: E731
    ref = np.linalg.norm(f(d1, p1, w1))
    assert np.linalg.norm(f(d1, p1, 2 * w1 - w2) - (2 * f(d1, p1, w1) - f(d1, p1, w2))) < 1e-5 * ref
    assert np.linalg.norm(f(2 * d1 - d2, 2 * p1 - p2, w1) - (2 * f(d1, p1, w1) - f(d2, p2, w1))) < 1e-5 * ref
    # symmetry of the third derivative: dH[a]·b = dH[b]·a
    a = np.concatenate([d1, p1])
    ab = f(d1, p1, w1)
    ba = f(w1[: L.num_vars], w1[L.num_vars:], a)
    assert np.linalg.norm(ab - ba) < 3e-6 * np.linalg.norm(ab)


def test_product_converges_at_second_order_in_its_step(monkeypatch):
    """The product's only approximation is the differences' step: halving it quarters the error
    (the most twisted state of the tests, where truncation dominates)."""
    import xshells.linkage.derivatives as D

    L = perturbed(banana(k=4), seed=3)
    rng = np.random.default_rng(1)
    dx, dp = scaled_direction(L, rng, True)
    u = np.concatenate(scaled_direction(L, rng, True))
    ref = hessian_derivative(L, dx, dp, with_rest_lengths=True) @ u
    errs = []
    for step in (2e-4, 1e-4, 5e-5):
        monkeypatch.setattr(D, "_PRODUCT_STEP", step)
        got = hessian_derivative_product(L, dx, dp, u, with_rest_lengths=True)
        errs.append(np.linalg.norm(got - ref) / np.linalg.norm(ref))
    assert errs[0] / errs[1] > 3.5 and errs[1] / errs[2] > 3.5, errs


def test_product_at_a_new_state_equals_the_product_after_a_gradient():
    """At a state not evaluated yet the rods' gradient comes from the product's own points."""
    L = perturbed(nonuniform(k=4), seed=8)
    rng = np.random.default_rng(6)
    dx, dp = scaled_direction(L, rng, True)
    u = np.concatenate(scaled_direction(L, rng, True))
    L.set_vars(L.get_vars() + 1e-3 * dx)  # nothing cached here
    fresh = hessian_derivative_product(L, dx, dp, u, with_rest_lengths=True)
    L.gradient()
    cached = hessian_derivative_product(L, dx, dp, u, with_rest_lengths=True)
    assert np.linalg.norm(fresh - cached) < 1e-8 * np.linalg.norm(cached)


def test_product_bad_input():
    L = nonuniform(k=3)
    n = L.num_vars
    with pytest.raises(InputError, match="dx"):
        hessian_derivative_product(L, np.zeros(3), None, np.zeros(n))
    with pytest.raises(InputError, match="dp"):
        hessian_derivative_product(L, np.zeros(n), np.zeros(2), np.zeros(n))
    with pytest.raises(InputError, match="w"):
        hessian_derivative_product(L, np.zeros(n), None, np.zeros(n), with_rest_lengths=True)
    assert not hessian_derivative_product(L, np.zeros(n), None, np.ones(n)).any()


def test_stretch_terms_match_differences_of_the_kernel_hessian():
    from xshells.linkage.derivatives import _stretch_terms
    from xshells.rod.rods import stretch_kernel

    rng = np.random.default_rng(0)
    n = 50
    q = np.concatenate([rng.standard_normal((6, n)), 1.0 + 0.3 * rng.random((1, n))])
    ks = 1.0 + rng.random(n)
    A, B, C = (rng.standard_normal((7, n)) for _ in range(3))
    y1, ba, bb = _stretch_terms(q, ks, A, B, C)
    H = lambda qq: stretch_kernel(qq, ks)[2]  # noqa: E731
    apply = lambda M, v: np.einsum("ijn,jn->in", M, v)  # noqa: E731
    errs = []
    for h in (2e-3, 1e-3, 5e-4):
        fd = (apply(H(q + h * A), B) - apply(H(q - h * A), B)) / (2 * h) + apply(H(q), C)
        errs.append(np.linalg.norm(fd - y1) / np.linalg.norm(y1))
    # the differences converge to ours at second order
    assert errs[0] / errs[1] > 3.8 and errs[1] / errs[2] > 3.8 and errs[2] < 1e-5, errs
    assert np.allclose(ba, apply(H(q), A), rtol=1e-13, atol=1e-13)
    assert np.allclose(bb, apply(H(q), B), rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("make", [nonuniform, banana])
def test_the_rod_jacobian_matches_central_differences_of_the_rod_variables(make):
    # rod_jacobian carries gradients of rod-point functions to the linkage's variables (the clearance barrier's
    # adjoint uses it): J δx against (rod_vars(x + hδx) − rod_vars(x − hδx)) / 2h, converging at second order
    L = perturbed(make(), 11)
    rng = np.random.default_rng(11)
    dx, _ = scaled_direction(L, rng, False)
    x = L.get_vars()
    J = L.rod_jacobian()
    assert J.shape == (L.rods.num_vars, L.num_vars)
    exact = J @ dx
    errors = [np.abs((L.rod_vars(x + h * dx) - L.rod_vars(x - h * dx)) / (2 * h) - exact).max() / np.abs(exact).max()
              for h in (2.0, 1.0)]  # (steps of the scaled direction: 0.02 rad rotations at h = 2)
    assert errors[1] < 1e-4 and errors[0] / errors[1] > 3.5, errors  # second order: the truncation halves twice
