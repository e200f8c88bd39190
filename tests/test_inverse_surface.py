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
    (lambda: (grid()[0], np.r_[grid()[1], [[0, 1, 7]]]), "not manifold"),
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
