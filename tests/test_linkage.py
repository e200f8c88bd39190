"""The reduced-variable linkage: derivatives, invariants, counts, real designs."""
import numpy as np
import pytest

from xshells.io import read_design
from xshells.linkage.grids import rhombic_grid
from xshells.linkage.linkage import Linkage
from xshells.section import Material

from data_paths import EXAMPLES

RECT = Material.uniform("rectangle", [10, 7], E=20000, nu=0.3)
PLUS = Material.uniform("+", [5.0, 5.0, 0.2, 0.2], E=20000, nu=0.3)


def nonuniform(k=4):
    return Linkage(read_design(EXAMPLES / "nonuniform_linkage.obj"), Material.uniform("rectangle", [0.1, 0.07], E=20000, nu=0.3), subdivision=k)


def banana(k=4):
    d = read_design(EXAMPLES / "wiggly_banana_5" / "flat_opt.msh")
    return Linkage(d, PLUS, subdivision=k)


def perturbed(L, seed, scale=1e-2):
    rng = np.random.default_rng(seed)
    x = L.get_vars()
    span = np.ptp(L.joint_positions(), axis=0).max()
    dx = rng.standard_normal(len(x))
    dx[: L.num_joint_vars] *= np.tile([span, span, span, 1, 1, 1, 1, 0, 0], L.num_joints) * scale
    dx[L.num_joint_vars :] *= span * scale * 0.1
    L.set_vars(x + dx)
    L.update_source_frame()
    return L


def fd_check(L, with_p, seed=0):
    """Central-difference checks of gradient and Hessian; returns the relative errors at h and h/2."""
    rng = np.random.default_rng(seed)
    x, p = L.get_vars(), L.rest_lengths
    z0 = np.concatenate([x, p]) if with_p else x
    nx = len(x)
    d = rng.standard_normal(len(z0))
    ell = 0.1 * np.mean(p)  # lengths move in the units of the design, angles in radians
    d[: L.num_joint_vars] *= np.tile([ell, ell, ell, 1e-2, 1e-2, 1e-2, 1e-2, 0.1 * ell, 0.1 * ell], L.num_joints)
    is_angle = L._free_rod >= 3 * L.rods.num_vertices
    d[L._free_reduced] *= np.where(is_angle, 1e-2, ell)
    if with_p:
        d[nx:] *= 0.1 * ell

    def set_z(z):
        L.set_vars(z[:nx])
        if with_p:
            L.set_rest_lengths(z[nx:])

    g = L.gradient(with_p)
    H = L.hessian(with_p)
    Hd = H @ d
    ge, he = [], []
    for h in 1e-3 / 2.0 ** np.arange(9):
        set_z(z0 + h * d)
        ep, gp = L.energy(), L.gradient(with_p)
        set_z(z0 - h * d)
        em, gm = L.energy(), L.gradient(with_p)
        set_z(z0)
        ge.append(abs((ep - em) / (2 * h) - g @ d) / abs(g @ d))
        he.append(np.linalg.norm((gp - gm) / (2 * h) - Hd) / np.linalg.norm(Hd))
    return ge, he, H


@pytest.mark.parametrize("make", [nonuniform, banana], ids=["obj", "msh"])
@pytest.mark.parametrize("state", ["flat", "3d"])
@pytest.mark.parametrize("with_p", [False, True])
def test_derivatives_match_finite_differences(make, state, with_p):
    L = make()
    if state == "3d":
        perturbed(L, seed=1)
    ge, he, H = fd_check(L, with_p)
    assert min(ge) < 1e-5 and min(he) < 1e-5
    # second order: while truncation dominates, halving h divides the error by about 4
    assert any(3.5 < a / b < 4.5 for a, b in zip(ge, ge[1:]))
    assert any(3.5 < a / b < 4.5 for a, b in zip(he, he[1:]))
    assert abs(H - H.T).max() <= 1e-12 * abs(H).max()


def test_straight_flat_grid_has_zero_energy_at_its_rest_lengths():
    L = Linkage(rhombic_grid(4, 3, spacing=100.0, angle=1.2), RECT, subdivision=5)
    scale = RECT.bending_stiffness[0] / 100.0
    parts = L.energy_parts()
    assert parts.total < 1e-20 * scale
    assert np.abs(L.gradient()).max() < 1e-9 * scale


def test_energy_invariant_under_translation_and_gradient_orthogonal_to_rigid_modes():
    L = perturbed(nonuniform(), seed=2)
    e0 = L.energy()
    x = L.get_vars()
    shift = np.zeros_like(x)
    for j in range(L.num_joints):
        shift[9 * j : 9 * j + 3] = [0.3, -0.2, 0.7]
    free_pos = L._free_rod < 3 * L.rods.num_vertices
    shift[L._free_reduced[free_pos]] = np.tile([0.3, -0.2, 0.7], L.rods.num_vertices)[L._free_rod[free_pos]]
    L.set_vars(x + shift)
    assert abs(L.energy() - e0) <= 1e-10 * abs(e0)
    L.set_vars(x)
    g = L.gradient()
    for w in np.eye(3):
        mode = np.zeros_like(x)
        P = L.joint_positions()
        for j in range(L.num_joints):
            mode[9 * j : 9 * j + 3] = np.cross(w, P[j])
            mode[9 * j + 3 : 9 * j + 6] = w
        vel = np.concatenate([np.cross(w, L.rods.points).ravel(), L.rods.t_src @ w])
        mode[L._free_reduced] = vel[L._free_rod]
        assert abs(g @ mode) <= 1e-8 * np.linalg.norm(g) * np.linalg.norm(mode)


def test_mass_matrix_is_symmetric_positive_definite():
    L = nonuniform()
    M = L.mass_matrix().toarray()
    assert np.allclose(M, M.T, atol=1e-14 * abs(M).max())
    assert np.linalg.eigvalsh(M).min() > 0


def test_mass_matrix_pattern_is_the_same_in_the_flat_and_a_moved_state():
    """The solvers' metric keeps one pattern (its exact zeros kept): the flat state's zero heights zero out
    products that a moved state has, and a changing pattern cost a new union pattern every deployment step."""
    L = nonuniform()
    M_flat = L.mass_matrix()
    J = L.rod_jacobian()
    D = L.rods.mass_matrix(L.rods.density / float(np.max(L.rods.density)))
    assert np.array_equal(M_flat.toarray(), (J.T @ D @ J).toarray())
    assert (M_flat.data == 0).any()  # structural zeros the product alone would drop
    perturbed(L, seed=3)
    M_moved = L.mass_matrix()
    J = L.rod_jacobian()
    assert np.array_equal(M_moved.indptr, M_flat.indptr) and np.array_equal(M_moved.indices, M_flat.indices)
    assert np.array_equal(M_moved.toarray(), (J.T @ D @ J).toarray())


@pytest.mark.parametrize("k", [3, 5, 10])
def test_dof_count_matches_the_graph_formula(k):
    d = read_design(EXAMPLES / "nonuniform_linkage.obj")
    L = Linkage(d, RECT, subdivision=k)
    assert L.num_vars == L.graph.dof(k)
    assert L.num_vars == 9 * L.num_joints + sum(
        (4 * k - 11) if (L.graph.segment_joints[s] >= 0).all() else (4 * k - 4) for s in range(L.num_segments)
    )


def test_selectors_and_pins():
    L = nonuniform()
    assert np.allclose(L.angle_selector() @ L.get_vars(), L.joint_angles())
    assert np.allclose(L.height_selector() @ L.get_vars(), L.joint_positions() @ L.graph.layout_normal)
    pins = L.rigid_pin_indices()
    assert len(pins) == 6 and pins[0] % 9 == 0
    assert 0 < L.average_angle() < np.pi


def test_rest_length_map_preserves_segment_lengths_of_straight_beams():
    L = Linkage(rhombic_grid(3, 3, spacing=50.0, angle=1.0), RECT, subdivision=6)
    k = L.subdivision
    edge = L.rest_length_map @ L.rest_lengths
    # joint-to-joint: k - 2 interior edges + two halves of joint edges == p
    for s in range(L.num_segments):
        e = edge[s * k : (s + 1) * k]
        assert np.isclose(e[1:-1].sum() + 0.5 * (e[0] + e[-1]), L.rest_lengths[s])


def _cases():
    import json

    from data_paths import DATA

    if not DATA.is_dir():
        return []
    return [c for c in json.load(open(DATA / "cases.json"))["cases"] if (DATA / c["file"]).exists()]


@pytest.mark.parametrize("case", _cases(), ids=lambda c: c["name"])
def test_every_paper_case_builds_with_the_dof_formula(case):
    from data_paths import DATA

    k = case.get("subdivision", 10)
    L = Linkage(read_design(DATA / case["file"]), RECT, subdivision=k)
    assert L.num_vars == L.graph.dof(k)
    assert np.isfinite(L.energy())


def test_paper_table_one_dof():
    L = Linkage(read_design(EXAMPLES / "wiggly_banana_5" / "flat_opt.msh"), PLUS, subdivision=10)
    assert (L.num_segments, L.num_joints, L.num_vars) == (264, 146, 8970)


# ---------------------------------------------------------------- fast assembly and the state cache
def _triple_product_hessian(L):
    import scipy.sparse as sp

    from xshells.linkage import joint_kernels as jk

    J = L.rod_jacobian()
    Hx = J.T @ L.rods.hessian() @ J
    w = L.rods.gradient()[L._inst_rows]
    Hj = jk.weighted_hessian(L._instance_q(L._x), L._inst_prm, w)
    n = Hj.shape[2]
    base = (9 * L._inst_joint)[None, None, :]
    rows = np.broadcast_to(base + np.arange(9)[:, None, None], (9, 9, n)).ravel()
    cols = np.broadcast_to(base + np.arange(9)[None, :, None], (9, 9, n)).ravel()
    return (Hx + sp.csr_matrix((Hj.ravel(), (rows, cols)), shape=Hx.shape)).tocsr()


@pytest.mark.parametrize("k", [3, 4])
def test_reduced_hessian_assembly_matches_the_triple_product(k):
    # k = 3: a vertex stencil can touch the terminal edges of both of its segment's joints
    L = perturbed(nonuniform(k), seed=5)
    x = L.get_vars()
    L.set_vars(x + 1e-4 * np.random.default_rng(2).standard_normal(len(x)))  # away from the source frame
    H, ref = L.hessian(), _triple_product_hessian(L)
    assert abs(H - ref).max() <= 1e-13 * abs(ref).max()
    assert H.has_canonical_format and abs(H - H.T).max() <= 1e-13 * abs(ref).max()
    assert np.isclose(L.energy(), L.rods.energy(), rtol=1e-13)
    assert np.allclose(L._rod_gradient(), L.rods.gradient(), rtol=0, atol=1e-13 * np.abs(L.rods.gradient()).max())


def test_state_cache_sees_changes_that_bypass_set_vars():
    from xshells.linkage.state import restore, snapshot

    L = perturbed(nonuniform(4), seed=6)
    snap = snapshot(L)
    e0, g0, H0 = L.energy(), L.gradient(), L.hessian().copy()
    x = L.get_vars()
    x[L.num_joint_vars] += 1e-2
    L.set_vars(x)
    L.update_source_frame()
    e1 = L.energy()
    assert abs(e1 - e0) > 1e-8 * abs(e0)
    restore(L, snap)  # assigns frames directly, then set_vars (equal to round-off: the terminal angles are recomputed)
    assert abs(L.energy() - e0) <= 1e-13 * abs(e0)
    assert np.allclose(L.gradient(), g0, rtol=0, atol=1e-10 * np.abs(g0).max())
    assert abs(L.hessian() - H0).max() <= 1e-10 * abs(H0).max()
    L.rods.t_src = L.rods.t_src + 1e-3  # a direct edit of the frames alone
    assert not np.array_equal(L.gradient(), g0)


def test_input_warnings_name_a_units_mismatch_and_a_design_that_is_not_flat():
    import numpy as np

    from xshells.io.design import Design
    from xshells.linkage.grids import rhombic_grid
    from xshells.linkage.linkage import Linkage
    from xshells.section import Material

    grid = rhombic_grid(3, 3, spacing=1.0, angle=np.radians(30))
    thin = Material.uniform("rectangle", [0.01, 0.005], E=20000, nu=0.3)
    assert Linkage(grid, thin, subdivision=3).input_warnings() == []
    wide = Linkage(grid, Material.uniform("rectangle", [10, 7], E=20000, nu=0.3), subdivision=3).input_warnings()
    assert len(wide) == 1 and "x as wide" in wide[0] and "same units" in wide[0]
    V = np.array(grid.vertices, float)
    V[:, 2] = 0.1 * V[:, 0] ** 2
    curved = Linkage(Design(V, np.array(grid.edges)), thin, subdivision=3).input_warnings()
    assert len(curved) == 1 and "not flat" in curved[0]


@pytest.mark.parametrize("text", [
    "v 0 0 0\nv 1 0 0\nv 2 0 0\nl 1 2 3\n",  # a straight polyline: node 1 a corner of two beams, at 0°
    "v 0 0 0\nv 1 0 0\nv -0.5 0.866 0\nv -0.5 -0.866 0\nv 2 0 0\nv 2 1 0\nv 2 -1 0\n"
    "l 1 2\nl 1 3\nl 1 4\nl 2 5\nl 6 5\nl 5 7\n",  # the same corner, its beams the other way round: 180°
])
def test_a_joint_with_parallel_beams_is_named_once_with_its_file_and_line(tmp_path, text):
    """It read "joint at vertex 1node 1 (line 2): its two beams are parallel (opening angle 0°)", and 180° for
    the same straight corner drawn the other way round: the file, the node once, one angle."""
    path = tmp_path / "p.obj"
    path.write_text(text)
    thin = Material.uniform("rectangle", [0.01, 0.005], E=20000, nu=0.3)
    with pytest.raises(Exception, match=r"^\S*p\.obj: node 1 \(line 2\): the joint's two beams are parallel "
                                        r"\(they cross at 0°\); a node of valence 2 is a hinge") as err:
        Linkage(read_design(path), thin, subdivision=3)
    assert "vertex" not in str(err.value) and "\n" not in str(err.value)


def test_rest_length_messages_name_the_segment_by_its_file_line(tmp_path):
    path = tmp_path / "g.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2\nl 1 3\n")
    thin = Material.uniform("rectangle", [0.01, 0.005], E=20000, nu=0.3)
    with pytest.raises(Exception, match=r"^\S*g\.obj: line 5: rest length -1\.0 is not positive"):
        Linkage(read_design(path), thin, subdivision=3, rest_lengths=[1.0, -1.0])


def test_the_units_warning_names_the_segment_by_its_file_line(tmp_path):
    """It said "as wide as segment 1", a 0-based index the file never shows."""
    path = tmp_path / "g.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 0.5 0\nl 1 2\nl 1 3\n")
    wide = Material.uniform("rectangle", [10, 7], E=20000, nu=0.3)
    (warning,) = Linkage(read_design(path), wide, subdivision=3).input_warnings()
    assert f"x as wide as the segment on line 5 of {path} (0.5 long)" in warning, warning


def test_a_design_far_from_the_origin_is_warned():
    """Georeferenced coordinates (1e8 mm from the origin for a 184 mm grid) deployed to a torque 0.06 % off
    without a word; 54,000 spans away it was within 1e-7. Warned beyond 10,000 spans."""
    from xshells.io.design import Design
    from xshells.linkage.grids import rhombic_grid
    from xshells.section import Material

    g = rhombic_grid(3, 3, spacing=50.0, angle=np.radians(30))
    m = Material.uniform("rectangle", [5, 3], E=20000, nu=0.3)
    near = Linkage(Design(np.array(g.vertices) + [5000.0, 0, 0], np.array(g.edges)), m, subdivision=4)
    assert not any("from the origin" in w for w in near.input_warnings())
    far = Linkage(Design(np.array(g.vertices) + [1e8, 2e7, 0], np.array(g.edges)), m, subdivision=4)
    (w,) = [w for w in far.input_warnings() if "from the origin" in w]
    assert "move it near the origin" in w and "1e+08" in w
