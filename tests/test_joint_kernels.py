"""Analytic joint-map kernels against JAX differentiation of ``joints.instance_outputs``."""
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from xshells.linkage import joint_kernels as jk
from xshells.linkage import joints


def _unit(v):
    return v / np.linalg.norm(v, axis=0)


def _rotate(w, v):
    """Rodrigues rotation of (3, N) vectors by (3, N) rotation vectors."""
    th = np.linalg.norm(w, axis=0)
    axis = w / np.where(th > 0, th, 1.0)
    c, s = np.cos(th), np.sin(th)
    return c * v + s * np.cross(axis, v, axis=0) + (1 - c) * np.sum(axis * v, axis=0) * axis


def random_instances(n, seed, omega_scale=0.0):
    """``q (9, n)``, ``prm (16, n)``: both beams, σ = ±1, φ zero and not, θ branches near ±π."""
    rng = np.random.default_rng(seed)
    b0 = _unit(rng.standard_normal((3, n)))
    n0 = _unit(np.cross(b0, rng.standard_normal((3, n)), axis=0))
    beam = (np.arange(n) % 2).astype(float)
    sigma = np.where((np.arange(n) // 2) % 2 == 0, 1.0, -1.0)
    q = np.empty((9, n))
    q[0:3] = rng.standard_normal((3, n))
    q[3:6] = _unit(rng.standard_normal((3, n))) * omega_scale
    q[6] = rng.uniform(0.3, 2.8, n)
    q[7:9] = rng.uniform(0.1, 2.0, (2, n))
    # the rod edge tangent at q, then a source frame within ~0.3 rad of it
    b, nn = _rotate(q[3:6], b0), _rotate(q[3:6], n0)
    sx = 2 * beam - 1
    te = sigma * (np.cos(q[6] / 2) * b + sx * np.sin(q[6] / 2) * np.cross(nn, b, axis=0))
    ts = _rotate(rng.uniform(-0.17, 0.17, (3, n)), te)
    d1s = _unit(np.cross(ts, rng.standard_normal((3, n)), axis=0))
    prm = np.empty((16, n))
    prm[0:3], prm[3:6], prm[6], prm[7] = b0, n0, beam, sigma
    prm[8:11], prm[11:14] = ts, d1s
    phi = np.where(np.arange(n) % 3 == 0, 0.0, rng.uniform(-np.pi, np.pi, n))
    prm[15] = phi
    theta_raw = joints.outputs(q, np.vstack([prm[:14], np.zeros(n), phi]))[6]
    # source θ on other 2π branches, and near ±π
    prm[14] = theta_raw + 2 * np.pi * rng.integers(-2, 3, n) + rng.uniform(-0.5, 0.5, n)
    return q, prm


def _single(qv, pv):
    return jnp.stack(joints.instance_outputs(tuple(qv), tuple(pv)))


_jac_ref = jax.jit(jax.vmap(jax.jacfwd(_single), in_axes=(1, 1), out_axes=2))
_hess_ref = jax.jit(
    jax.vmap(jax.hessian(lambda qv, pv, wv: jnp.dot(wv, _single(qv, pv))), in_axes=(1, 1, 1), out_axes=2)
)

N = 96
OMEGAS = [0.0, 1e-5, 0.2, 1.0]


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


def test_outputs_match_joints():
    for seed, om in enumerate(OMEGAS):
        q, prm = random_instances(N, seed, om)
        ref = joints.outputs(q, prm)
        out = jk.outputs(q, prm)
        assert np.max(np.abs(out - ref)) < 1e-13
        out2, _ = jk.outputs_and_jacobian(q, prm)
        np.testing.assert_array_equal(out, out2)


def test_branch_picks_source_theta():
    q, prm = random_instances(N, 7)
    out = jk.outputs(q, prm)
    assert np.all(np.abs(out[6] - prm[14]) <= np.pi)
    assert np.any(np.abs(out[6]) > 3.0)


@pytest.mark.parametrize("omega", OMEGAS)
def test_jacobian_matches_jax(omega):
    q, prm = random_instances(N, 11 + int(omega * 1e6) % 97, omega)
    _, jac = jk.outputs_and_jacobian(q, prm)
    ref = np.asarray(_jac_ref(q, prm))
    assert ref.shape == jac.shape == (7, 9, N)
    assert _rel(jac, ref) < 1e-10
    # also per column block, so that small blocks are not hidden by large ones
    assert _rel(jac[6], ref[6]) < 1e-10
    assert _rel(jac[:, 3:6], ref[:, 3:6]) < 1e-10


@pytest.mark.parametrize("omega", OMEGAS)
def test_weighted_hessian_matches_jax(omega):
    q, prm = random_instances(N, 23 + int(omega * 1e6) % 89, omega)
    rng = np.random.default_rng(5)
    w = rng.standard_normal((7, N))
    hess = jk.weighted_hessian(q, prm, w)
    ref = np.asarray(_hess_ref(q, prm, w))
    assert hess.shape == (9, 9, N)
    assert _rel(hess, ref) < 1e-9
    np.testing.assert_array_equal(hess, hess.transpose(1, 0, 2))
    # θ alone and positions alone
    for mask in (np.arange(7) == 6, np.arange(7) < 6):
        wm = w * mask[:, None]
        assert _rel(jk.weighted_hessian(q, prm, wm), np.asarray(_hess_ref(q, prm, wm))) < 1e-9


def test_mixed_rotation_magnitudes():
    """One batch holding ω = 0 exactly next to ω in every series/closed-form range."""
    q, prm = random_instances(N, 31, 1.0)
    scales = np.array([0.0, 1e-9, 1e-5, 1e-3, 0.05, 0.2, 1.0, 2.5])
    q[3:6] *= np.resize(scales, N)
    assert np.max(np.abs(jk.outputs(q, prm) - joints.outputs(q, prm))) < 1e-13
    _, jac = jk.outputs_and_jacobian(q, prm)
    assert _rel(jac, np.asarray(_jac_ref(q, prm))) < 1e-10
    w = np.random.default_rng(2).standard_normal((7, N))
    assert _rel(jk.weighted_hessian(q, prm, w), np.asarray(_hess_ref(q, prm, w))) < 1e-9


def test_coefficient_series_continuous():
    """Series branches agree with the closed forms at their switch-over points."""
    for threshold, tol in ((1e-2, 1e-9), (1e-8, 1e-6)):
        c = np.array(jk._coefficients(threshold * np.array([1 - 1e-12, 1 + 1e-12]), derivatives=True))
        assert np.all(np.abs(c[:, 0] - c[:, 1]) <= tol * np.abs(c[:, 1]))


def test_is_at_source():
    q, prm = random_instances(8, 3)
    assert jk.is_at_source(q)
    q[4, 5] = 1e-300
    assert not jk.is_at_source(q)


def _median_ms(f, reps=200):
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


if __name__ == "__main__":
    n = 624
    for om in (0.0, 0.2):
        q, prm = random_instances(n, 0, om)
        w = np.random.default_rng(1).standard_normal((7, n))
        print(f"N = {n}, |ω| = {om}")
        print(f"  numpy jacobian        {_median_ms(lambda: jk.outputs_and_jacobian(q, prm)):.3f} ms")
        print(f"  numpy weighted hessian {_median_ms(lambda: jk.weighted_hessian(q, prm, w)):.3f} ms")
