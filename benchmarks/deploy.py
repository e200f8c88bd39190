"""Deployment benchmark over the paper's designs (cases.json).

For each case, in a fresh process: build the linkage, find its assembly
state (rest-length solve, or the given rest lengths), deploy it, and print
segments, DoF, steps, reached/target angle, the final constrained gradient
norm ‖g‖, the smallest eigenvalue λmin of the free Hessian (stability under
a fixed torque) and λmin(ᾱ) with the average angle held (stability under the
deployment's angle control), rest-length-solve and
deployment times, Newton iterations, milliseconds per Newton iteration and
peak memory (RSS high-water mark), and beside them the authors' C++ on this
machine kind (one thread, same settings; issue 24's table) where measured.

    python benchmarks/deploy.py [--cases manta_ray:10 darth_vader ... | --cases all] [--repeat 3] [--json out.jsonl]

A case is a cases.json name, optionally ``:STEPS`` to override its steps
(``manta_ray:10`` is the design-zoo setting, ``manta_ray`` the 40-step demo).
``--cases all`` runs every case of cases.json that sets an angle
(``angle_deg``, ``angle_rad`` or ``open_by_deg``); the big ones take minutes.
``--repeat N`` runs each case N times, each in a fresh process, and reports
the median deploy time. OpenBLAS runs one thread unless
``OPENBLAS_NUM_THREADS`` is set, as in ``xshells deploy``.
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
DEFAULT = ["manta_ray:10", "manta_ray", "darth_vader", "boat", "elephant_ears", "hourglass"]
# The authors' C++ (ElasticRods), one thread, on this machine kind: deploy seconds, Newton iterations (issue 24)
CPP = {"manta_ray:10": (3.13, 101), "manta_ray": (5.93, 192), "darth_vader": (5.95, 198),
       "elephant_ears": (63.5, 339), "hourglass": (99.0, 253)}


def has_angle(case: dict) -> bool:
    return any(case.get(k) is not None for k in ("angle_deg", "angle_rad", "open_by_deg"))


def run_one(case: dict, steps: int | None = None) -> dict:
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
    steps = steps or case.get("steps") or 40
    t1 = time.perf_counter()
    res = deploy(L, angle, DeployOptions(steps=steps))
    t_deploy = time.perf_counter() - t1
    return {"name": case["name"], "segments": L.num_segments, "dof": L.num_vars, "steps": steps,
            "reached_deg": res.reached_angle_deg, "target_deg": res.target_angle_deg, "reached": res.converged,
            "message": res.message, "gradient_norm": res.gradient_norm, "min_eigenvalue": res.min_hessian_eigenvalue,
            "min_eigenvalue_fixed_angle": res.min_eigenvalue_at_fixed_angle,
            "rest_s": t_rest, "deploy_s": t_deploy, "newton": res.newton_iterations,
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _run_in_process(spec: str) -> dict:
    env = dict(os.environ)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    proc = subprocess.run([sys.executable, __file__, "--one", spec], capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else str(proc.returncode))
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=DEFAULT, help="case names (NAME or NAME:STEPS), or 'all' (every case with an angle)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per case (fresh processes); the median deploy time is reported")
    ap.add_argument("--json", help="also append one JSON line per case to this file")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    all_cases = json.load(open(os.path.join(DATA, "cases.json")))["cases"]
    cases = {c["name"]: c for c in all_cases}
    if args.one:
        name, _, steps = args.one.partition(":")
        r = run_one(cases[name], int(steps) if steps else None)
        r["case"] = args.one
        print(json.dumps(r))
        return
    specs = [c["name"] for c in all_cases if has_angle(c)] if args.cases == ["all"] else args.cases
    print(f"{'case':<44} {'seg':>5} {'DoF':>6} {'steps':>5} {'reached/target °':>16} {'|g|':>8} {'λmin':>9} {'λmin(ᾱ)':>9} "
          f"{'rest s':>6} {'deploy s':>8} {'Newton':>6} {'ms/it':>6} {'C++ s':>6} {'C++ it':>6} {'ratio':>5} {'peak MB':>7}", flush=True)
    for spec in specs:
        try:
            runs = [_run_in_process(spec) for _ in range(max(args.repeat, 1))]
        except RuntimeError as exc:
            print(f"{spec:<44} failed: {exc}", flush=True)
            continue
        runs.sort(key=lambda r: r["deploy_s"])
        r = runs[len(runs) // 2]  # the median run (of an odd count; the upper middle of an even one)
        mark = "" if r["reached"] else f"  ({r['message']})"
        cpp_s, cpp_it = CPP.get(spec, (float("nan"), None))
        ms_it = 1e3 * r["deploy_s"] / max(r["newton"], 1)
        print(f"{spec:<44} {r['segments']:>5} {r['dof']:>6} {r['steps']:>5} {r['reached_deg']:>7.2f}/{r['target_deg']:<7.2f}  "
              f"{r['gradient_norm']:>8.1e} {r['min_eigenvalue']:>9.2e} {r.get('min_eigenvalue_fixed_angle', float('nan')):>9.2e} {r['rest_s']:>6.1f} "
              f"{r['deploy_s']:>8.2f} {r['newton']:>6} {ms_it:>6.1f} {cpp_s:>6.2f} {cpp_it if cpp_it else '':>6} {r['deploy_s'] / cpp_s:>5.2f} "
              f"{r['peak_mb']:>7.0f}{mark}", flush=True)
        if args.json:
            with open(args.json, "a") as fh:
                fh.write(json.dumps({**r, "deploy_s_runs": [x["deploy_s"] for x in runs]}) + "\n")


if __name__ == "__main__":
    main()
