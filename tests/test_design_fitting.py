"""The fitting term T of eq. 6: joint faces, target surface, closest points, derivatives."""
from collections import Counter
from types import SimpleNamespace

import numpy as np
import pytest

from xshells.design.fitting import (
    FittingTerm,
    closest_points,
    joint_edges,
    joint_faces,
    planar_faces,
    read_surface,
    read_surface_faces,
    target_surface,
    triangulate_faces,
)
from xshells.errors import InputError
from xshells.io import design_from_arrays, read_design
from xshells.linkage.graph import analyze
from xshells.linkage.grids import rhombic_grid
from xshells.linkage.linkage import Linkage
from xshells.section import Material

from data_paths import EXAMPLES

RECT = Material.uniform("rectangle", [10, 7], E=20000, nu=0.3)
NX, NY, R = 5, 4, 6.0


@pytest.fixture(scope="module")
def grid():
    """A 5 x 4 rhombic grid whose joints are lifted onto the paraboloid z = (x² + y²)/R."""
    L = Linkage(rhombic_grid(NX, NY, 1.0, np.deg2rad(70)), RECT, subdivision=3)
    x = L.get_vars()
    P = L.joint_positions()
    P[:, 2] = (P[:, 0] ** 2 + P[:, 1] ** 2) / R
    x[: L.num_joint_vars].reshape(-1, 9)[:, :3] = P
    L.set_vars(x)
    return L


@pytest.fixture(scope="module", params=["manta_ray.obj", "wiggly_banana_5/flat_opt.msh"])
def real(request):
    return Linkage(read_design(EXAMPLES / request.param), RECT, subdivision=3)


def euler(L, faces):
    return L.num_joints - len(joint_edges(L.graph.segment_joints)) + len(faces)


def polygon_area(xy):
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


# ------------------------------------------------------------ joint faces
def test_grid_faces_are_its_quads(grid):
    faces = joint_faces(grid)
    assert len(faces) == NX * NY
    assert all(len(f) == 4 for f in faces)
    assert euler(grid, faces) == 1
    # Each quad is a grid cell: joints (i, j), (i+1, j), (i+1, j+1), (i, j+1).
    cells = {frozenset(f) for f in faces}
    vid = lambda i, j: i * (NY + 1) + j  # noqa: E731  (joints are the vertices, in order)
    expected = {frozenset((vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)))
                for i in range(NX) for j in range(NY)}
    assert cells == expected


def test_real_design_faces(real):
    faces = joint_faces(real)
    assert euler(real, faces) == 1
    g = real.graph
    flat = np.asarray(g.design.vertices)[g.joint_vertex]
    # Every joint-to-joint edge borders one or two faces, interior ones two.
    use = Counter()
    for f in faces:
        assert len(set(f)) == len(f) >= 3
        for a, b in zip(f, f[1:] + f[:1]):
            use[(min(a, b), max(a, b))] += 1
    assert set(use) == {tuple(e) for e in joint_edges(g.segment_joints).tolist()}
    assert set(use.values()) <= {1, 2}
    # Non-degenerate, all counter-clockwise in the layout plane (z = 0 here).
    assert np.allclose(np.abs(g.layout_normal), [0, 0, 1])
    areas = np.array([polygon_area(flat[f, :2]) for f in faces]) * np.sign(g.layout_normal[2])
    assert areas.min() > 1e-3 * np.median(areas)


def test_planar_faces_mixed_polygons_and_dangling_edges():
    # A square split into a triangle and a pentagon-like quad, with a
    # dangling chain (4 -> 5 -> 6) and a dangling edge inside (0 -> 7).
    xy = np.array([[0, 0], [2, 0], [2, 2], [0, 2], [3, 0], [4, 0], [5, 1], [0.5, 0.5], [1, 2]], float)
    edges = np.array([[0, 1], [1, 2], [2, 8], [8, 3], [3, 0], [0, 8], [1, 4], [4, 5], [5, 6], [0, 7]])
    faces = planar_faces(xy, edges)
    assert sorted(sorted(f) for f in faces) == [[0, 1, 2, 8], [0, 3, 8]]
    assert all(polygon_area(xy[f]) > 0 for f in faces)


def test_hole_faces_are_dropped():
    # A 4 x 4 grid without its centre joint: the four central quads become an octagonal hole.
    d = rhombic_grid(4, 4)
    centre = 2 * 5 + 2
    edges = np.array([e for e in d.edges.tolist() if centre not in e])
    g = analyze(design_from_arrays(d.vertices, edges))
    L = SimpleNamespace(graph=g)
    faces = joint_faces(L)
    assert len(faces) == 12 and all(len(f) == 4 for f in faces)
    every = joint_faces(L, max_sides=None)
    assert sorted(map(len, every)) == [4] * 12 + [8]


def test_crossing_segments_are_an_error():
    bowtie = design_from_arrays(np.array([[0, 0, 0], [1, 1, 0], [1, 0, 0], [0, 1, 0]], float),
                                np.array([[0, 1], [1, 2], [2, 3], [3, 0]]))
    with pytest.raises(InputError, match="cross"):
        joint_faces(SimpleNamespace(graph=analyze(bowtie)))


# --------------------------------------------------------- target surface
def test_triangulation_uses_shorter_diagonal():
    kite = np.array([[0, 0, 0], [2, -1, 0], [4, 0, 0], [2, 1, 0], [-1, 0.5, 0], [-1, -0.5, 0]], float)
    F = triangulate_faces(kite, [[0, 1, 2, 3]])
    assert all({1, 3} <= set(t) for t in F)  # 1-3 (length 2) is shorter than 0-2 (length 4)
    F = triangulate_faces(kite, [[1, 2, 3, 0]])
    assert all({1, 3} <= set(t) for t in F)
    F = triangulate_faces(kite[[1, 2, 3, 0]], [[3, 0, 1, 2]])  # same kite, other numbering
    assert all({0, 2} <= set(t) for t in F)
    F = triangulate_faces(kite, [[0, 5, 1, 2, 3, 4]])  # a hexagon is fanned from its first vertex
    assert len(F) == 4 and all(t[0] == 0 for t in F)
    assert np.allclose(np.cross(kite[F[:, 1]] - kite[F[:, 0]], kite[F[:, 2]] - kite[F[:, 0]])[:, 2] > 0, True)


def test_target_surface_stays_close_to_the_joints(grid):
    P = grid.joint_positions()
    span = np.linalg.norm(np.ptp(P, axis=0))
    V0, F0 = target_surface(grid, subdivisions=0)
    assert np.array_equal(V0, P) and len(F0) == 2 * NX * NY
    V, F = target_surface(grid)
    assert len(F) == 16 * len(F0)
    # Loop subdivision averages vertices: all inside the joints' bounding box.
    lo, hi = P.min(axis=0), P.max(axis=0)
    assert np.all(V >= lo - 1e-12) and np.all(V <= hi + 1e-12)
    C, _ = closest_points(V, F, P)
    assert np.max(np.linalg.norm(C - P, axis=1)) < 0.05 * span
    # The surface still hugs the paraboloid it was sampled from.
    assert np.max(np.abs(V[:, 2] - (V[:, 0] ** 2 + V[:, 1] ** 2) / R)) < 0.02 * span
    # Consistently oriented triangles (normals agree with the layout's +z side).
    nrm = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    assert np.all(nrm[:, 2] * np.sign(grid.graph.layout_normal[2]) > 0)


def test_read_surface(tmp_path):
    import meshio

    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 1]], float)
    F = np.array([[0, 1, 2], [1, 3, 2]])
    for ext in ("obj", "ply", "stl"):
        path = tmp_path / f"surf.{ext}"
        meshio.write(path, meshio.Mesh(V, [("triangle", F)]))
        Vr, Fr = read_surface(path)
        assert Fr.shape == (2, 3)
        assert np.allclose(np.sort(Vr[Fr].reshape(-1, 3), axis=0), np.sort(V[F].reshape(-1, 3), axis=0))


@pytest.mark.parametrize("content,reason", [
    (None, "cannot read"),
    ("solid garbage\n this is not an stl file \x00\x01", "cannot read"),
    ("v 0 0 0\nv 1 0 0\nl 1 2\n", "no triangles"),
    # squares overflow: `optimize` ended in an IndexError, `inverse` called it a zero-area triangle
    ("v 0 0 0\nv 3e300 0 0\nv 0 1 0\nf 1 2 3\n", "vertex 2 has a coordinate of 3e+300: too large"),
])
def test_bad_surface_file_is_one_line_naming_it(tmp_path, content, reason):
    path = tmp_path / ("missing.obj" if content is None else ("bad.stl" if "solid" in content else "lines.obj"))
    if content is not None:
        path.write_text(content)
    with pytest.raises(InputError) as err:
        read_surface(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and reason in msg


def _area(V, F):
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()


def _write_obj(path, V, faces):
    path.write_text("".join(f"v {float(a)!r} {float(b)!r} {float(c)!r}\n" for a, b, c in V)
                    + "".join("f " + " ".join(str(i + 1) for i in f) + "\n" for f in faces))


def test_quads_and_mixed_faces_are_all_read_as_triangles(tmp_path):
    # a 3×3 quad grid on a dome, all quads, and half of them as triangles before the other half (as one
    # exporter wrote it): before, quads were dropped without a word, leaving half the surface
    n = 3
    x, y = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0), indexing="ij")
    V = np.c_[x.ravel(), y.ravel(), 0.2 * (x * (n - x) + y * (n - y)).ravel()]
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    Q = np.c_[idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()]
    _write_obj(tmp_path / "quads.obj", V, Q)
    Vr, Fr, face = read_surface_faces(tmp_path / "quads.obj")
    assert Fr.shape == (2 * len(Q), 3) and list(np.bincount(face)) == [2] * len(Q)
    for q, (a, b) in zip(Q, Fr.reshape(-1, 2, 3)):
        assert set(a) | set(b) == set(q)  # the two halves cover the quad's corners
        d = sorted(set(a) & set(b))  # their shared diagonal is the shorter one
        other = sorted(set(q) - set(d))
        assert np.linalg.norm(Vr[d[0]] - Vr[d[1]]) <= np.linalg.norm(Vr[other[0]] - Vr[other[1]]) + 1e-12
    tri = [(a, b, c) for a, b, c, d in Q[:4]] + [(a, c, d) for a, b, c, d in Q[:4]]
    _write_obj(tmp_path / "mixed.obj", V, tri + [list(q) for q in Q[4:]])
    Vm, Fm, face_m = read_surface_faces(tmp_path / "mixed.obj")
    assert len(Fm) == 2 * len(Q) and face_m.max() == len(tri) + len(Q[4:]) - 1
    assert _area(Vm, Fm) == pytest.approx(_area(Vr, Fr))
    _write_obj(tmp_path / "tris.obj", V, tri)
    assert read_surface_faces(tmp_path / "tris.obj")[2] is None  # all triangles: each is its own face


def test_a_concave_quad_is_split_along_the_diagonal_inside_it():
    from xshells.design.fitting import _split_polygons

    V = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [3, 1, 0.0]])  # the corner (3, 1) points inward
    F, face = _split_polygons(V, np.array([[0, 1, 2, 3]]))  # the diagonal 0–2 is shorter but runs outside
    assert sorted(map(sorted, F.tolist())) == [[0, 1, 3], [1, 2, 3]]
    assert _area(V, F) == pytest.approx(4.0)  # the shoelace area: ((0·0 − 4·0) + (16 − 0) + (4 − 12) + 0)/2


def test_larger_convex_polygons_are_fanned_and_concave_ones_refused(tmp_path):
    hexagon = np.array([[0, 0, 0], [2, 0, 0], [3, 1, 0], [2, 2, 0], [0, 2, 0], [-1, 1, 0.0]])
    _write_obj(tmp_path / "hex.obj", hexagon, [range(6)])
    V, F, face = read_surface_faces(tmp_path / "hex.obj")
    assert len(F) == 4 and list(face) == [0, 0, 0, 0] and _area(V, F) == pytest.approx(6.0)
    star = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [2, 1, 0], [0, 4, 0.0]])
    _write_obj(tmp_path / "dart.obj", star, [[0, 1, 2], range(5)])
    with pytest.raises(InputError) as err:
        read_surface(tmp_path / "dart.obj")
    msg = str(err.value)
    assert "\n" not in msg and "dart.obj" in msg and "face 2" in msg and "not convex" in msg


@pytest.mark.parametrize("face, words", [
    ("f 1 3 2 4", "face 1 of the target surface is a polygon that is not convex or crosses itself"),  # a bow tie
    ("f 1 2", "face 1 of the target surface has only 2 corners"),
])
def test_a_face_that_crosses_itself_or_has_two_corners_is_named(tmp_path, face, words):
    (tmp_path / "t.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n" + face + "\n")
    with pytest.raises(InputError) as err:
        read_surface(tmp_path / "t.obj")
    assert words in str(err.value) and "\n" not in str(err.value)


def test_a_face_index_out_of_range_is_named(tmp_path):
    (tmp_path / "oob.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\nf 1 2 3 9\n")
    with pytest.raises(InputError, match=r"oob.obj: face 2 .*out of range"):
        read_surface(tmp_path / "oob.obj")
    (tmp_path / "rel.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nf -3 -2 -1\n")
    with pytest.raises(InputError, match=r"rel.obj: face 1 .*relative \(negative\) vertex indices"):
        read_surface(tmp_path / "rel.obj")


# ------------------------------------------------------- closest points
def closest_on_segment(p, a, b):
    t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    return a + t * (b - a)


def closest_on_triangle(p, a, b, c):
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    q = p - np.dot(p - a, n) * n
    M = np.c_[b - a, c - a]
    s, t = np.linalg.lstsq(M, q - a, rcond=None)[0]
    if s >= 0 and t >= 0 and s + t <= 1:
        return q
    cands = [closest_on_segment(p, a, b), closest_on_segment(p, b, c), closest_on_segment(p, c, a)]
    return min(cands, key=lambda x: np.linalg.norm(p - x))


def bumpy_mesh(n=4):
    u, v = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    V = np.c_[u.ravel(), v.ravel(), 0.3 * np.sin(3 * u.ravel()) * np.cos(2 * v.ravel())]
    idx = lambda i, j: i * (n + 1) + j  # noqa: E731
    F = [(idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)) for i in range(n) for j in range(n)]
    F += [(idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)) for i in range(n) for j in range(n)]
    return V, np.array(F)


def test_the_kept_tree_answers_as_igl_does_and_follows_the_mesh():
    import igl

    from xshells.design import fitting

    V, F = bumpy_mesh(6)
    P = np.random.default_rng(3).normal(0.5, 0.4, (50, 3))
    want = igl.point_mesh_squared_distance(P, V, F)
    for _ in range(2):  # built, then kept
        got = fitting.point_mesh_squared_distance(P, V, F)
        assert all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(got, want))
    assert len(fitting._TREES) >= 1
    kept = dict(fitting._TREES)
    fitting.point_mesh_squared_distance(P[:3], V, F)
    assert fitting._TREES.keys() == kept.keys()  # the same mesh: no new tree
    V2 = V.copy()
    V2[:, 2] += 0.25  # the same shapes, other values: a tree of its own, not the old one's answers
    got = fitting.point_mesh_squared_distance(P, V2, F)
    want = igl.point_mesh_squared_distance(P, V2, F)
    assert all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(got, want))


def test_closest_points_match_brute_force():
    V, F = bumpy_mesh()
    P = np.random.default_rng(0).uniform([-0.3, -0.3, -0.5], [1.3, 1.3, 0.8], size=(60, 3))
    C, J = closest_points(V, F, P)
    assert C.shape == (60, 3) and J.shape == (60, 3, 3)
    for p, c in zip(P, C):
        best = min((closest_on_triangle(p, *V[f]) for f in F), key=lambda x: np.linalg.norm(p - x))
        assert np.linalg.norm(p - c) == pytest.approx(np.linalg.norm(p - best), abs=1e-12)
        assert np.allclose(c, best, atol=1e-9)


def pyramid():
    V = np.array([[0, 0, 1], [1, 1, 0], [-1, 1, 0], [-1, -1, 0], [1, -1, 0]], float)
    F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]])
    return V, F


def fd_jacobian(V, F, p, h=1e-6):
    cols = [(closest_points(V, F, [p + h * e])[0][0] - closest_points(V, F, [p - h * e])[0][0]) / (2 * h)
            for e in np.eye(3)]
    return np.array(cols).T


@pytest.mark.parametrize("where", ["face", "ridge", "boundary edge", "apex", "base corner"])
def test_closest_point_jacobian_matches_finite_differences(where):
    V, F = pyramid()
    n0 = np.cross(V[1] - V[0], V[2] - V[0])
    n0 /= np.linalg.norm(n0)
    n1 = np.cross(V[2] - V[0], V[3] - V[0])
    n1 /= np.linalg.norm(n1)
    p = {
        "face": V[F[0]].mean(axis=0) + 0.1 * n0 + [0.05, -0.02, 0],
        "ridge": 0.6 * V[0] + 0.4 * V[2] + 0.2 * (n0 + n1),
        "boundary edge": 0.3 * V[1] + 0.7 * V[2] + [0, 0.3, -0.1],
        "apex": V[0] + [0.01, -0.02, 0.5],
        "base corner": V[3] + [-0.2, -0.3, -0.1],
    }[where]
    C, J = closest_points(V, F, [p])
    expected_rank = {"face": 2, "ridge": 1, "boundary edge": 1, "apex": 0, "base corner": 0}[where]
    assert np.linalg.matrix_rank(J[0], tol=1e-8) == expected_rank
    assert np.allclose(J[0], fd_jacobian(V, F, p), atol=1e-7)


def test_closest_point_jacobians_on_random_points():
    V, F = bumpy_mesh()
    P = np.random.default_rng(1).uniform([-0.2, -0.2, -0.4], [1.2, 1.2, 0.7], size=(40, 3))
    _, J = closest_points(V, F, P)
    ranks = Counter(int(np.linalg.matrix_rank(j, tol=1e-8)) for j in J)
    assert ranks[2] > 0 and ranks[1] + ranks[0] > 0
    for p, j in zip(P, J):
        assert np.allclose(j, fd_jacobian(V, F, p, h=1e-7), atol=1e-5)


# ------------------------------------------------------------ fitting term
def perturbed_term(grid, seed=0):
    rng = np.random.default_rng(seed)
    P0 = grid.joint_positions()
    n = len(P0)
    term = FittingTerm(P0 + 0.05 * rng.standard_normal(P0.shape), rng.uniform(0.1, 1.0, n),
                       rng.uniform(0.1, 1.0, n), target_surface(grid))
    return term, P0 + 0.1 * rng.standard_normal(P0.shape)


def test_fitting_value_and_gradient(grid):
    term, P = perturbed_term(grid)
    C, _ = closest_points(*term.surface, P)
    expected = 0.5 * np.sum(term.surface_weights * np.sum((P - C) ** 2, axis=1)) \
        + 0.5 * np.sum(term.weights * np.sum((P - term.targets) ** 2, axis=1))
    assert term.value(P) == pytest.approx(expected, rel=1e-14)
    assert term.value(term.targets) > 0 and FittingTerm(term.targets, term.weights).value(term.targets) == 0
    g = term.gradient(P)
    assert g.shape == P.shape
    d = np.random.default_rng(5).standard_normal(P.shape)
    errs = [abs((term.value(P + h * d) - term.value(P - h * d)) / (2 * h) - np.sum(g * d)) / abs(np.sum(g * d))
            for h in (1e-4, 1e-5, 1e-6)]
    assert min(errs) < 1e-7


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fitting_hessian_vector(grid, seed):
    term, P = perturbed_term(grid, seed)
    rng = np.random.default_rng(10 + seed)
    d = rng.standard_normal(P.shape)
    Hd = term.hessian_vector(P, d)
    assert Hd.shape == P.shape
    errs = [np.linalg.norm((term.gradient(P + h * d) - term.gradient(P - h * d)) / (2 * h) - Hd) / np.linalg.norm(Hd)
            for h in (1e-6, 1e-7, 1e-8)]
    assert min(errs) < 1e-6
    # Symmetric positive semidefinite (a sum of projections with nonnegative weights).
    e = rng.standard_normal(P.shape)
    assert np.sum(e * term.hessian_vector(P, d)) == pytest.approx(np.sum(d * term.hessian_vector(P, e)), rel=1e-12)
    assert np.sum(d * Hd) >= 0


def test_fitting_without_surface_is_point_to_point(grid):
    P0 = grid.joint_positions()
    w = np.linspace(1, 2, len(P0))
    term = FittingTerm(P0, w)
    P = P0 + 0.1
    assert np.allclose(term.gradient(P), 0.1 * w[:, None])
    assert np.allclose(term.hessian_vector(P, np.ones_like(P)), w[:, None])
    with pytest.raises(InputError):
        FittingTerm(P0, w, surface_weights=w)
    with pytest.raises(InputError):
        FittingTerm(P0, w[:-1])


def test_paper_defaults(grid):
    term = FittingTerm.paper_defaults(grid)
    n = grid.num_joints
    assert np.allclose(term.targets, grid.joint_positions())
    assert term.weights.sum() + term.surface_weights.sum() == pytest.approx(1.0)
    assert term.surface_weights.sum() == pytest.approx(0.9)
    assert np.allclose(term.surface_weights, 0.9 / n)
    assert term.weights.sum() == pytest.approx(0.1)
    valence = grid.graph.valence[grid.graph.joint_vertex]
    corner = valence == 2
    assert corner.sum() == 4  # the grid's corners
    assert np.allclose(term.weights[corner] / term.weights[~corner].max(), 10.0)
    assert np.allclose(term.weights[~corner], term.weights[~corner][0])
    # At the targets, only the (small) distance to the subdivided surface remains.
    span = np.linalg.norm(np.ptp(term.targets, axis=0))
    assert 0 < term.value(term.targets) < 0.45 * (0.05 * span) ** 2
    V, F = target_surface(grid, subdivisions=1)
    assert len(FittingTerm.paper_defaults(grid, surface=(V, F)).surface[1]) == len(F)


def test_a_file_meshio_cannot_read_is_one_input_error_for_every_command(tmp_path):
    """meshio answers a corrupt file by printing "Error: Couldn't read file ..." and calling sys.exit(1): `xshells
    optimize --target-surface` printed that and exited 1 without its prefix."""
    from xshells.design.fitting import read_surface_noted
    from xshells.errors import InputError

    bad = tmp_path / "garbage.ply"
    bad.write_bytes(b"ply\nformat nonsense\n\x00\x01\x02")
    with pytest.raises(InputError, match="garbage.ply: cannot read the target surface as ply"):
        read_surface_noted(bad)
