"""The design-optimization job behind ``xshells optimize``: optimize, then write every output."""
from __future__ import annotations

import copy
import json
import os
import time
from dataclasses import asdict

import numpy as np

from ..deploy.case import case_guide, load_case, material_from_spec, target_angle
from ..deploy.run import _write_outputs, bending_field
from ..deploy.simulate import DeployOptions, deploy, rest_length_solve, rest_length_warning
from ..errors import InputError
from ..io import read_design, read_rest_lengths
from ..io.export import atomic_write_text, finite_json
from ..linkage.linkage import Linkage
from .objective import DesignProblem, DesignWeights, ks_min
from .optimize import OptimizeOptions, optimize


def build_problem(case_path, *, weights: DesignWeights, angle_deg=None, target_surface=None, rest_lengths_path=None,
                  deploy_steps=None, progress=False, keep_copy=False):
    """The design problem of a case: flat state at the design's average angle, deployed state at the target.

    With ``keep_copy``, ``problem.fresh_copy()`` builds the same problem again
    from copies of its inputs (the flat linkage, the initial deployment and
    the fitting term) without repeating the deployment.
    """
    case = load_case(case_path)
    design = read_design(case.design_path)
    rl_path = rest_lengths_path or case.rest_lengths_path
    p = read_rest_lengths(rl_path, design.num_segments, design) if rl_path else None
    L = Linkage(design, material_from_spec(case.material), subdivision=case.subdivision, rest_lengths=p)
    warnings = L.input_warnings()
    why = "".join(f"; {w}" for w in warnings)  # a failure below is most likely explained by these
    if design.note:  # how a .3dm was read (its layer, units and the conversion to mm): printed with the warnings
        warnings = [design.note] + list(warnings)
    if p is None:  # a solve that did not converge is said, not thrown away
        warnings = list(warnings) + rest_length_warning(rest_length_solve(L), L)
    target = target_angle(case, L, angle_deg)
    if not (0 < target < np.pi):
        raise InputError(f"target angle {np.degrees(target):.4g}° is out of reach: it must lie strictly between 0° and 180°")
    # Deploy from the flat equilibrium at the design's own angle (the flat
    # state of the problem), not from the file's unrelaxed state.
    from .equilibrium import ConstrainedEquilibrium

    D = copy.deepcopy(L)
    drawn = D.average_angle()
    ConstrainedEquilibrium(D, drawn).solve()
    flat_angle, flat_note = None, ""
    folded = _flat_state_problem(D, weights.ks_sharpness)
    if folded:
        # The drawn assembly state folds a joint once the joints may move, or leaves no room for a
        # positive bound on its smooth minimum angle: open it just enough (paper §5: ᾱ₀ "just large
        # enough"), as the smallest valid, planar flat state.
        flat_angle, D = _open_just_enough(L, drawn, weights.ks_sharpness)
        if flat_angle is None:
            raise InputError(f"{case_path}: the flat equilibrium at the design's average angle {np.degrees(drawn):.2f}° "
                             f"is not valid ({folded}), nor is it within "
                             f"{np.degrees(OPEN_LIMIT):.0f}° above it; open that joint in the drawing{why}")
        flat_note = (f"flat state opened from the drawn {np.degrees(drawn):.2f}° to {np.degrees(flat_angle):.2f}°: at the "
                     f"drawn angle {folded}")
    start_angle = drawn if flat_angle is None else flat_angle
    if target <= start_angle:
        # an X-shell deploys by opening: below the flat state's angle the optimizer "deployed" it by closing,
        # into inverted joints (nonuniform linkage, --angle 5 against 10.84°: J 4.58 -> 4527, exit 0)
        raise InputError(f"{case_path}: the target angle {np.degrees(target):.2f}° is not above the flat state's average "
                         f"angle {np.degrees(start_angle):.2f}°: an X-shell deploys by opening; give a larger --angle{why}")
    steps = deploy_steps or case.steps
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps, desc=f"deploying {case.name}", unit="step")
    try:
        res = deploy(D, target, DeployOptions(steps=steps, direction=case.direction, guide=case_guide(case, D.num_joints)),
                     callback=(lambda rec: bar.update(1) and False) if bar else None)
    finally:
        if bar is not None:
            bar.close()
    if not res.converged:
        raise InputError(f"{case_path}: the initial design does not deploy to {np.degrees(target):.2f}° ({res.message}){why}")
    from ..deploy.simulate import folded_joint

    folded = folded_joint(D)
    if folded:  # e.g. a target angle below the flat one: nothing to optimize from
        raise InputError(f"{case_path}: the initial design does not deploy to {np.degrees(target):.2f}°: {folded}{why}")
    from .fitting import FittingTerm, read_surface_noted

    surface = None
    if target_surface:
        V, F, _, note = read_surface_noted(target_surface)
        surface = (V, F)
        if note:  # a .3dm target: its layer and units, converted to mm, said as the design's are
            warnings = list(warnings) + [f"target surface {note}"]
    fitting = FittingTerm.paper_defaults(D, surface=surface)
    if surface is not None:
        far = _far_from_target(D, surface, target_surface)
        if far:
            warnings = list(warnings) + [far]
    spare = copy.deepcopy((L, D, fitting)) if keep_copy else None

    def make(L, D, fitting):
        problem = DesignProblem(L, target, weights, fitting=fitting, deployed=D, flat_angle=flat_angle)
        problem.flat_note = flat_note
        problem.input_warnings = warnings
        return problem

    problem = make(L, D, fitting)
    if spare is not None:
        problem.fresh_copy = lambda: make(*copy.deepcopy(spare))
    return problem, case.name


FAR_FROM_TARGET = 0.1
"""A target surface whose mean distance from the initial deployed joints exceeds this share of the span is
warned about (it is most likely in other units or another place than the design)."""


def _far_from_target(D, surface, path) -> str:
    """'' or a warning that the deployed joints of ``D`` lie far from the target ``surface`` (V, F)."""
    from .fitting import point_mesh_squared_distance

    P = D.joint_positions()
    mean = float(np.sqrt(point_mesh_squared_distance(P, *surface)[0]).mean())
    span = float(np.ptp(D.rods.points, axis=0).max())
    if mean > FAR_FROM_TARGET * span:
        return (f"target surface {path}: the initially deployed joints lie {mean:.4g} from it on average, "
                f"{mean / span:.3g} of the design's span {span:.4g} (is it in the design's units and place?)")
    return ""


OPEN_STEP = np.radians(0.25)
OPEN_LIMIT = np.radians(10.0)
# The smallest flat KS minimum angle to start from. KS lies below the true minimum by up to s·log n
# (3.7° for s = 0.01 and 600 joints), so only a positive bound ε on it keeps every joint open; a start
# with KS ≤ 0 leaves no positive ε feasible (the manta ray opened just enough to fold no joint had
# KS = −0.10°: with ε = KS − 0.5° its optimization folded joint 49 to −0.5°).
MIN_START_KS = np.radians(0.25)


def _flat_state_problem(E, ks_sharpness: float) -> str:
    """Why the flat equilibrium ``E`` cannot start a design optimization ("" if it can)."""
    from ..deploy.simulate import INVERTS, folded_joint

    folded = folded_joint(E).replace(f"{INVERTS}: ", "")
    if folded:
        return folded
    ks = ks_min(E.joint_angles(), ks_sharpness)[0]
    if ks < MIN_START_KS:
        return (f"its smooth minimum joint angle (KS, s = {ks_sharpness:g}) is {np.degrees(ks):.2f}°, below "
                f"{np.degrees(MIN_START_KS):.2f}°: no positive bound on it is feasible")
    return ""


def _open_just_enough(L, drawn: float, ks_sharpness: float):
    """The smallest average angle above ``drawn`` (in steps of OPEN_STEP, up to OPEN_LIMIT) whose flat
    equilibrium folds no joint, keeps its KS minimum angle at MIN_START_KS or more and stays planar, with
    that equilibrium (a copy of ``L``); (None, None) if none."""
    from .equilibrium import ConstrainedEquilibrium

    span = float(np.ptp(L.rods.points, axis=0).max())
    for k in range(1, int(round(OPEN_LIMIT / OPEN_STEP)) + 1):
        E = copy.deepcopy(L)
        try:
            ConstrainedEquilibrium(E, drawn + k * OPEN_STEP).solve()
        except ArithmeticError:
            continue
        planar = np.abs(E.height_selector() @ E.get_vars()).max() <= 1e-6 * span
        if planar and not _flat_state_problem(E, ks_sharpness):
            return drawn + k * OPEN_STEP, E
    return None, None


def _summary(problem, q) -> dict:
    """J, its weighted terms (they sum to J: γ·E₂/E₀, (1−γ)·E₃/E₀, β/2·T/l₀², and the planar-buckling
    penalty where it is on), the raw ratios E₂/E₀, E₃/E₀ and T/l₀², the energies and the constraints at ``q``."""
    t = problem.terms(q)
    flat, dep = problem.flat.L, problem.deployed.L
    w = problem.w
    terms = {"J_flat_energy_term": w.gamma * t["flat_energy"], "J_deployed_energy_term": (1 - w.gamma) * t["deployed_energy"],
             "J_fit_term": 0.5 * w.beta * t["fit"]}
    if "planar_buckling" in t:
        terms["J_planar_buckling_term"] = t["planar_buckling"]
    return {"J": t["J"], "terms": terms,
            "ratios": {"flat_energy_over_E0": t["flat_energy"], "deployed_energy_over_E0": t["deployed_energy"],
                       "fit_over_l0_squared": t["fit"]},
            "energy_flat": flat.energy(), "energy_deployed": dep.energy(),
            "planarity": problem.planarity(q), "min_angle_deg": float(np.degrees(problem.min_angle(q)))}


STATE_TOLERANCE = 1e-6
"""Above this distance (of the span) between the optimizer's states and a fresh deployment of the written
case, ``result.json`` warns (its figures are always the fresh deployment's)."""


def _write_case(case_path, out_dir, target: float, name: str, guide=None) -> str:
    """``OUT/case.json``: the input case with the optimized rest lengths (``design_parameters.txt``) and the
    run's target angle, its paths relative to ``out_dir``; returns its path. Where the input case names a guide
    (:mod:`xshells.deploy.guide`), the optimized deployed joints ``guide`` (nj, 3) are the written case's
    (``deploy_guide.txt``): the optimization followed that equilibrium, not the one the old guide described."""
    from ..io.strict_json import loads

    with open(case_path) as fh:
        spec = loads(fh.read(), str(case_path))
    base, out = os.path.dirname(os.path.abspath(case_path)), os.path.abspath(out_dir)

    def moved(path):
        path = path if os.path.isabs(path) else os.path.join(base, path)
        try:
            return os.path.relpath(path, out)
        except ValueError:  # another drive
            return path

    for key in ("file", "flat_file"):
        if spec.get(key):
            spec[key] = moved(spec[key])
    if isinstance(spec.get("material"), dict) and spec["material"].get("contour_file"):
        spec["material"]["contour_file"] = moved(spec["material"]["contour_file"])
    for key in ("angle_rad", "open_by_deg"):
        spec.pop(key, None)
    spec.update(name=name, angle_deg=float(np.degrees(target)), rest_lengths="design_parameters.txt")
    if spec.get("guide"):
        from ..deploy.guide import guide_text

        atomic_write_text(os.path.join(out_dir, "deploy_guide.txt"), guide_text(guide))
        spec["guide"] = "deploy_guide.txt"
    path = os.path.join(out_dir, "case.json")
    atomic_write_text(path, json.dumps(spec, indent=1) + "\n")
    return path


def _aligned(A, B):
    """``B`` (n, 3) moved rigidly onto ``A`` (least squares, no reflection)."""
    from ..deploy.guide import rigid_fit

    return rigid_fit(B, A)


def _deploy_written_case(case_json, out_dir, problem, optimizer_final):
    """Deploy ``case_json`` from flat as ``xshells deploy`` does (into ``OUT/deploy``); returns the summary of
    that deployment in the optimizer's objective, its flat and deployed linkages, and each state's distance
    from the optimizer's (max over rod points after a rigid alignment, relative to the span)."""
    from ..deploy.run import run_deployment

    case = load_case(case_json)
    states = {}
    deployed = run_deployment(case.design_path, material_from_spec(case.material), out_dir=os.path.join(out_dir, "deploy"),
                   subdivision=case.subdivision, target_angle=case.angle_rad, steps=case.steps,
                   rest_lengths_path=case.rest_lengths_path, direction=case.direction, progress=False, name=case.name,
                   states=states, guide_path=case.guide_path)
    distances = {}
    for state, eq in (("flat", problem.flat), ("deployed", problem.deployed)):
        A, B = eq.L.rods.points, states[state].rods.points
        span = float(np.ptp(A, axis=0).max())
        distances[state] = float(np.linalg.norm(_aligned(A, B) - A, axis=1).max() / span) if A.shape == B.shape else float("inf")
    w, flat, dep = problem.w, states["flat"], states["deployed"]
    P = problem.deployed.L.joint_positions()
    e2, e3 = flat.energy() / problem.E0, dep.energy() / problem.E0
    t = problem.fitting.value(_aligned(P, dep.joint_positions())) / problem.l0**2  # in the target's frame
    terms = {"J_flat_energy_term": w.gamma * e2, "J_deployed_energy_term": (1 - w.gamma) * e3, "J_fit_term": 0.5 * w.beta * t}
    extra = {k: v for k, v in optimizer_final["terms"].items() if k not in terms}  # the planar-buckling penalty, as optimized
    terms.update(extra)
    summary = {"J": float(sum(terms.values())), "terms": terms,
               "ratios": {"flat_energy_over_E0": e2, "deployed_energy_over_E0": e3, "fit_over_l0_squared": t},
               "energy_flat": flat.energy(), "energy_deployed": dep.energy()}
    summary["reached"], summary["message"] = bool(deployed["reached"]), deployed["message"]
    return summary, states, distances


def run_optimize(case_path, out_dir, *, weights: DesignWeights = DesignWeights(), options: OptimizeOptions = OptimizeOptions(),
                 angle_deg=None, target_surface=None, resume=False, baseline=True, progress=True) -> dict:
    """Optimize a case's rest lengths and write ``result.json``, ``design_parameters.txt``, meshes and figures.

    ``resume=True`` starts from ``out_dir/design_parameters.txt`` of an earlier
    run (a different ``angle_deg`` may be given). Ctrl-C keeps and writes the
    best design found so far.
    """
    os.makedirs(out_dir, exist_ok=True)
    t0 = time.perf_counter()
    rl = None
    if resume:
        rl = os.path.join(out_dir, "design_parameters.txt")
        if not os.path.exists(rl):
            raise InputError(f"--resume: {rl} does not exist (no earlier run in {out_dir})")
    with_baseline = baseline and options.method != "bfgs"
    problem, name = build_problem(case_path, weights=weights, angle_deg=angle_deg, target_surface=target_surface,
                                  rest_lengths_path=rl, progress=progress, keep_copy=with_baseline)
    q0 = np.ones(len(problem.p0))
    initial = _summary(problem, q0)
    # before and after share one colour scale per state (Fig. 6): the larger of the two maxima
    scale = {"flat": float(bending_field(problem.flat.L).max()), "deployed": float(bending_field(problem.deployed.L).max())}
    before = {"flat": copy.deepcopy(problem.flat.L), "deployed": copy.deepcopy(problem.deployed.L)}
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=options.max_iterations, desc=f"optimizing ({options.method})", unit="it")

    def on_iter(rec):
        if bar is not None:
            bar.set_postfix(J=f"{rec.J:.5g}", E3=f"{rec.deployed_energy:.4g}")
            if rec.iteration:
                bar.update(1)
        return False

    interrupted = False
    try:
        res = optimize(problem, options, callback=on_iter)
    finally:
        if bar is not None:
            bar.close()
    interrupted = res.interrupted
    optimizer_final = _summary(problem, res.q)
    p = res.rest_lengths
    atomic_write_text(os.path.join(out_dir, "design_parameters.txt"), "".join(f"{v:.17g}\n" for v in p))
    written_case = _write_case(case_path, out_dir, problem.deployed.angle, name, problem.deployed.L.joint_positions())
    # what is reported is what `xshells deploy OUT/case.json` reaches: the written case, deployed afresh
    final, fresh, distances = _deploy_written_case(written_case, out_dir, problem, optimizer_final)
    warnings = list(problem.input_warnings)
    if not final["reached"]:
        warnings.append(f"xshells deploy {written_case} does not reach the target: {final['message']}")
    for state, d in distances.items():  # the flat state: deploy's free one, not the optimizer's at ᾱ₀ (informative only)
        if state == "deployed" and d > STATE_TOLERANCE:
            warnings.append(f"the {state} state of a fresh deployment of the written case lies {d:.3g} of the span from "
                            f"the optimizer's (above {STATE_TOLERANCE:g}): the figures reported are the fresh deployment's")
    from ..io.fabrication import write_drawings

    write_drawings(out_dir, "flat_layout", problem.flat.L.graph.design, p)  # what to build: the optimized rest lengths
    from ..fabrication.run import flat_state_xy, write_outputs_of

    # drawn from the flat state the optimized rest lengths relax to: they are not the drawn layout's (up to 30 % off)
    flat_xy = flat_state_xy(fresh["flat"]) if fresh["flat"].graph.is_planar else None
    write_outputs_of(out_dir, fresh["flat"], fresh["flat"].joint_angles(), fresh["deployed"].joint_angles(), p, xy=flat_xy,
                     warnings=warnings)
    for state, L in (("flat", fresh["flat"]), ("deployed", fresh["deployed"])):
        vmax = max(scale[state], float(bending_field(L).max()))
        _write_outputs(out_dir, f"{state}_before", before[state], vmax=vmax)
        _write_outputs(out_dir, state, L, vmax=vmax)
    from ..fabrication.run import plan_of
    from ..rhino.write import write_3dm

    flat_L = fresh["flat"]  # the optimized design as one Rhino file: flat layout, deployed state, strips (mm)
    write_3dm(os.path.join(out_dir, "deployed.3dm"), flat_design=flat_L.graph.design if flat_L.graph.is_planar else None,
              deployed=fresh["deployed"], strips=plan_of(flat_L, flat_L.joint_angles(), fresh["deployed"].joint_angles(), p, xy=flat_xy),
              target=problem.fitting.surface if target_surface else None)  # the surface given, as fitted (mm)
    bfgs = None
    if with_baseline and not interrupted:
        base_problem = problem.fresh_copy()  # the same starting problem, without deploying again
        b = optimize(base_problem, OptimizeOptions(**{**options.__dict__, "method": "bfgs"}))
        bfgs = [asdict(r) for r in b.history]
    from ..viz.render import plot_convergence

    plot_convergence(os.path.join(out_dir, "convergence.png"), {options.method: [r.J for r in res.history],
                                                                 **({"BFGS": [r["J"] for r in bfgs]} if bfgs else {})},
                     title=name)
    iters = max(res.iterations, 1)
    result = {
        "name": name,
        "J": final["J"],
        "terms": final["terms"],  # weighted: they sum to J
        "ratios": final["ratios"],  # unweighted: E_flat/E0, E_deployed/E0, T/l0²
        "energy_flat": final["energy_flat"],
        "energy_deployed": final["energy_deployed"],
        "initial": {"J": initial["J"], "energy_flat": initial["energy_flat"], "energy_deployed": initial["energy_deployed"]},
        "constraints": {"planarity": optimizer_final["planarity"], "min_angle_deg": optimizer_final["min_angle_deg"],
                        "planarity_tolerance": options.planarity_tolerance},
        "optimizer_state": {k: optimizer_final[k] for k in ("J", "terms", "ratios", "energy_flat", "energy_deployed")},
        "fresh_deployment": {"reached": final["reached"], "message": final["message"], "folder": "deploy"},
        "state_distance": distances,  # fresh deployment against the optimizer's states, max over rod points / span
        "method": options.method,
        "weights": asdict(weights),
        "target_angle_deg": float(np.degrees(problem.deployed.angle)),
        "flat_angle_deg": float(np.degrees(problem.flat.angle)),
        "flat_angle_note": problem.flat_note,
        "warnings": warnings,
        "input": problem.flat.L.graph.design.note,  # how a .3dm was read, else None
        "iterations": res.iterations,
        "time_s": res.time_s,
        "time_per_iteration_s": res.time_s / iters,
        "total_time_s": time.perf_counter() - t0,
        "status": "interrupted" if interrupted else "complete",
        "message": res.message,
        "history": [asdict(r) for r in res.history],
        "bfgs_history": bfgs,
        "rest_lengths": p.tolist(),
    }
    atomic_write_text(os.path.join(out_dir, "result.json"), finite_json(result, indent=1))
    if interrupted:
        raise KeyboardInterrupt
    return result
