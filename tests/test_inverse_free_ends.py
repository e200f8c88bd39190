"""Free ends (xshells.inverse.free_ends): beams continued to the boundary, hand-computed on a square."""
from types import SimpleNamespace

import numpy as np
import pytest

from xshells.inverse.free_ends import MAX_LENGTH, add_free_ends, attach, beam_ends
from xshells.inverse.net import Net
from xshells.inverse.surface import TargetSurface


def _square(n=10, size=10.0):
    """The square [0, size]² in the plane z = 0, triangulated; its chart is itself."""
    x = np.linspace(0, size, n + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    V = np.c_[X.ravel(), Y.ravel(), np.zeros(X.size)]
    idx = np.arange(X.size).reshape(X.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.r_[np.c_[a, b, c], np.c_[a, c, d]].astype(np.int64)
    S = TargetSurface(V, F, "square", float(np.hypot(size, size)), size * size)
    return S, SimpleNamespace(flat=V[:, :2].copy())


def _grid(xs, ys, shear=0.0):
    """Joints at xs × ys; family 0 runs along x, family 1 along y. Flat positions sheared by ``shear``."""
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    P = np.c_[X.ravel(), Y.ravel(), np.zeros(X.size)]
    idx = np.arange(X.size).reshape(X.shape)
    segs = np.r_[np.c_[idx[:-1, :].ravel(), idx[1:, :].ravel()], np.c_[idx[:, :-1].ravel(), idx[:, 1:].ravel()]]
    fam = np.r_[np.zeros(idx[:-1, :].size), np.ones(idx[:, :-1].size)].astype(np.int64)
    flat = np.c_[P[:, 0] + shear * P[:, 1], P[:, 1]]
    return Net(P, flat, segs.astype(np.int64), fam)


def test_beam_ends_are_the_joints_with_one_segment_of_a_family():
    net = _grid([1.0, 4.0, 7.0], [0.5, 3.5, 6.5, 9.5])
    ends = beam_ends(net)
    assert len(ends) == 2 * 4 + 2 * 3  # each of the 4 x-beams and the 3 y-beams has two ends
    for j, o, f in ends:
        assert ((net.segments == [j, o]) | (net.segments == [o, j])).all(1)[net.family == f].sum() == 1


def test_each_beam_runs_on_to_the_boundary_or_max_length_and_short_ones_are_dropped():
    S, smap = _square()
    spacing = 3.0
    net = _grid([1.0, 4.0, 7.0], [0.5, 3.5, 6.5, 9.5], shear=0.2)
    out = add_free_ends(net, S, smap, spacing)
    k = net.num_joints
    assert np.array_equal(out.joints[:k], net.joints) and np.array_equal(out.segments[:len(net.segments)], net.segments)
    new = out.segments[len(net.segments):]
    ends = out.joints[k:]
    # the y-beams end 0.5 from the boundary, under MIN_LENGTH (0.25 spacings = 0.75): no free end;
    # each x-beam runs on by 1 to x = 0 and by MAX_LENGTH spacings (2.7 < 3) to x = 9.7
    assert len(ends) == 8 and (out.family[len(net.segments):] == 0).all()
    assert np.sort(ends[:, 0]) == pytest.approx([0.0] * 4 + [7.0 + MAX_LENGTH * spacing] * 4, abs=1e-6)
    assert np.allclose(sorted(ends[:, 1]), np.repeat([0.5, 3.5, 6.5, 9.5], 2))
    # the segments run along their beams (0 → 1 in the family's direction), the new points are free ends
    for a, b in new:
        assert out.joints[b, 0] > out.joints[a, 0]
    assert (np.bincount(out.segments.ravel()) == 1).sum() == 8  # each new point ends one segment: a free end
    # flat: the beam's last flat segment continued by the same length (the shear keeps flat x-beams along x)
    L3 = np.linalg.norm(out.joints[new[:, 1]] - out.joints[new[:, 0]], axis=1)
    L2 = np.linalg.norm(out.flat[new[:, 1]] - out.flat[new[:, 0]], axis=1)
    assert np.allclose(L3, L2) and np.allclose(out.flat[k:, 1], ends[:, 1])


def test_a_net_reaching_the_boundary_everywhere_is_returned_as_it_is():
    S, smap = _square()
    net = _grid([0.0, 5.0, 10.0], [0.0, 5.0, 10.0])
    assert add_free_ends(net, S, smap, 5.0) is net


def test_attach_continues_each_last_segment_by_its_length_in_the_beams_direction():
    from xshells.inverse.free_ends import FreeEnds

    P = np.array([[0.0, 0.0], [3.0, 4.0], [6.0, 8.0]])  # one beam 0 → 1 → 2, segments of length 5
    segs = np.array([[0, 1], [1, 2]])
    ends = FreeEnds(joint=np.array([2, 0]), previous=np.array([1, 1]), family=np.array([0, 0]),
                    length=np.array([2.5, 1.0]), point=np.zeros((2, 3)), outward=np.array([True, False]))
    Q, S, p = attach(P, segs, ends, np.array([5.0, 5.0]))
    assert np.allclose(Q[3], [7.5, 10.0]) and np.allclose(Q[4], [-0.6, -0.8])
    assert S.tolist() == [[0, 1], [1, 2], [2, 3], [4, 0]]  # both run along the beam, 4 → 0 → 1 → 2 → 3
    assert p.tolist() == [5.0, 5.0, 2.5, 1.0]


def test_free_ends_that_cross_another_beam_without_a_joint_are_named():
    """recheck 34: free ends crossing a beam of the other family in the flat layout were kept, the result valid."""
    from xshells.inverse.free_ends import crossing_ends

    P = np.array([[0, 0], [2, 0], [1, 1], [1, 2], [1, 3], [1, -1], [3, 0], [3, -0.5]], float)
    beams = [[0, 1], [2, 3]]
    ends = [[3, 4],  # runs on along its beam: clear
            [2, 5],  # across beam 0 at (1, 0), no joint there
            [1, 6],  # on from beam 0's end: shares its node
            [0, 7]]  # across the free end [2, 5]: the later of the two is named
    assert crossing_ends(P, np.array(beams + ends), 2).tolist() == [1, 3]
    assert crossing_ends(P, np.array(beams + ends[:1]), 2).tolist() == []
    assert crossing_ends(P, np.array(beams), 2).tolist() == []


def test_the_length_cap_holds_on_the_surface_where_the_chart_shortens_lengths():
    """The chart is the square shrunk four times along x: a chart length of 0.9 spacings along x is 3.6 on the
    surface (a fanned net's free ends on the barrel vault ran 3.7 spacings). The cap is on the surface."""
    S, smap = _square(size=40.0)
    smap.flat[:, 0] *= 0.25
    spacing = 3.0
    net = _grid([1.0, 4.0, 7.0], [10.0, 13.0, 16.0])  # the x-beams end at x = 7, 33 from the boundary
    out = add_free_ends(net, S, smap, spacing)
    k = net.num_joints
    L = np.linalg.norm(out.joints[k:] - out.joints[out.segments[len(net.segments):, 0]], axis=1)
    assert len(L) and L.max() <= MAX_LENGTH * spacing * (1 + 1e-9)
    right = out.joints[k:, 0] > 7.0
    assert right.sum() == 3 and out.joints[k:][right, 0] == pytest.approx(7.0 + MAX_LENGTH * spacing, rel=1e-6)
