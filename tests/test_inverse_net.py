"""Beam nets on a surface: spacing, crossing angle, valence, and the flat positions that keep the lengths."""
import numpy as np
import pytest

from test_inverse_surface import grid
from xshells.errors import InputError
from xshells.inverse.net import read_net, surface_net
from xshells.inverse.scissor import scissor_map
from xshells.inverse.surface import check_target


@pytest.fixture(scope="module")
def plane_net():
    s = check_target(*grid(n=13, size=1200.0))
    m = scissor_map(s, np.radians(90), np.radians(20))
    return s, surface_net(s, m, np.radians(90), 100.0)


def test_segments_are_spacing_long_and_cross_at_the_angle(plane_net):
    s, net = plane_net
    L = net.segment_lengths()
    assert np.allclose(L, 100.0, rtol=1e-6)  # a plane: exact
    deg = np.bincount(net.segments.ravel(), minlength=net.num_joints)
    assert deg.max() <= 4 and deg.min() >= 2
    a = [net.joints[b] - net.joints[a] for a, b in net.segments[net.family == 0][:1]]
    c = [net.joints[b] - net.joints[a] for a, b in net.segments[net.family == 1][:1]]
    cosang = abs(np.dot(a[0], c[0])) / (np.linalg.norm(a[0]) * np.linalg.norm(c[0]))
    assert np.degrees(np.arccos(cosang)) == pytest.approx(90.0, abs=1e-6)


def test_flat_positions_keep_the_lengths_and_close_the_angle(plane_net):
    s, net = plane_net
    assert np.allclose(net.segment_lengths(flat=True), net.segment_lengths(), rtol=1e-6)
    f0 = net.flat[net.segments[net.family == 0][0]]
    f1 = net.flat[net.segments[net.family == 1][0]]
    u, v = f0[1] - f0[0], f1[1] - f1[0]
    ang = np.degrees(np.arccos(abs(u @ v) / np.linalg.norm(u) / np.linalg.norm(v)))
    assert ang == pytest.approx(20.0, abs=1e-6)


def test_the_net_covers_the_surface(plane_net):
    s, net = plane_net
    assert np.ptp(net.joints[:, 0]) > 0.8 * 1200 and np.ptp(net.joints[:, 1]) > 0.8 * 1200


def test_read_net_accepts_quads_and_lines_and_refuses_other_faces(tmp_path):
    p = tmp_path / "q.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nf 1 2 3 4\nf 2 5 6 3\n")
    V, S = read_net(p)
    assert len(V) == 6 and len(S) == 7
    t = tmp_path / "t.obj"
    t.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match=r"t.obj:4: a face with 3 sides"):
        read_net(t)
    star = tmp_path / "star.obj"
    star.write_text("v 0 0 0\n" + "".join(f"v {np.cos(a):.3f} {np.sin(a):.3f} 0\n" for a in np.linspace(0, 6, 5)) +
                    "".join(f"l 1 {k}\n" for k in range(2, 7)))
    with pytest.raises(InputError, match="vertex 1 has 5 segments"):
        read_net(star)


def test_a_designers_net_is_flattened_with_its_lengths_and_closed_to_the_flat_angle(tmp_path):
    from xshells.inverse.flatten import net_from_file

    s = check_target(*grid(n=13, size=1200.0, height=lambda x, y: -(x**2 + y**2) / 6000.0))
    m = scissor_map(s, np.radians(90), np.radians(20))
    auto = surface_net(s, m, np.radians(90), 150.0)
    path = tmp_path / "net.obj"
    path.write_text("".join("v %.9g %.9g %.9g\n" % tuple(p) for p in auto.joints) +
                    "".join(f"l {a + 1} {b + 1}\n" for a, b in auto.segments))
    net = net_from_file(path, s, m, np.radians(20))
    ratio = net.segment_lengths(flat=True) / net.segment_lengths()
    assert np.abs(ratio - 1).max() < 0.01
    a = net.flat[net.segments[net.family == 0][0]]
    b = net.flat[net.segments[net.family == 1][0]]
    u, v = a[1] - a[0], b[1] - b[0]
    ang = np.degrees(np.arccos(abs(u @ v) / np.linalg.norm(u) / np.linalg.norm(v)))
    assert 15 < ang < 25


def test_a_net_far_from_the_surface_is_refused(tmp_path):
    from xshells.inverse.flatten import net_from_file

    s = check_target(*grid(n=7, size=1000.0))
    m = scissor_map(s, np.radians(90), np.radians(20))
    path = tmp_path / "far.obj"
    path.write_text("v 0 0 500\nv 100 0 500\nv 100 100 500\nv 0 100 500\nf 1 2 3 4\n")
    with pytest.raises(InputError, match="vertex 1 lies 500 from the surface"):
        net_from_file(path, s, m, np.radians(20))


def test_close_like_turns_beam_b_around_where_the_start_reads_the_supplement():
    from xshells.inverse.flatten import close_like

    c, s = np.cos(np.radians(10)), np.sin(np.radians(10))
    start = np.array([[0, 0], [-c, -s], [c, s], [c, -s], [-c, s]], float)  # joint 0; beam A 1-0-2, beam B 3-0-4
    nbr = -np.ones((5, 2, 2), np.int64)
    nbr[0] = [[1, 2], [3, 4]]  # B runs from lower right to upper left: A and B read 160°
    out = close_like(nbr, start)
    assert out[0].tolist() == [[1, 2], [4, 3]]
    assert close_like(out, start)[0].tolist() == [[1, 2], [4, 3]]  # already closing the small angle: kept


@pytest.mark.parametrize("deployed", [70.0, 120.0])
def test_a_designers_net_deployed_past_90_degrees_closes_its_own_angle(deployed):
    """A net crossing at 120° on the surface reads 60° from its 3D geometry: its layout must still close the
    120° (the layout the scissor map gives, up to a rigid motion), not fold into the other 20° layout."""
    from xshells.inverse.flatten import flat_crossing_angles, net_from_arrays

    s = check_target(*grid(n=13, size=1200.0, height=lambda x, y: -(x**2 + y**2) / 6000.0))
    m = scissor_map(s, np.radians(deployed), np.radians(20))
    auto = surface_net(s, m, np.radians(deployed), 150.0)
    net = net_from_arrays(auto.joints, auto.segments, s, m, np.radians(20), "the net", follow_start=True)
    assert np.abs(net.segment_lengths(flat=True) / net.segment_lengths() - 1).max() < 0.01
    ang = np.degrees(flat_crossing_angles(net))
    assert np.all((ang > 15) & (ang < 25)), (ang.min(), ang.max())
    A, B = net.flat - net.flat.mean(axis=0), auto.flat - auto.flat.mean(axis=0)
    U, _, Vt = np.linalg.svd(A.T @ B)
    assert np.abs(A @ (U @ Vt) - B).max() < 0.01 * np.ptp(B, axis=0).max()  # folded the other way: 41 %


def test_a_nets_bisector_is_that_of_the_angle_nearest_the_deployed_one():
    from xshells.inverse.flatten import net_bisector

    a, b = np.array([np.cos(np.pi / 3), np.sin(np.pi / 3), 0]), np.array([np.cos(np.pi / 3), -np.sin(np.pi / 3), 0])
    n = 5
    X = np.array([100.0 * (i * a + j * b) for i in range(n) for j in range(n)])  # beams crossing at 120° and 60°
    idx = np.arange(n * n).reshape(n, n)
    S = np.r_[np.c_[idx[:-1].ravel(), idx[1:].ravel()], np.c_[idx[:, :-1].ravel(), idx[:, 1:].ravel()]]
    assert abs(net_bisector(X, S, np.radians(120))[0]) == pytest.approx(1.0, abs=1e-9)  # opens about x
    assert abs(net_bisector(X, S, np.radians(60))[1]) == pytest.approx(1.0, abs=1e-9)  # the other angle: about y
    assert abs(net_bisector(X[:, [1, 0, 2]], S, np.radians(110))[1]) == pytest.approx(1.0, abs=1e-9)


# ---------------------------------------------------------------- recheck34: --net input faults
def test_a_net_vertex_with_two_coordinates_is_named_by_line(tmp_path):
    # "v 0 0" made a ragged array: an internal ValueError
    p = tmp_path / "n2.obj"
    p.write_text("v 0 0 0\nv 1 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    with pytest.raises(InputError, match=r"n2.obj:2: a vertex needs three numbers \(x y z\), got 2"):
        read_net(p)


def _quad_grid_obj(n=4):
    verts = "".join(f"v {100.0 * i} {100.0 * j} 0\n" for i in range(n) for j in range(n))
    faces = "".join(f"f {i * n + j + 1} {(i + 1) * n + j + 1} {(i + 1) * n + j + 2} {i * n + j + 2}\n"
                    for i in range(n - 1) for j in range(n - 1))
    return verts + faces


def test_a_net_with_a_diagonal_is_refused_naming_the_triangles_joints(tmp_path):
    # a quad grid plus one diagonal between two boundary joints ran to a late "stopped"
    p = tmp_path / "diag.obj"
    p.write_text(_quad_grid_obj() + "l 2 5\n")
    ok = tmp_path / "ok.obj"
    ok.write_text(_quad_grid_obj())
    V, S = read_net(ok)
    assert len(V) == 16 and len(S) == 24
    with pytest.raises(InputError, match=r"diag.obj:26: vertices 1, 2 and 5 form a triangle") as exc:
        read_net(p)
    assert "\n" not in str(exc.value)
    pent = tmp_path / "pent.obj"  # a pentagon given as a face is refused by its side count
    pent.write_text("v 0 0 0\nv 1 0 0\nv 1.5 1 0\nv 0.5 1.5 0\nv -0.5 1 0\nf 1 2 3 4 5\n")
    with pytest.raises(InputError, match=r"pent.obj:6: a face with 5 sides"):
        read_net(pent)


def test_estimate_segments_is_a_float_and_does_not_overflow_for_a_tiny_spacing():
    # spacing 1e-300 raised OverflowError (int(round(inf))) before the "more than 5,000 segments" check
    from xshells.inverse.net import estimate_segments

    s = check_target(*grid(n=4, size=1000.0))
    assert estimate_segments(s, 100.0, np.radians(90)) == 200.0
    n = estimate_segments(s, 1e-300, np.radians(90))
    assert isinstance(n, float) and n > 5000


def test_a_disconnected_net_names_its_file_once(tmp_path):
    from xshells.inverse.flatten import net_from_file

    s = check_target(*grid(n=7, size=1000.0))
    m = scissor_map(s, np.radians(90), np.radians(20))
    one = "v 0 0 0\nv 100 0 0\nv 100 100 0\nv 0 100 0\n"
    two = "v 300 300 0\nv 400 300 0\nv 400 400 0\nv 300 400 0\n"
    p = tmp_path / "two.obj"
    p.write_text(one + two + "f 1 2 3 4\nf 5 6 7 8\n")
    with pytest.raises(InputError) as exc:
        net_from_file(p, s, m, np.radians(20))
    msg = str(exc.value)
    assert msg.count(str(p)) == 1 and "disconnected" in msg, msg
