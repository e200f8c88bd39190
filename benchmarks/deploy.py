"""Deployment benchmark over the paper's designs (cases.json).

Prints case, segments, DoF, steps, reached/target angle, rest-length-solve
and deployment times, Newton iterations and peak memory (RSS high-water
mark of a fresh process per case). Targets (issue 5): the authors' C++, one
thread: manta ray 5.9 s, Darth Vader 5.9 s, elephant ears 64 s, hourglass
99 s; the boat stalls at 60.5° of 62°.

    python benchmarks/deploy.py [--cases manta_ray darth_vader ...]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "shared", "data", "elasticrods")
DEFAULT = ["manta_ray", "darth_vader", "boat", "elephant_ears", "hourglass"]


def run_one(case: dict) -> dict:
    import numpy as np

    from xshells.deploy.case import material_from_spec
    from xshells.deploy.run import run_deployment

    angle = np.radians(case["angle_deg"]) if case.get("angle_deg") is not None else case.get("angle_rad")
    rl = os.path.join(DATA, case["rest_lengths"]) if case.get("rest_lengths") else None
    out = os.path.join("/tmp", "xshells_bench", case["name"])
    r = run_deployment(os.path.join(DATA, case.get("flat_file") or case["file"]), material_from_spec(case["material"]),
                       out_dir=out, subdivision=case.get("subdivision", 10), target_angle=angle,
                       open_by=np.radians(case["open_by_deg"]) if case.get("open_by_deg") else None,
                       steps=case.get("steps", 40), rest_lengths_path=rl, progress=False, name=case["name"])
    return {"name": case["name"], "segments": r["segments"], "dof": r["dof"], "steps": len(r["steps"]),
            "reached_deg": r["deployed"]["average_angle_deg"], "target_deg": r["target_angle_deg"], "reached": r["reached"],
            "rest_s": r["timings_s"]["rest_length_solve"], "deploy_s": r["timings_s"]["deploy"],
            "newton": r["newton_iterations"], "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=DEFAULT)
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    cases = {c["name"]: c for c in json.load(open(os.path.join(DATA, "cases.json")))["cases"]}
    if args.one:
        print(json.dumps(run_one(cases[args.one])))
        return
    print(f"{'case':<16} {'segments':>8} {'DoF':>7} {'steps':>5} {'reached/target °':>17} {'rest s':>7} {'deploy s':>9} {'Newton':>7} {'peak MB':>8}")
    for name in args.cases:
        proc = subprocess.run([sys.executable, __file__, "--one", name], capture_output=True, text=True)
        if proc.returncode != 0:
            print(f"{name:<16} failed: {proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else proc.returncode}")
            continue
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        mark = "" if r["reached"] else " (stopped)"
        print(f"{r['name']:<16} {r['segments']:>8} {r['dof']:>7} {r['steps']:>5} {r['reached_deg']:>8.2f}/{r['target_deg']:<7.2f}  "
              f"{r['rest_s']:>7.1f} {r['deploy_s']:>9.1f} {r['newton']:>7} {r['peak_mb']:>8.0f}{mark}")


if __name__ == "__main__":
    main()
