"""Sweep benchmark: 8-task deployment sweeps, serial vs a 2-worker LocalCluster.

Two sweeps: the tests' (a 3×3 grid, about a second per task, one task
failing) and the bundled ``sweep_example.yaml`` (regular and irregular
grids, a few seconds per task), plus 8 and 64 no-op tasks for the machinery
alone (the difference between the two separates the fixed start-up cost from
the cost per task).

Each configuration runs in a fresh process (imports, JAX cache loading and
cluster start-up included, as a user pays them). Rows per sweep:

- ``serial``: ``--workers 0``, in one process with the numeric libraries'
  own threads (OpenBLAS and XLA use every core): the baseline, what a user
  gets without a cluster;
- ``serial 1-thr``: the same, with one thread per library (``OMP/OPENBLAS/
  MKL_NUM_THREADS=1`` and XLA's single-thread flag), i.e. one local worker's
  configuration without Dask;
- ``N workers``: the local cluster (each worker pinned to one thread).

``--repeat K`` runs the rows K times, interleaved, and shows the median
(all process times in the last column). Columns:

- ``process s``: wall time of the whole process (Python, JAX and xshells
  imports included): what a user waits for;
- ``sweep s``: wall time of ``run_sweep`` (cluster start and shutdown included);
- ``overhead/task``: ``(workers × time − Σ in-task time) / tasks``, i.e. what
  each task costs beyond its own computation (start-up, scheduling, idle
  workers at the tail, writing results); for the no-op sweep the tasks do
  nothing, so this is the machinery alone;
- ``speedup``: serial process time / this process time;
- ``peak MB``: the largest resident set of any process (client or worker);
- ``task CPU s``: CPU time summed over the tasks (of the whole process that
  ran each task); above the serial row's: the work itself got dearer;
- ``load``: the 1-minute load average before each run (min-max over the
  repeats): others' work on the machine, which the times include;
- ``CPU share``: in-task CPU time / in-task wall time; 1 means the tasks had
  their cores to themselves, 0.3 that other work on the machine left them a
  third of one (then the times say little about the sweep itself).

Targets (issue 9): overhead ≤ 1 s/task, 2 workers ≥ 1.7× serial on 2 cores.

    python benchmarks/sweep.py [--spec SPEC.yaml] [--workers 2] [--repeat 3] [--no-noop]
"""
from __future__ import annotations

import time

T_START = time.perf_counter()  # before any heavy import: "process" time includes them

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile

import numpy as np  # noqa: E402

EXAMPLE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "xshells", "data", "examples", "sweep_example.yaml")
ANGLES = [60, 65, 70, 75, 80, 85, 90, 179.9]  # as in tests/test_sweeps.py; 179.9°: a joint inverts on the way (diverged)


def grid_spec(folder: str) -> str:
    """The tests' 8-task sweep: a 3×3 warped grid deployed to 8 angles (one unreachable)."""
    from xshells.io.export import write_design_obj
    from xshells.linkage.grids import rhombic_grid

    def warp(p):
        r = np.linalg.norm(p, axis=1, keepdims=True)
        return p * (1.0 - 0.25 * (r / r.max()) ** 2)

    write_design_obj(os.path.join(folder, "grid.obj"), rhombic_grid(3, 3, spacing=100.0, angle=np.radians(30), warp=warp))
    spec = {"name": "grid", "task": "deploy",
            "base": {"file": "grid.obj", "subdivision": 4, "steps": 4,
                     "material": {"type": "rectangle", "E": 2000, "nu": 0.3, "params": [4.0, 1.5]}},
            "axes": {"angle_deg": ANGLES}}
    path = os.path.join(folder, "sweep.json")
    with open(path, "w") as fh:
        json.dump(spec, fh)
    return path


def noop_spec(folder: str, n: int) -> str:
    path = os.path.join(folder, f"noop{n}.json")
    with open(path, "w") as fh:
        json.dump({"name": "noop", "task": "noop", "axes": {"sleep_s": [i * 1e-6 for i in range(n)]}}, fh)
    return path


def child(spec_path: str, out: str, workers: int) -> None:
    """Run one sweep in this (fresh) process and print its figures as JSON."""
    from xshells.sweeps import SweepSettings, load_spec, run_sweep

    spec = load_spec(spec_path)
    t = time.perf_counter()
    rep = run_sweep(spec, out, SweepSettings(workers=workers))
    wall = time.perf_counter() - t
    client_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"tasks": len(rep.records), "wall": wall, "process": time.perf_counter() - T_START, "in_task": sum(r["elapsed_s"] for r in rep.records),
                      "task_cpu": sum(r["cpu_s"] or 0 for r in rep.records),
                      "cpu_share": sum(r["cpu_s"] or 0 for r in rep.records) / max(sum(r["elapsed_s"] for r in rep.records), 1e-9),
                      "peak_mb": max([client_mb] + [r["peak_rss_mb"] for r in rep.records]),
                      "failed": rep.failed, "energies": [r["result"].get("energy") for r in rep.records]}))


def measure(spec_path: str, workers: int, pinned: bool = False) -> dict:
    """One sweep in a fresh process; ``pinned``: its numeric libraries on one thread, as local workers run."""
    env = dict(os.environ)
    if pinned:
        from xshells.sweeps.run import worker_env

        env.update(worker_env(env))
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as out:
        res = subprocess.run([sys.executable, __file__, "--child", spec_path, out, str(workers)],
                             capture_output=True, text=True, check=True, env=env)
    return {**json.loads(res.stdout.strip().splitlines()[-1]), "load": load}


def median_run(runs: list) -> dict:
    """The run of median process time (an odd count: the middle one), with the load range of all runs."""
    ordered = sorted(runs, key=lambda m: m["process"])
    m = dict(ordered[(len(ordered) - 1) // 2])
    m["loads"] = (min(r["load"] for r in runs), max(r["load"] for r in runs))
    m["all"] = [r["process"] for r in runs]
    return m


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spec", help="a sweep file (default: the tests' grid sweep and sweep_example.yaml)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1, help="runs of each configuration (interleaved); the median is shown")
    ap.add_argument("--no-noop", action="store_true", help="skip the no-op sweeps")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child[0], args.child[1], int(args.child[2]))
        return
    with tempfile.TemporaryDirectory() as folder:
        specs = [args.spec] if args.spec else [grid_spec(folder), EXAMPLE]
        rows, noop_walls = [], {}
        cases = [("deploy", p) for p in specs]
        if not args.no_noop:
            cases += [("noop", noop_spec(folder, 8)), ("noop", noop_spec(folder, 64))]
        for name, path in cases:
            # serial as `--workers 0` runs it (the libraries' own threads), serial with one thread per
            # library (what each local worker gets), then the local cluster
            configs = [("serial", 0, False)] + ([("serial 1-thr", 0, True)] if name == "deploy" else []) \
                + [(f"{args.workers} workers", args.workers, False)]
            runs = {label: [] for label, _, _ in configs}
            for _ in range(max(args.repeat, 1)):
                for label, w, pinned in configs:
                    runs[label].append(measure(path, w, pinned))
            meds = {label: median_run(r) for label, r in runs.items()}
            serial, dist = meds["serial"], meds[f"{args.workers} workers"]
            if name == "deploy":
                pairs = [(a, b) for a, b in zip(serial["energies"], dist["energies"]) if a is not None and b is not None]
                diff = max((abs(a - b) / max(abs(b), 1e-300) for a, b in pairs), default=0.0)
                print(f"{os.path.basename(path)}: largest relative energy difference serial vs distributed: {diff:.3g}")
            if name == "noop":
                noop_walls[dist["tasks"]] = dist["wall"]
            for label, w, _ in configs:
                m = meds[label]
                n = m["tasks"]
                w = max(w, 1)
                rows.append((os.path.splitext(os.path.basename(path))[0] if name == "deploy" else "noop", n, label,
                             m["process"], m["wall"], (w * m["wall"] - m["in_task"]) / n, serial["process"] / m["process"],
                             m["peak_mb"], m["task_cpu"], m["cpu_share"], m["loads"], m["all"]))
    print(f"{os.cpu_count()} cores; medians of {max(args.repeat, 1)} run(s); load: 1-minute load average "
          f"before each run (min-max), {os.getloadavg()[0]:.2f} at the end")
    print(f"{'case':<15}{'tasks':>6}  {'workers':<13}{'process s':>10}{'sweep s':>9}{'overhead/task s':>17}"
          f"{'speedup':>9}{'peak MB':>9}{'task CPU s':>12}{'CPU share':>11}{'load':>11}  runs (process s)")
    for case, n, label, proc, wall, over, speed, mb, cpu, share, loads, every in rows:
        print(f"{case:<15}{n:>6}  {label:<13}{proc:>10.2f}{wall:>9.2f}{over:>17.2f}{speed:>9.2f}{mb:>9.0f}{cpu:>12.2f}"
              f"{share:>11.2f}{loads[0]:>6.2f}-{loads[1]:<4.2f}  {' '.join(f'{x:.1f}' for x in every)}")
    if 8 in noop_walls and 64 in noop_walls:
        per_task = (noop_walls[64] - noop_walls[8]) / 56
        print(f"no-op tasks on {args.workers} workers: fixed cost (cluster start and stop) {noop_walls[8] - 8 * per_task:.2f} s, "
              f"then {1e3 * per_task:.1f} ms of wall time per task")


if __name__ == "__main__":
    main()
