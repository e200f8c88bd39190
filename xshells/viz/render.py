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


def _length_label(name: str, unit: str) -> str:
    """An axis label with its length unit: ``"x (mm)"``; ``unit`` empty: the surface file's own units."""
    return f"{name} ({unit or 'surface units'})"


def _clear_of(fig, ax, below: list, gap: float = 0.01, tries: int = 3) -> None:
    """Raise and shorten ``ax`` until everything it draws (tick and axis labels included) stays above the artists
    ``below`` (a colour bar and its texts), in figure coordinates. A 3D view's labels fall where its projection puts
    them: on a deep shell (Darth Vader's realizable target) the x label and ticks ran into the colour bar."""
    inverse = fig.transFigure.inverted()
    for _ in range(tries):
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        floor = max(a.get_window_extent(renderer).transformed(inverse).y1 for a in below) + gap
        low = ax.get_tightbbox(renderer).transformed(inverse).y0
        if low >= floor:
            return
        box = ax.get_position()
        rise = min(floor - low, 0.5 * box.height)
        ax.set_position((box.x0, box.y0 + rise, box.width, box.height - rise))


def render_fit(path, V: np.ndarray, F: np.ndarray, points: np.ndarray, edges: np.ndarray, distances: np.ndarray,
               title: str = "", unit: str = "", joint_max: float | None = None):
    """The deployed beams over the target surface, coloured by their centrelines' distance to it.

    Parameters
    ----------
    path : str
        The PNG to write.
    V, F : (n, 3), (m, 3)
        The target surface.
    points : (k, 3), edges : (e, 2)
        Rod centrelines (placed in the surface's frame).
    distances : (k,)
        Per rod vertex, in the surface's length unit; each edge shows the mean of its endpoints. The colour
        scale runs from 0 to their maximum (free ends included), which its label states.
    title : str
        E.g. the joints' fit as the result reports it.
    unit : str
        The length unit of the axes and the colour bar ("mm"); empty: "surface units".
    joint_max : float, optional
        The joints' largest distance, in the same unit: marked on the colour bar, so that the title's
        figure and the colours compare.

    Returns
    -------
    matplotlib.figure.Figure
        The closed figure, for inspection.
    """
    plt = _pyplot()
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    u = unit or "surface units"
    fig = plt.figure(figsize=(8.0, 5.0))
    ax = fig.add_axes((0.0, 0.16, 1.0, 0.78), projection="3d")
    ax.computed_zorder = False  # the beams over the surface (sorted by depth, the surface hid them)
    top = max(float(np.max(distances)), 1e-12)
    vals = 0.5 * (distances[edges[:, 0]] + distances[edges[:, 1]])
    lc = Line3DCollection(points[edges], array=vals, cmap="plasma", linewidths=2.0, zorder=2)
    lc.set_clim(0.0, top)
    P = np.vstack([V, points])
    lo, hi = P.min(axis=0), P.max(axis=0)
    pad = 0.02 * float(np.max(hi - lo))
    ax.set(xlim=(lo[0] - pad, hi[0] + pad), ylim=(lo[1] - pad, hi[1] + pad), zlim=(lo[2] - pad, hi[2] + pad))
    ax.set_box_aspect(np.maximum(hi - lo + 2 * pad, 1e-3 * float(np.max(hi - lo))), zoom=1.2)  # one scale
    ax.view_init(elev=28, azim=-60)
    for axis, name in zip((ax.xaxis, ax.yaxis, ax.zaxis), "xyz"):
        axis.set_major_locator(MaxNLocator(4))  # few ticks: the x and y labels collided at the near corner
        axis.set_label_text(_length_label(name, unit))
    ax.tick_params(labelsize=8, pad=1)
    ax.set_title(title)
    cax = fig.add_axes((0.225, 0.1, 0.55, 0.03))
    cb = fig.colorbar(lc, cax=cax, orientation="horizontal",
                      label=f"distance of the beam centrelines to the surface ({u}): up to {top:.3g}, free ends included")
    marker = None
    if joint_max is not None:
        cb.ax.axvline(joint_max, color="black", linewidth=2.0)
        marker = cb.ax.text(joint_max, 1.15, f"joints' max {joint_max:.3g}", transform=cb.ax.get_xaxis_transform(),
                            ha="center", va="bottom", fontsize=8)
    # the layout is settled on the empty view: the surface and the beams are most of a draw's cost (their limits
    # are set above, so adding them after changes nothing else)
    _clear_of(fig, ax, [cax] + ([marker] if marker is not None else []))
    ax.plot_trisurf(V[:, 0], V[:, 1], V[:, 2], triangles=F, color="#9ab8d8", alpha=0.45, linewidth=0.15,
                    edgecolor="#6f8fb3", shade=True, zorder=1)
    ax.add_collection3d(lc)
    _save(fig, path)
    plt.close(fig)
    return fig


def render_flat(path, points: np.ndarray, edges: np.ndarray, vertex_values: np.ndarray | None = None, title: str = "",
                label: str = "√(bending energy per unit length) (√N for mm and MPa)", axes: tuple = ("x", "y"),
                vmax: float | None = None, unit: str = ""):
    """A top view (the first two coordinates, equal scale, tight bounds) of a flat layout's rod centrelines,
    optionally coloured per edge.

    Parameters
    ----------
    path : str
        The PNG to write.
    points : (k, 2 or 3), edges : (e, 2)
        Rod centrelines; only the first two coordinates are drawn.
    vertex_values : (k,), optional
        Colour field; each edge shows the mean of its endpoints. None: the beams in dark grey.
    title, label : str
        The title and the colour bar's label (what the field is, with its unit).
    axes : (str, str)
        The names of the two coordinates (a layout drawn in another plane, projected on it).
    vmax : float, optional
        The top of the colour scale (default: the field's maximum).
    unit : str
        The length unit of the axes ("mm"), if known: then the axis labels state it.

    Returns
    -------
    matplotlib.figure.Figure
        The closed figure, for inspection.
    """
    plt = _pyplot()
    from matplotlib.collections import LineCollection
    from mpl_toolkits.axes_grid1 import make_axes_locatable

    segs = points[edges][:, :, :2]
    lo, hi = segs.reshape(-1, 2).min(axis=0), segs.reshape(-1, 2).max(axis=0)
    span = np.maximum(hi - lo, 1e-12 * max(float(np.max(hi - lo)), 1e-300))
    aspect = float(span[1] / span[0])
    side = 7.5  # inches for the longer side of the drawing
    w, h = (side, side * aspect) if aspect <= 1 else (side / aspect, side)
    wide = aspect < 0.8
    # at least 6.5 in wide, for the title (the saved picture is cropped to the drawing, its labels and title)
    fig, ax = plt.subplots(figsize=(max(w + (0 if wide else 1.6), 6.5), max(h, 1.5) + (1.4 if wide else 0.6)))
    if vertex_values is None:
        lc = LineCollection(segs, colors="0.2", linewidths=1.4)
    else:
        vals = 0.5 * (vertex_values[edges[:, 0]] + vertex_values[edges[:, 1]])
        lc = LineCollection(segs, array=vals, cmap="viridis", linewidths=1.4)
        lc.set_clim(0.0, float(np.max(vertex_values)) if vmax is None else vmax)
    ax.add_collection(lc)
    m = 0.02 * float(np.max(span))
    ax.set_xlim(lo[0] - m, hi[0] + m)
    ax.set_ylim(lo[1] - m, hi[1] + m)
    ax.set_aspect("equal")
    ax.set_xlabel(f"{axes[0]} ({unit})" if unit else axes[0])
    ax.set_ylabel(f"{axes[1]} ({unit})" if unit else axes[1])
    ax.set_title(title)
    if vertex_values is not None:  # beside the drawing, whatever its shape (not a fixed figure fraction away)
        cax = make_axes_locatable(ax).append_axes("bottom" if wide else "right", size="4%" if not wide else "6%",
                                                  pad=0.6 if wide else 0.15)
        fig.colorbar(lc, cax=cax, orientation="horizontal" if wide else "vertical", label=label)
    _save(fig, path)
    plt.close(fig)
    return fig


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
