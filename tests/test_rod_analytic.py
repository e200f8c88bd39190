"""Analytic NumPy stencil kernels against automatic differentiation of the definitions."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import xshells  # noqa: F401  (enables float64 in JAX)
from xshells.rod import analytic, stencils

jax.config.update("jax_enable_x64", True)

VARIANTS = ["2008", "2010"]


def _unit(v):
    return v / np.linalg.norm(v, axis=0)


def _rotate(axis, angle, v):
    """Rotate columns of v about unit columns of axis by angle (Rodrigues)."""
    c, s = np.cos(angle), np.sin(angle)
    return c * v + s * np.cross(axis, v, axis=0) + (1 - c) * np.sum(axis * v, axis=0) * axis


def _transport(a, b, v):
    c = np.cross(a, b, axis=0)
    d = np.sum(a * b, axis=0)
    return d * v + np.cross(c, v, axis=0) + np.sum(c * v, axis=0) / (1 + d) * c


def random_stencils(n, seed, perturb_source=0.0, twist_near_pi=False):
    """Random vertex stencils (q (13, n), prm (23, n)); source frames at the current tangents
    unless ``perturb_source`` (radians) rotates them away."""
    rng = np.random.default_rng(seed)
    x1 = rng.standard_normal((3, n))
    l0, l1 = 0.3 + 1.7 * rng.random(n), 0.3 + 1.7 * rng.random(n)
    t0 = _unit(rng.standard_normal((3, n)))
    t1 = _unit(t0 + 1.2 * rng.standard_normal((3, n)))  # bent (up to ~150°), never reversed
    bad = np.sum(t0 * t1, axis=0) < -0.85
    t1[:, bad] = _unit(t0[:, bad] + 0.5 * rng.standard_normal((3, int(bad.sum()))))
    x0, x2 = x1 - l0 * t0, x1 + l1 * t1
    q = np.concatenate([x0, x1, x2, rng.uniform(-np.pi, np.pi, (2, n)), 0.3 + 1.7 * rng.random((2, n))])
    frames = []
    for t in (t0, t1):
        d1 = _unit(np.cross(t, rng.standard_normal((3, n)), axis=0))
        if perturb_source:
            axis = _unit(np.cross(t, rng.standard_normal((3, n)), axis=0))
            angle = perturb_source * (0.5 + rng.random(n))
            t, d1 = _rotate(axis, angle, t), _rotate(axis, angle, d1)
        frames.append((t, d1))
    if twist_near_pi:
        # put edge 1's director at ±(π − small) from the transported director of edge 0
        u = _transport(t0, t1, _transport(frames[0][0], t0, frames[0][1]))
        ang = np.where(rng.random(n) < 0.5, 1.0, -1.0) * (np.pi - 0.02 * rng.random(n))
        d1 = _rotate(t1, ang, u)
        ts = frames[1][0]
        frames[1] = (ts, _transport(t1, ts, d1))  # its source, transported back
        stored = ang + 2 * np.pi * rng.integers(-1, 2, n) + 0.3 * np.sign(ang)  # branch chosen either side
    prm = np.empty((23, n))
    prm[0:3], prm[3:6] = frames[0]
    prm[6:9], prm[9:12] = frames[1]
    B = 0.5 + 2.0 * rng.random((4, n))
    prm[12:16] = B  # B1 ≠ B2, either stiffer
    prm[16] = 0.5 + rng.random(n)
    prm[17:21] = 0.5 * rng.standard_normal((4, n))
    prm[21] = 0.3 * rng.standard_normal(n)
    if twist_near_pi:
        prm[22] = stored
    else:
        # stored reference twist near the actual one
        ref = np.asarray(stencils.reference_twist(
            tuple(t0), tuple(_transport(prm[0:3], t0, prm[3:6])),
            tuple(t1), tuple(_transport(prm[6:9], t1, prm[9:12])), np.zeros(n)))
        prm[22] = ref + 0.1 * rng.standard_normal(n)
    return q, prm


def _jax_grad(q, prm, variant):
    pt = tuple(jnp.asarray(r) for r in prm)
    g = jax.grad(lambda qq: stencils.vertex_energy(qq, pt, variant))(tuple(jnp.asarray(r) for r in q))
    return np.stack([np.asarray(r) for r in g])


def _jax_energies(q, prm, variant):
    b, t = stencils.vertex_energies(tuple(q), tuple(prm), variant)
    return np.asarray(b), np.asarray(t)


def _jax_hessian(q, prm, variant):
    """Per-stencil Hessians (13, 13, n) by jax.hessian on tuples of rows."""
    pt = tuple(jnp.asarray(r) for r in prm)
    h = jax.hessian(lambda qq: stencils.vertex_energy(qq, pt, variant))(tuple(jnp.asarray(r) for r in q))
    n = q.shape[1]
    out = np.empty((13, 13, n))
    idx = np.arange(n)
    for a in range(13):
        for b in range(13):
            out[a, b] = np.asarray(h[a][b])[idx, idx]
    return out


def _rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("perturb", [0.0, 0.1])
def test_vertex_gradient_matches_jax(variant, perturb):
    q, prm = random_stencils(64, seed=11, perturb_source=perturb)
    g_ad = _jax_grad(q, prm, variant)
    g = analytic.vertex_gradient(q, prm, variant)
    assert g.shape == (13, 64) and g.dtype == np.float64
    # per stencil, relative to that stencil's largest entry
    err = np.abs(g - g_ad).max(axis=0) / np.abs(g_ad).max(axis=0)
    assert err.max() < 1e-9
    bend, twist, g2 = analytic.vertex_energy_and_gradient(q, prm, variant)
    b_ad, t_ad = _jax_energies(q, prm, variant)
    assert np.allclose(bend, b_ad, rtol=1e-12, atol=0) and np.allclose(twist, t_ad, rtol=1e-12, atol=1e-300)
    assert np.array_equal(g, g2)


@pytest.mark.parametrize("variant", VARIANTS)
def test_vertex_gradient_on_the_other_twist_branch(variant):
    q, prm = random_stencils(32, seed=12, perturb_source=0.1, twist_near_pi=True)
    g_ad = _jax_grad(q, prm, variant)
    g = analytic.vertex_gradient(q, prm, variant)
    err = np.abs(g - g_ad).max(axis=0) / np.abs(g_ad).max(axis=0)
    assert err.max() < 1e-9
    _, t_ad = _jax_energies(q, prm, variant)
    assert np.allclose(analytic.vertex_energy_and_gradient(q, prm, variant)[1], t_ad, rtol=1e-12)


def test_unknown_variant_is_rejected():
    q, prm = random_stencils(2, seed=0)
    with pytest.raises(ValueError):
        analytic.vertex_gradient(q, prm, "1999")


def _check_hessian(q, prm, variant, tol=1e-8):
    H_ad = _jax_hessian(q, prm, variant)
    H = analytic.vertex_hessian(q, prm, variant)
    assert H.shape == (13, 13, q.shape[1]) and H.dtype == np.float64
    err = np.abs(H - H_ad).max(axis=(0, 1)) / np.abs(H_ad).max(axis=(0, 1))
    assert err.max() < tol
    asym = np.abs(H - H.transpose(1, 0, 2)).max(axis=(0, 1)) / np.abs(H).max(axis=(0, 1))
    assert asym.max() < 1e-13


@pytest.mark.parametrize("variant", VARIANTS)
def test_vertex_hessian_matches_jax_at_the_source_frame(variant):
    _check_hessian(*random_stencils(24, seed=21), variant)


@pytest.mark.parametrize("variant", VARIANTS)
def test_vertex_hessian_on_the_other_twist_branch(variant):
    _check_hessian(*random_stencils(24, seed=22, twist_near_pi=True), variant)


@pytest.mark.parametrize("variant", VARIANTS)
def test_vertex_hessian_matches_jax_away_from_the_source_frame(variant):
    _check_hessian(*random_stencils(24, seed=23, perturb_source=0.1, twist_near_pi=True), variant)
    _check_hessian(*random_stencils(24, seed=24, perturb_source=0.5), variant)


def test_edge_kernel_matches_jax():
    rng = np.random.default_rng(31)
    n = 40
    x0 = rng.standard_normal((3, n))
    x1 = x0 + (0.2 + rng.random(n)) * _unit(rng.standard_normal((3, n)))
    q = np.concatenate([x0, x1, (0.3 + rng.random(n))[None]])
    ks = 1.0 + 10 * rng.random(n)
    energy, g, H = analytic.edge_energy_gradient_hessian(q, ks)
    fun = lambda qq: jnp.sum(stencils.edge_energies(qq, jnp.asarray(ks)))  # noqa: E731
    qt = tuple(jnp.asarray(r) for r in q)
    assert np.allclose(energy, np.asarray(stencils.edge_energies(qt, ks)), rtol=1e-13, atol=0)
    g_ad = np.stack([np.asarray(r) for r in jax.grad(fun)(qt)])
    assert np.abs(g - g_ad).max() <= 1e-12 * np.abs(g_ad).max()
    h = jax.hessian(fun)(qt)
    idx = np.arange(n)
    H_ad = np.array([[np.asarray(h[a][b])[idx, idx] for b in range(7)] for a in range(7)])
    assert np.abs(H - H_ad).max() <= 1e-12 * np.abs(H_ad).max()
    # a scalar stiffness broadcasts
    assert np.allclose(analytic.edge_energy_gradient_hessian(q, 2.0)[2], 2.0 * analytic.edge_energy_gradient_hessian(q, 1.0)[2])
