"""An equilibrium at a fixed average opening angle, with its sensitivities (paper Appendix B).

The equilibrium ``x*(p)`` minimizes ``E(x, p)`` subject to ``a·x = ᾱ`` (``a``
averages the joint angles) with one joint's position and rotation held.
Differentiating its optimality conditions gives linear systems with the KKT
matrix

    K = [[H, a], [aᵀ, 0]]

on the free variables. ``H`` alone need not be positive definite (the
mechanism's opening mode is held only by the constraint), but on ``aᵀw = 0``
``H w = (H + ρ a aᵀ) w``, and the augmented matrix is positive definite at a
stable constrained equilibrium. So every KKT solve is two back-solves with
one Cholesky factor of ``H + ρ a aᵀ`` (one of them, with ``a``, cached).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.sparse as sp

from ..linkage.derivatives import hessian_derivative_product
from ..solve import NewtonOptions, NotPositiveDefinite, SparseCholesky, minimize
from ..solve.tether import Tether, Tethered as _Tethered  # noqa: F401  (Tether: the springs' home was here)

#: columns per block of :meth:`ConstrainedEquilibrium._kkt_solve_free`'s projection (a temporary of f × 16)
_PROJECTION_COLUMNS = 16


class ConstrainedEquilibrium:
    """One state of the linkage (flat or deployed) held at an average angle.

    Parameters
    ----------
    linkage : Linkage
        Owned by this object: it follows the design parameters.
    angle : float
        Average opening angle ᾱ (radians).
    pins : (6,) int array, optional
        Held variables (default: the central joint's position and rotation,
        chosen once so that they never move between solves).
    """

    def __init__(self, linkage, angle: float, pins=None, newton: NewtonOptions | None = None):
        self.L = linkage
        self.angle = float(angle)
        n = linkage.num_vars
        self.pins = linkage.rigid_pin_indices() if pins is None else np.asarray(pins, int)
        self.free = np.setdiff1d(np.arange(n), self.pins)
        self.a = np.zeros(n)
        self.a[linkage.angle_indices()] = 1.0 / linkage.num_joints
        self.af = self.a[self.free]
        self.newton = newton or _default_newton(linkage)
        self.chol = SparseCholesky()
        self.newton_iterations = 0
        self.Hfull = None
        self.chol_matrix = None  # H + ρ a aᵀ on the free variables, the matrix of ``chol``
        # Trial designs in an outer optimization: give up on the first
        # indefinite Hessian (a planar flat state that is a saddle buckles)
        # or after ``trial_iterations`` Newton steps, instead of following a
        # long escape to a state the optimizer will reject anyway.
        self.stop_on_indefinite = False
        self.trial_iterations: int | None = None
        # A dead load (generalized force, shape (n,)) the state is in equilibrium with: ∇E = load. It does
        # not depend on x or p, so the sensitivities and adjoints below are those of the unloaded problem.
        self.load: np.ndarray | None = None
        # Springs ½ k |x_r − t_r|² on some variables (a Tether): they add k to the Hessian's diagonal and
        # nothing else (no p dependence, no third derivatives). Inverse design holds a first deployed state
        # on the target with them and lets it go in steps.
        self.tether: Tether | None = None

    @property
    def nx(self) -> int:
        return self.L.num_vars

    def solve(self) -> None:
        """Newton-solve at the current rest lengths from the current state, then factorize."""
        options = self.newton
        if self.trial_iterations is not None:
            options = replace(options, max_iterations=min(options.max_iterations, self.trial_iterations))
        stop = (lambda it, rep: rep.indefinite_events > 0) if self.stop_on_indefinite else None
        problem = self.L if self.tether is None else _Tethered(self.L, self.tether)
        report = minimize(problem, fixed=self.pins, force=self.load, constraint=self._constraint(), options=options,
                          callback=stop)
        self.newton_iterations += report.iterations
        if not report.converged:
            if report.message == "stopped by callback":
                raise ArithmeticError(f"{self._state_name()} has an indefinite Hessian (unstable)")
            raise ArithmeticError(f"{self._state_name(True)} did not converge ({report.message})")
        self.L.update_source_frame()
        self.factorize()

    def _constraint(self):
        """The solve's one linear constraint: the average angle held."""
        return self.a, self.angle

    def _state_name(self, solve: bool = False) -> str:
        return f"equilibrium at {np.degrees(self.angle):.2f}°" if solve else f"the state at {np.degrees(self.angle):.2f}°"

    def factorize(self) -> None:
        """Hessian blocks at the current state and the Cholesky factor of ``H + ρ a aᵀ`` (free variables)."""
        nx = self.nx
        Hfull = self.L.hessian(with_rest_lengths=True).tocsr()
        if self.tether is not None:
            Hfull = (Hfull + self.tether.diagonal(Hfull.shape[0])).tocsr()
        self.Hfull = Hfull
        self.Hxp = Hfull[:nx, nx:].tocsr()
        self.Hpx = Hfull[nx:, :nx].tocsr()
        self.Hpp = Hfull[nx:, nx:].tocsr()
        H = Hfull[:nx, :nx][self.free][:, self.free]
        idx = np.flatnonzero(self.af)
        rho = 10.0 * float(np.abs(H.diagonal()).max()) / float(self.af @ self.af)
        for _ in range(8):
            aa = sp.csr_matrix((np.full(len(idx) ** 2, rho * self.af[idx[0]] ** 2),
                                (np.repeat(idx, len(idx)), np.tile(idx, len(idx)))), shape=H.shape)
            try:
                self.chol_matrix = (H + aa).tocsr()
                self.chol.factorize(self.chol_matrix)
                break
            except NotPositiveDefinite:
                rho *= 100.0
        else:
            raise ArithmeticError(f"the constrained equilibrium at {np.degrees(self.angle):.2f}° is unstable")
        self._v = self.chol.solve(self.af)
        self._av = float(self.af @ self._v)

    def kkt_solve(self, r: np.ndarray) -> np.ndarray:
        """``w`` with ``H w + a μ = r``, ``aᵀw = 0`` on the free variables; (num_vars,), zero on the pins."""
        u = self.chol.solve(np.asarray(r, float)[self.free])
        w = np.zeros(self.nx)
        w[self.free] = u - (float(self.af @ u) / self._av) * self._v
        return w

    def kkt_solve_many(self, R: np.ndarray) -> np.ndarray:
        """:meth:`kkt_solve` for the columns of ``R`` (num_vars, k) at once."""
        return self._kkt_solve_free(np.asarray(R, float)[self.free])

    def _kkt_solve_free(self, Rf: np.ndarray) -> np.ndarray:
        """:meth:`kkt_solve_many` given the free rows (f, k) of the right-hand sides."""
        U = self.chol.solve(Rf)
        # the rank-one projection a few columns at a time: one np.outer of all (f, k) formed a temporary as
        # large as U first (41 ms of a 0.2 s state Jacobian at 8,700 × 333); the same products and
        # differences, so the same bits (BLAS dger would fuse them, and the design loop follows rounding)
        c = (self.af @ U) / self._av
        for j in range(0, U.shape[1], _PROJECTION_COLUMNS):
            U[:, j : j + _PROJECTION_COLUMNS] -= np.outer(self._v, c[j : j + _PROJECTION_COLUMNS])
        W = np.zeros((self.nx, U.shape[1]))
        W[self.free] = U
        return W

    def state_jacobian(self) -> np.ndarray:
        """``∂x*/∂p`` (num_vars, S), dense: one multi-column KKT solve.

        The right-hand sides are formed from the free rows only and column-major, as CHOLMOD takes them
        (from a row-major array cvxopt copied them element by element: 17 ms of a 0.24 s solve at 8,000 × 340).
        """
        return self._kkt_solve_free((-self.Hxp[self.free]).toarray(order="F"))

    def energy_hessian_p(self, X=None) -> np.ndarray:
        """``d²E(x*(p), p)/dp² = H_pp + H_px ∂x*/∂p`` (S, S), dense and exact.

        (``dE/dp = ∂E/∂p`` at the constrained equilibrium, so no third
        derivatives enter.)
        """
        X = self.state_jacobian() if X is None else X
        Hs = self.Hpp.toarray() + self.Hpx @ X
        return 0.5 * (Hs + Hs.T)

    def state_derivative(self, dp: np.ndarray) -> np.ndarray:
        """First-order change ``δx = ∂x*/∂p · δp``."""
        return self.kkt_solve(-(self.Hxp @ dp))

    def energy_gradient_p(self) -> np.ndarray:
        """``∂E/∂p`` at the state (equal to ``dE(x*(p), p)/dp``: the angle is held)."""
        return self.L.gradient(with_rest_lengths=True)[self.nx:]

    def hessian_derivative_product(self, dx, dp, v) -> np.ndarray:
        """Directional derivative of the (x, p) Hessian along ``(δx, δp)``, applied to ``v`` (nx + S,)."""
        return hessian_derivative_product(self.L, dx, dp, v, with_rest_lengths=True)

    def second_order_change(self, dx, dp) -> np.ndarray:
        """``δpᵀ ∂²x*/∂p² δp`` (Appendix A), given ``δx`` for ``δp``."""
        z = self.hessian_derivative_product(dx, dp, np.concatenate([dx, dp]))
        return self.kkt_solve(-z[: self.nx])

    def predict(self, dp) -> np.ndarray:
        """Second-order Taylor prediction of ``x*(p + δp)`` (without moving the state)."""
        dx = self.state_derivative(dp)
        return self.L.get_vars() + dx + 0.5 * self.second_order_change(dx, dp)


def _default_newton(linkage) -> NewtonOptions:
    # Tight: adjoint gradients are only as accurate as the equilibria. The
    # floor is what round-off in the stiff stretching terms leaves.
    eps = np.finfo(float).eps
    rods = linkage.rods
    coords = float(np.abs(rods.points).max())
    floor = 10.0 * eps * float(rods.ks.max()) * coords / float(rods.rest_lengths.min()) * np.sqrt(linkage.num_vars)
    B = float(np.max(rods.bending_stiffness))
    span = float(np.ptp(rods.points, axis=0).max())
    return NewtonOptions(gradient_tolerance=max(1e-10 * B / span**2 * np.sqrt(linkage.num_vars), floor), max_iterations=100,
                         saddle_gradient_factor=float("inf"))


class FreeEquilibrium(ConstrainedEquilibrium):
    """A state of the linkage with its opening angle free: where the assembled layout settles once let go.

    The design optimization holds its flat state at the flat angle ᾱ₀, but a linkage built from the design
    and released settles where its energy is least, and with the rest lengths of a design in progress that
    can be several degrees more closed (measured on the swimming ray's stage designs: 20.1° held, 17.5°
    released, the nearest beams of one family 21.9 and 18.1 mm apart). What is built is the released state,
    so a bound on it (the beams' clearance) follows this one.

    The sensitivities are those of an unconstrained minimum: ``H δx = −H_xp δp`` on the free variables, with
    ``H`` positive definite at a stable state. ``angle``: the average angle of the last factorized state (not held).
    """

    def __init__(self, linkage, pins=None, newton: NewtonOptions | None = None):
        super().__init__(linkage, linkage.average_angle(), pins=pins, newton=newton)

    def _constraint(self):
        return None  # the angle is free

    def _state_name(self, solve: bool = False) -> str:
        return f"the released state (now at {np.degrees(self.L.average_angle()):.2f}°)"

    def factorize(self) -> None:
        """Hessian blocks at the current state and the Cholesky factor of ``H`` (free variables)."""
        self.angle = float(self.L.average_angle())
        nx = self.nx
        Hfull = self.L.hessian(with_rest_lengths=True).tocsr()
        self.Hfull = Hfull
        self.Hxp = Hfull[:nx, nx:].tocsr()
        self.Hpx = Hfull[nx:, :nx].tocsr()
        self.Hpp = Hfull[nx:, nx:].tocsr()
        self.chol_matrix = Hfull[:nx, :nx][self.free][:, self.free].tocsr()
        try:
            self.chol.factorize(self.chol_matrix)
        except NotPositiveDefinite:
            raise ArithmeticError(f"the released state (at {np.degrees(self.angle):.2f}°) is unstable") from None

    def kkt_solve(self, r: np.ndarray) -> np.ndarray:
        """``w`` with ``H w = r`` on the free variables; (num_vars,), zero on the pins."""
        w = np.zeros(self.nx)
        w[self.free] = self.chol.solve(np.asarray(r, float)[self.free])
        return w

    def _kkt_solve_free(self, Rf: np.ndarray) -> np.ndarray:
        W = np.zeros((self.nx, Rf.shape[1]))
        W[self.free] = self.chol.solve(Rf)
        return W
