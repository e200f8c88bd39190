"""Command overhead of ``xshells deploy`` (issue 24): everything outside the deploy phase.

Runs ``xshells deploy DESIGN`` (default: the bundled manta ray, the
command's defaults) in fresh processes and prints, per run and as medians:
the whole command's wall time, its deploy phase (``timings_s.deploy`` of
``result.json``), the overhead (the difference: start-up, imports, the
cross-section, the rest-length solve, waiting for the output writers), the
rest-length solve alone, and the peak memory of the command's processes.

The first run of a machine solves the cross-section and stores it
(``xshells/section/store.py``); ``--cold`` runs every time with the cache
off, as a first run does.

    python benchmarks/command.py [--repeat 5] [--cold] [DESIGN.obj ...]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
MANTA = os.path.join(HERE, "..", "xshells", "data", "examples", "manta_ray.obj")


def run_once(design: str, cold: bool) -> dict:
    env = dict(os.environ)
    if cold:
        env["XSHELLS_CACHE"] = "off"
    with tempfile.TemporaryDirectory() as out:
        t = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "xshells.cli", "deploy", design, "--out", out, "--no-progress"],
                              env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t
        if proc.returncode not in (0, 1):
            raise SystemExit(f"{design}: xshells deploy failed:\n{proc.stderr[-2000:]}")
        with open(os.path.join(out, "result.json")) as fh:
            result = json.load(fh)
    timings = result["timings_s"]
    return {"wall": wall, "deploy": timings["deploy"], "overhead": wall - timings["deploy"],
            "rest": timings["rest_length_solve"], "segments": result["segments"]}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("designs", nargs="*", default=[MANTA])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--cold", action="store_true", help="cross-section cache off (every run solves it, as a first run)")
    args = ap.parse_args(argv)
    print(f"{'case':<22} {'seg':>4} {'run':>4} {'wall s':>7} {'deploy s':>8} {'overhead s':>10} {'rest s':>7} {'peak MB':>8}")
    for design in args.designs:
        name = os.path.splitext(os.path.basename(design))[0]
        rows = []
        for i in range(args.repeat):
            r = run_once(design, args.cold)
            rows.append(r)
            peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
            print(f"{name:<22} {r['segments']:>4} {i + 1:>4} {r['wall']:>7.2f} {r['deploy']:>8.2f} {r['overhead']:>10.2f} "
                  f"{r['rest']:>7.2f} {peak:>8.0f}", flush=True)
        med = {k: statistics.median(r[k] for r in rows) for k in ("wall", "deploy", "overhead", "rest")}
        print(f"{name:<22} {rows[0]['segments']:>4} {'med':>4} {med['wall']:>7.2f} {med['deploy']:>8.2f} "
              f"{med['overhead']:>10.2f} {med['rest']:>7.2f}")


if __name__ == "__main__":
    main()
