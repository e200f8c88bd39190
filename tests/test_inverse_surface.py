"""Target surfaces for inverse design: every defect is one clear line; good meshes come out oriented."""
import numpy as np
import pytest

from xshells.errors import InputError
from xshells.inverse.surface import check_target, load_target


def grid(n=6, size=1000.0, height=None):
    x, y = np.meshgrid(np.linspace(-size / 2, size / 2, n), np.linspace(-size / 2, size / 2, n), indexing="ij")
    z = np.zeros_like(x) if height is None else height(x, y)
    V = np.c_[x.ravel(), y.ravel(), z.ravel()]
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    return V, F


def test_a_grid_is_accepted_with_its_diagonal_area_and_one_boundary():
    V, F = grid()
    s = check_target(V, F)
    assert s.diagonal == pytest.approx(np.sqrt(2) * 1000.0)
    assert s.area == pytest.approx(1e6)
    assert s.boundary_loops == 1


def test_faces_are_oriented_consistently_and_upward():
    V, F = grid(height=lambda x, y: -1e-4 * (x**2 + y**2))
    F = F.copy()
    F[::3] = F[::3, ::-1]  # mixed orientation, as some exporters write
    s = check_target(V, F)
    n = s.face_normals
    assert (n[:, 2] > 0).all()


@pytest.mark.parametrize("make, words", [
    (lambda: (np.zeros((0, 3)), np.zeros((0, 3), int)), "empty"),
    (lambda: (np.where(np.arange(36)[:, None] == 7, np.nan, grid()[0]), grid()[1]), "non-finite"),
    (lambda: (grid()[0], np.r_[grid()[1], [[0, 7, 20]]]), "not manifold"),  # a fin on the diagonal 0–7
    (lambda: (np.r_[grid()[0], grid()[0] + 5000.0], np.r_[grid()[1], grid()[1] + 36]), "separate pieces"),
    (lambda: (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]), np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])), "closed"),
    (lambda: (np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0], [0, 1, 0]]), np.array([[0, 1, 2], [0, 1, 3]])), "zero area"),
])
def test_bad_meshes_get_one_line_naming_the_problem(make, words):
    V, F = make()
    with pytest.raises(InputError) as exc:
        check_target(V, F, "t.obj")
    msg = str(exc.value)
    assert msg.startswith("t.obj:") and words in msg and "\n" not in msg


def test_a_quad_of_no_area_is_named_as_the_file_numbers_it(tmp_path):
    p = tmp_path / "q.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nv 0 1 0\nf 1 2 5\nf 1 2 3 4\n")
    with pytest.raises(InputError, match=r"q.obj: 2 triangles have zero area \(the first is face 2\)"):
        load_target(p)


def test_unreadable_and_triangle_free_files(tmp_path):
    p = tmp_path / "lines.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nl 1 2\n")
    with pytest.raises(InputError, match="no triangles"):
        load_target(p)
    with pytest.raises(InputError, match="cannot read"):
        load_target(tmp_path / "missing.obj")


def test_the_angle_defect_of_a_pyramid_apex_is_two_pi_less_its_four_face_angles():
    from xshells.inverse.surface import angle_defects

    V = np.array([[-1.0, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [0, 0, 1]])
    F = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    k = angle_defects(check_target(V, F))
    apex = 2.0 * np.arctan(1.0 / np.sqrt(2.0))  # each side face: base 2, slant height √2
    assert k[-1] == pytest.approx(2 * np.pi - 4 * apex, rel=1e-12)  # 1.3594 rad
    assert np.all(k[:-1] == 0.0)  # boundary vertices carry none


def _cap(n, R=2000.0, half_angle=np.radians(30.0)):
    r = R * np.sin(half_angle)
    V, F = grid(n, 2 * r, height=lambda x, y: np.sqrt(np.maximum(R**2 - x**2 - y**2, 0.0)))
    keep = np.hypot(V[:, 0], V[:, 1]) <= r
    F = F[keep[F].all(axis=1)]
    return check_target(V, F)


def test_total_curvature_of_a_spherical_cap_tends_to_gauss_bonnet():
    from xshells.inverse.surface import total_curvature

    exact = 2 * np.pi * (1 - np.cos(np.radians(30.0)))  # ∫K dA = area / R²
    errors = np.array([abs(total_curvature(_cap(n)) - exact) / exact for n in (21, 41, 81, 161)])
    assert errors[-1] < 0.04
    # first order: what is missed is the boundary ring's share, whose width is the mesh size
    assert np.all((errors[1:] / errors[:-1] > 0.4) & (errors[1:] / errors[:-1] < 0.6))


def test_a_curved_developable_surface_is_named_and_a_nearly_flat_or_doubly_curved_one_is_not():
    from xshells.inverse.surface import developable_warning, total_curvature

    def cylinder(radius):
        V, F = grid(21, 2000.0, height=lambda x, y: np.sqrt(radius**2 - x**2) - radius)
        return check_target(V, F)

    barrel = cylinder(1500.0)
    assert total_curvature(barrel) < 1e-9  # each strip of triangles is planar
    assert "developable" in developable_warning(barrel, 0.01)
    assert developable_warning(cylinder(1e5), 0.01) == ""  # within the bar of its plane
    assert developable_warning(_cap(21), 0.01) == ""


# ---------------------------------------------------------------- recheck34: surface input faults
def _mobius(n=24, w=100.0, R=1000.0):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    V = []
    for s in (-w, w):
        V += [[(R + s * np.cos(a / 2)) * np.cos(a), (R + s * np.cos(a / 2)) * np.sin(a), s * np.sin(a / 2)] for a in t]
    V = np.array(V)
    F = []
    for i in range(n):
        j = (i + 1) % n
        a, b, c, d = i, j, n + j, n + i
        if j == 0:  # the half twist: the strip's edges swap as it closes
            b, c = n + j, j
        F += [[a, b, c], [a, c, d]]
    return V, np.array(F)


def test_a_mobius_strip_is_refused_as_one_sided():
    # it was "the surface has -16 handle(s)": igl.bfs_orient cannot tell, Euler's formula then lies
    V, F = _mobius()
    with pytest.raises(InputError) as exc:
        check_target(V, F, "m.obj")
    assert str(exc.value) == "m.obj: the surface is one-sided (not orientable, like a Möbius strip): an X-shell is a two-sided sheet"
    V, F = grid()
    F = F.copy()
    F[::2] = F[::2, ::-1]  # a mixed but orientable export is still accepted
    check_target(V, F, "g.obj")


@pytest.mark.parametrize("flip", [False, True])
def test_a_duplicate_face_is_named_with_both_face_numbers(flip):
    # it was "the mesh is not manifold: the edge between vertices 6 and 18 has 3 triangles"
    V, F = grid()
    F = np.r_[F, F[10:11, ::-1] if flip else F[10:11]]
    with pytest.raises(InputError, match=rf"d.obj: triangle {len(F)} duplicates triangle 11 \(the same three vertices\)"):
        check_target(V, F, "d.obj")


def test_an_unwelded_seam_is_named_with_a_coincident_vertex_pair():
    # two halves of one grid whose seam vertices were exported twice: it was "2 separate pieces"
    V, F = grid(n=5)  # a grid line at x = 0: vertices 11 to 15
    left = F[(V[F][:, :, 0] <= 1e-9).all(axis=1)]
    right = F[(V[F][:, :, 0] >= -1e-9).all(axis=1)] + len(V)
    with pytest.raises(InputError) as exc:
        check_target(np.r_[V, V], np.r_[left, right], "s.obj")
    msg = str(exc.value)
    assert "touch at coincident vertices that are not merged (vertices 11 and 36): weld them" in msg, msg
    with pytest.raises(InputError, match="2 separate pieces"):  # apart: still two pieces
        check_target(np.r_[V, V + [5000.0, 0, 0]], np.r_[left, right], "s.obj")


def test_unused_vertices_are_dropped_before_the_finiteness_check():
    # an unused NaN vertex was refused while an unused 1e20 one was accepted
    V, F = grid()
    for extra in (np.nan, 1e20):
        s = check_target(np.r_[V, [[extra, 0, 0]]], F, "u.obj")
        assert len(s.V) == len(V)
    bad = V.copy()
    bad[7, 2] = np.nan
    with pytest.raises(InputError, match="u.obj: vertex 8 has a non-finite coordinate"):
        check_target(bad, F, "u.obj")


@pytest.mark.parametrize("name, text, formats", [
    ("obj_named.stl", "".join("v %g %g %g\n" % tuple(v) for v in grid()[0]) +
     "".join("f %d %d %d\n" % tuple(f + 1) for f in grid()[1]), "stl"),
    ("garbage.ply", "ply\nformat nonsense\n", "ply"),
    ("garbage.msh", "not a mesh at all\n", "ansys or gmsh"),
])
def test_a_file_meshio_cannot_read_is_one_input_error_not_an_exit(tmp_path, capsys, name, text, formats):
    # meshio printed "Error: Couldn't read file ... as stl" and called sys.exit(1): no prefix, exit code 1
    p = tmp_path / name
    p.write_text(text)
    with pytest.raises(InputError) as exc:
        load_target(p)
    assert str(exc.value).startswith(f"{p}: cannot read the target surface as {formats}:")
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""


def test_reading_a_gmsh_file_prints_nothing(tmp_path, capsys):
    # meshio's gmsh reader printed blank lines on stdout
    import meshio

    V, F = grid()
    meshio.write(str(tmp_path / "g.msh"), meshio.Mesh(V, [("triangle", F)]), file_format="gmsh22")
    capsys.readouterr()
    assert len(load_target(tmp_path / "g.msh").F) == len(F)
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""


def _dome(n=101):
    """A paraboloid dome over a 2000 × 2000 square, 2 (n − 1)² triangles."""
    return grid(n, 2000.0, height=lambda x, y: 400.0 - 2e-4 * (x**2 + y**2))


def test_a_fine_mesh_is_simplified_within_the_tolerance_and_a_coarse_one_is_left_alone():
    from xshells.inverse.surface import simplified

    fine = check_target(*_dome(), "dome.obj")  # 20,000 triangles
    s = simplified(fine, max_triangles=2000, tolerance=1e-3)
    assert len(s.F) <= 2000 and s.boundary_loops == 1 and s.path == "dome.obj"
    before, kept, gap = s.simplified
    assert (before, kept) == (20000, len(s.F)) and 0 < gap <= 1e-3 * fine.diagonal
    # the recorded distance is what it says: the fine mesh's vertices lie that close to the simplified one
    from xshells.inverse.surface import _largest_distance

    assert _largest_distance(fine.V, s) <= gap * (1 + 1e-9)
    assert s.area == pytest.approx(fine.area, rel=1e-3) and s.diagonal == pytest.approx(fine.diagonal, rel=1e-3)
    assert simplified(fine, max_triangles=20000) is fine  # not finer than the limit: the file's own mesh
    coarse = check_target(*_dome(11))  # 200 triangles
    assert simplified(coarse, max_triangles=200) is coarse


def test_a_simplification_that_cannot_stay_within_the_tolerance_keeps_the_files_mesh():
    from xshells.inverse.surface import simplified

    fine = check_target(*_dome(41))
    assert simplified(fine, max_triangles=500, tolerance=1e-12) is fine


def test_load_target_simplifies_a_mesh_finer_than_the_limit(tmp_path, monkeypatch):
    import xshells.inverse.surface as surface

    V, F = _dome(31)  # 1,800 triangles
    path = tmp_path / "dome.obj"
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in V) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))
    monkeypatch.setattr(surface, "MAX_TRIANGLES", 1000)
    monkeypatch.setattr(surface, "SIMPLIFY_TOLERANCE", 1e-3)
    monkeypatch.setattr(surface.simplified, "__defaults__", (1000, 1e-3))
    s = load_target(str(path))
    assert s.simplified is not None and len(s.F) <= 1000 and s.path == str(path)
    assert load_target(str(path), simplify=False).simplified is None


def test_the_simplification_note_names_the_file_the_triangles_and_the_distance():
    from xshells.inverse.run import simplification, simplification_note
    from xshells.inverse.surface import simplified

    fine = check_target(*_dome(), "dome.obj")
    assert simplification_note(fine) is None and simplification(fine) is None
    s = simplified(fine, max_triangles=2000, tolerance=1e-3)
    note = simplification_note(s)
    assert note.startswith("dome.obj: its 20,000 triangles are simplified to ") and "surface units" in note
    assert "\n" not in note
    info = simplification(s)
    assert info["triangles"] == 20000 and info["triangles_kept"] == len(s.F)
    assert info["max_distance"] == s.simplified[2] and info["max_distance_of_diagonal"] == s.simplified[2] / s.diagonal


def test_a_simplification_that_fails_keeps_more_triangles_then_the_files_mesh(monkeypatch):
    import igl

    from xshells.inverse.surface import simplified

    fine = check_target(*_dome(41))  # 3,200 triangles
    calls = []

    def broken(V, F, m):
        calls.append(m)
        raise RuntimeError("qslim failed")

    monkeypatch.setattr(igl, "qslim", broken)
    assert simplified(fine, max_triangles=500) is fine
    assert calls == [500, 1000, 2000]
