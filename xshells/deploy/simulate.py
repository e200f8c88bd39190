"""Rest-length solve (eq. 2) and deployment by an average-angle constraint (eqs. 3–4).

Deployment increases the average opening angle ``ᾱ`` of the actuated joints
in steps: each step applies a predictor that restores the new angle exactly
(the full block-elimination step of eq. 4), then Newton correctors at fixed
``ᾱ``. When the flat state turns into a saddle the solver leaves it along
the most negative curvature direction, on the side ``direction`` asks for.
The constraint's multiplier gives the actuation torque.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..errors import InputError
from ..linkage.linkage import Linkage
from ..solve import NewtonOptions, minimize, smallest_eigenvalues


@dataclass(frozen=True)
class DeployOptions:
    """Settings of :func:`deploy`.

    Attributes
    ----------
    steps : int
        Angle increments between the start and the target.
    direction : {"up", "down"}
        Which mirror-image branch to take when the flat state buckles
        ("up" = along the layout normal).
    newton : NewtonOptions
        Corrector settings (gradient tolerance relative to the first gradient scale).
    final_tolerance_factor : float
        The last solve is tightened by this factor.
    """

    steps: int = 40
    direction: str = "up"
    # Escape along negative curvature whenever the Hessian is indefinite, not
    # only near stationary points: deployments start from exactly symmetric
    # flat states whose out-of-plane gradient is zero.
    newton: NewtonOptions = NewtonOptions(gradient_tolerance=1e-6, max_iterations=200, saddle_gradient_factor=float("inf"))
    final_tolerance_factor: float = 1e-1


@dataclass
class StepRecord:
    step: int
    average_angle_deg: float
    energy: float
    energy_stretch: float
    energy_bend: float
    energy_twist: float
    torque: float
    max_abs_z: float
    iterations: int
    converged: bool


@dataclass
class DeploymentResult:
    steps: list = field(default_factory=list)
    reached_angle_deg: float = 0.0
    target_angle_deg: float = 0.0
    converged: bool = False
    message: str = ""
    torque: float = 0.0
    min_hessian_eigenvalue: float = float("nan")
    stiffness_gap: float = float("nan")
    newton_iterations: int = 0
    time_s: float = 0.0


class _RestLengthProblem:
    """The linkage with its per-segment rest lengths appended to the variables."""

    def __init__(self, linkage: Linkage):
        self.L = linkage
        self.nx = linkage.num_vars

    def get_vars(self):
        return np.concatenate([self.L.get_vars(), self.L.rest_lengths])

    def set_vars(self, z):
        self.L.set_vars(z[: self.nx])
        self.L.set_rest_lengths(z[self.nx :])

    def energy(self):
        return self.L.energy()

    def gradient(self):
        return self.L.gradient(True)

    def hessian(self):
        return self.L.hessian(True)

    def mass_matrix(self):
        M = self.L.mass_matrix()
        return sp.block_diag([M, M.diagonal().mean() * sp.eye(self.L.num_segments)], format="csr")

    def update_source_frame(self):
        self.L.update_source_frame()

    def min_arc_length(self):
        return self.L.min_arc_length()


def _gradient_scale(linkage: Linkage) -> float:
    """A force scale for tolerances: bending stiffness over span squared."""
    B = float(np.max(linkage.rods.bending_stiffness))
    span = float(np.ptp(linkage.joint_positions(), axis=0).max())
    return B / span**2


def _noise_floor(linkage: Linkage) -> float:
    """Gradient norm that round-off alone produces: stiff stretching of edges
    whose endpoints carry the design's absolute coordinates."""
    eps = np.finfo(float).eps
    coords = float(np.abs(linkage.rods.points).max())
    edge = float(linkage.rods.rest_lengths.min())
    return 10.0 * eps * float(linkage.rods.ks.max()) * coords / edge * np.sqrt(linkage.num_vars)


def rest_length_solve(linkage: Linkage, options: NewtonOptions | None = None, min_rest_length: float | None = None):
    """Minimize the energy over the state and the rest lengths with joint positions held (eq. 2).

    Rest lengths stay above ``min_rest_length`` (default: 1/100 of the
    shortest segment): any that would fall below are fixed at the bound and
    the solve repeats (a simple active set).
    """
    scale = _gradient_scale(linkage)
    opts = options or NewtonOptions(gradient_tolerance=max(1e-8 * scale * np.sqrt(linkage.num_vars), _noise_floor(linkage)),
                                    max_iterations=100)
    eps = min_rest_length if min_rest_length is not None else 0.01 * float(np.min(linkage.rest_lengths))
    P = _RestLengthProblem(linkage)
    fixed = list((9 * np.arange(linkage.num_joints)[:, None] + np.arange(3)[None, :]).ravel())
    active: list[int] = []
    for _ in range(10):
        report = minimize(P, fixed=np.array(fixed + [P.nx + s for s in active], dtype=int), options=opts)
        p = linkage.rest_lengths
        low = [s for s in np.flatnonzero(p < eps) if s not in active]
        if not low:
            return report
        p[low] = eps
        linkage.set_rest_lengths(p)
        active += low
    return report


def deploy(linkage: Linkage, target_angle: float, options: DeployOptions = DeployOptions(), actuated=None,
           callback=None) -> DeploymentResult:
    """Open the linkage to an average joint angle ``target_angle`` (radians).

    Parameters
    ----------
    linkage : Linkage
        Modified in place; it ends in the deployed equilibrium (or the last
        one reached).
    target_angle : float
    options : DeployOptions
    actuated : (m,) int array, optional
        Joints whose average angle is driven (default all).
    callback : callable(StepRecord) -> bool, optional
        Progress; return True to stop (the result keeps what was finished).
    """
    if options.direction not in ("up", "down"):
        raise InputError(f"direction must be 'up' or 'down', got {options.direction!r}")
    if not (0 < target_angle < np.pi):
        raise InputError(f"target angle {np.degrees(target_angle):.4g}° is out of reach: an opening angle must lie strictly between 0° and 180°")
    start = time.perf_counter()
    joints = np.arange(linkage.num_joints) if actuated is None else np.asarray(actuated, int)
    a = np.zeros(linkage.num_vars)
    a[linkage.angle_indices()[joints]] = 1.0 / len(joints)
    alpha0 = float(a @ linkage.get_vars())
    pins = linkage.rigid_pin_indices()
    # "up" = bulging along the layout normal: joints near the middle rise above those near the rim
    P = linkage.joint_positions()
    r2 = np.sum((P - P.mean(axis=0)) ** 2, axis=1)
    bulge = r2.mean() - r2
    hint = (linkage.height_selector().T @ bulge) * (1.0 if options.direction == "up" else -1.0)
    scale = _gradient_scale(linkage) * np.sqrt(linkage.num_vars)
    floor = _noise_floor(linkage)
    newton = NewtonOptions(**{**options.newton.__dict__, "gradient_tolerance": max(options.newton.gradient_tolerance * scale, floor)})
    result = DeploymentResult(target_angle_deg=float(np.degrees(target_angle)))
    Sz = linkage.height_selector()
    z0 = Sz @ linkage.get_vars()
    for i in range(1, options.steps + 1):
        angle = alpha0 + (target_angle - alpha0) * i / options.steps
        opts = newton
        if i == options.steps:
            opts = NewtonOptions(**{**newton.__dict__, "gradient_tolerance": max(newton.gradient_tolerance * options.final_tolerance_factor, floor)})
        report = minimize(linkage, fixed=pins, constraint=(a, angle), options=opts, saddle_hint=hint)
        result.newton_iterations += report.iterations
        parts = linkage.energy_parts()
        z = Sz @ linkage.get_vars() - z0
        g = linkage.gradient()
        torque = float(np.mean(g[linkage.angle_indices()[joints]]))
        rec = StepRecord(i, float(np.degrees(a @ linkage.get_vars())), parts.total, parts.stretch, parts.bend, parts.twist,
                         torque, float(np.abs(z).max()), report.iterations, report.converged)
        result.steps.append(rec)
        result.reached_angle_deg, result.torque = rec.average_angle_deg, torque
        if not report.converged:
            result.message = f"stopped at {rec.average_angle_deg:.2f}° of {np.degrees(target_angle):.2f}°: the solver did not converge ({report.message})"
            break
        if callback is not None and callback(rec):
            result.message = f"stopped by request at {rec.average_angle_deg:.2f}°"
            break
    else:
        result.converged = True
        result.message = "reached the target angle"
    try:
        free = np.setdiff1d(np.arange(linkage.num_vars), pins)
        H = linkage.hessian()[free][:, free]
        M = linkage.mass_matrix()[free][:, free]
        lam = smallest_eigenvalues(H, M, k=2)
        result.min_hessian_eigenvalue = float(lam[0])
        result.stiffness_gap = float(lam[1] / lam[0]) if lam[0] != 0 else float("inf")
    except Exception as exc:  # eigen-solver trouble must not lose the deployment
        result.message += f"; stability check failed: {exc}"
    result.time_s = time.perf_counter() - start
    return result


def solve_equilibrium(linkage: Linkage, *, torques=None, gravity=None, joint_forces=None,
                      options: NewtonOptions | None = None, fixed=None):
    """Static equilibrium under loads: ``argmin E(x) − f·x`` (paper §6 for torques).

    Parameters
    ----------
    torques : (nj,) array, optional
        Joint torques τ acting on the opening angles (``f = S_αᵀ τ``).
    gravity : (3,) array, optional
        Gravitational acceleration as a dead load (needs densities).
    joint_forces : (nj, 3) array, optional
        Point forces at the joints.
    fixed : int array, optional
        Held variables (default: one joint's position and rotation).

    Returns
    -------
    NewtonReport
    """
    f = np.zeros(linkage.num_vars)
    if torques is not None:
        tau = np.asarray(torques, float)
        if tau.shape != (linkage.num_joints,):
            raise InputError(f"torques: expected {linkage.num_joints} values (one per joint), got shape {tau.shape}")
        f += linkage.angle_selector().T @ tau
    if gravity is not None:
        f += linkage.gravity_force(gravity)
    if joint_forces is not None:
        f += linkage.joint_force(joint_forces)
    scale = _gradient_scale(linkage) * np.sqrt(linkage.num_vars)
    opts = options or NewtonOptions(gradient_tolerance=max(1e-7 * scale, _noise_floor(linkage)), max_iterations=300,
                                    saddle_gradient_factor=float("inf"))
    pins = linkage.rigid_pin_indices() if fixed is None else fixed
    return minimize(linkage, fixed=pins, force=f, options=opts)
