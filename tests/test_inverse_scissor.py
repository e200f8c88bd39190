"""The scissor map: closing an opened X-shell patch is an anisotropic scaling along the beams' bisector."""
import numpy as np
import pytest

from test_inverse_surface import grid
from xshells.inverse.scissor import scissor_map, stretches
from xshells.inverse.surface import check_target


@pytest.mark.parametrize("alpha, alpha0", [(90, 20), (120, 30), (60, 10)])
def test_the_stretches_open_the_beam_directions_from_alpha0_to_alpha(alpha, alpha0):
    a, a0 = np.radians(alpha), np.radians(alpha0)
    l1, l2 = stretches(a, a0)
    for s in (1, -1):
        d = np.array([l1 * np.cos(a0 / 2), l2 * s * np.sin(a0 / 2)])  # a flat beam direction, opened
        assert np.linalg.norm(d) == pytest.approx(1.0)  # inextensible
        assert np.arctan2(d[1], d[0]) == pytest.approx(s * a / 2)


def test_a_plane_closes_to_a_uniform_scaling_exactly():
    s = check_target(*grid(n=9))
    m = scissor_map(s, np.radians(90), np.radians(20))
    assert m.residual < 1e-10
    J = m.frames.jacobians(m.flat)
    sv = np.linalg.svd(J, compute_uv=False)
    l1, l2 = m.stretch
    assert np.allclose(sv[:, 0], 1 / l1) and np.allclose(sv[:, 1], 1 / l2)
    d3 = m.frames.to_3d(m.director)
    assert np.allclose(np.abs(d3 @ d3[0]), 1.0, atol=1e-8)  # one director everywhere


def test_curved_surfaces_have_layouts_closed_uniformly_to_within_a_small_residual():
    # a shallow cap (positive curvature) and a cylinder (developable): the anisotropic metric can be made flat
    cap = check_target(*grid(n=15, height=lambda x, y: -(x**2 + y**2) / 4000.0))
    cyl = check_target(*grid(n=15, height=lambda x, y: np.sqrt(1500.0**2 - x**2) - 1500.0))
    for s in (cap, cyl):
        m = scissor_map(s, np.radians(90), np.radians(20))
        assert m.residual < 5e-3
        assert (np.linalg.det(m.frames.jacobians(m.flat)) > 0).all()  # no triangle flips: the layout is one sheet


@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (1.0, 1.0, 0.0)])
def test_a_plane_closes_about_the_axis_it_is_given(axis):
    s = check_target(*grid(n=9))
    m = scissor_map(s, np.radians(110), np.radians(20), axis=axis)
    d3 = m.frames.to_3d(m.director)
    assert np.allclose(np.abs(d3 @ np.asarray(axis) / np.linalg.norm(axis)), 1.0, atol=1e-8)
