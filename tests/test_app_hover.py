"""Joint labels on hover (``xshells.app.hover``): the pointer message, the camera projection, the pick."""
from __future__ import annotations

import numpy as np
import pytest

from xshells.app import hover

DOWN = {"position": (0.0, 0.0, 10.0), "wxyz": (0.0, 1.0, 0.0, 0.0), "fov": np.pi / 2}  # looking down -z, +y up


def test_a_camera_looking_straight_down_projects_by_hand():
    # R = diag(1, -1, -1): camera x along +x, its y (down the screen) along -y, its z (forward) along -z
    ndc, front = hover.project(np.array([[1.0, 0, 0], [0, 2.0, 0], [0, 0, 20.0]]), DOWN["position"], DOWN["wxyz"],
                               DOWN["fov"], aspect=2.0)
    np.testing.assert_allclose(ndc[:2], [[0.1 / 2.0, 0.0], [0.0, 0.2]], atol=1e-15)
    assert front.tolist() == [True, True, False]


def test_projection_is_invariant_to_the_quaternions_sign_and_scale():
    P = np.random.default_rng(0).normal(size=(20, 3))
    pos, q = (3.0, -2.0, 5.0), np.array([0.3, -0.5, 0.7, 0.4])
    a, fa = hover.project(P, pos, q, 0.8, 1.5)
    b, fb = hover.project(P, pos, -2.5 * q, 0.8, 1.5)
    np.testing.assert_allclose(a[fa], b[fb], atol=1e-12)
    assert (fa == fb).all()


def test_projection_agrees_with_a_look_at_camera():
    """A camera built from position, look-at and up (OpenCV axes): the target projects to the centre, and a
    point one unit up the screen at the target's depth projects to y = 1 / (depth tan(fov/2))."""
    pos, target = np.array([2.0, -3.0, 4.0]), np.array([0.5, 0.2, 0.1])
    z = (target - pos) / np.linalg.norm(target - pos)
    x = np.cross(z, [0, 0, 1.0]); x /= np.linalg.norm(x)
    y = np.cross(z, x)  # down the screen
    R = np.c_[x, y, z]
    from scipy.spatial.transform import Rotation

    qx, qy, qz, qw = Rotation.from_matrix(R).as_quat()
    fov, depth = 0.9, np.linalg.norm(target - pos)
    ndc, front = hover.project(np.array([target, target - y, target + 0.5 * x]), pos, (qw, qx, qy, qz), fov, 1.25)
    t = np.tan(fov / 2)
    np.testing.assert_allclose(ndc, [[0, 0], [0, 1 / (depth * t)], [0.5 / (depth * t * 1.25), 0]], atol=1e-12)
    assert front.all()


def test_the_pick_is_the_nearest_point_within_the_radius_in_pixels():
    P = np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 5.0]])  # the third is above the second, nearer the camera
    # 800 × 400 px, aspect 2: one scene unit at depth 10 is 0.05 in x, 20 px
    at = lambda x, y: np.array([x, y])  # noqa: E731
    assert hover.pick_on_screen(P, at(0.0, 0.0), 800, 400, DOWN) == 0
    assert hover.pick_on_screen(P, at(8 / 400, 0.0), 800, 400, DOWN, radius_px=13) == 0
    assert hover.pick_on_screen(P, at(-14 / 400, 0.0), 800, 400, DOWN, radius_px=13) is None
    # (1, 0, 5) is at depth 5: 40 px from the centre; (1, 0, 0) 20 px
    assert hover.pick_on_screen(P, at(40 / 400, 0.0), 800, 400, DOWN) == 2
    assert hover.pick_on_screen(P, at(21 / 400, 0.0), 800, 400, DOWN) == 1
    behind = dict(DOWN, position=(0.0, 0.0, -10.0))
    assert hover.pick_on_screen(P, at(0.0, 0.0), 800, 400, behind) is None
    assert hover.pick_on_screen(np.zeros((0, 3)), at(0.0, 0.0), 800, 400, DOWN) is None


@pytest.mark.parametrize("text", ["", "1 2 3", "a b c d", "0 0 0 100", "0 0 100 -1", "nan 0 100 100", "5 0 100 100"])
def test_a_malformed_or_empty_pointer_message_is_none(text):
    assert hover.parse_pointer(text) is None


def test_a_pointer_message_parses():
    xy, w, h = hover.parse_pointer("-0.25 0.5 1400.0 800.0")
    assert xy.tolist() == [-0.25, 0.5] and (w, h) == (1400.0, 800.0)


def test_the_relay_element_is_one_attribute_safe_snippet():
    html = hover.relay_html()
    assert html.startswith("<div data-xshells-hover></div>")  # the marker the script finds its field by
    script = html.split('onerror="', 1)[1].rsplit('"', 1)[0]
    assert '"' not in script and "\n" not in script and "INTERVAL" not in script
    assert str(hover.RELAY_INTERVAL_MS) in script


def test_labels_give_the_coordinates_in_the_designs_unit_to_a_ten_thousandth_of_the_span():
    # the manta ray's joint 81, 20 m from the origin on a 2317 mm span: "(2.078e+04, -7852)" with 4 significant digits
    assert hover.flat_label(81, (20781.34, -7852.37), 2316.9) == "joint 81  (20781.3, -7852.4)"
    assert hover.flat_label(40, (0.629312, 0.48241), 2.0) == "joint 40  (0.6293, 0.4824)"  # a unit-sized layout
    assert hover.height_label(5, 304.6921, 2316.9) == "joint 5  (height 304.7)"
    assert [hover.decimals(s) for s in (2e4, 1e4, 2316.9, 100.0, 2.0, 0.0, float("nan"))] == [0, 0, 1, 2, 4, 4, 4]
