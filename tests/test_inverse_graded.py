"""The graded net: curves traced on the surface, crossing at the graded angle, growing to cover it."""
import json

import numpy as np
import pytest

from data_paths import EXAMPLES
from test_inverse_surface import grid
from xshells.cli import main
from xshells.inverse.flatten import chart, net_from_arrays
from xshells.inverse.graded import graded_net_quads
from xshells.inverse.metrics import coverage
from xshells.inverse.scissor import scissor_map
from xshells.inverse.surface import check_target

CAP = EXAMPLES / "targets" / "spherical_cap_R2000_30deg.obj"


def _net(surface, spacing, grading_deg, angle_deg=90.0):
    m = scissor_map(surface, np.radians(angle_deg), np.radians(20))
    to_chart = chart(surface, m)
    axis = np.array([1.0, 0.0, 0.0])
    X, S = graded_net_quads(surface, lambda P: to_chart(P)[0], axis, np.radians(angle_deg), spacing,
                            np.radians(grading_deg))
    return X, S, net_from_arrays(X, S, surface, m, np.radians(20), "test net")


@pytest.fixture(scope="module")
def plane():
    return check_target(*grid(n=25, size=1200.0))


def test_ungraded_on_a_plane_is_the_uniform_grid(plane):
    X, S, net = _net(plane, 100.0, 0.0)
    L = net.segment_lengths()
    assert np.allclose(L, 100.0, rtol=1e-6)  # straight curves on a plane, seeds 2 s sin(α/2) apart
    deg = np.bincount(S.ravel(), minlength=len(X))
    assert deg.max() == 4 and deg.min() == 2


def test_graded_crossings_follow_the_angle_profile(plane):
    X, S, net = _net(plane, 100.0, -25.0)
    # the joints on the middle line (x ≈ 0) cross at α + Δ = 65°, the farthest at about α − Δ = 115°
    fam = net.family
    angles = []
    for j in range(len(X)):
        inc = S[(S == j).any(axis=1)]
        f = fam[(S == j).any(axis=1)]
        if len(inc) != 4:
            continue
        d = [X[s[1] if s[0] == j else s[0]] - X[j] for s in inc]
        a = [v / np.linalg.norm(v) for v, k in zip(d, f) if k == 0]
        b = [v / np.linalg.norm(v) for v, k in zip(d, f) if k == 1]
        ta, tb = a[0] - a[1], b[0] - b[1]  # central-difference tangents of the two beams
        c = abs(ta @ tb) / np.linalg.norm(ta) / np.linalg.norm(tb)
        angles.append((X[j, 0], np.degrees(np.arccos(c))))
    angles = np.array(angles)
    # ω(x) = α + Δ (1 − 2 (x / d_max)²) with d_max = 600, the half-width; chords measure the acute angle
    omega = 90.0 - 25.0 * (1.0 - 2.0 * (angles[:, 0] / 600.0) ** 2)
    acute = np.minimum(omega, 180.0 - omega)
    assert len(angles) > 50
    assert np.abs(angles[:, 1] - acute).max() < 4.0
    assert angles[np.abs(angles[:, 0]) < 60, 1].max() < 70.0  # narrow on the middle line


def test_grading_puts_chebyshev_defects_into_the_net(plane):
    def median_defect(net):
        X, S = net.joints, net.segments
        # A quad's opposite sides are not kept as such (the flat layout's grid of labels is gone), so
        # each segment is paired with the nearest segment of its own family: the one a joint row over.
        L = net.segment_lengths()
        mids = 0.5 * (X[S[:, 0]] + X[S[:, 1]])
        out = []
        for fam in (0, 1):
            idx = np.flatnonzero(net.family == fam)
            for i in idx:
                d = np.linalg.norm(mids[idx] - mids[i], axis=1)
                d[idx == i] = np.inf
                k = idx[np.argmin(d)]
                out.append(abs(L[i] - L[k]) / L[i])
        return float(np.median(out))

    flat_grid = median_defect(_net(plane, 100.0, 0.0)[2])
    graded = median_defect(_net(plane, 100.0, -25.0)[2])
    assert flat_grid < 1e-6
    assert graded > 0.02  # the paper's layouts: about 7 % median


def test_the_net_grows_to_cover_a_square_whose_diamond_would_not(plane):
    # seeded on the middle line only, a 90° net covers the inscribed diamond: half the square
    X, S, _ = _net(plane, 100.0, 0.0)
    assert coverage(plane, X, S, 75.0) >= 0.9


def test_joints_lie_on_a_curved_surface():
    V, F = grid(n=31, size=1600.0, height=lambda x, y: np.sqrt(2000.0**2 - x**2 - y**2) - 2000.0)
    s = check_target(V, F)
    X, S, _ = _net(s, 200.0, -25.0)
    import igl

    sq, _, _ = igl.point_mesh_squared_distance(X, s.V, s.F)
    assert np.sqrt(sq).max() <= 1e-9 * s.diagonal
    assert np.bincount(S.ravel()).max() <= 4


def test_a_grading_that_leaves_the_angle_range_is_one_line(tmp_path, capsys):
    code = main(["inverse", str(CAP), "--grading", "95", "--out", str(tmp_path / "o"), "--no-progress"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--grading 95" in err[0]


def test_grading_and_a_given_net_are_one_line(tmp_path, capsys):
    net = tmp_path / "net.obj"
    net.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    code = main(["inverse", str(CAP), "--grading", "-25", "--net", str(net), "--out", str(tmp_path / "o"),
                 "--no-progress"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--grading" in err[0] and "--net" in err[0]


def test_graded_inverse_design_of_the_cap_is_valid_and_rises(tmp_path, monkeypatch):
    import dataclasses

    import xshells.inverse.guide as guide

    # the graded net is the subject, not the fit: three short stages (the whole schedule took 50-80 s of the suite),
    # and no heavier designs (they run in workers, without the short stages)
    real = guide.guided_optimization
    monkeypatch.setattr(guide, "guided_optimization", lambda problem, hold, options, **kw: real(
        problem, hold, dataclasses.replace(options, schedule=(0.5, 0.15, 0.0), iterations=4, final_iterations=8), **kw))
    out = tmp_path / "cap"
    diag = float(np.linalg.norm([1918.0, 1918.0, 266.0]))
    # with its progress bars, as a user runs it (the graded net's bar counts curves, with no total)
    main(["inverse", str(CAP), "--grading", "-25", "--spacing", f"{diag / 8:.3f}", "--no-heavier", "--out", str(out)])
    r = json.loads((out / "result.json").read_text())
    assert r["valid"], r["message"]
    assert r["flat_planarity"] <= 1e-6 and not r["folded"] and not r["overlap"]
    assert r["min_eigenvalue_at_fixed_angle"] >= 0
    assert np.ptp(np.array(r["deployed_joints"])[:, 2]) > 100  # it rises onto the cap
    assert r["grading_deg"] == -25.0
