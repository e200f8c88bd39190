"""Stage checks: the design as it stands, deployed from its flat state as the verification will deploy it.

After each stage of the design optimization (and every few iterations of the
last, :class:`~.guide.GuideOptions`), the flat layout is settled and deployed
from flat with no hold, with those free ends that keep clear of the other
beams. The design whose own deployment fits the surface best is kept: a held
state can end on a branch that a deployment from flat never reaches.

A check needs only the design's arrays (flat vertices, rest lengths, where the
optimization holds the joints), so it can run in a process beside the
optimization (:class:`StageChecks`, ``beside=True``). Checks took about a fifth
of an inverse design (the pointy wings' penalized design: 73 s of 334 s under
cProfile, 2026-12-06), and a design often runs alone on the two-core machine
(the last candidate, a buckling retry, ``--beams even``). Each check is the same
function on the same arrays in either place, and the results are taken in
the order the stages asked for them, so the kept design is the same to the
last bit.
"""
from __future__ import annotations

import signal
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CheckContext:
    """What every check of one design shares: sent once to the checking process.

    Attributes
    ----------
    surface : TargetSurface
    material : Material
    subdivision, steps : int
        The case's subdivision and deployment steps.
    direction : str
        "up" or "down".
    theta : float
        The deployed average angle (radians).
    width : float
        The beams' width (0: no clearance checks).
    edges : (s, 2) int
        The net's segments (joint indices of the flat vertices).
    ends : FreeEnds or None
        The free ends to attach (:mod:`.free_ends`).
    guide : bool
        Whether a stage whose deployment from flat is not close may be guided, once deployed, into the state the
        optimization tracks (:func:`deployed_fits`), and kept so where that fits better.
    """

    surface: object
    material: object
    subdivision: int
    steps: int
    direction: str
    theta: float
    width: float
    edges: np.ndarray
    ends: object = None
    guide: bool = False


#: Within this share of its span of the layout's plane a state is planar: the issue's bar for the flat state, and
#: the mark of a deployment that never buckled
PLANAR = 1e-6


def flat_planarity(linkage) -> float:
    """How far the linkage's rod points leave their mean plane z, over the rods' span (0 for a planar state)."""
    pts = linkage.rods.points
    return float(np.abs(pts[:, 2] - pts[:, 2].mean()).max()) / float(np.ptp(pts, axis=0).max())


def stage_arrays(Pv: np.ndarray, p: np.ndarray, edges, ends=None):
    """The design a stage would write, from the flat linkage's vertices ``Pv`` (k, 3) and rest lengths ``p`` (s,):
    its flat vertices (k', 3) centred in the plane z = 0, segments (s', 2) and rest lengths (s',), with ``ends``
    (:class:`.free_ends.FreeEnds`) attached when given."""
    Pf = np.asarray(Pv, float)
    Pf = Pf - Pf.mean(axis=0)
    Pf[:, 2] = 0.0  # planar to round-off (checked on the verification's flat state)
    p = np.asarray(p, float)
    if ends is not None and len(ends):
        from .free_ends import attach

        return attach(Pf, edges, ends, p)
    return Pf, np.asarray(edges, np.int64), p


def settled_flat(ctx: CheckContext, Pf, edges, p):
    """The linkage of a flat design, settled with its angles free as ``xshells deploy`` settles a case with
    rest lengths."""
    from ..io.design import design_from_arrays
    from ..linkage.linkage import Linkage
    from ..solve import NewtonOptions, minimize

    fwd = Linkage(design_from_arrays(Pf, edges), ctx.material, subdivision=ctx.subdivision, rest_lengths=p)
    minimize(fwd, fixed=fwd.rigid_pin_indices(), options=NewtonOptions(gradient_tolerance=1e-9, max_iterations=100))
    return fwd


def with_free_ends(ctx: CheckContext, Pv, p):
    """The stage's design with those free ends that keep clear of the other beams, settled:
    ``((Pf, edges, p), linkage, the free ends used)``."""
    from ..linkage.clearance import crowded_segments
    from .free_ends import crossing_ends

    use, n = ctx.ends, len(ctx.edges)
    for _ in range(4):
        Pf, edges, q = stage_arrays(Pv, p, ctx.edges, use)
        fwd = settled_flat(ctx, Pf, edges, q)
        crowded = crowded_segments(fwd, ctx.width) if ctx.width > 0 else np.zeros(0, np.int64)
        # free ends too close to a neighbouring beam, or across another beam without a joint: left off
        bad = np.union1d(crowded[crowded >= n] - n, crossing_ends(Pf, edges, n))
        if not len(bad) or not len(use):
            return (Pf, edges, q), fwd, use
        use = use.subset(~np.isin(np.arange(len(use)), bad))
    Pf, edges, q = stage_arrays(Pv, p, ctx.edges, use)
    return (Pf, edges, q), settled_flat(ctx, Pf, edges, q), use


def check_stage(ctx: CheckContext, Pv: np.ndarray, p: np.ndarray, guess: np.ndarray, try_guide: bool = True) -> dict:
    """Deploy the design ``(Pv, p)`` from flat and measure its fit.

    Parameters
    ----------
    Pv : (k, 3) float
        The flat linkage's vertices.
    p : (s,) float
        Its rest lengths.
    guess : (j, 3) float
        Where the optimization holds the joints, in the surface's frame: the start of the placement.
    try_guide : bool
        Whether a guided deployment may be tried (with ``ctx.guide``): :class:`StageChecks` asks it only of the
        stages without load, whose tracked state can be an equilibrium of the design alone.

    Returns
    -------
    dict
        ``{"why": ...}`` where the design cannot be kept (its flat layout overlaps or leaves its plane,
        its deployment stops);
        else ``fit`` and ``top`` (mean and largest joint distance, design units), ``rise`` (how far the
        deployment left the layout's plane, relative to the flat span: about 0 where it never buckled),
        ``design`` (Pf, edges, p), ``free_ends`` (attached), ``tracked`` (the placed deployed joints, (j, 3)) and
        ``direction``: the case's direction that deploys it so, ``ctx.direction`` unless the mirror image of
        that deployment (the other direction's) fits better; ``guide`` (j, 3) where the deployment guided into
        the tracked state fits better (:func:`deployed_fits`), else None.
    """
    from ..linkage.clearance import beam_overlaps

    if ctx.ends is not None and len(ctx.ends):
        made, fwd, used = with_free_ends(ctx, Pv, p)
    else:
        made = stage_arrays(Pv, p, ctx.edges)
        fwd, used = settled_flat(ctx, *made), None
    overlap = beam_overlaps(fwd, ctx.width) if ctx.width > 0 else ""
    if overlap:  # not buildable: the verification would refuse it
        return {"why": f"the flat layout is not buildable: {overlap}"}
    flat_z = flat_planarity(fwd)
    if flat_z > PLANAR:  # let go, it buckles out of its plane: the verification would find it invalid (the boat's
        # fanned net, 2026-12-07: its last stage design was kept, 0.0014 of the span off the plane, status invalid)
        return {"why": f"its flat state leaves the plane by {flat_z:.2g} of its span"}
    res, unguided, guided = deployed_fits(ctx, fwd, guess, bool(ctx.guide and try_guide))
    if not res.converged:
        return {"why": f"its deployment from flat stopped: {res.message}"}
    (direction, placed, d, rise), guide = unguided, None
    if guided is not None and _rank(guided[2], ctx.surface) < _rank(d, ctx.surface):
        (direction, placed, d, rise), guide = guided, np.array(guess, float)
    return {"fit": float(np.mean(d)), "top": float(np.max(d)), "rise": rise, "design": made, "direction": direction,
            "free_ends": 0 if used is None else len(used), "tracked": placed, "guide": guide}


def deployed_fits(ctx: CheckContext, fwd, guess: np.ndarray, try_guide: bool) -> tuple:
    """Deploy the settled flat linkage ``fwd`` (in place) and measure the state reached and, where
    :func:`wants_guide` says so, the state it settles into guided into the tracked state ``guess`` (j, 3).

    The guide is chosen once the target angle is reached (``deploy``'s ``guide_at_end``), so the guided state is
    the one a case naming ``guess`` as its guide deploys to, to the last bit, with one deployment instead of two.

    Returns
    -------
    tuple
        ``(deployment result, unguided, guided)``: each fit is ``(direction, placed joints (j, 3), their distances
        (j,), rise)``, ``rise`` being how far the state left the layout's plane over the flat span. ``guided`` is
        None where no guide was tried, it was not followed, or let go the shell went back to the unguided state
        (:data:`SAME_STATE`); its direction is ``ctx.direction``, as a case with a guide deploys it. The unguided
        fit's direction is ``ctx.direction``, or the other one where the mirror image of the state reached (which
        the other direction deploys to) fits better.
    """
    from ..deploy.simulate import DeployOptions, deploy
    from .metrics import mirror_image

    span = float(np.ptp(fwd.rods.points, axis=0).max())  # the flat span, as the verification's rise is measured
    fits = {}

    def reached(linkage):
        """The state reached: its fit, and the guide to try (or None)."""
        Y = linkage.joint_positions()
        rise = float(np.ptp(linkage.rods.points[:, 2])) / span
        placed, d = _placed(ctx.surface, Y, guess)
        fits["unguided"] = (ctx.direction, placed, d, rise)
        # The flat layout is symmetric about its plane, so the other direction deploys it to this state's mirror
        # image (to round-off: 1e-11 of the span, tested): where that fits better, the design's case asks for it.
        # Without this, a design whose deployment had passed to the mirror image was no longer kept, while the
        # optimization went on closing in on the surface (the pavilion's last stage: 9.2 % up, 0.47 % down).
        mirrored, dm = _placed(ctx.surface, mirror_image(Y, linkage.graph.layout_normal), guess)
        if _rank(dm, ctx.surface) < _rank(d, ctx.surface):
            fits["unguided"] = (OTHER_DIRECTION[ctx.direction], mirrored, dm, rise)
        # a guide names each of the design's joints once: the tracked joints must be the design's
        if try_guide and len(guess) == linkage.num_joints and wants_guide(ctx.surface, fits["unguided"][2], guess):
            return np.asarray(guess, float)
        return None

    res = deploy(fwd, ctx.theta, DeployOptions(steps=ctx.steps, direction=ctx.direction), guide_at_end=reached)
    if not res.converged:
        return res, None, None
    guided = None
    if res.guide is not None and res.guide.held and res.guide.moved > SAME_STATE:
        # followed, and let go it stayed in another equilibrium than the one reached unguided
        guided = (ctx.direction, *_placed(ctx.surface, fwd.joint_positions(), guess),
                  float(np.ptp(fwd.rods.points[:, 2])) / span)
    return res, fits["unguided"], guided


#: a guided state this close to the unguided one (largest joint distance over the span) is the same equilibrium
#: (measured: 1e-11 where the guide led back to it), and the check keeps the unguided one, with no guide to write
SAME_STATE = 1e-6


def wants_guide(surface, d: np.ndarray, guess: np.ndarray) -> bool:
    """Whether a guided deployment is worth trying: the deployment from flat (joint distances ``d``) is not close
    (:data:`.board.CLOSE`), and the state the optimization tracks (``guess``, placed on the surface) fits better."""
    from .board import close_misses
    from .metrics import surface_distances

    diag = surface.diagonal
    if not close_misses({"fit_mean": float(np.mean(d)) / diag, "fit_max": float(np.max(d)) / diag}):
        return False
    return _rank(surface_distances(surface, np.asarray(guess, float)), surface) < _rank(d, surface)


OTHER_DIRECTION = {"up": "down", "down": "up"}


def _placed(surface, Y: np.ndarray, guess: np.ndarray) -> tuple:
    """(placed joints (j, 3), their distances to the surface (j,)): ``Y`` placed on the surface from ``guess``."""
    from .metrics import apply, place, surface_distances

    placed = apply(place(surface, Y, guess), Y)
    return placed, surface_distances(surface, placed)


def _rank(d: np.ndarray, surface) -> tuple:
    """How the run ranks a stage's design by its distances ``d`` (:func:`.run.stage_rank`)."""
    from .run import stage_rank

    return stage_rank(float(np.mean(d)) / surface.diagonal, float(np.max(d)) / surface.diagonal)


_CONTEXT = None  # in the checking process: the design's CheckContext


def _init_checker(ctx: CheckContext, numpy_errors=None) -> None:
    global _CONTEXT
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the optimizing process's to handle
    from .processes import follow_numpy_errors

    follow_numpy_errors(numpy_errors)
    _CONTEXT = ctx
    from ..deploy import simulate  # noqa: F401  (imported while the optimization's first stage runs)


def _check_beside(Pv, p, guess, try_guide) -> dict:
    return check_stage(_CONTEXT, Pv, p, guess, try_guide)


def _ready() -> bool:
    return True


class StageChecks:
    """The checks of one design, in the order asked: run at once here, or queued to one process beside.

    Parameters
    ----------
    ctx : CheckContext
    beside : bool
        Run the checks in a process of their own (forked from a fork server, as :mod:`.processes` does)
        while the optimization goes on here.
    """

    def __init__(self, ctx: CheckContext, beside: bool = False):
        self.ctx = ctx
        self._asked = []  # (load factor, result dict or Future), in the order asked
        self._pool = None
        if beside:
            from concurrent.futures import ProcessPoolExecutor

            from .processes import mp_context

            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=mp_context(), initializer=_init_checker,
                                             initargs=(ctx, np.geterr()))
            self._pool.submit(_ready)  # starts the process (and its imports) now, not at the first check

    @property
    def beside(self) -> bool:
        return self._pool is not None

    def ask(self, mu: float, Pv: np.ndarray, p: np.ndarray, guess: np.ndarray) -> None:
        """Check the design ``(Pv, p)`` reached at load factor ``mu`` (the arrays are copied).

        A guided deployment (``ctx.guide``) is tried only where ``mu`` is 0: under a load the tracked state is
        held there by it, not an equilibrium of the design alone for a guide to find. Measured on the manta ray,
        the breather and the clapper, every kept guided check was at load 0; trying every stage doubled the
        time of the small inverse tests' designs (the saddle's 110 s to 200 s)."""
        args = (np.array(Pv, float), np.array(p, float), np.array(guess, float), mu == 0.0)
        if self._pool is None:
            self._asked.append((mu, args, check_stage(self.ctx, *args)))
        else:
            from concurrent.futures.process import BrokenProcessPool

            try:
                self._asked.append((mu, args, self._pool.submit(_check_beside, *args)))
            except BrokenProcessPool:  # the process died (killed, out of memory): the checks go on here
                self.close()
                self._asked.append((mu, args, check_stage(self.ctx, *args)))

    def results(self, wait: bool = True) -> list:
        """``[(load factor, result of :func:`check_stage`)]`` in the order asked. ``wait=False`` (after Ctrl-C):
        only the checks that have ended, the others dropped. The checking process is ended either way; a
        check it could not return (the process died) is run here."""
        from concurrent.futures import Future
        from concurrent.futures.process import BrokenProcessPool

        out = []
        try:
            for mu, args, r in self._asked:
                if isinstance(r, Future):
                    if not wait and (not r.done() or r.cancelled() or r.exception() is not None):
                        continue
                    try:
                        r = r.result()
                    except BrokenProcessPool:
                        r = check_stage(self.ctx, *args)
                out.append((mu, r))
        except BaseException:
            self.close()
            raise
        self.close(graceful=wait)
        return out

    def close(self, graceful: bool = False) -> None:
        """End the checking process, dropping checks not yet run: ``graceful`` once every check has ended,
        else at once (it ignores Ctrl-C, so it is terminated here)."""
        if self._pool is None:
            return
        from .processes import end_pool

        pool, self._pool = self._pool, None
        end_pool(pool, wait=graceful)
