"""The job behind ``xshells analyze``: deploy, then support, load and check the shell (docs/analysis.md)."""
from __future__ import annotations

import copy
import csv
import io
import os
import time
from dataclasses import replace

import numpy as np

from ..errors import STOP, InputError
from ..io.export import atomic_write_text, finite_json
from .static import Load, StaticOptions, Support


def parse_supports(text: str, kind: str = "pinned"):
    """``lowest:N`` → ("lowest", N); ``joints:i,j,…`` → ("joints", [i, j, …]) (input vertex indices)."""
    head, _, rest = str(text).partition(":")
    vertices = None
    try:
        if head == "lowest":
            n = int(rest)
            return "lowest", n
        if head == "joints":
            vertices = [int(v) for v in rest.split(",") if v.strip()]
    except ValueError:
        pass
    if vertices is not None:
        twice = next((v for i, v in enumerate(vertices) if v in vertices[:i]), None)
        if twice is not None:  # it would be held and counted as two supports: twice the reactions
            raise InputError(f"--supports {text}: vertex {twice} is listed twice")
        return "joints", vertices
    raise InputError(f"--supports {text}: use lowest:N or joints:i,j,… (input vertex indices)")


def parse_load(text: str) -> Load:
    """``self-weight``, ``point:VERTEX:FX,FY,FZ`` or ``area:Q``."""
    t = str(text).strip()
    if t == "self-weight":
        return Load("self-weight")
    parts = t.split(":")
    try:
        if parts[0] == "point" and len(parts) == 3:
            vec = tuple(float(v) for v in parts[2].split(","))
            if len(vec) != 3 or not np.all(np.isfinite(vec)):
                raise ValueError
            if not any(vec):  # nothing to analyse (and a relative balance of 0/0)
                raise InputError(f"--load {text}: a point load of zero")
            return Load("point", vertex=int(parts[1]), vector=vec)
        if parts[0] == "area" and len(parts) == 2:
            q = float(parts[1])
            if not np.isfinite(q):
                raise ValueError
            if q == 0:
                raise InputError(f"--load {text}: an area load of zero")
            return Load("area", q=q)
    except InputError:
        raise
    except ValueError:
        pass
    raise InputError(f"--load {text}: use self-weight, point:VERTEX:FX,FY,FZ or area:Q")


def run_analysis(design_path, material, *, out_dir, supports_spec, support_type="pinned", loads=(), joints="locked",
                 load_factor=1.0, strength=None, density_given=True, subdivision=10, target_angle=None, open_by=None,
                 steps=40, rest_lengths_path=None, direction="up", name=None, progress=True, critical=True,
                 guide_path=None) -> dict:
    """Deploy (as ``xshells deploy``, outputs in ``out_dir/deploy``; with the case's guide, ``guide_path``), then
    analyse under the loads."""
    from ..deploy.run import run_deployment
    from .static import (critical_load_factor, free_rigid_modes, held_variables, load_vector, lowest_supports,
                         reactions, smallest_eigenvalue)
    from .stress import beam_report, check_strength, rod_stresses

    t0 = time.perf_counter()
    strength = check_strength(strength)
    if not np.isfinite(load_factor) or load_factor <= 0:
        raise InputError(f"--load-factor must be a positive number, got {load_factor:g}")
    if not loads:
        raise InputError("give at least one --load (self-weight, point:VERTEX:FX,FY,FZ or area:Q)")
    if sum(l.kind == "self-weight" for l in loads) > 1:  # point and area loads add up; the weight is there once
        raise InputError("--load self-weight is given twice: the shell has one self-weight")
    if any(l.kind == "self-weight" for l in loads) and not density_given:
        raise InputError("--load self-weight needs a density: give --density, a --grade, or the material's density")
    from ..io import read_design

    design = read_design(design_path)  # supports and loads are checked before the deployment's work
    used = set(design.edges.ravel().tolist())
    n = design.num_vertices
    if supports_spec[0] == "joints":
        for v in supports_spec[1]:
            if v not in used:
                raise InputError(f"--supports: vertex {v} does not exist (the design's segments use vertices 0 to {n - 1})")
    for load in loads:
        if load.kind == "point" and load.vertex not in used:
            raise InputError(f"point load at vertex {load.vertex}: no such vertex in the design (0 to {n - 1})")
    os.makedirs(out_dir, exist_ok=True)
    states = {}
    dep = run_deployment(design_path, material, out_dir=os.path.join(out_dir, "deploy"), subdivision=subdivision,
                         target_angle=target_angle, open_by=open_by, steps=steps, rest_lengths_path=rest_lengths_path,
                         direction=direction, progress=progress, name=name, states=states, strength=strength,
                         guide_path=guide_path)
    if not dep["reached"]:
        raise InputError(f"the deployment did not reach its angle ({dep['message']}): nothing to analyse")
    L = states["deployed"]
    from .static import translate

    origin = L.vertex_positions().mean(axis=0)
    translate(L, -origin)  # about the origin: less round-off (results are shift-invariant; outputs are shifted back)
    t_dep = time.perf_counter() - t0
    mode, arg = supports_spec
    vertices = lowest_supports(L, arg) if mode == "lowest" else arg
    n = L.graph.design.num_vertices
    for v in vertices:
        if not (0 <= v < n):
            raise InputError(f"--supports: vertex {v} does not exist (the design has vertices 0 to {n - 1})")
    supports = [Support(int(v), support_type) for v in vertices]
    modes = free_rigid_modes(L, supports)
    if modes:
        raise InputError(f"the supports ({len(supports)}, {support_type}) leave {modes} rigid motion(s) free: the "
                         f"structure is a mechanism; add supports")
    opts = StaticOptions(joints=joints)
    held = held_variables(L, supports, joints)
    base = None
    if joints == "free":  # the actuation torque stays: the deployed state is in equilibrium with it
        base = np.zeros(L.num_vars)
        rows = L.angle_indices()
        base[rows] = L.gradient()[rows]
    f, resultant = load_vector(L, loads, opts.gravity)
    unloaded = copy.deepcopy(L)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(desc="loading" + (", then the critical load search" if critical else ""), unit="step")

    def on_path(lam):
        if bar is not None:
            bar.update(1)
            bar.set_postfix(load_factor=f"{lam:.4g}")
        return STOP.requested  # a SIGTERM's stop that a finalizer swallowed: the search ends as for Ctrl-C

    t2 = time.perf_counter()
    try:  # the path from zero load, through the requested load and (with critical) on until stability ends
        crit = critical_load_factor(unloaded, f, held, opts, base_force=base, start=load_factor, search=critical,
                                    callback=on_path)
    finally:
        if bar is not None:
            bar.close()
    t_crit = time.perf_counter() - t2
    interrupted = crit.interrupted
    shown = crit if critical or crit.factor is not None else None  # without --no-critical, the path's end is reported
    t1 = time.perf_counter()
    with STOP.deferred():  # what was finished is kept: the loaded state and its files (seconds)
        st, buckled = _loaded_state(L, unloaded, f, held, base, opts, load_factor, crit)
        # which equilibrium is shown: "post-snap" where the load passes the critical factor and the state the shell
        # goes to was found, "pre-snap" where it was not (the last equilibrium before the critical factor),
        # "loaded" on the path from zero load (stable or not, as "stable" says)
        state_kind = ("post-snap" if st.converged else "pre-snap") if buckled else "loaded"
        if interrupted:
            st.converged = False
            st.message = ("interrupted during the critical load search (the loaded state was solved)"
                          if crit.target_state is not None else
                          f"interrupted before the requested load, at load factor {st.load_factor:.4g}")
        reached = st.load_factor
        if abs(reached - load_factor) <= 1e-12 * load_factor:  # the path's steps add up to it within round-off
            reached = st.load_factor = load_factor
        total_force = (base if base is not None else 0.0) + reached * f
        reac, reac_total = reactions(L, supports, total_force, held)
        try:
            mu = smallest_eigenvalue(L, held)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError, RuntimeError) as exc:  # ARPACK on a bad state
            mu = float("nan")
            st.message += f"; its stability could not be computed ({type(exc).__name__})"
        stresses = rod_stresses(L, strength)
    t_load = time.perf_counter() - t1
    disp = np.linalg.norm(st.displacement, axis=1)
    beams = beam_report(L, stresses)
    result = {
        "input": design.note,  # how a .3dm was read (its layer, units and the conversion to mm), else None
        "name": name, "status": "interrupted" if interrupted else "complete" if st.converged else "stopped",
        "message": st.message,
        "segments": int(L.num_segments), "joints": int(L.num_joints),
        "units": "those of the input: N, mm and MPa for the bundled data",
        "supports": [{"vertex": s.vertex, "kind": s.kind} for s in supports], "joint_mode": joints,
        "loads": [l.__dict__ for l in loads], "load_factor": load_factor, "load_factor_reached": st.load_factor,
        "max_displacement": float(disp.max()), "max_displacement_vertex": int(np.argmax(disp)),
        "max_von_mises": stresses.max_von_mises, "max_utilization": stresses.max_utilization, "strength": strength,
        "reactions": reac, "reactions_total": reac_total.tolist(), "total_load": (reached * resultant).tolist(),
        # relative to the total load; None where the loads cancel (self-balanced, or nothing reached)
        "equilibrium_error": (float(np.linalg.norm(reac_total + reached * resultant) / np.linalg.norm(reached * resultant))
                              if np.linalg.norm(reached * resultant) > 0 else None),
        "min_eigenvalue": None if np.isnan(mu) else mu, "stable": None if np.isnan(mu) else bool(mu >= 0),
        # a multiple of the --load, as --load-factor is (the same whatever the split of a load between them);
        # critical_load_ratio: the critical load over the load applied (below 1: it has buckled)
        "critical_load_factor": None if shown is None else shown.factor,
        "critical_load_ratio": None if shown is None or shown.factor is None else shown.factor / load_factor,
        "critical_total_load": None if shown is None or shown.factor is None else (shown.factor * resultant).tolist(),
        # informative where the loads cancel (a squeeze: the resultant is 0): the critical factor times the
        # applied loads' magnitude (docs/analysis.md)
        "critical_load_magnitude": (None if shown is None or shown.factor is None
                                    else shown.factor * _load_magnitude(unloaded, loads, opts.gravity)),
        "critical_bracket": None if shown is None else list(shown.bracket),
        "critical_method": None if shown is None else shown.method,
        "critical_searched_to": None if shown is None else shown.searched_to,
        "critical_kind": None if shown is None or shown.factor is None else shown.kind,
        "buckled": bool(buckled) or bool(mu < 0), "state": state_kind,
        "deployment": {"reached": dep["reached"], "angle_deg": dep["deployed"]["average_angle_deg"],
                       "utilization_max": dep.get("utilization_max")},
        "timings_s": {"deploy": t_dep, "load": t_load, "critical": t_crit, "total": time.perf_counter() - t0},
    }
    for b in beams:
        b["position"] = (np.asarray(b["position"]) + origin).tolist()
    result["origin_shift"] = origin.tolist()
    result["warnings"] = (_support_warnings(unloaded, supports, reac, reached * resultant,
                                            reached * _load_magnitude(unloaded, loads, opts.gravity))
                          + _warnings(result, L, held, total_force))
    with STOP.deferred():
        _write_outputs(out_dir, L, unloaded, st, stresses, beams, crit, held, result, origin, f, mode=not interrupted)
        atomic_write_text(os.path.join(out_dir, "result.json"), finite_json(result, indent=1))
    if interrupted or STOP.requested:
        raise KeyboardInterrupt
    return result


def _write_outputs(out_dir, L, unloaded, st, stresses, beams, crit, held, result, origin, f, mode=True) -> None:
    """beams.csv, loaded.ply, loaded.3dm, analysis.png and (``mode``) buckling_mode.png."""
    from ..io.sweep import write_ply
    from ..linkage.export import swept_mesh
    from .static import translate
    from ..viz.render import render_analysis

    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["beam", "max_von_mises", "max_utilization", "segment", "nearest_joint", "x", "y", "z"])
    for b in beams:
        w.writerow([b["beam"], b["max_von_mises"], b["max_utilization"], b["segment"], b["nearest_joint"], *b["position"]])
    atomic_write_text(os.path.join(out_dir, "beams.csv"), buf.getvalue())
    fields = {"von_mises": stresses.von_mises, "normal_stress": stresses.normal, "shear_stress": stresses.shear}
    if stresses.utilization is not None:
        fields["utilization"] = stresses.utilization
    shown = copy.deepcopy(L)
    translate(shown, origin)  # back in the design's frame
    write_ply(os.path.join(out_dir, "loaded.ply"), swept_mesh(shown, fields))
    from ..rhino.write import write_3dm

    write_3dm(os.path.join(out_dir, "loaded.3dm"), deployed=shown)  # the loaded shell's centerlines and beams (mm)
    d = L.rods.points - unloaded.rods.points
    span = float(np.ptp(unloaded.rods.points, axis=0).max())
    dmax = float(np.linalg.norm(d, axis=1).max())
    # a displacement at round-off (a vanishing load, free joints held by their torque) is drawn as it is: scaled
    # to a tenth of the span it was noise blown up into a shape
    tiny = dmax <= 1e-8 * span
    scale = 1.0 if tiny else 0.1 * span / dmax
    value = stresses.utilization if stresses.utilization is not None else stresses.von_mises
    P0 = unloaded.vertex_positions()
    P_drawn = P0 + scale * (L.vertex_positions() - P0) + origin  # where render_analysis draws the loaded vertices
    points = [ld for ld in result["loads"] if ld["kind"] == "point"]
    loads = (P_drawn[[ld["vertex"] for ld in points]].reshape(-1, 3),
             np.array([ld["vector"] for ld in points], float).reshape(-1, 3))
    others = sorted({ld["kind"] for ld in result["loads"] if ld["kind"] != "point"})
    unit = "the design's length unit"
    render_analysis(os.path.join(out_dir, "analysis.png"), unloaded.rods.points + origin, L.rods.points + origin, L.rods.edges, value,
                    scale, label=("utilization (von Mises stress / strength)" if stresses.utilization is not None else
                                  "von Mises stress (MPa for a design in mm)"),
                    title=(("BUCKLED: " if result["buckled"] else "") + f"max displacement {result['max_displacement']:.3g} ({unit}), "
                           + ("drawn unscaled (round-off size)" if tiny else f"shown ×{scale:.3g}")
                           + (f"\nloads: {', '.join(others + (['point (arrows)'] if points else []))}; "
                              f"supports: triangles pinned, squares clamped")),
                    supports=unloaded.vertex_positions()[[s["vertex"] for s in result["supports"]]] + origin,
                    support_kinds=[s["kind"] for s in result["supports"]], loads=loads)
    if not mode:
        return
    # the lowest mode at the last stable state before the critical factor where one was found, else at the
    # state analysed
    found = crit is not None and crit.factor is not None and crit.last_stable is not None
    if found:
        at_state = copy.deepcopy(unloaded)
        from ..linkage.state import restore

        restore(at_state, crit.last_stable)
    else:
        at_state = L
    # at a limit point, the direction it snaps in: the path's tangent H⁻¹f, which the critical mode dominates
    # there; the lowest eigenvector can be another, soft mode (the boat's: μ 1.4e-8 beside the fold's 5.3e-8,
    # cosine 0.02 with the tangent)
    snap = found and crit.kind == "limit point"
    mode = _buckling_mode(at_state, held, f if snap else None)
    if mode is not None:
        md = mode.reshape(-1, 3)
        md = md / max(float(np.linalg.norm(md, axis=1).max()), 1e-300)  # largest amplitude 1
        s2 = 0.1 * span
        at = crit.bracket[0] if found else result["load_factor_reached"]
        title = (f"snap-through mode (the path's tangent) at load factor {crit.factor:.4g}" if snap else
                 f"buckling mode at load factor {crit.factor:.4g}" if found else
                 f"lowest mode at load factor {at:.4g} (no instability up to "
                 f"{(result['critical_searched_to'] or at) / result['load_factor']:.3g}× the load applied)")
        # the mode at amplitude 1, drawn × s2 (render_analysis scales the difference: passing it scaled already
        # drew it at s2², 10 times the span's tenth the title stated for the manta ray)
        render_analysis(os.path.join(out_dir, "buckling_mode.png"), at_state.rods.points + origin,
                        at_state.rods.points + origin + md, L.rods.edges, np.linalg.norm(md, axis=1), s2,
                        label="relative amplitude", title=title + f"\nlargest amplitude shown {s2:.3g} ({unit})")


#: The reactions' balance promised (relative to the load): below it, a warning says why it is not met.
BALANCE = 1e-8


#: A support is said to pull when it pulls with more than this fraction of the applied load's magnitude
#: (:func:`_load_magnitude`): a few per cent, far above the equilibrium's round-off (1e-6 N on a 1 mN load), and a
#: pull that a designer would not neglect (0.65 % of the legged pavilion's weight was flagged).
PULL = 0.02


def _load_magnitude(linkage, loads, gravity) -> float:
    """The magnitude of ``loads`` (at factor 1): the norm of their resultant, or of the largest of them where they
    cancel more than that (a squeeze: two opposite point loads, resultant 0)."""
    from .static import load_vector

    each = [float(np.linalg.norm(load_vector(linkage, [ld], gravity)[1])) for ld in loads]
    return max([float(np.linalg.norm(load_vector(linkage, loads, gravity)[1]))] + each)


def _outside_footprint(Q, c, tol) -> bool:
    """Whether the point ``c`` (2,) lies farther than ``tol`` outside the convex hull of the points ``Q`` (n, 2):
    a polygon, or for one or two supports (or supports in a line) a point or a segment."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(Q)
        return bool(np.max(hull.equations[:, :2] @ c + hull.equations[:, 2]) > tol)  # outward unit normals
    except (QhullError, ValueError):  # fewer than three points, or all in a line: a point or a segment
        pass
    a = Q.mean(axis=0)
    d = Q - a
    if float(np.abs(d).max()) <= tol:
        nearest = a
    else:
        u = np.linalg.svd(d)[2][0]  # the segment's direction
        s = d @ u
        nearest = a + np.clip(float((c - a) @ u), s.min(), s.max()) * u
    return bool(np.linalg.norm(c - nearest) > tol)


def _support_warnings(unloaded, supports, reac, resultant, magnitude) -> list:
    """Set-ups that mislead, one line each: supports bunched at one end, the weight outside their footprint, and
    supports that pull (a support that can only push would let the shell lift off it).

    ``resultant`` (3,) and ``magnitude`` are those of the load applied (:func:`_load_magnitude`). Gravity is
    along −z of the deployed state as computed, which need not stand level (the boat's mirror plane leans 10°
    from vertical): ``lowest:N`` may then pick one end only.
    """
    out = []
    P = unloaded.rods.points
    Q = unloaded.vertex_positions()[[s.vertex for s in supports]]
    span = float(np.ptp(P[:, :2], axis=0).max())
    spread = float(np.ptp(Q[:, :2], axis=0).max())
    if spread < span / 3.0:
        who = "the support lies" if len(supports) == 1 else f"the {len(supports)} supports lie"
        out.append(f"{who} within {spread:.3g} of the shell's horizontal extent of {span:.3g}: "
                   f"it stands on one end (gravity is -z of the deployed state, which may stand tilted)")
    elif _outside_footprint(Q[:, :2], P[:, :2].mean(axis=0), 1e-3 * span):
        # with two supports the footprint is their segment: a shell held at one side only (the Delaunay test
        # raised for fewer than three points and said nothing)
        out.append("the shell's centre lies outside its supports' footprint (seen from above): it cantilevers "
                   "from them (gravity is -z of the deployed state, which may stand tilted)")
    down = np.asarray(resultant, float)
    balanced = float(np.linalg.norm(down)) <= 1e-3 * magnitude  # self-balanced: no direction "against the load"
    up = np.array([0.0, 0.0, 1.0]) if balanced else -down / np.linalg.norm(down)
    pulling = [(r["vertex"], float(np.dot(r["force"], up))) for r in reac]
    pulling = [(v, p) for v, p in pulling if p < -PULL * magnitude]
    if pulling and magnitude > 0:
        listed = ", ".join(f"{v} ({p:.3g})" for v, p in pulling)
        how = "down (-z; the loads cancel)" if balanced else "against the load"
        out.append(f"the support(s) at vertex {listed} pull the shell {how}, more than {PULL:.0%} of the load "
                   f"({magnitude:.3g}): it would lift off a support that can only push")
    return out


def _warnings(result, L, held, total_force) -> list:
    """One line each: what in the set-up or the result a designer should not miss."""
    out = []
    err = result["equilibrium_error"]
    if err is not None and err > BALANCE:
        # the Newton solve stops at the stiffness forces' round-off, whatever the tolerance asked of it: a load of
        # the order of that round-off cannot be balanced to 1e-8 of itself (0.01 N on the boat: 4e-7)
        free = np.setdiff1d(np.arange(L.num_vars), held)
        residual = float(np.linalg.norm((L.gradient() - total_force)[free]))
        out.append(f"the reactions balance the load to {err:.1e} of it only: the equilibrium's residual force "
                   f"({residual:.1e}, the stiffness forces' round-off) is not small against a load this small "
                   f"({np.linalg.norm(result['total_load']):.3g})")
    return out


def _loaded_state(L, unloaded, f, held, base, opts, load_factor, crit):
    """Put ``L`` in the equilibrium at ``load_factor`` found along the path ``crit``; (LoadedState, buckled).

    Where the path reached the requested load, its state there, polished for the reactions' balance. Where
    stability ended before it, the state Newton finds from the last stable one (where the shell snaps or
    buckles to, or none: the result then stops at the last stable factor). An interrupted or unfinished path
    leaves the last stable state.
    """
    from ..linkage.state import restore
    from .static import solve_loaded

    if crit.target_state is not None:
        restore(L, crit.target_state)
        st = solve_loaded(L, f, held, load_factor, replace(opts, load_steps=1), base_force=base,
                          start_factor=load_factor)
        buckled = False
    elif crit.factor is not None and not crit.interrupted:
        restore(L, crit.last_stable)
        st = solve_loaded(L, f, held, load_factor, opts, base_force=base, start_factor=crit.bracket[0])
        buckled = True
        what = "it snaps through" if crit.kind == "limit point" else "it buckles"
        if st.converged:
            st.message = (f"the load passes the critical load factor {crit.factor:.4g} ({crit.kind}: {what}); the state "
                          f"shown is the one it goes to")
        else:  # Newton from the last stable state did not converge: it is left there (or where Newton stopped)
            restore(L, crit.last_stable)
            st.load_factor = crit.bracket[0]
            st.message = (f"the load passes the critical load factor {crit.factor:.4g} ({crit.kind}: {what}); the state "
                          f"past it was not found ({st.message}); shown: the last equilibrium before it, at load "
                          f"factor {st.load_factor:.4g}")
    else:
        restore(L, crit.last_stable)
        lo = crit.bracket[0]
        st = solve_loaded(L, f, held, lo, replace(opts, load_steps=1), base_force=base, start_factor=lo)
        st.converged = False
        st.message = f"the path from zero load stopped at load factor {lo:.4g} after {len(crit.samples) - 1} steps"
        buckled = False
    st.displacement = L.vertex_positions() - unloaded.vertex_positions()  # from the unloaded state, not the path's last
    return st, buckled


def _buckling_mode(state, held, f=None):
    """The rod points' displacement (3V,) of the lowest mode of the Hessian of ``state`` (a linkage), or with
    ``f`` of the path's tangent H⁻¹f (None where it cannot be computed)."""
    import scipy.sparse.linalg as spla

    work = state
    free = np.setdiff1d(np.arange(work.num_vars), held)
    H = work.hessian()[free][:, free].tocsc()
    M = work.mass_matrix()[free][:, free].tocsc()
    if f is not None:
        x = np.zeros(work.num_vars)
        with np.errstate(all="ignore"):
            x[free] = spla.spsolve(H, np.asarray(f, float)[free])
        return (work.rod_jacobian() @ x)[: 3 * work.rods.num_vertices] if np.all(np.isfinite(x)) else None
    try:
        shift = 1e-8 * abs(spla.eigsh(H, k=1, M=M, which="LM", return_eigenvectors=False)[0])
        _, vec = spla.eigsh(H, k=1, M=M, sigma=-shift, which="LM")
    except Exception:
        return None
    x = np.zeros(work.num_vars)
    x[free] = vec[:, 0]
    J = work.rod_jacobian()
    return (J @ x)[: 3 * work.rods.num_vertices]
