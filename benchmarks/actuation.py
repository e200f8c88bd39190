"""Sparse-actuation benchmark on the asymmetric pointy wings (paper Figs. 8, 9).

Prints case, DoF, time and peak memory for: the dense deployment, one
sparsification (η = 3e-4, p = 1/2), a sweep of 8 η values at p = 1/2, and
the paper's own 4-actuator torques evaluated in our model. Targets (issue 7):
one sparsification ≤ 60 s, the 8-value sweep ≤ 5 min.

    python benchmarks/actuation.py [--sweep-ps 0.5]
"""
from __future__ import annotations

import argparse
import os
import resource
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
CASE = os.path.join(HERE, "..", "xshells", "data", "examples", "asymm_wings_pointy", "case.json")
REFERENCE = os.path.join(HERE, "..", "xshells", "data", "examples", "asymm_wings_pointy", "reference_torques_4.txt")


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweep-ps", default="0.5", help="comma-separated p values for the η sweep")
    ap.add_argument("--out", default=None, help="write sweep.csv and sweep.png here")
    args = ap.parse_args(argv)
    from xshells.actuation import SparsifyOptions, sparsify
    from xshells.actuation.run import DEFAULT_ETAS, dense_deployment
    from xshells.deploy import solve_equilibrium
    from xshells.linkage.state import restore

    rows = []
    dense = dense_deployment(CASE)
    L = dense.linkage
    rows.append(("dense deployment (50 steps)", L.num_vars, dense.time_s, f"torque {dense.tau_ref:.4g}/joint"))
    restore(L, dense.state)
    r = sparsify(L, dense.tau_ref, SparsifyOptions(eta=3e-4, p=0.5), flat_energy=dense.flat_energy)
    rows.append(("sparsify η=3e-4 p=1/2", L.num_vars, r.time_s,
                 f"{len(r.actuated)} actuators, fit mean {100 * r.fit_mean:.2f}% max {100 * r.fit_max:.2f}%, {r.iterations} its"))
    sweep_rows = []
    for p in [float(v) for v in args.sweep_ps.split(",")]:
        t0 = time.perf_counter()
        counts = []
        for eta in DEFAULT_ETAS:
            restore(L, dense.state)
            s = sparsify(L, dense.tau_ref, SparsifyOptions(eta=eta, p=p))
            counts.append(f"{len(s.actuated)}:{100 * s.fit_mean:.2f}%")
            sweep_rows.append({"p": p, "eta": eta, "num_actuators": len(s.actuated), "fit_mean": s.fit_mean})
        rows.append((f"sweep 8 η, p={p:g}", L.num_vars, time.perf_counter() - t0, " ".join(counts)))
    # the paper's 4 actuators, in our model
    restore(L, dense.state)
    targets = L.joint_positions()
    tau = np.loadtxt(REFERENCE)
    t0 = time.perf_counter()
    rep = solve_equilibrium(L, torques=tau)
    d = np.linalg.norm(L.joint_positions() - targets, axis=1) / np.linalg.norm(np.ptp(targets, axis=0))
    rows.append(("paper's 4 torques", L.num_vars, time.perf_counter() - t0,
                 f"converged {rep.converged}, fit mean {100 * d.mean():.2f}% max {100 * d.max():.2f}%"))
    if args.out:
        from xshells.actuation.run import _write_sweep

        os.makedirs(args.out, exist_ok=True)
        _write_sweep(args.out, sweep_rows, "asymm_wings_pointy")
    print(f"{'case':<30} {'DoF':>6} {'time s':>8}  result")
    for name, dof, t, info in rows:
        print(f"{name:<30} {dof:>6} {t:>8.1f}  {info}")
    print(f"peak memory {peak_mb():.0f} MB")


if __name__ == "__main__":
    main()
