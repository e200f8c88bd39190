"""Rendered views of a linkage with beams coloured by the square root of
bending-energy density (as in the paper's Fig. 6), and deployment curves."""
from __future__ import annotations

import os

import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


DPI = 110
PAD_INCHES = 0.1  # matplotlib's savefig.pad_inches


def _save(fig, path) -> None:
    """``fig`` as a PNG cropped to its artists plus a margin, as ``savefig(bbox_inches="tight")`` crops it, in one
    drawing instead of two (savefig draws once to find the box, then again to save: the deployed picture took
    0.13 s against 0.08, on the path of every ``xshells deploy``). Written atomically."""
    from PIL import Image

    tmp = str(path) + ".tmp.png"
    try:
        fig.set_dpi(DPI)
        fig.canvas.draw()
        box = fig.get_tightbbox(fig.canvas.get_renderer()).padded(PAD_INCHES)
        rgba = np.asarray(fig.canvas.buffer_rgba())
        h, w = rgba.shape[:2]
        x0, x1 = max(0, int(np.floor(box.x0 * DPI))), min(w, int(np.ceil(box.x1 * DPI)))
        y0, y1 = max(0, h - int(np.ceil(box.y1 * DPI))), min(h, h - int(np.floor(box.y0 * DPI)))
        Image.fromarray(np.ascontiguousarray(rgba[y0:y1, x0:x1])).save(tmp, format="png")
        os.replace(tmp, path)
    except BaseException:  # interrupted (Ctrl-C, SIGTERM) or failed: no half-written picture
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _equal_axes(ax, points: np.ndarray) -> None:
    """One scale on all three axes (a cube around the points), and the views' common camera."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    c, r = 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo))
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.view_init(elev=28, azim=-60)


def render_linkage(path, points: np.ndarray, edges: np.ndarray, vertex_values: np.ndarray, title: str = "",
                   label: str = "√(bending energy density)", vmax: float | None = None) -> None:
    """Save a 3D view of rod centerlines coloured per edge.

    Parameters
    ----------
    points : (V, 3) array
    edges : (E, 2) int array
    vertex_values : (V,) array
        Colour field; each edge shows the mean of its endpoints.
    vmax : float, optional
        Top of the colour scale (from 0), so that several views compare;
        default: the field's maximum.
    """
    plt = _pyplot()
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    segs = points[edges]
    vals = 0.5 * (vertex_values[edges[:, 0]] + vertex_values[edges[:, 1]])
    fig = plt.figure(figsize=(7, 5.5))
    ax = fig.add_subplot(projection="3d")
    lc = Line3DCollection(segs, array=vals, cmap="viridis", linewidths=1.6)
    if vmax is not None:
        lc.set_clim(0.0, vmax)
    ax.add_collection3d(lc)
    _equal_axes(ax, points)
    fig.colorbar(lc, ax=ax, shrink=0.6, label=label)
    ax.set_title(title)
    _save(fig, path)
    plt.close(fig)


def plot_deployment(path, angles_deg, energies, torques, title: str = "", utilization=None) -> None:
    """Energy and actuation torque against the average opening angle; below them the largest
    utilization (stress / strength) where given, with the breaking line at 1."""
    plt = _pyplot()
    if utilization is None:
        fig, ax1 = plt.subplots(figsize=(6.5, 4))
    else:
        fig, (ax1, ax3) = plt.subplots(2, 1, figsize=(6.5, 6.2), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
        ax3.plot(angles_deg, utilization, "d-", color="tab:purple", ms=3)
        ax3.axhline(1.0, color="k", lw=0.8, ls="--")
        ax3.set_ylabel("largest utilization")
        ax3.set_xlabel("average opening angle (°)")
    ax1.plot(angles_deg, energies, "o-", color="tab:blue", ms=3, label="elastic energy")
    ax1.set_xlabel("average opening angle (°)")
    # units follow the input, never converted: force × length (N·mm for a design in mm with E in MPa)
    ax1.set_ylabel("elastic energy (N·mm for mm, MPa)", color="tab:blue")
    ax2 = ax1.twinx()
    ax2.plot(angles_deg, torques, "s-", color="tab:red", ms=3, label="torque per joint")
    ax2.set_ylabel("torque per joint (N·mm/rad for mm, MPa)", color="tab:red")
    if utilization is not None:
        ax1.set_xlabel("")
    ax1.set_title(title)
    # room for both axes' labels beside six-digit tick labels (the crop keeps to the canvas: the energy label
    # lost its first letter and the torque label half its width)
    fig.subplots_adjust(left=0.17, right=0.83)
    # no tight_layout: the saved picture is cropped to its artists anyway (bbox_inches="tight"), and
    # tight_layout was 0.09 of the 0.14 s this plot took, on the critical path of ``xshells deploy``
    _save(fig, path)
    plt.close(fig)


def render_actuators(path, linkage, actuated, torques, reference=None, title: str = "", labels=None) -> None:
    """The deployed linkage with its actuated joints marked (paper Fig. 8).

    Parameters
    ----------
    linkage : Linkage
        At the sparsely actuated equilibrium.
    actuated : (m,) int array
        Joint numbers carrying an actuator.
    torques : (n,) array
        Torque per joint; marker areas scale with it.
    reference : (n, 3) array, optional
        Dense-actuation joint positions, drawn as small grey dots.
    labels : (m,) optional
        A label per actuator (the input vertex numbers), written beside its marker.
    """
    plt = _pyplot()
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    rods = linkage.rods
    segs = [rods.points[a:b] for a, b in zip(rods.vertex_offsets[:-1], rods.vertex_offsets[1:])]
    P = linkage.joint_positions()
    fig = plt.figure(figsize=(7, 5.5))
    ax = fig.add_subplot(projection="3d", computed_zorder=False)  # the markers on top of the rods, not sorted behind them
    ax.add_collection3d(Line3DCollection(segs, colors="0.35", linewidths=1.1))
    if reference is not None:
        R = np.asarray(reference)
        ax.scatter(R[:, 0], R[:, 1], R[:, 2], s=3, c="0.6", depthshade=False, label="dense actuation")
    actuated = np.asarray(actuated, int)
    if len(actuated):
        tau = np.asarray(torques)[actuated]
        size = 60 + 200 * tau / tau.max()
        ax.scatter(P[actuated, 0], P[actuated, 1], P[actuated, 2], s=size, c="tab:red", edgecolors="k", linewidths=1.2,
                   depthshade=False, zorder=10, label="actuators (area ∝ torque)")
    _equal_axes(ax, rods.points)
    if len(actuated) and labels is not None and len(actuated) <= 40:  # more would hide each other: result.json lists them
        from mpl_toolkits.mplot3d import proj3d

        proj = ax.get_proj()
        for (x, y, z), text in zip(P[actuated], labels):  # beside the marker (offset on screen), not over it
            x2, y2, _ = proj3d.proj_transform(x, y, z, proj)
            ax.annotate(str(text), (x2, y2), xytext=(8, 6), textcoords="offset points", fontsize=9, fontweight="bold",
                        color="darkred", zorder=11, bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.8))
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(title)
    _save(fig, path)
    plt.close(fig)


def plot_actuation_tradeoff(path, rows, title: str = "") -> None:
    """Fitting distance against the number of actuators, one curve per ``p`` (paper Fig. 9).

    ``rows``: dicts with ``p``, ``num_actuators`` and ``fit_mean`` (relative to the span); rows
    without ``p`` (the elimination's) make a curve of their own.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    groups = {r.get("p") for r in rows}
    failed_drawn = False
    for p in sorted(groups - {None}, reverse=True) + ([None] if None in groups else []):
        sel = sorted((r for r in rows if r.get("p") == p), key=lambda r: r["num_actuators"])
        line, = ax.plot([r["num_actuators"] for r in sel], [100 * r["fit_mean"] for r in sel], "o-", ms=4,
                        label="elimination (--max-fit / --actuators)" if p is None else f"p = {p:g}")
        bad = [r for r in sel if not _truthy(r.get("converged", True))]
        if bad:  # a run that stopped short (iteration limit, collapsed trust region): an open ring
            ax.plot([r["num_actuators"] for r in bad], [100 * r["fit_mean"] for r in bad], "o", ms=11, mfc="none",
                    mec="C3", mew=1.5, label=None if failed_drawn else "not converged")
            failed_drawn = True
    ax.set_xlabel("number of actuators")
    ax.set_ylabel("mean joint distance to\nthe dense deployment (% of span)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title(title)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def _truthy(value) -> bool:
    """A flag from a row: a bool, or its text as read back from a CSV."""
    return value if isinstance(value, bool) else str(value).strip().lower() in ("true", "1", "yes")


def plot_actuation_curve(path, rows, *, max_fit=None, chosen=None, chosen_failed=False, title: str = "") -> None:
    """Mean and largest joint deviation against the number of actuators, from one elimination run.

    ``rows``: dicts with ``num_actuators``, ``fit_mean`` and ``fit_max``
    (relative to the span); ``max_fit`` draws the limit, ``chosen`` marks
    the answer's actuator count.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    # dense actuation (every joint) fits exactly: no point on a log scale
    sel = sorted((r for r in rows if r["fit_mean"] > 0 and r["fit_max"] > 0), key=lambda r: r["num_actuators"])
    if not sel:
        sel = sorted(rows, key=lambda r: r["num_actuators"])
    k = [r["num_actuators"] for r in sel]
    ax.plot(k, [100 * r["fit_mean"] for r in sel], "o-", ms=4, color="C0", label="mean deviation")
    ax.plot(k, [100 * r["fit_max"] for r in sel], "s--", ms=3, color="C1", alpha=0.8, label="largest deviation")
    if max_fit is not None:
        ax.axhline(100 * max_fit, color="C3", lw=1, label=f"limit on the mean ({100 * max_fit:g}%)")
    if chosen is not None:
        r = min(sel, key=lambda r: abs(r["num_actuators"] - chosen))
        what = f"{r['num_actuators']} actuator{'' if r['num_actuators'] == 1 else 's'}"
        if chosen_failed:  # no answer met the request: an open marker, and the legend says so
            ax.plot([r["num_actuators"]], [100 * r["fit_mean"]], "X", ms=12, mfc="none", mec="C3", mew=2, zorder=5,
                    label=f"NOT CONVERGED, last state: {what}")
        else:
            ax.plot([r["num_actuators"]], [100 * r["fit_mean"]], "*", ms=14, color="C3", zorder=5, label=f"answer: {what}")
    ax.set_xscale("log")
    if all(r["fit_mean"] > 0 for r in sel):
        ax.set_yscale("log")
    ax.set_xlabel("number of actuators")
    ax.set_ylabel("joint distance to the dense deployment (% of span)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title(title)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def plot_convergence(path, curves: dict, title: str = "") -> None:
    """Objective against iteration, one curve per method (paper Fig. 7)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, J in curves.items():
        ax.plot(np.arange(len(J)), J, "o-", ms=3, label=label)
    ax.set_xlabel("iteration")
    ax.set_ylabel("J")
    ax.set_yscale("log")
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def render_fit(path, V: np.ndarray, F: np.ndarray, points: np.ndarray, edges: np.ndarray, distances: np.ndarray,
               title: str = "", label: str = "distance to the surface") -> None:
    """The deployed beams over the translucent target surface, coloured by their distance to it.

    Parameters
    ----------
    V, F : (n, 3), (m, 3)
        The target surface.
    points : (k, 3), edges : (e, 2)
        Rod centerlines (placed in the surface's frame).
    distances : (k,)
        Per rod vertex; each edge shows the mean of its endpoints.
    """
    plt = _pyplot()
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    fig = plt.figure(figsize=(7.5, 5.8))
    ax = fig.add_subplot(projection="3d")
    ax.plot_trisurf(V[:, 0], V[:, 1], V[:, 2], triangles=F, color="0.75", alpha=0.25, linewidth=0, shade=True)
    vals = 0.5 * (distances[edges[:, 0]] + distances[edges[:, 1]])
    lc = Line3DCollection(points[edges], array=vals, cmap="plasma", linewidths=1.8)
    lc.set_clim(0.0, max(float(vals.max()), 1e-12))
    ax.add_collection3d(lc)
    _equal_axes(ax, np.vstack([V, points]))
    fig.colorbar(lc, ax=ax, shrink=0.6, label=label)
    ax.set_title(title)
    _save(fig, path)
    plt.close(fig)


def render_flat(path, points: np.ndarray, edges: np.ndarray, vertex_values: np.ndarray | None = None, title: str = "",
                label: str = "√(bending energy density)", axes: tuple = ("x", "y"), vmax: float | None = None) -> None:
    """A top view (the first two coordinates, equal scale) of a flat layout's rod centerlines, optionally coloured
    per edge. ``axes``: the names of those two coordinates (a layout drawn in another plane, projected on it);
    ``vmax``: the top of the colour scale (default: the field's maximum)."""
    plt = _pyplot()
    from matplotlib.collections import LineCollection

    span = np.ptp(points[:, :2], axis=0)
    aspect = float(span[1] / max(span[0], 1e-300))
    fig, ax = plt.subplots(figsize=(9.0, float(np.clip(9.0 * aspect, 2.2, 9.0)) + 1.8))
    segs = points[edges][:, :, :2]
    if vertex_values is None:
        lc = LineCollection(segs, colors="0.2", linewidths=1.4)
    else:
        vals = 0.5 * (vertex_values[edges[:, 0]] + vertex_values[edges[:, 1]])
        lc = LineCollection(segs, array=vals, cmap="viridis", linewidths=1.4)
        if vmax is not None:
            lc.set_clim(0.0, vmax)
        fig.colorbar(lc, ax=ax, orientation="horizontal" if aspect < 0.6 else "vertical", shrink=0.6, pad=0.18,
                     label=label)
    ax.add_collection(lc)
    ax.autoscale()
    ax.set_aspect("equal")
    ax.set_xlabel(axes[0])
    ax.set_ylabel(axes[1])
    ax.set_title(title)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def render_analysis(path, points0: np.ndarray, points: np.ndarray, edges: np.ndarray, vertex_values: np.ndarray,
                    scale: float, label: str = "utilization", title: str = "", supports=None, loads=None,
                    support_kinds=None) -> None:
    """The loaded shell: the unloaded centerlines in grey and the displaced ones (displacement × ``scale``),
    coloured per edge by ``vertex_values`` (e.g. the utilization).

    The colour scale runs from 0 to the largest vertex value (the edges' colours are their vertices' means,
    which stop short of the maximum reported). ``supports``: (k, 3) points drawn as triangles, or where
    ``support_kinds`` (k,) says "clamped" as squares; ``loads``: (points (m, 3), forces (m, 3)) drawn as arrows
    pointing at the points, each a tenth of the drawing's span long (a small load's arrow, scaled with the
    largest, was a dot). The load points are where the loaded vertices are drawn: the unloaded ones plus
    ``scale`` × the displacement (at the true loaded position the arrows hung beside the exaggerated shape).
    """
    plt = _pyplot()
    from matplotlib.colors import Normalize
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    shown = points0 + scale * (points - points0)
    fig = plt.figure(figsize=(7.5, 5.8))
    ax = fig.add_subplot(projection="3d")
    ax.computed_zorder = False  # the markers and arrows over the shell (sorted by depth, the beams hid them)
    ax.add_collection3d(Line3DCollection(points0[edges], colors="0.75", linewidths=0.8))
    vals = 0.5 * (vertex_values[edges[:, 0]] + vertex_values[edges[:, 1]])
    top = float(np.max(vertex_values)) if len(vertex_values) else 1.0
    lc = Line3DCollection(shown[edges], array=vals, cmap="inferno_r", linewidths=1.8,
                          norm=Normalize(vmin=min(0.0, float(np.min(vertex_values))), vmax=top if top > 0 else 1.0))
    ax.add_collection3d(lc)
    span = float(np.ptp(np.vstack([points0, shown]), axis=0).max()) or 1.0
    if supports is not None and len(supports):
        S = np.asarray(supports, float)
        kinds = np.asarray(["pinned"] * len(S) if support_kinds is None else list(support_kinds))
        for kind, marker in (("pinned", "^"), ("clamped", "s")):
            if np.any(kinds == kind):
                K = S[kinds == kind]
                ax.scatter(K[:, 0], K[:, 1], K[:, 2], marker=marker, s=60, c="tab:blue", depthshade=False,
                           label=f"{kind} supports", zorder=9)
    if loads is not None and len(loads[0]):
        at, F = (np.asarray(a, float) for a in loads)
        F = F / np.maximum(np.linalg.norm(F, axis=1), 1e-300)[:, None] * 0.1 * span
        ax.quiver(at[:, 0] - F[:, 0], at[:, 1] - F[:, 1], at[:, 2] - F[:, 2], F[:, 0], F[:, 1], F[:, 2],
                  color="tab:green", linewidth=2.5, arrow_length_ratio=0.3, label="point loads", zorder=10)
    if (supports is not None and len(supports)) or (loads is not None and len(loads[0])):
        ax.legend(loc="upper left", fontsize=8)
    _equal_axes(ax, np.vstack([points0, shown]))
    fig.colorbar(lc, ax=ax, shrink=0.6, label=label)
    ax.set_title(title, fontsize=10)
    _save(fig, path)
    plt.close(fig)
