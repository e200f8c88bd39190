"""The sparsification job: dense deployment, then sparse torques, written to a folder.

``run_selection`` is what ``xshells sparsify`` runs by default (the fewest
actuators within a deviation limit, or the best N, by elimination; it also
writes the trade-off curve); ``run_sparsify`` solves eq. 8 for a given
``η`` (``--eta``); ``run_sweep`` runs eq. 8 over ``η`` for several ``p``.
"""
from __future__ import annotations

import csv
import io
import os
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..deploy.case import case_guide, load_case, material_from_spec, target_angle
from ..deploy.simulate import DeployOptions, deploy, rest_length_solve, rest_length_warning
from ..errors import STOP, InputError
from ..io.design import read_design, read_rest_lengths
from ..io.export import atomic_write_text, finite_json
from ..linkage.linkage import Linkage
from ..linkage.state import restore, snapshot
from ..solve import NewtonOptions, minimize
from .selection import RESTRICTED, UNHOLDABLE, SelectionOptions, select_actuators
from .sparsify import SparsifyOptions, sparsify


@dataclass
class DenseDeployment:
    """The densely actuated deployment that sparsification starts from."""

    linkage: Linkage
    state: dict
    tau_ref: float
    flat_energy: float
    dense_energy: float
    time_s: float
    name: str
    warnings: list = field(default_factory=list)
    target_angle_deg: float = float("nan")  # the average angle deployed to


def dense_deployment(case_path, *, angle_deg=None, progress=False) -> DenseDeployment:
    """Assembly state and dense deployment of a case (rest lengths from the case, else the rest-length solve)."""
    t0 = time.perf_counter()
    case = load_case(case_path)
    design = read_design(case.design_path)
    p = read_rest_lengths(case.rest_lengths_path, design.num_segments, design) if case.rest_lengths_path else None
    L = Linkage(design, material_from_spec(case.material), subdivision=case.subdivision, rest_lengths=p)
    warnings = L.input_warnings()
    why = "".join(f"; {w}" for w in warnings)  # a failure below is most likely explained by these
    if design.note:  # how a .3dm was read (its layer, units and the conversion to mm): printed with the warnings
        warnings = [design.note] + list(warnings)
    if p is None:  # a solve that did not converge is said, not thrown away
        warnings = list(warnings) + rest_length_warning(rest_length_solve(L), L)
    else:
        minimize(L, fixed=L.rigid_pin_indices(), options=NewtonOptions(gradient_tolerance=1e-9, max_iterations=100))
    flat_energy = L.energy()
    target = target_angle(case, L, angle_deg)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=case.steps, desc=f"dense deployment of {case.name}", unit="step")
    try:
        res = deploy(L, target, DeployOptions(steps=case.steps, direction=case.direction, guide=case_guide(case, L.num_joints)),
                     callback=(lambda rec: bar.update(1) and False) if bar else None)
    finally:
        if bar is not None:
            bar.close()
    if not res.converged:
        raise InputError(f"{case_path}: the dense deployment did not reach its target ({res.message}){why}")
    if not res.torque > 0:
        raise InputError(f"{case_path}: the dense deployment needs a closing torque ({res.torque:.4g}); sparse actuation assumes opening torques")
    return DenseDeployment(L, snapshot(L), float(res.torque), float(flat_energy), float(L.energy()),
                           time.perf_counter() - t0, case.name, warnings, float(np.degrees(target)))


def _allowed_from_vertices(L: Linkage, candidates) -> np.ndarray | None:
    if candidates is None:
        return None
    vertex_to_joint = {int(v): j for j, v in enumerate(L.graph.joint_vertex)}
    allowed = np.zeros(L.num_joints, bool)
    nv = len(L.design.vertices)
    for v in candidates:
        v = int(v)
        if not 0 <= v < nv:
            raise InputError(f"candidate joint {v} is out of range: the design has vertices 0..{nv - 1}")
        if v not in vertex_to_joint:
            raise InputError(f"candidate {v} is a free end, not a joint")
        allowed[vertex_to_joint[v]] = True
    return allowed


UNITS = ("torques and work in the energy's units (N·mm for designs in mm and MPa); fit distances relative to the "
         "bounding-box diagonal of the dense deployment")


def _result_dict(dense: DenseDeployment, res, method: dict) -> dict:
    """``result.json`` of either method: the fields they share, ``method``'s own, and a suggestion."""
    L = dense.linkage
    jv = np.asarray(L.graph.joint_vertex)
    out = {
        "name": dense.name,
        "target_angle_deg": dense.target_angle_deg,
        **method,
        "actuated_joints": [int(jv[j]) for j in res.actuated],
        "torques": [float(res.torques[j]) for j in res.actuated],
        "num_actuators": int(len(res.actuated)),
        "num_joints": int(L.num_joints),
        "fit_mean": res.fit_mean,
        "fit_max": res.fit_max,
        # not part of the fit (the joints'): how far the free ends moved from the dense deployment
        "num_free_ends": int(len(L.graph.free_end_vertex)),
        "free_end_fit_mean": res.free_end_fit_mean if len(L.graph.free_end_vertex) else None,
        "free_end_fit_max": res.free_end_fit_max if len(L.graph.free_end_vertex) else None,
        "work": res.work,
        "dense_torque": dense.tau_ref,
        "dense_work": dense.dense_energy - dense.flat_energy,
        "status": "interrupted" if "interrupted" in res.message else "complete",
        "converged": res.converged,
        "message": res.message,
        "warnings": dense.warnings,
        "input": L.graph.design.note,  # how a .3dm was read (its layer, units and the conversion to mm), else None
        "time_s": res.time_s,
        "dense_deployment_time_s": dense.time_s,
        "joint_vertices": jv.tolist(),
        "all_torques": res.torques.tolist(),
        "units": UNITS,
    }
    out["suggestion"] = suggestion(out)
    return out


def _count(k: int, what: str = "actuator") -> str:
    return f"{k} {what}{'' if k == 1 else 's'}"


OUTPUTS = ("result.json", "torques.txt", "actuators.png", "actuated.3dm", "sweep.csv", "sweep.png")
"""Every file ``xshells sparsify`` writes into its folder (besides ``case.json`` for a bare design)."""


def remove_stale_outputs(out_dir) -> list[str]:
    """Removes what an earlier ``xshells sparsify`` left in ``out_dir``; returns the names removed.

    A run writes only some of :data:`OUTPUTS` (an ``--eta`` run no sweep
    files), and one that fails writes none: an earlier run's files would sit
    beside, or in place of, this run's.
    """
    removed = []
    for name in OUTPUTS:
        path = os.path.join(out_dir, name)
        if os.path.isfile(path) and _ours(path):
            os.remove(path)
            removed.append(name)
    if removed:
        import sys

        print(f"removed an earlier run's {', '.join(removed)} from {out_dir}/", file=sys.stderr)
    return removed


def _ours(path) -> bool:
    """Whether ``path`` is a file of ``xshells sparsify`` (another command's result.json is left alone)."""
    name = os.path.basename(path)
    if name not in ("result.json", "sweep.csv"):
        return True  # names only this command writes
    try:
        with open(path, encoding="utf-8") as f:
            head = f.read(200_000 if name == "result.json" else 200)
    except (OSError, UnicodeDecodeError):
        return False
    if name == "sweep.csv":
        return head.startswith(("num_actuators,", "p,eta,"))
    return '"actuated_joints"' in head and '"dense_torque"' in head


def _write_outputs(out_dir, dense: DenseDeployment, res, result: dict, title: str) -> None:
    """``result.json``, ``torques.txt``, ``actuators.png`` (over the dense deployment's joints) and ``actuated.3dm``."""
    L = dense.linkage
    restore(L, res.state)  # the answer's equilibrium (the solvers hand the linkage back at the dense state)
    atomic_write_text(os.path.join(out_dir, "result.json"), finite_json(result, indent=1))
    atomic_write_text(os.path.join(out_dir, "torques.txt"), "".join(f"{v:.10g}\n" for v in res.torques))
    from ..viz.render import render_actuators

    restore_after = snapshot(L)
    restore(L, dense.state)
    dense_joints = L.joint_positions()
    restore(L, restore_after)
    render_actuators(os.path.join(out_dir, "actuators.png"), L, res.actuated, res.torques, reference=dense_joints, title=title,
                     labels=np.asarray(L.graph.joint_vertex)[np.asarray(res.actuated, int)])
    from ..rhino.write import write_3dm

    act = np.asarray(res.actuated, int)  # the sparsely actuated state, its actuators and their torques (mm)
    write_3dm(os.path.join(out_dir, "actuated.3dm"), deployed=L,
              actuators=(L.joint_positions()[act], np.asarray(res.torques, float)[act], L.graph.joint_vertex[act]))


def _start(case_path, out_dir, dense, angle_deg, progress, candidates):
    """The output folder (an earlier run's outputs removed), the dense deployment (given or computed) at its state,
    and the allowed joints."""
    os.makedirs(out_dir, exist_ok=True)
    remove_stale_outputs(out_dir)
    dense = dense or dense_deployment(case_path, angle_deg=angle_deg, progress=progress)
    allowed = _allowed_from_vertices(dense.linkage, candidates)
    restore(dense.linkage, dense.state)
    return dense, allowed


ETA_ACCEPT_FIT = 0.01
"""With ``--eta``, an answer whose mean joint deviation is above this (unless ``--max-fit`` says otherwise)
is reported as not converged: eq. 8 has no limit on the fit, and a large ``η`` or a small ``--tau-max``
gives an optimum far from the shape (0 actuators at 12 %)."""


def _far_from_target(res, accept: float) -> str:
    """'' or why an eq. 8 answer is not one (its fit above ``accept``)."""
    if res.fit_mean <= accept:
        return ""
    return (f"the answer's mean joint deviation {100 * res.fit_mean:.2f}% (max {100 * res.fit_max:.2f}%) is above "
            f"{100 * accept:g}% of the span{' with no actuator at all' if not len(res.actuated) else ''}")


def run_sparsify(case_path, out_dir, options: SparsifyOptions = SparsifyOptions(), *, candidates=None,
                 angle_deg=None, progress=True, dense: DenseDeployment | None = None,
                 accept_fit: float = ETA_ACCEPT_FIT) -> dict:
    """Sparse actuation of a case; writes ``result.json``, ``torques.txt`` and ``actuators.png`` into ``out_dir``.

    Returns the ``result.json`` content. Ctrl-C during the optimization keeps
    and writes the last accepted iterate. An answer whose mean deviation is
    above ``accept_fit`` counts as not converged (its message says why).
    """
    dense, allowed = _start(case_path, out_dir, dense, angle_deg, progress, candidates)
    L = dense.linkage
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(desc="sparsifying", unit="it", total=options.max_iterations)

    def on_iter(rec):
        if bar is not None:
            bar.set_postfix(actuators=rec.num_actuators, f=f"{rec.objective:.4g}")
            bar.update(1)
        return False

    try:
        res = sparsify(L, dense.tau_ref, options, allowed=allowed, flat_energy=dense.flat_energy, callback=on_iter)
    finally:
        if bar is not None:
            bar.close()
    far = _far_from_target(res, accept_fit)
    if far and "interrupted" not in res.message:
        res.message = (f"{res.message}, but {far}" if res.converged else f"{res.message}; {far}")
        res.converged = False
    result = _result_dict(dense, res, {"method": "eta", "eta": options.eta, "p": options.p, "tau_max": options.tau_max,
                                       "max_fit": accept_fit, "objective": res.objective, "iterations": res.iterations})
    _write_outputs(out_dir, dense, res, result,
                   f"{dense.name}: {_count(len(res.actuated))} (η = {options.eta:g}, p = {options.p:g}; "
                   f"mean {100 * res.fit_mean:.2f}%{'' if res.converged else ', NOT CONVERGED'})")
    return result


DEFAULT_ETAS = tuple(float(v) for v in np.geomspace(1e-5, 1e-2, 8))
DEFAULT_PS = (1.0, 0.5, 0.25)


class SweepInterrupted(KeyboardInterrupt):
    """Ctrl-C during ``run_sweep``: ``rows`` holds the runs that finished (written to ``sweep.csv``/``sweep.png``);
    the run that was cut short is not among them."""

    def __init__(self, rows, total):
        super().__init__(f"interrupted: {len(rows)} of {total} runs finished")
        self.rows, self.total = rows, total


def run_sweep(case_path, out_dir, *, etas=DEFAULT_ETAS, ps=DEFAULT_PS, base: SparsifyOptions = SparsifyOptions(),
              candidates=None, angle_deg=None, progress=True) -> list[dict]:
    """Sparsify for every ``(p, η)``; writes ``sweep.csv`` and ``sweep.png`` (Fig. 9) into ``out_dir``.

    Every run starts from the dense deployment, so each point is what a
    single ``xshells sparsify`` gives (warm starts from a neighbouring ``η``
    were measured to land in worse local minima). ``candidates``: the input
    vertices that may carry an actuator (default all). Rows are written as
    they finish, each with ``converged`` and ``message``. Ctrl-C stops the
    sweep: the finished rows stay written, the run it cut short is dropped,
    and :class:`SweepInterrupted` (a KeyboardInterrupt) carries the rows.
    """
    for eta in etas:
        replace(base, eta=eta)  # validates
    for p in ps:
        replace(base, p=p)
    os.makedirs(out_dir, exist_ok=True)
    remove_stale_outputs(out_dir)
    dense = dense_deployment(case_path, angle_deg=angle_deg, progress=progress)
    L = dense.linkage
    allowed = _allowed_from_vertices(L, candidates)
    rows: list[dict] = []
    total = len(etas) * len(ps)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc="sweep", unit="run")
    try:
        for p in ps:
            for eta in sorted(etas):
                restore(L, dense.state)
                opts = replace(base, eta=eta, p=p)
                try:
                    res = sparsify(L, dense.tau_ref, opts, allowed=allowed, flat_energy=dense.flat_energy)
                except KeyboardInterrupt:
                    raise SweepInterrupted(rows, total) from None
                if "interrupted" in res.message or STOP.requested:  # sparsify keeps its last iterate: not a finished run
                    raise SweepInterrupted(rows, total)
                jv = np.asarray(L.graph.joint_vertex)
                rows.append({"p": p, "eta": eta, "num_actuators": len(res.actuated), "fit_mean": res.fit_mean,
                             "fit_max": res.fit_max, "work": res.work, "iterations": res.iterations, "time_s": res.time_s,
                             "converged": bool(res.converged), "message": res.message,
                             "actuated_joints": " ".join(str(int(jv[j])) for j in res.actuated)})
                _write_sweep(out_dir, rows, dense.name)
                if bar is not None:
                    bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    return rows


def _write_csv(path, rows) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0].keys()))
    w.writeheader()
    w.writerows(rows)
    atomic_write_text(path, buf.getvalue())


def _write_sweep(out_dir, rows, name) -> None:
    _write_csv(os.path.join(out_dir, "sweep.csv"), rows)
    from ..viz.render import plot_actuation_tradeoff

    plot_actuation_tradeoff(os.path.join(out_dir, "sweep.png"), rows, title=name)


def suggestion(result: dict) -> str:
    """What to try when a run did not end as asked ('' when it did)."""
    if result["converged"]:
        return ""
    msg = result["message"]
    if result.get("method") == "elimination":
        if RESTRICTED in msg:
            ways = [w for flag, w in (("--candidates", "allow more joints (--candidates)"),
                                      ("--tau-max", "allow larger torques (--tau-max)")) if flag in msg]
            return " or ".join(ways)
        if UNHOLDABLE in msg:
            return ("try another --angle: one where the dense deployment's torque still rises with the angle "
                    "(xshells deploy writes it into deployment.csv)")
        if "no answer met" in msg:
            return "try a larger --max-fit, or allow more joints (--candidates)"
        if "interrupted" in msg or "stopped" in msg:
            return "run again to finish; the answer above is the best one found before the stop"
        if result.get("actuators_requested"):
            return "try a larger --actuators, or --max-fit to let the count follow the deviation"
        return "check the warnings above; a larger --max-fit gives fewer actuators"
    if "interrupted" in msg or "stopped" in msg:
        return "run again to finish; the answer above is the last accepted iterate before the stop"
    if "is above" in msg and "of the span" in msg:
        return ("a smaller --eta (more actuators)" + (", a larger --tau-max" if result.get("tau_max") is not None else "")
                + ", or the default mode (no --eta: the fewest actuators within --max-fit)")
    if "trust region collapsed" in msg or "iteration limit" in msg or "step vanished" in msg:
        return ("try the default mode (no --eta: the fewest actuators within --max-fit), "
                "or a larger --max-iters, or another --eta")
    if "not valid" in msg:
        return "try the default mode (no --eta), or a smaller --eta"
    return "try the default mode (no --eta)"


def _curve_rows(L, curve) -> list[dict]:
    jv = np.asarray(L.graph.joint_vertex)
    return [{"num_actuators": c.num_actuators, "fit_mean": c.fit_mean, "fit_max": c.fit_max, "work": c.work,
             "time_s": round(c.time_s, 3), "actuated_joints": " ".join(str(int(jv[j])) for j in c.actuated),
             "torques": " ".join(f"{v:.6g}" for v in c.torques)} for c in curve]


def _write_curve(out_dir, rows, name, options: SelectionOptions, chosen, converged=True) -> None:
    _write_csv(os.path.join(out_dir, "sweep.csv"), rows)
    from ..viz.render import plot_actuation_curve

    plot_actuation_curve(os.path.join(out_dir, "sweep.png"), rows, max_fit=options.max_fit if options.actuators is None else None,
                         chosen=chosen, chosen_failed=not converged, title=f"{name}: actuators against deviation")


def run_selection(case_path, out_dir, options: SelectionOptions = SelectionOptions(), *, candidates=None,
                  angle_deg=None, progress=True, dense: DenseDeployment | None = None) -> dict:
    """The fewest actuators within ``options.max_fit`` (or the best ``options.actuators``) for a case.

    Writes ``result.json``, ``torques.txt``, ``actuators.png`` and the
    trade-off curve ``sweep.csv`` / ``sweep.png`` (one row per accepted cut)
    into ``out_dir``; returns the ``result.json`` content. Ctrl-C keeps and
    writes the best answer found so far.
    """
    dense, allowed = _start(case_path, out_dir, dense, angle_deg, progress, candidates)
    L = dense.linkage
    bar = None
    if progress:
        from tqdm import tqdm

        goal = options.actuators or 1
        bar = tqdm(desc="choosing actuators", unit="cut", total=max(L.num_joints - goal, 1))

    def on_cut(point):
        if bar is not None:
            bar.set_postfix(actuators=point.num_actuators, mean=f"{100 * point.fit_mean:.3f}%", refresh=False)
            bar.n = min(L.num_joints - point.num_actuators, bar.total)
            bar.refresh()
        return False

    try:
        res = select_actuators(L, dense.tau_ref, options, allowed=allowed, flat_energy=dense.flat_energy, callback=on_cut)
    finally:
        if bar is not None:
            bar.close()
    result = _result_dict(dense, res, {"method": "elimination", "max_fit": options.max_fit,
                                       "actuators_requested": options.actuators, "tau_max": options.tau_max,
                                       "rounds": res.rounds, "equilibrium_solves": res.equilibrium_solves})
    _write_curve(out_dir, _curve_rows(dense.linkage, res.curve), dense.name, options, len(res.actuated), res.converged)
    limit = f"mean ≤ {100 * options.max_fit:g}%" if options.actuators is None else f"best {options.actuators}"
    _write_outputs(out_dir, dense, res, result,
                   f"{dense.name}: {_count(len(res.actuated))} ({limit}; mean {100 * res.fit_mean:.2f}%"
                   f"{'' if res.converged else ', NOT CONVERGED'})")
    return result
