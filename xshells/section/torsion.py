"""Saint-Venant torsion constant from the warping function, with P2 elements.

The warping function ψ solves (paper §3, Landau & Lifshitz)::

    Δψ = 0 in Ω,    n·∇ψ = n·(y, -x) on ∂Ω,

and the torsion constant is ``J = ∫_Ω |(-y, x) + ∇ψ|² dA``, so that the
twisting stiffness is ``G J``.

Weak form. Since ``div (y, -x) = 0``, the Neumann load is a volume
integral: ``∫_∂Ω v n·(y, -x) ds = ∫_Ω ∇v·(y, -x) dA``. We assemble it
that way, so it is exact on the meshed domain (curved P2 edges included)
and needs no facet quadrature.

Why J converges from above. Write ``r⊥ = (-y, x)`` and ``a(u, v) = ∫∇u·∇v``.
Testing the (discrete) weak form with ``v = ψ_h`` gives
``∫ r⊥·∇ψ_h = -a(ψ_h, ψ_h)``, hence

    J_h = ∫|r⊥|² - a(ψ_h, ψ_h)       and      J_h - J = a(ψ - ψ_h, ψ - ψ_h) ≥ 0.

So the error in J is exactly the squared energy norm of the error in ψ:
O(h⁴) for P2 where ψ is smooth, and the residual estimator of ψ_h is an
estimate of the error in J; we refine where it is large.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.sparse.linalg import splu
from skfem import (Basis, BilinearForm, ElementTriP2, FacetBasis, Functional,
                   InteriorFacetBasis, LinearForm, MeshTri, MeshTri2, condense)
from skfem.helpers import dot, grad

from . import store
from .mesh import TriMesh, refine, triangulate_loops
from .profiles import Profile, signed_area
from .properties import DEFAULT_RTOL

MAX_LEVELS = 14
# the first mesh has about this many triangles per unit of (area / thinnest-part estimate)
INITIAL_TRIANGLES = 60
# Dörfler bulk: refine the fewest triangles carrying this share of the estimated error
BULK_FRACTION = 0.6


@BilinearForm
def _laplace(u, v, w):
    return dot(grad(u), grad(v))


@LinearForm
def _warping_load(v, w):
    # ∫ ∇v·(y, -x): the Neumann data n·(y, -x) moved inside by the divergence theorem
    x, y = w.x
    return y * grad(v)[0] - x * grad(v)[1]


@Functional
def _torsion_integrand(w):
    x, y = w.x
    g = grad(w["psi"])
    return (g[0] - y) ** 2 + (g[1] + x) ** 2


@Functional
def _interior_jump(w):
    # h_e ‖[∂ψ/∂n]‖² on interior edges (n is the side-0 normal)
    jump = dot(grad(w["psi0"]) - grad(w["psi1"]), w.n)
    return w.h * jump ** 2


@Functional
def _boundary_residual(w):
    # h_e ‖n·(y, -x) - ∂ψ/∂n‖² on boundary edges
    x, y = w.x
    n = w.n
    r = n[0] * y - n[1] * x - dot(grad(w["psi"]), n)
    return w.h * r ** 2


@dataclass(frozen=True)
class WarpingSolution:
    """ψ on one mesh.

    Attributes
    ----------
    basis : skfem.Basis
        P2 basis on the (possibly curved) mesh, in centroid-centred coordinates.
    psi : ndarray, shape (n_dofs,)
        Warping function, mean zero.
    torsion_constant : float
        ``J_h``.
    """

    basis: Basis
    psi: np.ndarray
    torsion_constant: float

    @property
    def n_dofs(self) -> int:
        return int(self.basis.N)

    @property
    def n_triangles(self) -> int:
        return int(self.basis.mesh.t.shape[1])


@dataclass(frozen=True)
class TorsionResult:
    """Outcome of the refinement loop.

    Attributes
    ----------
    torsion_constant : float
        J on the finest mesh.
    solution : WarpingSolution
        The finest solve.
    history : list of (n_dofs, J)
        One entry per level.
    converged : bool
        Whether the last relative change was below ``rtol``.
    """

    torsion_constant: float
    solution: WarpingSolution
    history: list = field(default_factory=list)
    converged: bool = True

    @property
    def relative_change(self) -> float:
        """|J_k - J_{k-1}| / J_k for the last two levels (inf with one level)."""
        return store.relative_change(self.history)


def skfem_mesh(mesh: TriMesh, origin: np.ndarray, projector=None) -> MeshTri | MeshTri2:
    """An scikit-fem mesh shifted so that ``origin`` (2,) is at (0, 0).

    With a ``projector`` (see :class:`Profile`), boundary-edge midpoints are
    moved onto the exact curve, giving an isoparametric quadratic mesh.
    """
    linear = MeshTri(np.ascontiguousarray((mesh.points - origin).T), np.ascontiguousarray(mesh.triangles.T))
    if projector is None:
        return linear
    quadratic = MeshTri2.from_mesh(linear)
    doflocs = quadratic.doflocs.copy()
    midpoint_dofs = linear.nvertices + linear.boundary_facets()
    doflocs[:, midpoint_dofs] = (projector(doflocs[:, midpoint_dofs].T + origin) - origin).T
    return replace(quadratic, doflocs=doflocs)


def solve_warping(mesh: MeshTri | MeshTri2) -> WarpingSolution:
    """Solve for ψ with P2 elements and integrate J on the mesh.

    The constant in ψ is fixed by pinning one node, then ψ is shifted to
    mean zero (only ∇ψ enters J).
    """
    basis = Basis(mesh, ElementTriP2())
    stiffness = _laplace.assemble(basis)
    load = _warping_load.assemble(basis)
    psi = np.zeros(basis.N)
    pinned = np.array([0])
    psi[:] = condense_solve(stiffness, load, pinned)
    psi -= np.asarray(basis.interpolate(psi)).mean()  # rough mean; only ∇ψ matters
    J = float(_torsion_integrand.assemble(basis, psi=basis.interpolate(psi)))
    return WarpingSolution(basis=basis, psi=psi, torsion_constant=J)


def condense_solve(matrix, rhs: np.ndarray, pinned: np.ndarray) -> np.ndarray:
    """Solve ``matrix x = rhs`` with ``x[pinned] = 0``; returns x, shape (n,)."""
    x = np.zeros(matrix.shape[0])
    A, b, _, free = condense(matrix, rhs, D=pinned)
    # The pinned Laplacian is symmetric positive definite: a symmetric ordering
    # without pivoting is several times faster than spsolve's default.
    factor = splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
    x[free] = factor.solve(b)
    return x


def error_indicators(solution: WarpingSolution) -> np.ndarray:
    """Residual error indicator η_T² per triangle, shape (n_triangles,).

    Edge terms only: for P2 on straight triangles the interior residual Δψ_h
    is small next to the flux jumps, and the sum of η_T² tracks J_h - J.
    """
    basis, psi = solution.basis, solution.psi
    mesh = basis.mesh
    element = basis.elem
    sides = [InteriorFacetBasis(mesh, element, side=i) for i in (0, 1)]
    jumps = _interior_jump.elemental(sides[0], psi0=sides[0].interpolate(psi), psi1=sides[1].interpolate(psi))
    boundary = FacetBasis(mesh, element)
    residual = _boundary_residual.elemental(boundary, psi=boundary.interpolate(psi))
    per_facet = np.zeros(mesh.facets.shape[1])
    np.add.at(per_facet, sides[0].find, 0.5 * jumps)  # an interior edge is shared by two triangles
    np.add.at(per_facet, boundary.find, residual)
    return per_facet[mesh.t2f].sum(axis=0)


def initial_max_area(profile: Profile) -> float:
    """Triangle area limit for the first mesh.

    Scaled by the thinnest part (area / perimeter is about half a wall
    thickness) so that thin walls get a few triangles across.
    """
    loops = profile.loops
    area = abs(sum(signed_area(l) for l in loops))
    perimeter = sum(np.linalg.norm(np.roll(l, -1, axis=0) - l, axis=1).sum() for l in loops)
    wall = 2 * area / perimeter
    return min(area / INITIAL_TRIANGLES, (wall / 2) ** 2)


def subdivide_loop(loop: np.ndarray, factor: int, projector) -> np.ndarray:
    """Split each edge of ``loop`` (n, 2) into ``factor`` pieces and project onto the curve; (n*factor, 2)."""
    t = np.arange(factor)[None, :, None] / factor
    nxt = np.roll(loop, -1, axis=0)
    points = (loop[:, None, :] * (1 - t) + nxt[:, None, :] * t).reshape(-1, 2)
    return projector(points)


def torsion_constant(profile: Profile, centroid: np.ndarray, rtol: float = DEFAULT_RTOL,
                     max_levels: int = MAX_LEVELS) -> TorsionResult:
    """Refine until J changes by less than ``rtol`` relative between levels.

    Polygons are refined adaptively (re-entrant corners need it to keep a
    fast rate); curved profiles are refined uniformly, halving the edge
    length each level.

    Parameters
    ----------
    profile : Profile
    centroid : ndarray, shape (2,)
        Origin for the solve (J does not depend on it, conditioning does).
    rtol : float
    max_levels : int
    """
    if profile.projector is not None:
        return _refine_uniformly(profile, centroid, rtol, max_levels)
    return _refine_adaptively(profile, centroid, rtol, max_levels)


def dorfler_marking(eta: np.ndarray, fraction: float) -> np.ndarray:
    """Boolean mask (m,) of the fewest triangles whose η_T² sum to ``fraction`` of the total.

    Refining a fixed share of the error each level makes the error drop by
    a fixed factor, so the change between levels measures the error.
    """
    order = np.argsort(eta)[::-1]
    cumulative = np.cumsum(eta[order])
    count = int(np.searchsorted(cumulative, fraction * cumulative[-1])) + 1
    marked = np.zeros(len(eta), dtype=bool)
    marked[order[:count]] = True
    return marked


def _converged(history: list, rtol: float) -> bool:
    if len(history) < 2:
        return False
    return abs(history[-1][1] - history[-2][1]) <= rtol * abs(history[-1][1])


def _refine_adaptively(profile, centroid, rtol, max_levels) -> TorsionResult:
    mesh = triangulate_loops(profile.loops, initial_max_area(profile))
    history = []
    for _ in range(max_levels):
        solution = solve_warping(skfem_mesh(mesh, centroid))
        history.append((solution.n_dofs, solution.torsion_constant))
        if _converged(history, rtol):
            break
        eta = error_indicators(solution)
        marked = dorfler_marking(eta, BULK_FRACTION)
        mesh = refine(mesh, np.where(marked, mesh.triangle_areas() / 4, -1.0))
    return TorsionResult(solution.torsion_constant, solution, history, _converged(history, rtol))


def _refine_uniformly(profile, centroid, rtol, max_levels) -> TorsionResult:
    # start from every 4th outline point; each level doubles the boundary resolution
    base = [loop[::4] for loop in profile.loops]
    history = []
    for level in range(max_levels):
        loops = [subdivide_loop(l, 2 ** level, profile.projector) for l in base]
        spacing = min(np.linalg.norm(np.roll(l, -1, axis=0) - l, axis=1).mean() for l in loops)
        mesh = triangulate_loops(loops, max_area=spacing ** 2)
        solution = solve_warping(skfem_mesh(mesh, centroid, profile.projector))
        history.append((solution.n_dofs, solution.torsion_constant))
        if _converged(history, rtol):
            break
    return TorsionResult(solution.torsion_constant, solution, history, _converged(history, rtol))


# ------------------------------------------------------------ shear stress
def _split_loop(loop: np.ndarray, h: float) -> np.ndarray:
    """``loop`` (n, 2) with every edge split into pieces no longer than ``h`` (straight edges)."""
    out = []
    nxt = np.roll(loop, -1, axis=0)
    for a, b in zip(loop, nxt):
        k = max(1, int(np.ceil(np.linalg.norm(b - a) / h)))
        out.append(a + (b - a) * (np.arange(k) / k)[:, None])
    return np.concatenate(out)


def reentrant_corners(loops: list[np.ndarray]) -> np.ndarray:
    """Vertices (k, 2) where the region bounded by ``loops`` (outer first, then holes) has an interior angle > 180°."""
    out = []
    for i, loop in enumerate(loops):
        orient = np.sign(signed_area(loop))
        e_in = loop - np.roll(loop, 1, axis=0)
        e_out = np.roll(loop, -1, axis=0) - loop
        turn = e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0]
        # the outer loop turns against its orientation at a re-entrant corner; a hole's convex corners are re-entrant
        mask = turn * orient < -1e-12 * np.abs(turn).max() if i == 0 else turn * orient > 1e-12 * np.abs(turn).max()
        out.append(loop[mask])
    return np.concatenate(out) if out else np.zeros((0, 2))


def boundary_shear_factor(solution: WarpingSolution, corners: np.ndarray | None = None, radius: float = 0.0) -> float:
    """``max |∇ψ + (−y, x)|`` over the boundary's quadrature points: τ_max = G θ′ times this.

    The Saint-Venant shear stress is ``τ = G θ′ (∇ψ + (−y, x))``; being
    harmonic, its magnitude peaks on the boundary. Points within ``radius``
    of a ``corners`` point (mesh coordinates) are left out.
    """
    from skfem import FacetBasis

    fb = FacetBasis(solution.basis.mesh, solution.basis.elem)
    g = fb.interpolate(solution.psi).grad  # (2, facets, points)
    x, y = np.asarray(fb.global_coordinates())
    mag = np.sqrt((g[0] - y) ** 2 + (g[1] + x) ** 2)
    if corners is not None and len(corners) and radius > 0:
        d = np.min(np.hypot(x[..., None] - corners[:, 0], y[..., None] - corners[:, 1]), axis=-1)
        mag = np.where(d > radius, mag, 0.0)
    return float(mag.max())


CORNER_EXCLUSION = 1.0 / 20.0


def shear_stress_factor(profile: Profile, centroid: np.ndarray, rtol: float = 1e-3, max_levels: int = 6):
    """``k_τ`` with ``τ_max = G θ′ k_τ`` (a length), refining uniformly until it changes by less than ``rtol``.

    Returns ``(k_τ, converged)``. At re-entrant corners (L, I, + and most
    custom sections) the exact shear stress is infinite; the maximum is
    taken outside disks of radius ``CORNER_EXCLUSION`` × the section's
    smallest extent around them, as a fillet of that radius would spread it.
    """
    loops = profile.loops
    extent = float(min(np.ptp(np.concatenate(loops), axis=0)))
    corners = reentrant_corners(loops) - centroid if profile.projector is None else np.zeros((0, 2))
    radius = CORNER_EXCLUSION * extent
    previous, value = None, float("nan")
    for level in range(max_levels):
        h = extent / (8 * 2**level)
        if profile.projector is not None:
            base = [loop[::4] for loop in loops]
            factor = max(1, int(np.ceil(max(np.linalg.norm(np.roll(b, -1, axis=0) - b, axis=1).max() for b in base) / h)))
            ring = [subdivide_loop(b, factor, profile.projector) for b in base]
        else:
            ring = [_split_loop(loop, h) for loop in loops]
        mesh = triangulate_loops(ring, max_area=h * h)
        value = boundary_shear_factor(solve_warping(skfem_mesh(mesh, centroid, profile.projector)), corners, radius)
        if previous is not None and abs(value - previous) <= rtol * value:
            return value, True
        previous = value
    return value, False
