"""Sparse-actuation benchmark: the fewest actuators within 1 % of the span, one row per design (issue 25).

Each design runs in its own process (so that its peak memory is its own):
the dense deployment, then ``xshells sparsify``'s default (elimination,
``--max-fit 1%``). Further rows: eq. 8 at η = 3e-4 on the pointy wings, and
the reference implementation's own torque sets evaluated in our model.
Target: ≤ 2 minutes per sparsification (beyond the dense deployment) for
designs up to 600 segments.

    python benchmarks/actuation.py [--designs wings,arch,breather,swimming_ray,two_asymm_bumps] [--no-reference]

``swimming_ray`` and ``two_asymm_bumps`` are read from the shared ElasticRods
data beside the repository (skipped when it is absent).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
EXAMPLES = os.path.join(HERE, "..", "xshells", "data", "examples")
SHARED = os.path.join(HERE, "..", "..", "shared", "data", "elasticrods")
BUNDLED = {
    "wings": os.path.join(EXAMPLES, "asymm_wings_pointy", "case.json"),
    "arch": os.path.join(EXAMPLES, "two_bumps_architectural", "case.json"),
    "breather": os.path.join(EXAMPLES, "breather_hole", "case.json"),
}
SHARED_CASES = ("swimming_ray", "two_asymm_bumps")


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def case_path(name: str, tmp: str) -> str | None:
    if name in BUNDLED:
        return BUNDLED[name]
    cases = os.path.join(SHARED, "cases.json")
    if not os.path.exists(cases):
        return None
    c = next(c for c in json.load(open(cases))["cases"] if c["name"] == name)
    c = dict(c, file=os.path.join(SHARED, c["file"]))
    path = os.path.join(tmp, f"{name}.json")
    json.dump(c, open(path, "w"))
    return path


def one(case: str, mode: str) -> dict:
    """Runs in a child process: the dense deployment and one sparsification."""
    from xshells.actuation import SelectionOptions, SparsifyOptions, select_actuators, sparsify
    from xshells.actuation.run import dense_deployment

    dense = dense_deployment(case)
    L = dense.linkage
    if mode == "eta":
        r = sparsify(L, dense.tau_ref, SparsifyOptions(eta=3e-4, p=0.5), flat_energy=dense.flat_energy)
    else:
        r = select_actuators(L, dense.tau_ref, SelectionOptions(max_fit=0.01), flat_energy=dense.flat_energy)
    folded = "not valid" in r.message
    return {"name": dense.name, "segments": int(L.design.num_segments), "joints": int(L.num_joints), "dof": int(L.num_vars),
            "dense_s": dense.time_s, "time_s": r.time_s, "actuators": int(len(r.actuated)), "fit_mean": r.fit_mean,
            "fit_max": r.fit_max, "converged": bool(r.converged), "folded": folded, "message": r.message, "peak_mb": peak_mb()}


def reference_rows() -> list[tuple]:
    """The reference's torque sets in our model (the architectural ones were computed with E = 20 GPa)."""
    from xshells.actuation.run import dense_deployment
    from xshells.deploy import solve_equilibrium
    from xshells.linkage.state import restore

    rows = []
    sets = [("wings", "asymm_wings_pointy", ["reference_torques_4.txt"], 1.0),
            ("arch", "two_bumps_architectural", [f"architectural_scale_torques_{k}.txt" for k in (7, 11, 14)], 0.1)]
    for key, folder, files, scale in sets:
        dense = dense_deployment(BUNDLED[key])
        L = dense.linkage
        targets = L.joint_positions()
        l0 = np.linalg.norm(np.ptp(targets, axis=0))
        for f in files:
            restore(L, dense.state)
            tau = np.loadtxt(os.path.join(EXAMPLES, folder, f))[np.asarray(L.graph.joint_vertex)] * scale
            t0 = time.perf_counter()
            rep = solve_equilibrium(L, torques=tau)
            d = np.linalg.norm(L.joint_positions() - targets, axis=1) / l0
            rows.append((f"{dense.name}: {f}" + (f" x {scale:g}" if scale != 1 else ""), L.num_vars,
                         time.perf_counter() - t0, f"{int(np.count_nonzero(tau > 1e-3 * tau.max()))} actuators, converged "
                         f"{rep.converged}, mean {100 * d.mean():.2f}% max {100 * d.max():.2f}%"))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--designs", default="wings,arch,breather,swimming_ray,two_asymm_bumps")
    ap.add_argument("--no-reference", action="store_true", help="skip the reference torque sets")
    ap.add_argument("--no-eta", action="store_true", help="skip the eq. 8 row")
    ap.add_argument("--one", nargs=2, metavar=("CASE", "MODE"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print("RESULT " + json.dumps(one(*args.one)))
        return
    runs = [(d, "select") for d in args.designs.split(",") if d]
    if not args.no_eta:
        runs.append(("wings", "eta"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, mode in runs:
            path = case_path(name, tmp)
            if path is None:
                print(f"{name}: shared data not found, skipped", file=sys.stderr)
                continue
            out = subprocess.run([sys.executable, __file__, "--one", path, mode], capture_output=True, text=True)
            line = next((l for l in out.stdout.splitlines() if l.startswith("RESULT ")), None)
            if line is None:
                print(f"{name}: failed\n{out.stderr[-2000:]}", file=sys.stderr)
                continue
            r = json.loads(line[7:])
            r["mode"] = "--max-fit 1%" if mode == "select" else "--eta 3e-4"
            rows.append(r)
            print(f"  done {r['name']} ({r['mode']}): {r['actuators']} actuators in {r['time_s']:.1f} s", file=sys.stderr, flush=True)
    print(f"{'case':<42} {'mode':<12} {'segs':>5} {'joints':>6} {'DoF':>6} {'dense s':>8} {'sparsify s':>10} "
          f"{'actuators':>9} {'% joints':>8} {'mean %':>7} {'max %':>6} {'ok':>3} {'peak MB':>8}")
    for r in rows:
        ok = "yes" if r["converged"] and not r["folded"] else "NO"
        print(f"{r['name']:<42} {r['mode']:<12} {r['segments']:>5} {r['joints']:>6} {r['dof']:>6} {r['dense_s']:>8.1f} "
              f"{r['time_s']:>10.1f} {r['actuators']:>9} {100 * r['actuators'] / r['joints']:>8.1f} "
              f"{100 * r['fit_mean']:>7.3f} {100 * r['fit_max']:>6.2f} {ok:>3} {r['peak_mb']:>8.0f}")
    if not args.no_reference:
        print()
        print(f"{'reference torque set':<62} {'DoF':>6} {'time s':>7}  result")
        for name, dof, t, info in reference_rows():
            print(f"{name:<62} {dof:>6} {t:>7.1f}  {info}")


if __name__ == "__main__":
    main()
