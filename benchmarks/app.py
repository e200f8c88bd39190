"""``xshells app`` benchmark: start-up to an interactive page, and the view update after a slider move.

For each case, in a fresh process: start the app (server + session), load
the page in headless Chromium (launched beforehand) and time until it is
connected and showing the panel; deploy to the first angle (cold, from the
flat assembly state); then move the angle slider by small amounts and time
from the slider change to the deployed mesh being pushed to the page (warm
start from the last state). Peak memory is the process's RSS high-water mark
(app + solver; Chromium runs in its own processes and is not counted).
Targets (issue 8): view update ≤ 1 s after a slider move at ~300 segments;
page interactive ≤ 3 s after start.

    python benchmarks/app.py [--cases manta_ray nonuniform grid10]
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
EXAMPLES = os.path.join(HERE, "..", "xshells", "data", "examples")
CASES = {
    # the demo's material and subdivision (xshells demo: rectangle 10 × 7 mm, E 20000, ν 0.3, k = 8)
    "manta_ray": (os.path.join(EXAMPLES, "manta_ray.obj"), [46.0, 90.0]),
    "nonuniform": (os.path.join(EXAMPLES, "nonuniform_linkage.obj"), [40.0]),
    "grid10": (None, [110.0]),
}
MOVES = (1.0, 1.0, -2.0, 5.0, -0.5)


def run_one(name: str) -> dict:
    import numpy as np
    from playwright.sync_api import sync_playwright

    from xshells.app.cli import start
    from xshells.app.loading import grid_project
    from xshells.app.session import Session
    from xshells.app.ui import App

    path, angles = CASES[name]
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", headless=True,
                                     args=["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                                           "--disable-background-networking", "--disable-component-update", "--disable-sync"])
        page = browser.new_page()
        t0 = time.perf_counter()
        if path is None:
            app = App(Session(grid_project(10, 10), out_dir="/tmp/xshells-bench-app"), port=8791)
        else:
            app = start(path, port=8791, out_dir="/tmp/xshells-bench-app")
        t_server = time.perf_counter() - t0
        page.goto(f"http://127.0.0.1:{app.server.get_port()}")
        page.get_by_text("Open example").first.wait_for(timeout=60000)
        while not app.server.get_clients():
            time.sleep(0.01)
        t_page = time.perf_counter() - t0
        drawn = {}
        app.session.listeners.append(lambda e, p: drawn.__setitem__(e, time.perf_counter()) if e == "deployed" else None)
        s = app.session
        rows = []
        for a in angles:
            t = time.perf_counter()
            app.angle.value = a
            s.worker.wait_idle(600)
            cold = time.perf_counter() - t
            warm = []
            for d in MOVES:
                drawn.clear()
                t = time.perf_counter()
                app.angle.value = round(float(app.angle.value) + d, 1)
                while "deployed" not in drawn:
                    time.sleep(0.002)
                warm.append(drawn["deployed"] - t)
                s.worker.wait_idle(60)  # let the stability job finish before the next move
            rows.append({"angle": a, "cold_s": cold, "warm_s": warm})
        out = {"case": name, "segments": s.layout.num_segments, "dof": s.sim.num_vars, "server_s": t_server,
               "page_s": t_page, "rows": rows, "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
        browser.close()
        app.stop()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(run_one(args.one)))
        return
    print(f"{'case':12s} {'segs':>5s} {'DoF':>6s} {'server':>7s} {'page':>6s} {'angle':>6s} {'cold':>7s} "
          f"{'warm median':>11s} {'warm max':>8s} {'peak MB':>8s}")
    for name in args.cases:
        res = subprocess.run([sys.executable, __file__, "--one", name], capture_output=True, text=True)
        line = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
        if res.returncode or not line:
            print(f"{name:12s} failed: {res.stderr.strip().splitlines()[-1] if res.stderr.strip() else res.returncode}")
            continue
        r = json.loads(line[-1])
        import numpy as np

        for row in r["rows"]:
            w = np.array(row["warm_s"])
            print(f"{r['case']:12s} {r['segments']:5d} {r['dof']:6d} {r['server_s']:6.2f}s {r['page_s']:5.2f}s "
                  f"{row['angle']:5.1f}° {row['cold_s']:6.2f}s {np.median(w):10.2f}s {w.max():7.2f}s {r['peak_mb']:8.0f}")


if __name__ == "__main__":
    main()
