"""A deployment guided into one of its equilibria: held on a shape at the target angle, then let go.

A design can have more than one stable equilibrium at its deployed angle,
and the deployment from flat reaches one of them. The inverse design of
the manta ray's realizable target found one that fits the target within
a quarter of the bar while the deployment from flat reached another, its
tail flat (docs/inverse.md, "Guided deployments"). A workshop reaches the
other one the way it would be built: open the shell, push it into shape,
and let go. Where that state is an equilibrium, the shell stays.

So a case may name a *guide*: joint positions (nj, 3) of the shape wanted,
in any rigid placement. Once the deployment reaches its angle, springs on
the joints pull the shell onto the guide (placed rigidly on the state
reached), their stiffness raised in steps until the shell is within a
fraction of a segment of it; then the springs are taken away at once and
the shell is solved to equilibrium at the same angle, with no load. What
is reported is that equilibrium, with its own stability: the guide only
chooses the branch, it carries no force in the result.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError


@dataclass(frozen=True)
class GuideOptions:
    """Settings of :func:`settle_into`: how hard the springs may pull before the guide is given up.

    ``stiffnesses`` are tried in turn, in units of ``E·I/ℓ³`` (bending one
    segment of the median length ℓ about its weak axis), until the RMS
    joint-to-guide distance is at most ``hold_tolerance`` × ℓ. The stiffest
    is 1000: a guide the shell cannot be brought within 5 % of a segment of
    by then is not a shape of this design at its angle.
    """

    stiffnesses: tuple = (1e-2, 1e-1, 1.0, 10.0, 100.0, 1000.0)
    hold_tolerance: float = 0.05


@dataclass
class GuideReport:
    """What a guided settle did (lengths relative to the layout's span, as the deployment reports ``max_abs_z``).

    Attributes
    ----------
    held : bool
        Whether the springs brought the shell within the tolerance of the guide.
    stiffness : float
        The springs' stiffness of the hold (force per length).
    held_rms : float
        RMS joint distance of the held state to the guide.
    released_rms : float
        RMS joint distance of the state let go to the guide (after a rigid fit).
    moved : float
        The largest joint distance between the state the deployment reached and the one let go (after a rigid fit):
        about 0 where the guide led back to the same equilibrium.
    energy_unguided, energy : float
        Elastic energies of the two states.
    note : str
        One line for the summary.
    """

    held: bool = False
    stiffness: float = 0.0
    held_rms: float = float("nan")
    released_rms: float = float("nan")
    moved: float = float("nan")
    energy_unguided: float = float("nan")
    energy: float = float("nan")
    note: str = ""


def check_guide(guide, num_joints: int | None, where: str = "guide") -> np.ndarray:
    """``guide`` as an (nj, 3) float array, or a one-line InputError naming ``where`` (``num_joints`` None: any
    number of rows)."""
    G = np.asarray(guide, float)
    if G.ndim != 2 or G.shape[1] != 3:
        raise InputError(f"{where}: expected one 'x y z' row per joint, got an array of shape {G.shape}")
    if num_joints is not None and len(G) != num_joints:
        raise InputError(f"{where}: {len(G)} joint positions for a design with {num_joints} joints (one row per joint, "
                         "in the design's joint order)")
    bad = np.flatnonzero(~np.isfinite(G).all(axis=1))
    if len(bad):
        raise InputError(f"{where}: joint {int(bad[0])} (row {int(bad[0]) + 1}) is not finite")
    if float(np.ptp(G, axis=0).max()) == 0.0:
        raise InputError(f"{where}: every joint is at the same point")
    return G


def read_guide(path, num_joints: int | None) -> np.ndarray:
    """The guide file ``path``: one ``x y z`` line per joint (``#`` comments allowed), as an (nj, 3) array."""
    from ..errors import check_input_file

    check_input_file(path, "guide file")
    rows = []
    try:
        with open(path, encoding="utf-8-sig") as fh:
            for k, line in enumerate(fh, 1):
                text = line.split("#", 1)[0].strip()
                if not text:
                    continue
                parts = text.replace(",", " ").split()
                if len(parts) != 3:
                    raise InputError(f"{path}, line {k}: expected 3 numbers 'x y z', got {len(parts)}")
                try:
                    rows.append([float(v) for v in parts])
                except ValueError:
                    raise InputError(f"{path}, line {k}: not a number in {text!r}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read guide file ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text file (byte {exc.start} is not UTF-8)") from None
    return check_guide(np.array(rows, float).reshape(-1, 3), num_joints, str(path))


def guide_text(guide: np.ndarray) -> str:
    """A guide file's text (full precision, so that a case deploys the same to round-off)."""
    head = "# xshells guide: the deployed joint positions to settle into, one 'x y z' line per joint (design units)\n"
    return head + "".join(f"{x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in np.asarray(guide, float))


def rigid_fit(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """``src`` (n, 3) moved by the rotation and translation that bring it closest to ``dst`` (least squares)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    U, _, Vt = np.linalg.svd((src - cs).T @ (dst - cd))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return (src - cs) @ (U @ D @ Vt) + cd


def _rms(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((A - B) ** 2, axis=1))))


def segment_stiffness(linkage, length: float) -> float:
    """E·I_min/ℓ³ (force per length) of the most flexible material, ℓ = ``length``: the stiffness of bending one
    segment of that length, the unit of the springs that hold a shell on a shape."""
    return float(min(min(m.bending_stiffness) for m in linkage.materials) / length**3)


def joint_rows(linkage) -> np.ndarray:
    """The variables of the joints' positions, (3·nj,), joint by joint."""
    return ((9 * np.arange(linkage.num_joints))[:, None] + np.arange(3)[None, :]).ravel()


def settle_into(linkage, guide: np.ndarray, a: np.ndarray, angle: float, held, release,
                options: GuideOptions = GuideOptions()) -> GuideReport:
    """Hold the deployed ``linkage`` (in place) on ``guide`` at the average angle ``a·x = angle``, then let go.

    Parameters
    ----------
    linkage : Linkage
        At its deployed equilibrium; it ends in the equilibrium let go into (or, where the hold or the release
        fails, back where it was).
    guide : (nj, 3) float
        The joint positions wanted, in any rigid placement.
    a : (n,) float
        The average-angle constraint's row.
    held : (k,) int
        Variables held during the hold besides the springs (the joint-edge bounds at their limit). Not the
        deployment's rigid pins: the springs hold the rigid motion, and a guide far from the state reached (its
        mirror image, say) cannot be reached with the central joint held where it is.
    release : callable() -> NewtonReport
        Solves the linkage to equilibrium at ``angle`` without springs, from its current state (the deployment's
        own corrector, with its pins and bounds).
    """
    from ..linkage.state import restore, snapshot
    from ..solve import NewtonOptions, minimize
    from ..solve.tether import Tether, Tethered

    before = snapshot(linkage)
    Y0 = linkage.joint_positions()
    span = float(np.ptp(linkage.rods.points, axis=0).max()) or 1.0
    report = GuideReport(energy_unguided=float(linkage.energy()))
    G = rigid_fit(np.asarray(guide, float), Y0)  # onto the state reached: the springs then pull only the difference
    rows = joint_rows(linkage)
    sj = linkage.graph.segment_joints
    sj = sj[(sj >= 0).all(axis=1)]  # joint to joint (a free end has one joint)
    ell = float(np.median(np.linalg.norm(Y0[sj[:, 1]] - Y0[sj[:, 0]], axis=1))) if len(sj) else span
    unit = segment_stiffness(linkage, ell)
    opts = NewtonOptions(gradient_tolerance=1e-6 * max(unit * ell, 1e-300), max_iterations=300,
                         saddle_gradient_factor=float("inf"))
    for factor in options.stiffnesses:
        tether = Tether(factor * unit, rows, G.ravel())
        rep = minimize(Tethered(linkage, tether), fixed=np.asarray(held, np.int64), constraint=(a, angle), options=opts)
        linkage.update_source_frame()
        report.stiffness, report.held_rms = tether.k, _rms(linkage.joint_positions(), G) / span
        if rep.converged and report.held_rms * span <= options.hold_tolerance * ell:
            report.held = True
            break
    if not report.held:
        restore(linkage, before)
        report.note = (f"the guide was not followed: springs of up to {report.stiffness:.3g} per unit length held the "
                       f"joints {100 * report.held_rms:.3g}% of the span from it (RMS); the state reached is kept")
        return report
    rep = release()
    if not rep.converged:
        restore(linkage, before)
        report.held = False
        report.note = f"let go from the guide, the shell found no equilibrium ({rep.message}); the state reached is kept"
        return report
    Y = linkage.joint_positions()
    report.released_rms = _rms(rigid_fit(G, Y), Y) / span
    report.moved = float(np.linalg.norm(rigid_fit(Y0, Y) - Y, axis=1).max()) / span
    report.energy = float(linkage.energy())
    report.note = (f"guided: held on the guide and let go, the shell stays {100 * report.released_rms:.3g}% of the span "
                   f"from it (RMS), {100 * report.moved:.3g}% from where the deployment from flat ended (largest joint); "
                   f"energy {report.energy:.6g} against {report.energy_unguided:.6g}")
    return report
