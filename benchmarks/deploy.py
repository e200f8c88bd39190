"""Deployment benchmark over the paper's designs (cases.json).

For each case, in a fresh process: build the linkage, find its assembly
state (rest-length solve, or the given rest lengths), deploy it, and print
segments, DoF, steps, reached/target angle, the final constrained gradient
norm ‖g‖, the smallest eigenvalue λmin of the free Hessian (stability under
a fixed torque) and λmin(ᾱ) with the average angle held (stability under the
deployment's angle control), rest-length-solve and
deployment times, Newton iterations and peak memory (RSS high-water mark).
Targets (issue 5): the authors' C++, one thread: manta ray 5.9 s, Darth
Vader 5.9 s, elephant ears 64 s, hourglass 99 s.

    python benchmarks/deploy.py [--cases manta_ray darth_vader ... | --cases all] [--json out.jsonl]

``--cases all`` runs every case of cases.json that sets an angle
(``angle_deg``, ``angle_rad`` or ``open_by_deg``); the big ones take minutes.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "shared", "data", "elasticrods")
DEFAULT = ["manta_ray", "darth_vader", "boat", "elephant_ears", "hourglass"]


def has_angle(case: dict) -> bool:
    return any(case.get(k) is not None for k in ("angle_deg", "angle_rad", "open_by_deg"))


def run_one(case: dict) -> dict:
    import numpy as np

    from xshells.deploy.case import material_from_spec
    from xshells.deploy.simulate import DeployOptions, deploy, rest_length_solve
    from xshells.io import read_design, read_rest_lengths
    from xshells.linkage.linkage import Linkage
    from xshells.solve import NewtonOptions, minimize

    design = read_design(os.path.join(DATA, case.get("flat_file") or case["file"]))
    p = read_rest_lengths(os.path.join(DATA, case["rest_lengths"]), design.num_segments) if case.get("rest_lengths") else None
    material = dict(case["material"])
    if material.get("contour_file"):  # paths in cases.json are relative to it
        material["contour_file"] = os.path.join(DATA, material["contour_file"])
    L = Linkage(design, material_from_spec(material), subdivision=case.get("subdivision", 10), rest_lengths=p)
    t0 = time.perf_counter()
    if p is None:
        rest_length_solve(L)
    else:  # as xshells deploy does with given rest lengths
        minimize(L, fixed=L.rigid_pin_indices(), options=NewtonOptions(gradient_tolerance=1e-9, max_iterations=100))
    t_rest = time.perf_counter() - t0
    if case.get("angle_deg") is not None:
        angle = np.radians(case["angle_deg"])
    elif case.get("angle_rad") is not None:
        angle = float(case["angle_rad"])
    else:
        angle = L.average_angle() + np.radians(case.get("open_by_deg") or 60.0)
    steps = case.get("steps") or 40
    t1 = time.perf_counter()
    res = deploy(L, angle, DeployOptions(steps=steps))
    t_deploy = time.perf_counter() - t1
    return {"name": case["name"], "segments": L.num_segments, "dof": L.num_vars, "steps": steps,
            "reached_deg": res.reached_angle_deg, "target_deg": res.target_angle_deg, "reached": res.converged,
            "message": res.message, "gradient_norm": res.gradient_norm, "min_eigenvalue": res.min_hessian_eigenvalue,
            "min_eigenvalue_fixed_angle": res.min_eigenvalue_at_fixed_angle,
            "rest_s": t_rest, "deploy_s": t_deploy, "newton": res.newton_iterations,
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=DEFAULT, help="case names, or 'all' (every case with an angle)")
    ap.add_argument("--json", help="also append one JSON line per case to this file")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    all_cases = json.load(open(os.path.join(DATA, "cases.json")))["cases"]
    cases = {c["name"]: c for c in all_cases}
    if args.one:
        print(json.dumps(run_one(cases[args.one])))
        return
    names = [c["name"] for c in all_cases if has_angle(c)] if args.cases == ["all"] else args.cases
    print(f"{'case':<42} {'seg':>5} {'DoF':>6} {'steps':>5} {'reached/target °':>16} {'|g|':>8} {'λmin':>9} {'λmin(ᾱ)':>9} "
          f"{'rest s':>6} {'deploy s':>8} {'Newton':>6} {'peak MB':>7}", flush=True)
    for name in names:
        proc = subprocess.run([sys.executable, __file__, "--one", name], capture_output=True, text=True)
        if proc.returncode != 0:
            print(f"{name:<42} failed: {proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else proc.returncode}", flush=True)
            continue
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        mark = "" if r["reached"] else f"  ({r['message']})"
        print(f"{r['name']:<42} {r['segments']:>5} {r['dof']:>6} {r['steps']:>5} {r['reached_deg']:>7.2f}/{r['target_deg']:<7.2f}  "
              f"{r['gradient_norm']:>8.1e} {r['min_eigenvalue']:>9.2e} {r.get('min_eigenvalue_fixed_angle', float('nan')):>9.2e} {r['rest_s']:>6.1f} {r['deploy_s']:>8.1f} {r['newton']:>6} "
              f"{r['peak_mb']:>7.0f}{mark}", flush=True)
        if args.json:
            with open(args.json, "a") as fh:
                fh.write(json.dumps(r) + "\n")


if __name__ == "__main__":
    main()
