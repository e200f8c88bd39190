"""The design objective J(p) of eq. 5 and the flat-state constraints, with adjoint derivatives.

Variables are the per-segment rest lengths, scaled by their initial values
(``q = p / p₀``) so that a trust radius of 0.1 means "10 % longer or
shorter" for every segment.

* ``J = γ/E₀ E(x₂D*) + (1−γ)/E₀ E(x₃D*) + β/(2 l₀²) T(x₃D*)``;
* planarity ``c = ‖S_z x₂D* − h₀‖²`` (``h₀`` the flat layout's height);
* minimum angle ``KS(S_α x₂D*, s)`` in the overflow-safe form of Appendix A.

Gradients use one adjoint solve per state-only term; Hessian-vector products
use the forward sensitivity ``δx``, the adjoint's variation ``δw`` and the
Hessian's directional derivative (Appendix B), all with the factorizations
of the two equilibria.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .equilibrium import ConstrainedEquilibrium


@dataclass(frozen=True)
class DesignWeights:
    """Weights of eq. 5.

    Attributes
    ----------
    gamma : float
        Share of the flat state's energy, in [0, 1]. Default 0.9, as in the
        reference implementation.
    beta : float
        Weight of the fitting term (≥ 0). Default 1000: with γ = 0.9 it
        keeps the balance ``(1 − γ)/β = 1e-4`` of the deployed energy
        against the fit, and the flat energy then counts (docs/design.md:
        on the wiggly banana the flat energy ends 7.2× lower, against 5.4×
        with γ = 0.5, β = 5000, the same deployed energy and fit).
    ks_sharpness : float
        ``s`` of the KS minimum (radians).
    buckling : float
        Weight of the planar-buckling penalty (≥ 0; 0, the default: off).
        The penalty asks the layout's *planar* opening to the deployed angle
        to be unstable out of its plane, so that a deployment from flat
        buckles (:meth:`DesignProblem.planar_buckling`); it is scaled so that
        at the starting design it is ``buckling`` times ``J``.
    buckling_target : float
        The smooth minimum ``σ`` of the planar state's lowest out-of-plane
        eigenvalues, relative to their starting size, that the penalty asks
        for (< 0: unstable): it acts while ``σ > buckling_target``.
    """

    gamma: float = 0.9
    beta: float = 1000.0
    ks_sharpness: float = 0.01
    buckling: float = 0.0
    buckling_target: float = -0.5

    def __post_init__(self):
        if not (0.0 <= self.gamma <= 1.0):
            raise InputError(f"gamma must lie in [0, 1], got {self.gamma}")
        if not (self.beta >= 0.0 and np.isfinite(self.beta)):
            raise InputError(f"beta must be a non-negative number, got {self.beta}")
        if not self.ks_sharpness > 0:
            raise InputError(f"the KS sharpness must be positive, got {self.ks_sharpness}")
        if not (self.buckling >= 0.0 and np.isfinite(self.buckling)):
            raise InputError(f"the buckling weight must be a non-negative number, got {self.buckling}")
        if not (np.isfinite(self.buckling_target) and self.buckling_target < 1.0):
            raise InputError(f"the buckling target must be below 1 (the starting size), got {self.buckling_target}")


def ks_min(alpha: np.ndarray, s: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Smooth minimum ``KS(α, s) = min α − s log Σ exp((min α − α_i)/s)``.

    Returns
    -------
    value : float
    weights : (n,) array
        ``∂KS/∂α`` (the softmin weights, summing to one).
    curvature : callable
        ``v ↦ ∂²KS/∂α² v``.
    """
    m = float(alpha.min())
    e = np.exp((m - alpha) / s)
    total = float(e.sum())
    pi = e / total

    def curvature(v):
        return -(pi * v - pi * float(pi @ v)) / s

    return m - s * np.log(total), pi, curvature


#: KS sharpness of :meth:`DesignProblem.flat_clearance`, on distances over the beams' width: the smooth minimum
#: lies below the smallest distance by at most 0.02·log(pairs)·width (0.14 width for 1,000 pairs), so the barrier
#: at the width keeps the beams little more than that apart
CLEARANCE_SHARPNESS = 0.02
#: pairs of rod points farther apart than this many widths are left out of the clearance (their weight is e⁻⁵⁰ where the nearest pair is a width apart)
CLEARANCE_REACH = 2.0


class _StateTerm:
    """A scalar function of one equilibrium state: value, ∇ₓ and ∇²ₓ·v, as callables on the linkage."""

    def __init__(self, value, gradient, hessian_vector):
        self.value, self.gradient, self.hessian_vector = value, gradient, hessian_vector


def _move_equilibrium(eq, dp, p) -> None:
    """Re-solve one equilibrium at new rest lengths ``p``: from the second-order prediction
    (Appendix A), or, if that fails, from the current state."""
    from ..linkage.state import restore, snapshot

    start = snapshot(eq.L)
    x_pred = eq.predict(dp)
    eq.L.set_rest_lengths(p)
    if np.isfinite(x_pred).all():
        try:
            # A long prediction can turn a joint half a turn from its source frame, where the frame transport
            # divides by zero. The solve then stops on the non-finite state (InvalidState) and the state is
            # re-solved from where it was, so NumPy's warnings on the way are noise to the user.
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                eq.L.set_vars(x_pred)
                eq.solve()
            return
        except (ArithmeticError, InputError):
            restore(eq.L, start)
            eq.L.set_rest_lengths(p)
    eq.solve()


class DesignProblem:
    """J, c and the KS angle constraint as functions of the scaled rest lengths ``q``.

    Parameters
    ----------
    linkage : Linkage
        At its flat assembly state (the rest lengths it holds are ``p₀``).
    target_angle : float
        ᾱ_tgt (radians).
    weights : DesignWeights
    fitting : object
        The fitting term on joint positions (see :mod:`.fitting`):
        ``value(P)``, ``gradient(P)`` (n, 3), ``hessian_vector(P, dP)`` (n, 3).
        Default: the paper's defaults at the initial deployed state.
    flat_angle : float, optional
        ᾱ₀ (default: the flat state's current average angle).
    deployed : Linkage, optional
        An already deployed copy of ``linkage`` at ``target_angle`` (skips
        the deployment).
    deploy_steps : int
        Angle increments for the initial deployment.
    deployed_load : (n,) array, optional
        A dead load holding the deployed state (see :meth:`set_deployed_load`).
    deployed_tether : Tether, optional
        Springs holding the deployed state (a :class:`~.equilibrium.Tether`; see ``deployed.tether``).

    Attributes ``flat_note`` (why ᾱ₀ differs from the drawn angle, or "") and
    ``input_warnings`` (:meth:`Linkage.input_warnings`) are set by whoever
    built the problem from a file (:func:`xshells.design.run.build_problem`).
    """

    flat_note: str = ""
    input_warnings: tuple = ()
    fresh_copy = None  # set by design.run.build_problem(keep_copy=True): a callable giving the same problem anew

    def __init__(self, linkage, target_angle: float, weights: DesignWeights = DesignWeights(), fitting=None,
                 flat_angle: float | None = None, deployed=None, deploy_steps: int = 20, direction: str = "up",
                 deployed_load=None, deployed_tether=None):
        self.w = weights
        self.p0 = linkage.rest_lengths
        flat_angle = linkage.average_angle() if flat_angle is None else float(flat_angle)
        self.flat = ConstrainedEquilibrium(linkage, flat_angle)
        if deployed is None:
            from ..deploy.simulate import DeployOptions, deploy

            deployed = copy.deepcopy(linkage)
            res = deploy(deployed, target_angle, DeployOptions(steps=deploy_steps, direction=direction))
            if not res.converged:
                raise InputError(f"the initial design does not deploy to {np.degrees(target_angle):.2f}° ({res.message})")
        self.deployed = ConstrainedEquilibrium(deployed, target_angle)
        if deployed_load is not None:
            self.deployed.load = np.array(deployed_load, float)
        self.deployed.tether = deployed_tether
        self.flat.solve()
        self.deployed.solve()
        n = linkage.num_joints
        self.pos_rows = ((9 * np.arange(n))[:, None] + np.arange(3)[None, :])
        self.angle_rows = linkage.angle_indices()
        self.Sz = linkage.height_selector()
        self.h0 = float(np.mean(self.Sz @ linkage.get_vars()))
        if fitting is None:
            from .fitting import FittingTerm

            fitting = FittingTerm.paper_defaults(self.deployed.L)
        self.fitting = fitting
        P = self.deployed.L.joint_positions()
        self.l0 = float(np.linalg.norm(np.ptp(P, axis=0)))
        self.E0 = float(self.deployed.L.energy())
        self._q = np.ones(len(self.p0))
        self._cache: dict = {}
        self.planar = None  # the planar branch at the deployed angle, with weights.buckling > 0
        self._released = None  # the FreeEquilibrium that released_flat solves (built on first use)
        if weights.buckling > 0:
            self._init_planar(target_angle)

    @property
    def equilibria(self) -> tuple:
        """The equilibria that follow the design: flat, deployed, and the planar one if the penalty is on."""
        return (self.flat, self.deployed) if self.planar is None else (self.flat, self.deployed, self.planar)

    def released_flat(self):
        """The flat state let go, where the held flat state pushes to close; None where it pushes to open.

        The optimization holds its flat state at ᾱ₀. A layout built from the design and let go settles where
        its energy is least, and that is what is built and what the inverse design's checks measure. Where the
        held state's energy falls as the layout closes (``a·∇E > 0``), the released state is more closed and
        its beams of one family nearer (measured on the swimming ray's stage designs: 20.1° held, 17.5°
        released, the nearest beams 21.9 and 18.1 mm apart), so the clearance is measured there. Where it
        falls as the layout opens, the released state is more open (up to 87° from a first stage design) and
        the held state's clearance is the smaller: it is used, and the long release is not solved. At zero
        torque the two states are one, so the clearance is continuous across the switch.

        Solved afresh from the held state at every design (:class:`~.equilibrium.FreeEquilibrium`), so it is
        a function of the design alone, not of the designs visited before. None also where that solve fails.
        """
        key = ("released",)
        if key in self._cache:
            return self._cache[key]
        from ..linkage.state import restore, snapshot
        from .equilibrium import FreeEquilibrium

        flat, eq = self.flat, None
        g = flat.L.gradient()
        if float(flat.af @ g[flat.free]) > 0.0:  # closing lowers the energy
            if self._released is None:
                self._released = FreeEquilibrium(copy.deepcopy(flat.L), pins=flat.pins)
            eq = self._released
            restore(eq.L, snapshot(flat.L))
            try:
                eq.solve()
            except (ArithmeticError, InputError):
                eq = None
        self._cache[key] = eq
        return eq

    def _init_planar(self, target_angle: float, modes: int = 4) -> None:
        from .planar import buckling_block, out_of_plane_modes, planar_equilibrium

        try:
            self.planar = planar_equilibrium(self.flat.L, target_angle)
            self._planar_block = B = buckling_block(self.planar)
            self._planar_M = self.planar.L.mass_matrix()[B][:, B].tocsc()
            self._planar_modes = modes
            lam, _ = out_of_plane_modes(self.planar, B, self._planar_M, modes)
        except ArithmeticError as exc:
            raise InputError(f"the planar-buckling penalty cannot follow this layout: its planar opening to "
                             f"{np.degrees(target_angle):.2f}° fails ({exc}); design without it") from exc
        # relative to the starting size of the lowest eigenvalue: σ starts at about 1 (stable) or −1 (buckles)
        self._planar_ref = float(abs(lam[0])) or float(np.abs(lam).max()) or 1.0
        t = self.w.buckling_target
        base = self._base_terms()["J"]
        self._planar_eta = 2.0 * self.w.buckling * abs(base) / (1.0 - t) ** 2

    # ------------------------------------------------------------ state terms
    def _fit_term(self) -> _StateTerm:
        L, rows, fit = self.deployed.L, self.pos_rows, self.fitting

        def value():
            return float(fit.value(L.joint_positions()))

        def gradient():
            g = np.zeros(L.num_vars)
            g[rows] = fit.gradient(L.joint_positions())
            return g

        def hessian_vector(dx):
            h = np.zeros(L.num_vars)
            h[rows] = fit.hessian_vector(L.joint_positions(), dx[rows])
            return h

        return _StateTerm(value, gradient, hessian_vector)

    def _planarity_term(self) -> _StateTerm:
        L, Sz = self.flat.L, self.Sz

        def value():
            h = Sz @ L.get_vars() - self.h0
            return float(h @ h)

        def gradient():
            return 2.0 * (Sz.T @ (Sz @ L.get_vars() - self.h0))

        def hessian_vector(dx):
            return 2.0 * (Sz.T @ (Sz @ dx))

        return _StateTerm(value, gradient, hessian_vector)

    def _angle_term(self) -> _StateTerm:
        L, rows, s = self.flat.L, self.angle_rows, self.w.ks_sharpness

        def value():
            return ks_min(L.get_vars()[rows], s)[0]

        def gradient():
            g = np.zeros(L.num_vars)
            g[rows] = ks_min(L.get_vars()[rows], s)[1]
            return g

        def hessian_vector(dx):
            h = np.zeros(L.num_vars)
            h[rows] = ks_min(L.get_vars()[rows], s)[2](dx[rows])
            return h

        return _StateTerm(value, gradient, hessian_vector)

    # -------------------------------------------------------------- updates
    def set_deployed_load(self, load) -> None:
        """Hold the deployed state under a dead load ``load`` (shape (n,), or None) and re-solve it there.

        The load changes the state, not the design: the objective and its
        derivatives are then those of the loaded equilibrium.
        """
        self.deployed.load = None if load is None else np.array(load, float)
        self.deployed.solve()
        self._cache = {}

    def set_q(self, q) -> None:
        """Move both equilibria to the design ``p = q p₀`` (second-order predictor, then Newton)."""
        q = np.asarray(q, float)
        if q.shape != self._q.shape:
            raise InputError(f"expected {len(self._q)} design variables, got shape {q.shape}")
        if np.array_equal(q, self._q):
            return
        dp = (q - self._q) * self.p0
        p = q * self.p0
        if not (p > 0).all():
            raise ArithmeticError("a rest length would become non-positive")
        from ..linkage.state import restore, snapshot

        saved = [snapshot(eq.L) for eq in self.equilibria]
        try:
            for eq in self.equilibria:
                _move_equilibrium(eq, dp, p)
        except ArithmeticError:
            for eq, st in zip(self.equilibria, saved):  # stay at the last good design
                restore(eq.L, st)
                eq.factorize()
            self._cache = {}
            raise
        self._q = q.copy()
        self._cache = {}

    def _adjoint(self, name, eq, term):
        key = ("adjoint", name)
        if key not in self._cache:
            self._cache[key] = eq.kkt_solve(term.gradient())
        return self._cache[key]

    def _sensitivity(self, eq, dp, key):
        k = ("dx", key, dp.tobytes())
        if k not in self._cache:
            self._cache = {kk: v for kk, v in self._cache.items() if kk[0] != "dx" or kk[1] != key}
            self._cache[k] = eq.state_derivative(dp)
        return self._cache[k]

    def _state_gradient_p(self, eq, term, name):
        """``d term(x*(p))/dp = −H_pxᵀ w`` with ``K w = ∇ₓ term``."""
        w = self._adjoint(name, eq, term)
        return -(eq.Hpx @ w)

    def _state_hessp_p(self, eq, term, name, dp, key):
        w = self._adjoint(name, eq, term)
        dx = self._sensitivity(eq, dp, key)
        nx = eq.nx
        Dw = eq.hessian_derivative_product(dx, dp, np.concatenate([w, np.zeros(len(dp))]))
        dw = eq.kkt_solve(term.hessian_vector(dx) - Dw[:nx])
        return -(eq.Hpx @ dw + Dw[nx:])

    @staticmethod
    def _energy_hessp_p(eq, dx, dp):
        return eq.Hpx @ dx + eq.Hpp @ dp

    # ----------------------------------------------------------- objective
    def _base_terms(self) -> dict:
        e2, e3 = self.flat.L.energy() / self.E0, self.deployed.L.energy() / self.E0
        t = self._fit_term().value() / self.l0**2
        w = self.w
        return {"J": w.gamma * e2 + (1 - w.gamma) * e3 + 0.5 * w.beta * t, "flat_energy": e2, "deployed_energy": e3, "fit": t}

    def terms(self, q) -> dict:
        """``J`` and its terms (dimensionless) at ``q``: with the planar-buckling penalty on, also
        ``planar_buckling`` (the penalty, included in ``J``) and ``planar_sigma`` (σ)."""
        self.set_q(q)
        out = self._base_terms()
        if self.planar is not None:
            sigma, _ = self.planar_buckling(q)
            pen = 0.5 * self._planar_eta * max(0.0, sigma - self.w.buckling_target) ** 2
            out.update(J=out["J"] + pen, planar_buckling=pen, planar_sigma=sigma)
        return out

    def objective(self, q) -> float:
        return self.terms(q)["J"]

    def gradient(self, q) -> np.ndarray:
        self.set_q(q)
        w = self.w
        g = (w.gamma * self.flat.energy_gradient_p() + (1 - w.gamma) * self.deployed.energy_gradient_p()) / self.E0
        if w.beta:
            g = g + 0.5 * w.beta / self.l0**2 * self._state_gradient_p(self.deployed, self._fit_term(), "fit")
        g = g * self.p0
        if self.planar is not None:
            g = g + self._planar_eta * self._planar_excess(q) * self.planar_buckling(q)[1]
        return g

    def _planar_excess(self, q) -> float:
        return max(0.0, self.planar_buckling(q)[0] - self.w.buckling_target)

    def hessp(self, q, v) -> np.ndarray:
        self.set_q(q)
        dp = np.asarray(v, float) * self.p0
        w = self.w
        out = np.zeros(len(dp))
        if w.gamma:
            dx2 = self._flat_dx(dp)
            out += w.gamma / self.E0 * self._energy_hessp_p(self.flat, dx2, dp)
        dx3 = self._sensitivity(self.deployed, dp, "3d")
        out += (1 - w.gamma) / self.E0 * self._energy_hessp_p(self.deployed, dx3, dp)
        if w.beta:
            out += 0.5 * w.beta / self.l0**2 * self._state_hessp_p(self.deployed, self._fit_term(), "fit", dp, "3d")
        out = out * self.p0
        if self.planar is not None and self._planar_excess(q) > 0:  # the penalty's Gauss–Newton part
            ds = self.planar_buckling(q)[1]
            out = out + self._planar_eta * ds * float(ds @ np.asarray(v, float))
        return out

    def dense_hessian(self, q) -> np.ndarray:
        """A dense model of ``∇²J`` in ``q`` (S, S), from multi-column solves with the equilibria's factors.

        The energy terms are exact (:meth:`ConstrainedEquilibrium.energy_hessian_p`);
        the fitting term is its Gauss–Newton part ``Xᵀ ∇²T X`` (``X`` the
        deployed joint positions' Jacobian in ``p``), without the adjoint's
        third-derivative term that :meth:`hessp` includes. Costs ``2S``
        back-solves, no Hessian derivative.
        """
        self.set_q(q)
        k = ("dense_hessian",)
        if k in self._cache:
            return self._cache[k]
        w = self.w
        X3 = self.deployed.state_jacobian()
        H = (1 - w.gamma) / self.E0 * self.deployed.energy_hessian_p(X3)
        if w.gamma:
            H += w.gamma / self.E0 * self.flat.energy_hessian_p()
        if w.beta:
            L, rows, fit = self.deployed.L, self.pos_rows, self.fitting
            P = L.joint_positions()
            Xp = X3[rows.ravel()]  # (3n, S)
            if hasattr(fit, "hessian_vectors"):
                HX = fit.hessian_vectors(P, Xp.T.reshape(Xp.shape[1], -1, 3)).reshape(Xp.shape[1], -1).T
            else:
                HX = np.stack([fit.hessian_vector(P, Xp[:, j].reshape(-1, 3)).ravel() for j in range(Xp.shape[1])], axis=1)
            H += 0.5 * w.beta / self.l0**2 * (Xp.T @ HX)
        H = self.p0[:, None] * H * self.p0[None, :]
        if self.planar is not None and self._planar_excess(q) > 0:
            ds = self.planar_buckling(q)[1]
            H = H + self._planar_eta * np.outer(ds, ds)
        self._cache[k] = H
        return H

    def _flat_dx(self, dp):
        k = ("dx2", dp.tobytes())
        if k not in self._cache:
            self._cache[k] = self.flat.state_derivative(dp)
        return self._cache[k]

    # ---------------------------------------------------------- constraints
    def planarity(self, q) -> float:
        self.set_q(q)
        return self._planarity_term().value() / self.l0**2

    def planarity_gradient(self, q) -> np.ndarray:
        self.set_q(q)
        return self._state_gradient_p(self.flat, self._planarity_term(), "planarity") / self.l0**2 * self.p0

    def planarity_hessp(self, q, v) -> np.ndarray:
        self.set_q(q)
        dp = np.asarray(v, float) * self.p0
        return self._state_hessp_p(self.flat, self._planarity_term(), "planarity", dp, "2d") / self.l0**2 * self.p0

    def min_angle(self, q) -> float:
        self.set_q(q)
        return self._angle_term().value()

    def min_angle_gradient(self, q) -> np.ndarray:
        self.set_q(q)
        return self._state_gradient_p(self.flat, self._angle_term(), "angle") * self.p0

    def min_angle_hessp(self, q, v) -> np.ndarray:
        self.set_q(q)
        dp = np.asarray(v, float) * self.p0
        return self._state_hessp_p(self.flat, self._angle_term(), "angle", dp, "2d") * self.p0

    # ------------------------------------------------------------ clearance
    def flat_clearance(self, q, width: float) -> tuple[float, np.ndarray]:
        """How close the flat state's beams of one family come, as a smooth minimum, and its gradient in ``q``.

        Beams of one family lie in one layer and never meet at a joint, so where two of them come closer than
        the beams are wide the layout cannot be built (:func:`xshells.linkage.clearance.beam_overlaps`
        measures it so: in-plane distances between rod points of two beams of one family). This is the KS
        minimum of those distances over ``width`` (sharpness :data:`CLEARANCE_SHARPNESS`), times ``width``:
        at most the smallest distance, so ``KS ≥ width`` keeps every pair apart. Only pairs within
        ``CLEARANCE_REACH · width`` are looked at; where none is, the value is that reach and the gradient 0.

        Returns
        -------
        (value, gradient) : (float, (S,) array)
            The gradient is that of the flat equilibrium's value as the rest lengths ``q p₀`` move (adjoint).
        """
        from ..linkage.clearance import same_family_pairs

        self.set_q(q)
        key = ("clearance", float(width))
        if key in self._cache:
            return self._cache[key]
        eq = self.released_flat() or self.flat
        L = eq.L
        reach = CLEARANCE_REACH * width
        pairs, pts, _, _ = same_family_pairs(L, reach)
        if not len(pairs):
            out = (reach, np.zeros(len(self.p0)))
        else:
            i, j = pairs[:, 0], pairs[:, 1]
            diff = pts[i] - pts[j]
            d = np.linalg.norm(diff, axis=1)
            ks, pi, _ = ks_min(d / width, CLEARANCE_SHARPNESS)
            u = (pi / np.maximum(d, 1e-300))[:, None] * diff  # ∂KS·width/∂(point i) in the plane
            G = np.zeros((len(pts), 3))
            np.add.at(G[:, :2], i, u)
            np.add.at(G[:, :2], j, -u)
            g_rod = np.zeros(L.rods.num_vars)
            g_rod[: G.size] = G.ravel()
            gx = L.rod_jacobian().T @ g_rod
            term = _StateTerm(lambda: ks * width, lambda: gx, None)
            out = (float(ks * width), self._state_gradient_p(eq, term, ("clearance", float(width))) * self.p0)
        self._cache[key] = out
        return out

    # ------------------------------------------------------------ stability
    def flat_stability(self, q, modes: int = 4) -> tuple[float, np.ndarray]:
        """How far the flat state is from buckling, and its gradient in ``q``.

        The smallest eigenvalues ``λ_i`` of ``H v = λ M₀ v`` on the
        constraint's tangent space (``aᵀv = 0``; ``M₀`` the mass matrix of the
        initial flat state, held fixed so that ``λ`` depends on ``p`` only
        through ``H``), relative to the initial smallest one ``λ_ref`` and
        aggregated by the smooth minimum ``σ = KS(λ/λ_ref, 0.05)`` over the
        lowest ``modes`` (the lowest modes are close together and cross, so
        the bare minimum is not differentiable). While ``σ > 0`` the planar
        flat equilibrium is stable, hence it is the equilibrium found, and
        the planarity constraint ``c = 0`` holds; at ``σ ≤ 0`` the flat state
        buckles out of the plane. Unlike ``c``, whose gradient vanishes on
        the whole planar set, ``σ`` tells the optimizer how close a design is
        to buckling.

        ``dλ_i/dp = ∂³E[v_i, v_i, ·]_p − H_px w_i`` with ``K w_i =
        ∂³E[v_i, v_i, ·]_x`` (one adjoint solve each); ``∂³E[v, v, ·]`` is
        the second difference of gradients along ``v``.

        Returns
        -------
        value : float
        gradient : (S,) array
        """
        self.set_q(q)
        key = ("stability", modes)
        if key in self._cache:
            return self._cache[key]
        import scipy.sparse.linalg as spla

        eq = self.flat
        if getattr(self, "_M0", None) is None:
            self._M0 = self.flat.L.mass_matrix()[eq.free][:, eq.free].tocsc()
        M = self._M0
        n = len(eq.free)
        op = spla.LinearOperator((n, n), matvec=eq.chol.solve, dtype=float)
        v0 = getattr(self, "_stability_v0", None)
        lam, vecs = spla.eigsh(eq.chol_matrix, k=modes, M=M, sigma=0.0, which="LM", OPinv=op, tol=1e-10,
                               v0=np.ones(n) if v0 is None else v0)
        order = np.argsort(lam)
        lam, vecs = lam[order], vecs[:, order]
        self._stability_v0 = vecs[:, 0].copy()
        if getattr(self, "_lambda_ref", None) is None:
            self._lambda_ref = float(lam[0])
        value, weights, _ = ks_min(lam / self._lambda_ref, 0.05)
        from .planar import eigenvalue_gradients

        unit = np.stack([vecs[:, i] / np.sqrt(float(vecs[:, i] @ (M @ vecs[:, i]))) for i in range(modes)], axis=1)
        grads = eigenvalue_gradients(eq, eq.free, unit) * self.p0 / self._lambda_ref
        self._cache[key] = (float(value), weights @ grads)
        self._cache[("stability_modes", modes)] = (lam / self._lambda_ref, grads)
        return self._cache[key]

    def planar_buckling(self, q) -> tuple[float, np.ndarray]:
        """How far the planar opening to the deployed angle is from buckling out of its plane, and the gradient in ``q``.

        ``σ = KS(λ/λ_ref, 0.05)`` over the lowest out-of-plane eigenvalues of
        the planar state (:mod:`.planar`), ``λ_ref`` the size of the starting
        design's lowest one: σ > 0 while the planar opening is stable (a
        deployment from flat then stays flat), σ < 0 where it buckles.
        Requires ``weights.buckling > 0`` (the planar equilibrium is built then).
        """
        if self.planar is None:
            raise InputError("planar_buckling needs the planar branch: build the problem with weights.buckling > 0")
        self.set_q(q)
        key = ("planar",)
        if key not in self._cache:
            from .planar import eigenvalue_gradients, out_of_plane_modes

            B = self._planar_block
            lam, vecs = out_of_plane_modes(self.planar, B, self._planar_M, self._planar_modes,
                                           v0=getattr(self, "_planar_v0", None))
            self._planar_v0 = vecs[:, 0].copy()
            value, weights, _ = ks_min(lam / self._planar_ref, 0.05)
            grads = eigenvalue_gradients(self.planar, B, vecs) * self.p0 / self._planar_ref
            self._cache[key] = (float(value), weights @ grads)
        return self._cache[key]

    def flat_stability_modes(self, q, modes: int = 4) -> tuple[np.ndarray, np.ndarray]:
        """The lowest ``λ_i / λ_ref`` (modes,) and their gradients in ``q`` (modes, S); see :meth:`flat_stability`."""
        self.flat_stability(q, modes)
        return self._cache[("stability_modes", modes)]

    @property
    def rest_lengths(self) -> np.ndarray:
        return self._q * self.p0
