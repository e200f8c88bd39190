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
from ..solve.newton import STOPPED_BY_CALLBACK, _constrained_tangent

#: the words of a stop by a folding joint or a collapsing edge (the start's fallbacks look for them)
INVERTS = "the linkage inverts"
ABOUT_TO_INVERT = "the linkage is about to invert"

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
    step_tolerance_factor : float
        The solves before the last may be loosened by this factor (default 1:
        not loosened). 100 saves the last corrector iteration of most steps
        (Newton iterations, manta ray 40 steps 152 → 135, Darth Vader
        192 → 181) and leaves the bundled designs' deployed joints unchanged
        to 1e-10 of the span, but a layout near a bifurcation can then take
        another branch: `xshells inverse` on the shared spherical cap ended
        at a fit of 1.52 % of the diagonal instead of 0.98 %, and on the
        realizable two-bumps target at 4.07 % instead of 0.32 %.
    min_joint_edge_length : float, optional
        Lower bound ε on the joint edge lengths ``ℓA, ℓB`` (the two length
        variables of each joint). Default: 1/100 of the shortest one at the
        start. A length that would go below is held at ε (an active set,
        released when its gradient pulls it back up).
    inversion_margin : float
        Radians: deployment stops when a joint angle comes within this of 0 or π
        (default 0: when it reaches 0 or π, i.e. the joint folds through).
    collapse_ratio : float
        Deployment stops when a rod edge shrinks below this fraction of its rest length.
    start : {"auto", "average", "central-joint"}
        How the assembly state is held while it first relaxes. "average": at
        its average angle (the deployment's own control). "central-joint":
        only the pinned central joint's angle is held (one driving joint, as
        a physical assembly would be held), so the rest of the mechanism
        settles where its forces balance, possibly far from the drawn angle
        and out of plane; the steps then run from the average angle reached.
        "auto": "average", unless its first step folds a joint (or stalls
        beside one); then the start is re-done as "central-joint" (a drawn
        state whose equilibrium at its own average angle needs a joint folded
        through: the Fig. 14 "hole" design folds joint 28 at once). Where
        that folds a joint as well, "average" again with a first step of 2,
        4, then 8 increments (the swimming ray's narrow joint 118 folds on
        a short first step and stays open on a longer one).
    max_buckling_step_deg : float
        A step longer than this (degrees) that starts flat and ends buckled out
        of plane is redone from its flat start in sub-steps no longer than
        this, so that the layout buckles at its first instability, as the
        physical deployment does: one step of 60° landed two_asymm_bumps on
        another branch (one bump down, energy 52,225 against 46,046.5 with
        4 to 50 steps). 15°: the paper's coarsest settings are not redone (the
        manta ray at 10 steps takes 7.7° steps, the breather 11.9°, whose redo
        reached the same equilibrium in 354 Newton iterations instead of 160);
        two_asymm_bumps in 3 steps of 24.9° buckled down when asked up, in 4 of
        18.7° (and 5 to 50) up. ``inf``: never redone.
    guide : (nj, 3) float, optional
        Joint positions of the equilibrium wanted where the design has more
        than one: once the target angle is reached, the shell is held on
        them by springs and let go (:mod:`.guide`). The result is the
        equilibrium it settles into, with no load.
    """

    steps: int = 40
    direction: str = "up"
    # Escape along negative curvature whenever the Hessian is indefinite, not
    # only near stationary points: deployments start from exactly symmetric
    # flat states whose out-of-plane gradient is zero.
    # The shift decays by 100 after an indefinite spell, not by halves (NewtonOptions.shift_decay).
    # A point that Newton's quadratic convergence reached keeps its last step's positive-definite factor as its
    # minimum check and for the next step's tangent (NewtonOptions.minimum_from_last_step).
    # The first shift's scale λmax(H)/λmax(M) is measured once per linkage and free set (NewtonOptions.keep_shift_scale).
    newton: NewtonOptions = NewtonOptions(gradient_tolerance=1e-6, max_iterations=200, saddle_gradient_factor=float("inf"),
                                          shift_decay=100.0, minimum_from_last_step=0.01, keep_shift_scale=True)
    final_tolerance_factor: float = 1e-1
    step_tolerance_factor: float = 1.0
    min_joint_edge_length: float | None = None
    inversion_margin: float = 0.0
    collapse_ratio: float = 1e-2
    start: str = "auto"
    max_buckling_step_deg: float = 15.0
    guide: np.ndarray | None = field(default=None, repr=False, compare=False)


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
    min_eigenvalue_at_fixed_angle: float = float("nan")
    newton_iterations: int = 0
    time_s: float = 0.0
    active_joint_edges: list = field(default_factory=list)
    gradient_norm: float = float("nan")
    start: str = "average"
    start_angle_deg: float = float("nan")
    start_note: str = ""
    # steps redone in sub-steps because they buckled the flat layout in one coarse step (DeployOptions.max_buckling_step_deg)
    refined_steps: list = field(default_factory=list)
    # what the guide did (:class:`.guide.GuideReport`), where DeployOptions.guide asked for one
    guide: object = None


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


def max_abs_z(points) -> float:
    """The shell's height: the largest distance of a joint from its median height, heights measured along the
    normal of the joints' best-fit plane (least squares through their centroid).

    The one definition of ``max_abs_z`` (every step of a deployment, the deployed and flat summaries of
    result.json, the progress bar): independent of the shell's rigid orientation, so a shell tilted by
    which joint is pinned has the same height as the same shell level (the layout-normal height, the
    pinned joint's, measured 52.33 and 30.86 for one state). A flat state measures 0 to round-off.
    """
    P = np.asarray(points, float)
    if len(P) < 3:
        return 0.0
    Q = P - P.mean(axis=0)
    normal = np.linalg.svd(Q, full_matrices=False)[2][-1]  # the direction of least spread
    h = Q @ normal
    return float(np.abs(h - np.median(h)).max())


def _gradient_scale(linkage: Linkage) -> float:
    """A force scale for tolerances: bending stiffness over span squared."""
    B = float(np.max(linkage.rods.bending_stiffness))
    span = float(np.ptp(linkage.rods.points, axis=0).max())  # the rods', not the joints': one joint has no span
    return B / span**2


def _noise_floor(linkage: Linkage) -> float:
    """Gradient norm that round-off alone produces: stiff stretching of edges
    whose endpoints carry the design's absolute coordinates."""
    eps = np.finfo(float).eps
    coords = float(np.abs(linkage.rods.points).max())
    edge = float(linkage.rods.rest_lengths.min())
    return 10.0 * eps * float(linkage.rods.ks.max()) * coords / edge * np.sqrt(linkage.num_vars)


def rest_length_solve(linkage: Linkage, options: NewtonOptions | None = None, min_rest_length: float | None = None,
                      callback=None):
    """Minimize the energy over the state and the rest lengths with joint positions held (eq. 2).

    Rest lengths stay above ``min_rest_length`` (default: 1/100 of the
    shortest segment): any that would fall below are fixed at the bound and
    the solve repeats (a simple active set).

    A segment that ends at a free end keeps its rest length: nothing holds
    that end, so its rest length and the end's position slide together at
    zero energy (left free, a 2-by-3 grid's end segments drifted from 141 to
    1.7e7 length units).

    ``callback(iteration, report)``, if given, is called after every Newton
    iteration (return True or raise to stop: a large design's solve takes
    seconds, and the app's Cancel waited for it).
    """
    scale = _gradient_scale(linkage)
    opts = options or NewtonOptions(gradient_tolerance=max(1e-8 * scale * np.sqrt(linkage.num_vars), _noise_floor(linkage)),
                                    max_iterations=100)
    eps = min_rest_length if min_rest_length is not None else 0.01 * float(np.min(linkage.rest_lengths))
    P = _RestLengthProblem(linkage)
    fixed = list((9 * np.arange(linkage.num_joints)[:, None] + np.arange(3)[None, :]).ravel())
    fixed += [P.nx + int(s) for s in np.flatnonzero((linkage.graph.segment_joints < 0).any(axis=1))]
    active: list[int] = []
    for _ in range(10):
        report = minimize(P, fixed=np.array(fixed + [P.nx + s for s in active], dtype=int), options=opts, callback=callback)
        if report.message == STOPPED_BY_CALLBACK:
            return report
        p = linkage.rest_lengths
        low = [s for s in np.flatnonzero(p < eps) if s not in active]
        if not low:
            return report
        p[low] = eps
        linkage.set_rest_lengths(p)
        active += low
    return report


def rest_length_warning(report, linkage: Linkage) -> list[str]:
    """[] or the warning of a rest-length solve that did not converge (its report was once thrown away: a flat
    state with a twist energy of 2e8 was deployed without a word)."""
    if report is None or report.converged:
        return []
    parts = linkage.energy_parts()
    why = report.message or f"{report.iterations} iterations"
    return [f"the rest-length solve did not converge ({why}): the flat state is not in equilibrium (energy {parts.total:.4g}: stretch "
            f"{parts.stretch:.4g}, bend {parts.bend:.4g}, twist {parts.twist:.4g}); the deployment starts from it all the same"]


def deploy(linkage: Linkage, target_angle: float, options: DeployOptions = DeployOptions(), actuated=None,
           callback=None, newton_callback=None, guide_at_end=None) -> DeploymentResult:
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
    newton_callback : callable(iteration, NewtonReport) -> bool, optional
        Called after every Newton iteration of every solve (a step can take
        tens of seconds on a large design, so a stop checked only between
        steps waited that long: 40 s in the app on the 1004-segment fans).
        Return True, or raise, to stop at once; either way the linkage is put
        back at the last finished equilibrium (True: the result says it
        stopped by request; an exception passes on).
    guide_at_end : callable(Linkage) -> (j, 3) array or None, optional
        Where ``options.guide`` is None: called once with the deployed
        linkage when the target angle is reached, it returns the guide to
        settle into (as ``options.guide`` would be), or None. A caller can so
        choose a guide from the state reached, and gets the same state as a
        deployment naming that guide from the start, without deploying twice.
    """
    if options.direction not in ("up", "down"):
        raise InputError(f"direction must be 'up' or 'down', got {options.direction!r}")
    if options.start not in ("auto", "average", "central-joint"):
        raise InputError(f"start must be 'auto', 'average' or 'central-joint', got {options.start!r}")
    if options.guide is not None:  # a bad guide is refused before the deployment, not after it
        from .guide import check_guide

        check_guide(options.guide, linkage.num_joints)
    if not (0 < target_angle < np.pi):
        raise InputError(f"target angle {np.degrees(target_angle):.4g}° is out of reach: an opening angle must lie strictly between 0° and 180°")
    start = time.perf_counter()
    from ..linkage.state import restore, snapshot

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
    step_newton = NewtonOptions(**{**newton.__dict__, "gradient_tolerance": max(options.newton.gradient_tolerance * options.step_tolerance_factor * scale, floor)})
    result = DeploymentResult(target_angle_deg=float(np.degrees(target_angle)))
    target_deg = float(np.degrees(target_angle))

    # joint edge lengths ℓA, ℓB: bounded below by ε, with an active set
    edge_vars = (9 * np.arange(linkage.num_joints)[:, None] + np.array([7, 8])[None, :]).ravel()
    x = linkage.get_vars()
    eps = options.min_joint_edge_length
    if eps is None:
        eps = 0.01 * float(x[edge_vars].min())
    active = np.zeros(len(edge_vars), bool)
    if (x[edge_vars] < eps).any():
        active = x[edge_vars] < eps
        x[edge_vars[active]] = eps
        linkage.set_vars(x)

    def solve(angle, opts):
        """One corrector solve at average angle ``angle``, with the joint-edge bounds as an active set."""
        nonlocal active
        iterations = 0
        for _ in range(2 * len(edge_vars) + 2):
            report = minimize(linkage, fixed=np.concatenate([pins, edge_vars[active]]), constraint=(a, angle), options=opts,
                              saddle_hint=hint, callback=newton_callback)
            iterations += report.iterations
            if not report.converged:
                break
            x = linkage.get_vars()
            low = ~active & (x[edge_vars] < eps)
            if low.any():
                x[edge_vars[low]] = eps
                linkage.set_vars(x)
                active = active | low
                continue
            # release a bound whose length would grow (∂E/∂ℓ < 0 pulls it above ε)
            g = linkage.gradient()
            release = active & (g[edge_vars] < -opts.gradient_tolerance)
            if not release.any():
                break
            active = active & ~release
        report.iterations = iterations
        return report

    def inversion(x) -> str:
        """Why the state ``x`` is inverted (a joint folding flat or an edge collapsing), or ''."""
        why = folded_joint(linkage, x, options.inversion_margin)
        if why:
            return why
        rods = linkage.rods
        ratio = np.linalg.norm(rods.points[rods.edges[:, 1]] - rods.points[rods.edges[:, 0]], axis=1) / rods.rest_lengths
        e = int(np.argmin(ratio))
        if ratio[e] <= options.collapse_ratio:
            return (f"{INVERTS}: an edge of segment {e // linkage.subdivision} collapses to "
                    f"{100 * ratio[e]:.3g}% of its rest length")
        return ""

    def run_steps(alpha0: float, why: str, first: int = 1) -> bool:
        """Steps from ``alpha0`` to the target (none if ``why`` says the start is broken); whether the first folded a joint.

        The first step goes ``first`` increments of the ``options.steps`` at once (see :func:`start_and_steps`)."""
        last_good, last_angle = snapshot(linkage), float(np.degrees(alpha0))
        kept["state"] = last_good
        result.reached_angle_deg = last_angle  # until a step is taken
        previous = None  # (x, joint frames) of the equilibrium before the last one, for the predictor
        smooth = False  # whether the last step was easy (then the path is smooth enough to extrapolate)
        extrapolate = True  # until an extrapolated guess leads into negative curvature
        why = why or inversion(linkage.get_vars())
        if why:
            result.message = f"stopped at {last_angle:.2f}° of {target_deg:.2f}° before the first step: {why}"
            return False
        for i in range(first, options.steps + 1):
            angle = alpha0 + (target_angle - alpha0) * i / options.steps
            opts = step_newton
            if i == options.steps:
                opts = NewtonOptions(**{**newton.__dict__, "gradient_tolerance": max(newton.gradient_tolerance * options.final_tolerance_factor, floor)})
            try:
                used_lead = unstable_lead = False
                coarse = coarse_flat_step(last_angle, angle)
                if i > first:
                    previous, used_lead, unstable_lead = _predict(linkage, a, angle, previous if smooth and extrapolate else None, pins,
                                                   edge_vars[active])
                report = solve(angle, opts)
                if coarse is not None and report.converged and not _is_flat(linkage):
                    report = redo_in_substeps(i, angle, opts, coarse, report)
            except InputError as exc:  # a non-finite or degenerate state: keep the last equilibrium
                restore(linkage, last_good)
                result.message = (f"stopped at {last_angle:.2f}° of {target_deg:.2f}°: the solver broke down on the way to "
                                  f"{np.degrees(angle):.2f}° ({exc})")
                return False
            result.newton_iterations += report.iterations
            # extrapolate only along an easy stretch of the path: no negative curvature and quick convergence last step
            smooth = report.indefinite_events == 0 and report.iterations <= 3
            if unstable_lead or (used_lead and report.indefinite_events):
                extrapolate = False  # this path is too close to instabilities for extrapolation: tangent guesses from now on
            if not report.converged and report.message == STOPPED_BY_CALLBACK:  # newton_callback asked to stop
                restore(linkage, last_good)
                result.message = f"stopped by request at {last_angle:.2f}° (on the way to {np.degrees(angle):.2f}°)"
                return False
            if not report.converged:
                x_stalled = linkage.get_vars()
                reached_now = float(np.degrees(a @ x_stalled))
                restore(linkage, last_good)
                result.message = (f"stopped at {last_angle:.2f}° of {target_deg:.2f}°: the solver stalled on the way to "
                                  f"{np.degrees(angle):.2f}° (at {reached_now:.2f}°: {report.message})")
                alpha = x_stalled[linkage.angle_indices()]
                j = int(np.argmin(np.minimum(alpha, np.pi - alpha)))
                if min(alpha[j], np.pi - alpha[j]) < np.radians(5.0):
                    # a stall next to a folding joint is usually the inversion itself
                    result.message += (f"; joint {j} (vertex {int(linkage.graph.joint_vertex[j])}) is folding "
                                       f"({np.degrees(alpha[j]):.2f}°): {ABOUT_TO_INVERT}")
                    return i == first
                return False
            why = inversion(linkage.get_vars())
            if why:
                restore(linkage, last_good)
                result.message = f"stopped at {last_angle:.2f}° of {target_deg:.2f}°: {why} on the way to {np.degrees(angle):.2f}°"
                return i == first
            parts = linkage.energy_parts()
            g = linkage.gradient()
            torque = float(np.mean(g[linkage.angle_indices()[joints]]))
            rec = StepRecord(i, float(np.degrees(a @ linkage.get_vars())), parts.total, parts.stretch, parts.bend, parts.twist,
                             torque, max_abs_z(linkage.joint_positions()), report.iterations, report.converged)
            result.steps.append(rec)
            result.reached_angle_deg, result.torque = rec.average_angle_deg, torque
            last_good, last_angle = snapshot(linkage), rec.average_angle_deg
            kept["state"] = last_good
            if callback is not None and callback(rec):
                result.message = f"stopped by request at {rec.average_angle_deg:.2f}°"
                return False
        result.converged = True
        result.message = "reached the target angle"
        return False

    def coarse_flat_step(last_angle_deg: float, angle: float):
        """For a step longer than ``options.max_buckling_step_deg`` that starts flat: the start's state and joint
        bounds (what a redo starts from); else None (every step of a normal run: nothing is computed for it)."""
        if abs(np.degrees(angle) - last_angle_deg) <= options.max_buckling_step_deg or not _is_flat(linkage):
            return None
        return snapshot(linkage), active.copy(), last_angle_deg

    def redo_in_substeps(i: int, angle: float, opts, coarse, report):
        """Step ``i`` started flat and ended buckled in one coarse step, which can land on another branch than the
        deployment's own (it buckles at its first instability): redone from the flat start in sub-steps no longer
        than ``options.max_buckling_step_deg``. Returns the report of the whole, its iterations those of all tries."""
        nonlocal active
        snap, active_before, from_deg = coarse
        coarse_energy, spent = linkage.energy(), [report.iterations]
        restore(linkage, snap)
        active = active_before
        n = int(np.ceil(abs(np.degrees(angle) - from_deg) / options.max_buckling_step_deg))
        report = walk(np.radians(from_deg), angle, n, opts, spent)
        report.iterations = spent[0]
        if report.converged:
            result.refined_steps.append({
                "step": i, "from_deg": from_deg, "to_deg": float(np.degrees(angle)), "substeps": n,
                "energy_one_step": float(coarse_energy), "energy": float(linkage.energy())})
        return report

    def walk(start: float, end: float, n: int, opts, spent: list):
        """From the equilibrium at ``start`` to ``end`` in ``n`` equal sub-steps (radians), ``opts`` for the last.
        A sub-step that starts flat and ends buckled is redone from its start in 4 smaller ones, down to 1/8 of
        ``options.max_buckling_step_deg``: the crossing of the first instability must be short, or the layout
        can buckle to the other side (a warped grid asked "up" went down in 9° sub-steps, up in 7.5°)."""
        nonlocal active
        fine = np.radians(options.max_buckling_step_deg) / 8
        size = abs(end - start) / n
        report = None
        for k in range(1, n + 1):
            a0, sub = start + (end - start) * (k - 1) / n, start + (end - start) * k / n
            refine = size > fine and _is_flat(linkage)
            if refine:
                snap, active_before = snapshot(linkage), active.copy()
            # the tangent predictor between sub-steps; the first starts where it is, as the first step of all does
            # (the factor _predict would reuse is then still that of a try that was undone)
            if k > 1:
                _predict(linkage, a, sub, None, pins, edge_vars[active])
            report = solve(sub, opts if k == n else step_newton)
            spent[0] += report.iterations
            if report.converged and refine and not _is_flat(linkage):
                restore(linkage, snap)
                active = active_before
                report = walk(a0, sub, 4, opts if k == n else step_newton, spent)
            if not report.converged:
                break
        return report

    def relax_holding_central_joint() -> tuple[float, str]:
        """Relax with only the pinned joint's angle held; (the average angle reached, '' or why the start is broken)."""
        j = int(pins[0]) // 9
        held = np.concatenate([pins, [9 * j + 6]])
        opts = NewtonOptions(**{**newton.__dict__, "max_iterations": max(newton.max_iterations, 2000)})
        report = minimize(linkage, fixed=held, options=opts, saddle_hint=hint, callback=newton_callback)
        result.newton_iterations += report.iterations
        angle = float(a @ linkage.get_vars())
        result.start, result.start_angle_deg = "central-joint", float(np.degrees(angle))
        if not report.converged:
            return angle, f"relaxing with joint {j}'s angle held did not converge ({report.message})"
        return angle, inversion(linkage.get_vars())

    def folded_start() -> bool:
        """Whether the run just ended stopped at its start or first step by folding a joint (not by request)."""
        return INVERTS in result.message or ABOUT_TO_INVERT in result.message

    def longer_first_step(initial, initial_active, initial_angle: float) -> None:
        """Both starts fold a joint at once: from the assembly state, a first step of 2, 4, then 8 increments.

        A narrow joint of a stressed assembly state can close while the layout starts to open: held at the
        average angle, the swimming ray's joint 118 (6.3° flat) folds on a first step of 1.8° or 3.6°, and stays
        open on one of 5.6° or more, from where the deployment goes on in the given increments."""
        nonlocal active
        tried, lengths = result.start_note, []
        for first in (2, 4, 8):
            if first >= options.steps:
                return
            restore(linkage, initial)
            active = initial_active.copy()
            result.steps, result.torque, result.refined_steps = [], 0.0, []
            result.start, result.start_angle_deg = "average", float(np.degrees(initial_angle))
            lengths.append(f"{first} increments ({np.degrees(target_angle - initial_angle) * first / options.steps:.2f}°)")
            folded = run_steps(initial_angle, "", first=first)
            result.start_note = (f"{tried}, which folded a joint as well; " + (
                f"then held at the average angle again, with a first step of {lengths[-1]}" if not folded
                else f"first steps of {', '.join(lengths)} folded one too"))
            if not folded:
                return

    def start_and_steps() -> None:
        """The start (re-done held by the central joint if "auto" asks) and the steps to the target."""
        nonlocal active
        alpha = alpha0
        why = ""
        if options.start == "central-joint":
            alpha, why = relax_holding_central_joint()
        initial, initial_active, initial_angle = snapshot(linkage), active.copy(), alpha
        if run_steps(alpha, why) and options.start == "auto":
            # the assembly state cannot relax at its own average angle: start over, held by one joint
            first = result.message.split(": ", 1)[-1]
            restore(linkage, initial)
            active = initial_active
            result.steps, result.torque, result.refined_steps = [], 0.0, []
            alpha, why = relax_holding_central_joint()
            result.start_note = (f"held at its average angle {np.degrees(initial_angle):.2f}°, the assembly state cannot relax "
                                 f"({first}); relaxed with only the central joint's angle held"
                                 + ("" if why else f", it settled at {result.start_angle_deg:.2f}°"))
            if run_steps(alpha, why) or (not result.steps and not result.converged and folded_start()):
                longer_first_step(initial, initial_active, initial_angle)
        if result.start_note:
            result.message += f" (start: {result.start_note})"

    def guided() -> None:
        """Held on the guide at the target angle and let go (:func:`_guided_end`), once the target is reached."""
        nonlocal active
        if not result.converged:
            return
        guide = options.guide if options.guide is not None or guide_at_end is None else guide_at_end(linkage)
        if guide is None:
            return
        final = NewtonOptions(**{**newton.__dict__,
                                 "gradient_tolerance": max(newton.gradient_tolerance * options.final_tolerance_factor, floor)})
        before = active.copy()
        if _guided_end(linkage, result, guide, a, target_angle, joints, edge_vars[active],
                       lambda: solve(target_angle, final), inversion, kept["state"]):
            kept["state"] = snapshot(linkage)
        else:
            active = before  # the state reached, with its own bounds

    result.start, result.start_angle_deg = "average", float(np.degrees(alpha0))
    kept = {"state": snapshot(linkage)}  # the last finished equilibrium (the start until a step ends)
    try:
        start_and_steps()
        guided()
    except BaseException:
        # Ctrl-C, SIGTERM (the command line raises KeyboardInterrupt) or an error inside a solve: the linkage
        # is left in the last finished equilibrium, as a run that stops on its own leaves it, never in the
        # half-solved state of the step under way (an interrupted `xshells deploy` saved that as its result)
        from ..errors import STOP

        with STOP.deferred():
            restore(linkage, kept["state"])
        raise
    _final_checks(linkage, result, a, pins, edge_vars[active])
    result.time_s = time.perf_counter() - start
    return result


def _guided_end(linkage: Linkage, result: DeploymentResult, guide, a, angle: float, joints, held_edges, release,
                inversion, reached) -> bool:
    """The deployed ``linkage`` held on ``guide`` and let go (:func:`.guide.settle_into`); whether it settled.

    ``result.guide`` gets the report and ``result.message`` its note; where the shell settled, the last step's
    record is the settled state's. Where it did not, or settled with a joint folded (``inversion(x)`` says why),
    the linkage is put back in the state ``reached`` (a snapshot).
    """
    from ..linkage.state import restore
    from .guide import check_guide, settle_into

    result.guide = settle_into(linkage, check_guide(guide, linkage.num_joints), a, angle, held_edges, release)
    why = inversion(linkage.get_vars()) if result.guide.held else ""
    if why:
        restore(linkage, reached)
        result.guide.held = False
        result.guide.note = f"let go from the guide, {why}; the state reached is kept"
    result.message += f"; {result.guide.note}"
    if not result.guide.held:
        return False
    parts, last = linkage.energy_parts(), result.steps[-1]
    result.torque = float(np.mean(linkage.gradient()[linkage.angle_indices()[joints]]))
    result.steps[-1] = StepRecord(last.step, float(np.degrees(a @ linkage.get_vars())), parts.total, parts.stretch,
                                  parts.bend, parts.twist, result.torque, max_abs_z(linkage.joint_positions()),
                                  last.iterations, last.converged)
    return True


def _final_checks(linkage: Linkage, result: DeploymentResult, a, pins, held_edges) -> None:
    """The final state's constrained gradient norm and stability (smallest eigenvalues) into ``result``."""
    result.active_joint_edges = [int(v) for v in held_edges]
    # the constrained gradient norm of the final state (free variables, constraint force removed)
    held = np.zeros(linkage.num_vars, bool)
    held[pins] = True
    held[held_edges] = True
    gf, af = linkage.gradient()[~held], a[~held]
    result.gradient_norm = float(np.linalg.norm(gf - af * (af @ gf) / (af @ af)))
    try:
        free = np.setdiff1d(np.arange(linkage.num_vars), np.concatenate([pins, held_edges]))
        H = linkage.hessian()[free][:, free]
        M = linkage.mass_matrix()[free][:, free]
        lam, s_free = smallest_eigenvalues(H, M, k=2, return_shift=True)
        result.min_hessian_eigenvalue = float(lam[0])
        result.stiffness_gap = float(lam[1] / lam[0]) if lam[0] != 0 else float("inf")
        # Stability with the average angle held (the deployment's own control): H + ρ a aᵀ.
        # Past the torque's limit point the free Hessian's lowest (opening) mode turns
        # negative while this stays positive: the state is stable under angle control
        # but would snap under a fixed torque (the boat at 62°: −3.6e-8 against +4.7e-8).
        af = a[free]
        nz = np.flatnonzero(af)
        rho_a = 100.0 * float(np.abs(H.diagonal()).max()) / float(af @ af)
        A = sp.csr_matrix((np.full(len(nz) ** 2, rho_a * af[nz[0]] ** 2), (np.repeat(nz, len(nz)), np.tile(nz, len(nz)))),
                          shape=H.shape)
        # the free Hessian's shift serves (H + A ≥ H): no second search for λmax(H + A), λmax(M) and a shift
        result.min_eigenvalue_at_fixed_angle = float(smallest_eigenvalues((H + A).tocsr(), M, k=1,
                                                                          shift=s_free or None)[0])
    except Exception as exc:  # eigen-solver trouble must not lose the deployment
        result.message += f"; stability check failed: {exc}"


def _is_flat(linkage: Linkage) -> bool:
    """Whether the joints lie in one plane, to round-off (1e-8 of the span: a flat state after the rest-length
    solve measures 0, a buckled one well above 1e-3)."""
    P = linkage.joint_positions()
    return max_abs_z(P) <= 1e-8 * float(np.ptp(P, axis=0).max())


def folded_joints(linkage: Linkage, x=None, margin: float = 0.0) -> np.ndarray:
    """The joints (indices, shape (k,)) of the state ``x`` (default: the current one) whose opening angle is within
    ``margin`` radians of 0 or 180° or beyond."""
    alpha = (linkage.get_vars() if x is None else x)[linkage.angle_indices()]
    return np.flatnonzero(np.minimum(alpha, np.pi - alpha) <= margin)


def folded_joint(linkage: Linkage, x=None, margin: float = 0.0) -> str:
    """'' or why the state ``x`` (default: the current one) is inverted: a joint
    whose opening angle is within ``margin`` radians of 0 or 180° or beyond (the worst such joint is named)."""
    alpha = (linkage.get_vars() if x is None else x)[linkage.angle_indices()]
    j = int(np.argmin(np.minimum(alpha, np.pi - alpha)))
    if min(alpha[j], np.pi - alpha[j]) <= margin:
        return (f"{INVERTS}: joint {j} (vertex {int(linkage.graph.joint_vertex[j])}) reaches an opening angle of "
                f"{np.degrees(alpha[j]):.2f}° (a joint must stay strictly between 0° and 180°)")
    return ""


def _rotation_between(b_from, n_from, b_to, n_to) -> np.ndarray:
    """Rotation vectors ω (per row) with ``R(ω) b_from = b_to`` and ``R(ω) n_from = n_to`` (orthonormal pairs)."""
    F0 = np.stack([b_from, n_from, np.cross(b_from, n_from)], axis=2)
    F1 = np.stack([b_to, n_to, np.cross(b_to, n_to)], axis=2)
    R = F1 @ F0.transpose(0, 2, 1)
    w = 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    s = np.linalg.norm(w, axis=1)
    c = 0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0)
    th = np.arctan2(s, c)
    f = np.where(s > 1e-12, th / np.maximum(s, 1e-300), 1.0)
    return w * f[:, None]


def _constrained_gradient_norm(linkage: Linkage, x, a, held) -> float:
    linkage.set_vars(x)
    free = np.ones(linkage.num_vars, bool)
    free[held] = False
    g, af = linkage.gradient()[free], a[free]
    return float(np.linalg.norm(g - af * (af @ g) / (af @ af)))


def _predict(linkage: Linkage, a, angle, previous, pins, held):
    """Move a converged equilibrium towards the next one on the deployment path.

    With the path tangent ``t`` at the current equilibrium ``x_i`` and the one
    before, ``x_{i−1}``: ``x_{i+1} ≈ x_{i−1} + 2h t`` (central difference,
    error O(h³)); for the first step, ``x_i + h t`` (O(h²)). ``x_{i−1}``'s joint
    rotations are re-expressed in the current source frames. Near a snap or a
    bifurcation the central difference can be worse than the tangent alone,
    so the central difference is kept only if its constrained gradient is ten times
    smaller than the tangent's and the state there is still stable. Both satisfy
    ``a·x = angle``. Returns what the next call needs (``previous=None``
    skips the central difference), whether the central difference was
    used, and whether it was turned down for instability; any trouble leaves the
    state as it is (Newton then starts there).
    """
    x = linkage.get_vars()
    current = (x, linkage.joint_b0.copy(), linkage.joint_n0.copy())
    t = _constrained_tangent(linkage, np.concatenate([pins, held]), a, reuse=True)
    if t is None:
        return current, False, False
    h = angle - float(a @ x)
    allheld = np.concatenate([pins, held]).astype(int)
    guess, used, unstable = x + h * t, False, False
    try:
        if previous is not None:
            xp, bp, np_ = previous
            xq = xp.copy()
            xq[: linkage.num_joint_vars].reshape(-1, 9)[:, 3:6] = _rotation_between(current[1], current[2], bp, np_)
            lead = xq + (h + float(a @ (x - xq))) * t  # central difference: x_{i−1} + 2h t for equal steps
            lead[allheld] = x[allheld]
            # keep it only where it is clearly better and still stable on the constraint surface (positive
            # definite augmented Hessian: its factorization is then reused by the first Newton iteration,
            # so the lead is evaluated last and the check runs on the lead's state)
            if np.isfinite(lead).all() and abs(float(a @ lead) - angle) <= 1e-9 * max(abs(angle), 1.0):
                g_guess = _constrained_gradient_norm(linkage, guess, a, allheld)
                if _constrained_gradient_norm(linkage, lead, a, allheld) < 0.1 * g_guess:
                    unstable = _constrained_tangent(linkage, allheld, a) is None
                    guess, used = (guess, False) if unstable else (lead, True)
        linkage.set_vars(guess)
    except InputError:
        linkage.set_vars(x)
        used = False
    return current, used, unstable


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
