"""Fanned nets (xshells.inverse.fanned): straight flat lines, the fan's angle profile, lengths kept on the surface."""
import numpy as np
import pytest

from data_paths import EXAMPLES
from xshells.errors import InputError
from xshells.inverse.fanned import ChartLift, FanLines, fanned_net, first_deployment_fit, screen_fans
from xshells.inverse.scissor import scissor_map
from xshells.inverse.surface import load_target

CAP = EXAMPLES / "targets" / "spherical_cap_R2000_30deg.obj"


def _lines(kappa):
    # a lattice closed to 20° about the x axis: steps of 100 along the two beam directions
    h = np.radians(10.0)
    a, b = 100 * np.array([np.cos(h), np.sin(h)]), 100 * np.array([np.cos(h), -np.sin(h)])
    return FanLines(origin=np.zeros(2), a=a, b=b, axis=np.array([1.0, 0.0]), centre=np.zeros(2), half=1000.0,
                    mid=0.0, kappa=kappa)


def test_no_fan_is_the_affine_lattice():
    L = _lines(0.0)
    i, j = np.meshgrid(np.arange(-4, 5), np.arange(-4, 5), indexing="ij")
    P = L.points(i.ravel(), j.ravel())
    assert np.allclose(P, i.ravel()[:, None] * L.a + j.ravel()[:, None] * L.b, atol=1e-9)


def test_a_fan_keeps_every_beam_straight_and_opens_its_middle_lines_more():
    L = _lines(0.3)
    for fixed in (-6, 0, 3):
        k = np.arange(-5, 6)
        for P in (L.points(k, np.full_like(k, fixed)), L.points(np.full_like(k, fixed), k)):  # both families
            c = P - P.mean(0)
            assert np.linalg.svd(c, compute_uv=False)[1] <= 1e-9 * np.abs(c).max()  # collinear
    # the family-0 line through the axis' middle (j = 0 crosses it at x = 0) leaves it at 10° × (1 + 0.3)
    d = np.diff(L.points(np.array([-1, 1]), np.array([0, 0])), axis=0)[0]
    assert np.degrees(np.arctan2(d[1], d[0])) == pytest.approx(13.0, abs=1e-9)
    # a line crossing the axis at the footprint's end (x = 1000): j such that j*b crosses there
    base = np.array([1000.0, 0.0])
    p, d = L._line(base[None], L.a)
    assert np.degrees(np.arctan2(d[0, 1], d[0, 0])) == pytest.approx(7.0, abs=1e-9)
    p, d = L._line(np.array([[3000.0, 0.0]]), L.a)  # beyond the footprint: the end angle, not a reversed one
    assert np.degrees(np.arctan2(d[0, 1], d[0, 0])) == pytest.approx(7.0, abs=1e-9)


@pytest.fixture(scope="module")
def cap():
    surf = load_target(CAP)
    smap = scissor_map(surf, np.radians(90.0), np.radians(20.0), 0.0)
    return surf, smap


def test_the_chart_lift_derivative_matches_finite_differences(cap):
    surf, smap = cap
    lift = ChartLift(surf, smap)
    rng = np.random.default_rng(3)
    u = smap.flat[surf.F[rng.integers(0, len(surf.F), 20)]].mean(axis=1)  # triangle centroids: away from edges
    X, M = lift.jacobian(u)
    h = 1e-4 * np.ptp(smap.flat, axis=0).max()
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        fd = (lift(u + e)[0] - lift(u - e)[0]) / (2 * h)
        assert np.abs(fd - M[:, :, k]).max() <= 1e-6 * np.abs(M).max()
    assert np.abs(lift(u)[1]).max() <= 1e-9 * h and not lift.outside(u).any()  # inside the chart


@pytest.mark.parametrize("kappa", [0.0, 0.15])
def test_the_net_keeps_its_flat_lengths_on_the_surface(cap, kappa):
    from xshells.inverse.flatten import flat_crossing_angles
    from xshells.inverse.metrics import coverage, surface_distances

    surf, smap = cap
    s = surf.diagonal / 10
    net = fanned_net(surf, smap, np.radians(90.0), s, kappa)
    L3, Lf = net.segment_lengths(), net.segment_lengths(flat=True)
    assert np.median(np.abs(L3 / Lf - 1)) < 0.005 and np.abs(L3 / Lf - 1).max() < 0.03
    assert surface_distances(surf, net.joints).max() <= 0.35 * s
    assert coverage(surf, net.joints, net.segments, 0.75 * s) >= 0.9
    a = np.degrees(flat_crossing_angles(net))
    if kappa == 0.0:
        assert np.ptp(a) < 1e-6  # a uniform grid: one angle everywhere
    else:
        assert a.max() > 20.0 * 1.1 and a.min() < 20.0 * 0.95  # opened in the middle, closed at the ends


def test_bad_fans_are_refused(cap):
    surf, smap = cap
    with pytest.raises(InputError, match="fan"):
        fanned_net(surf, smap, np.radians(90.0), surf.diagonal / 10, 0.5)


def test_the_screen_ranks_its_candidates_by_their_first_deployment(cap):
    from xshells.deploy.case import material_from_spec

    surf, _ = cap
    mat = material_from_spec({"type": "rectangle", "E": 20000, "nu": 0.3, "params": [10, 7]})
    seen = []
    c = screen_fans(surf, mat, 90.0, 20.0, surf.diagonal / 8, kappas=(0.0, 0.15), steps=10, on_candidate=seen.append)
    assert len(c) == len(seen) == 4 and {x.orientation for x in c} == {0.0, 90.0}
    fits = [x.first_fit for x in c if x.first_fit is not None]
    assert fits == sorted(fits) and all(np.isfinite(fits))
    assert all(x.message for x in c if x.first_fit is None)
    # the two bisectors side by side in two processes: the same candidates, in the same order
    seen2 = []
    c2 = screen_fans(surf, mat, 90.0, 20.0, surf.diagonal / 8, kappas=(0.0, 0.15), steps=10, on_candidate=seen2.append,
                     workers=2)
    assert len(seen2) == 4
    assert [(x.kappa, x.orientation, x.segments) for x in c2] == [(x.kappa, x.orientation, x.segments) for x in c]
    assert [x.first_fit or 0.0 for x in c2] == pytest.approx([x.first_fit or 0.0 for x in c], rel=1e-9)


def test_the_cli_refuses_a_fan_without_fanned_beams(capsys, tmp_path):
    from xshells.cli import main

    assert main(["inverse", str(CAP), "--fan", "0.1", "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--fan" in err[0]
    assert main(["inverse", str(CAP), "--beams", "fanned", "--fan", "0.7", "--out", str(tmp_path / "b")]) == 2
    assert "between -0.5 and 0.5" in capsys.readouterr().err


def test_the_screen_ranks_buckled_first_deployments_before_flat_ones_on_a_curved_surface():
    from xshells.inverse.fanned import FLAT_RISE, FanCandidate, screen_rank
    from xshells.inverse.surface import TargetSurface, load_target, plane_deviation

    cap = load_target(EXAMPLES / "targets" / "spherical_cap_R2000_30deg.obj")
    assert plane_deviation(cap) > FLAT_RISE
    h = FLAT_RISE * cap.diagonal
    cands = [FanCandidate(0.1, 0.0, 100, 0.015, 0.0),  # flat, the closest first fit
             FanCandidate(-0.2, 0.0, 90, 0.020, 2.0 * h),  # buckled
             FanCandidate(0.2, 90.0, message="stopped"),  # failed
             FanCandidate(-0.1, 90.0, 95, 0.018, 0.5 * h)]  # rose less than FLAT_RISE: flat
    assert [c.kappa for c in sorted(cands, key=screen_rank(cap))] == [-0.2, 0.1, -0.1, 0.2]
    # on a flat surface the first fit alone ranks them
    V = np.array([[0, 0, 0], [1000, 0, 0], [1000, 1000, 0], [0, 1000, 0]], float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    square = TargetSurface(V, F, "square", float(np.hypot(1000, 1000)), 1e6)
    assert [c.kappa for c in sorted(cands, key=screen_rank(square))] == [0.1, -0.1, -0.2, 0.2]
