"""Placement, distances and coverage, on cases with known answers."""
import numpy as np
import pytest

from test_inverse_surface import grid
from xshells.inverse.metrics import apply, coverage, kabsch, place, surface_distances
from xshells.inverse.surface import check_target


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_kabsch_recovers_a_rigid_motion_exactly():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(20, 3))
    R, t = rotation([1, 2, 3], 0.7), np.array([5.0, -2.0, 1.0])
    T = kabsch(P, P @ R.T + t)
    assert np.allclose(T[:3, :3], R) and np.allclose(T[:3, 3], t)
    assert np.isclose(np.linalg.det(T[:3, :3]), 1.0)


def test_place_puts_points_taken_from_the_surface_back_on_it():
    s = check_target(*grid(n=11, size=1000.0, height=lambda x, y: (x**2 - y**2) / 3000.0))
    pts = s.V[::7].copy()
    R, t = rotation([0, 1, 1], 0.2), np.array([30.0, 10.0, -20.0])
    moved = pts @ R.T + t
    T = place(s, moved, pts)
    assert surface_distances(s, apply(T, moved)).max() < 1e-6 * s.diagonal


def test_coverage_of_a_plane_by_beams_is_the_strip_area():
    s = check_target(*grid(n=21, size=1000.0))
    P = np.array([[-500.0, 0, 0], [500.0, 0, 0]])
    one = coverage(s, P, np.array([[0, 1]]), 100.0)
    assert one == pytest.approx(0.2, abs=0.01)  # a strip 200 wide across a 1000 square
    xs = np.linspace(-500, 500, 6)
    many = np.array([[x, y, 0.0] for x in xs for y in (-500.0, 500.0)])
    edges = np.array([[2 * k, 2 * k + 1] for k in range(6)])
    assert coverage(s, many, edges, 100.0) == pytest.approx(1.0)


def test_the_mirror_image_reflects_through_the_plane_normal_to_the_given_direction():
    from xshells.inverse.metrics import mirror_image

    P = np.array([[1.0, 2.0, 3.0], [-4.0, 0.5, -2.0]])
    assert np.array_equal(mirror_image(P, (0.0, 0.0, 1.0)), P * [1.0, 1.0, -1.0])
    n = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    assert np.allclose(mirror_image(P, n), P[:, [1, 0, 2]] * [-1.0, -1.0, 1.0])
