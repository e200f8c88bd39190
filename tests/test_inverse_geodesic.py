"""The geodesic net: curves that run straight on the surface, joints found by a flood fill."""
import numpy as np
import pytest

from test_inverse_surface import grid
from xshells.cli import main
from xshells.inverse.flatten import chart
from xshells.inverse.geodesic import MAX_SEGMENT, MIN_SEGMENT, geodesic_net_quads, trace_geodesics
from xshells.inverse.graded import _Field, _Projector
from xshells.inverse.scissor import scissor_map
from xshells.inverse.surface import check_target

R = 2000.0
K = 350.0 / 1200.0**2  # the shared hypar's z = K (x² − y²)


def _sphere(size=1600.0, radius=R, n=41):
    return check_target(*grid(n=n, size=size, height=lambda x, y: np.sqrt(radius**2 - x**2 - y**2) - radius))


def _hypar(n=49):
    return check_target(*grid(n=n, size=2400.0, height=lambda x, y: K * (x**2 - y**2)))


def _trace_from_centre(surface, angle_deg, spacing=100.0):
    """One geodesic through the origin leaving at ``angle_deg`` from the x axis."""
    project = _Projector(surface)
    centre = project(np.zeros((1, 3)))[0]
    field = _Field(np.array([1.0, 0.0, 0.0]), centre[0], 1.0, np.radians(2 * angle_deg), 0.0)
    (curve,), _ = trace_geodesics(project, field, centre, +1.0, spacing / 8.0, 1000)
    return curve


def _net(surface, spacing, angle_deg=90.0):
    m = scissor_map(surface, np.radians(angle_deg), np.radians(20))
    to_chart = chart(surface, m)
    return geodesic_net_quads(surface, lambda P: to_chart(P)[0], np.array([1.0, 0.0, 0.0]), np.radians(angle_deg),
                              spacing)


def test_a_geodesic_on_a_plane_is_a_straight_line():
    c = _trace_from_centre(check_target(*grid(n=21, size=1000.0)), 30.0)
    d = np.array([np.cos(np.radians(30)), np.sin(np.radians(30)), 0.0])
    off = c - np.outer(c @ d, d)
    assert np.ptp(c @ d) > 900  # it crosses the square
    assert np.abs(off).max() < 1e-9 * 1000


def test_a_geodesic_on_a_sphere_is_a_great_circle():
    # a great circle lies in a plane through the sphere's centre (0, 0, −R); a latitude-like curve would not
    c = _trace_from_centre(_sphere(), 30.0)
    rel = c - np.array([0.0, 0.0, -R])
    normal = np.linalg.svd(rel, full_matrices=False)[2][-1]
    assert np.ptp(c[:, 0]) > 1000
    # the mesh is a chordal approximation (sagitta of a 40 mm chord on R = 2000: 0.1 mm); the last point at
    # each end is the step that crossed the boundary, projected back onto it (sideways by up to a millimetre)
    assert np.abs(rel[1:-1] @ normal).max() < 0.2


def test_a_geodesic_on_a_sphere_is_not_the_graded_curve():
    # the same start, traced along a fixed field instead: it bends away from the great circle's plane
    from xshells.inverse.graded import _trace

    s = _sphere()
    project = _Projector(s)
    centre = project(np.zeros((1, 3)))[0]
    field = _Field(np.array([1.0, 0.0, 0.0]), centre[0], 1.0, np.radians(60.0), 0.0)
    (curve,), _ = _trace(project, field, centre, +1.0, 12.5, 1000)
    rel = curve - np.array([0.0, 0.0, -R])
    normal = np.linalg.svd(rel, full_matrices=False)[2][-1]
    assert np.abs(rel @ normal).max() > 5.0


@pytest.mark.parametrize("angle", [45.0, -45.0])
def test_on_a_hypar_the_geodesics_at_45_degrees_are_its_rulings(angle):
    # z = K (x² − y²) holds the straight lines y = ±x (z = 0): they are geodesics, so the traced curve is one
    c = _trace_from_centre(_hypar(), angle)
    d = np.array([1.0, np.sign(angle), 0.0]) / np.sqrt(2)
    off = c - np.outer(c @ d, d)
    assert np.ptp(c @ d) > 2000
    # y = x runs along the grid's diagonals (exact); y = −x cuts across triangles, whose linear interpolant
    # of z sags by up to K h² / 4 ≈ 0.15 mm (h = 50 mm)
    assert np.abs(off).max() < 0.3


def test_on_a_plane_the_geodesic_net_is_the_uniform_grid():
    s = check_target(*grid(n=25, size=1200.0))
    X, S = _net(s, 100.0)
    L = np.linalg.norm(X[S[:, 1]] - X[S[:, 0]], axis=1)
    assert np.allclose(L, 100.0, rtol=1e-6)
    deg = np.bincount(S.ravel(), minlength=len(X))
    assert deg.max() == 4 and deg.min() == 2


@pytest.mark.parametrize("surface", ["hypar", "dome"])
def test_segments_stay_within_bounds_where_geodesics_spread_or_gather(surface):
    # a steep dome (R = 1000 over 1600 × 1600) makes its geodesics gather: the flood fill drops the short
    # segments and keeps one piece of valence-4 (at most) joints on the surface
    s = _hypar() if surface == "hypar" else _sphere(size=1300.0, radius=1000.0)
    spacing = 150.0
    X, S = _net(s, spacing)
    chord = np.linalg.norm(X[S[:, 1]] - X[S[:, 0]], axis=1)
    assert len(S) > 60
    assert chord.max() <= MAX_SEGMENT * spacing
    assert chord.min() >= 0.9 * MIN_SEGMENT * spacing  # a chord is a little shorter than its arc
    assert np.bincount(S.ravel()).max() <= 4
    import igl

    sq, _, _ = igl.point_mesh_squared_distance(X, s.V, s.F)
    assert np.sqrt(sq).max() <= 1e-9 * s.diagonal
    # one piece: every joint reachable from joint 0
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    A = sp.coo_matrix((np.ones(len(S)), (S[:, 0], S[:, 1])), shape=(len(X), len(X)))
    assert connected_components(A, directed=False)[0] == 1


def test_on_the_hypar_spacings_vary_where_the_evenly_spaced_net_keeps_them():
    # geodesics spread on a saddle: joint spacings along the beams grow away from the middle line
    X, S = _net(_hypar(), 250.0)
    L = np.linalg.norm(X[S[:, 1]] - X[S[:, 0]], axis=1)
    assert L.max() / L.min() > 1.1


@pytest.mark.parametrize("extra, needle", [
    (["--beams", "geodesic", "--grading", "-25"], "--grading"),
    (["--beams", "geodesic", "--net", "NET"], "--beams"),
])
def test_geodesic_beams_and_options_that_shape_another_net_are_one_line(tmp_path, capsys, extra, needle):
    net = tmp_path / "net.obj"
    net.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    V, F = grid(n=21, size=1200.0, height=lambda x, y: K * (x**2 - y**2))
    surf = tmp_path / "hypar.obj"
    surf.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in V) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))
    extra = [str(net) if e == "NET" else e for e in extra]
    code = main(["inverse", str(surf), *extra, "--out", str(tmp_path / "o"), "--no-progress"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0]
