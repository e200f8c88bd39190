"""``xshells app`` benchmark: start-up to an interactive page, and the view update after a slider move.

Start-up (``--startup``, repeated ``--repeat`` times): headless Chromium is
launched first; the clock starts when ``xshells app DESIGN`` is spawned as a
new process. The page counts as **interactive** when (1) the page shows the
app's panel as filled in by the server (the opened example, "topology: ok"),
(2) a control answers: the "click mode" dropdown is changed *in the page* and
the server's hint for that mode comes back, and (3) a screenshot shows the
flat layout's joints (red) in the left half of the view. The solver (JAX,
SciPy, the assembly and the first deployment) runs on a background thread
after the page has connected, so the figures also say when the first
deployed state arrived. The same checks run, interleaved, on a bare viser
page (no xshells): the floor that Python, viser and the browser set. A
second breakdown times each start-up step in one process (imports, design,
session, server with panels, then the solver's steps).

Slider (default): for each case, in a fresh process: start the app (server +
session), load the page, deploy to the first angle (cold, from the flat
assembly state); then move the angle slider by small amounts and time from
the slider change to the deployed mesh being pushed to the page (warm start
from the last state). Peak memory is the process's RSS high-water mark (app +
solver; Chromium runs in its own processes and is not counted).

Targets (issue 8): view update ≤ 1 s after a slider move at ~300 segments;
page interactive ≤ 3 s after start. The load average is printed with each
figure (the development machine is shared).

    python benchmarks/app.py [--cases manta_ray nonuniform grid10]
    python benchmarks/app.py --startup [--repeat 3]
    python benchmarks/app.py --edit [--cases manta_ray elephant_ears]

Edits (``--edit``, issue 22): through the ``Session`` API, edit, ``request_angle``, then wait until the
worker is idle (the deployed view, and its stability, are back): 10 moves of one joint by 0.2 % of the
span, 10 brushes, 10 drags (previews, then the release), and a topology edit (a free-end segment added,
then undone). Targets: a drag ≤ 1 s median and ≤ 2 s max on the manta ray at 90°; a topology edit ≤ 3 s.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import resource
import socket
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


CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
XSHELLS = os.path.join(os.path.dirname(sys.executable), "xshells")


def _red_joints_on_left(png: bytes) -> bool:
    """Whether a screenshot shows the flat layout's red joints (220, 40, 40) in the view's left half."""
    import io

    import numpy as np
    from PIL import Image

    im = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    left = im[:, : im.shape[1] // 2]
    red = (left[..., 0] > 180) & (left[..., 1] < 90) & (left[..., 2] < 90)
    return int(red.sum()) > 50


# The floor: a bare viser page with the same checks (a panel text, a dropdown whose
# change the server answers, red points on the left), and nothing of xshells.
BARE_VISER = """
import sys, time, numpy as np, viser
s = viser.ViserServer(port=int(sys.argv[1]), verbose=False)
s.gui.add_markdown("**topology:** ok")
d = s.gui.add_dropdown("click mode", ("view / orbit", "move joint"))
hint = s.gui.add_markdown("drag to orbit")
d.on_update(lambda _: setattr(hint, "content", "then drag its handle"))
P = np.c_[np.random.default_rng(0).uniform(-2, -0.5, (300, 2)), np.zeros(300)].astype(np.float32)
s.scene.add_point_cloud("/joints", P, colors=(220, 40, 40), point_size=0.02, point_shape="circle")
while True:
    time.sleep(1)
"""


def startup_once(port: int = 8792, bare: bool = False) -> dict:
    """One start of ``xshells app manta_ray.obj`` in a new process, timed from the spawn (see the module docstring).

    ``bare``: the same for :data:`BARE_VISER`, the floor set by Python, viser and the browser.
    """
    import tempfile

    from playwright.sync_api import sync_playwright

    out = {"load_before": os.getloadavg()[0]}
    with sync_playwright() as pw, tempfile.TemporaryDirectory() as tmp:
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", headless=True, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 800})
        t0 = time.perf_counter()
        cmd = ([sys.executable, "-c", BARE_VISER, str(port)] if bare else
               [XSHELLS, "app", CASES["manta_ray"][0], "--port", str(port), "--out", tmp])
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            while True:  # until the server listens
                try:
                    socket.create_connection(("127.0.0.1", port), timeout=1).close()
                    break
                except OSError:
                    if proc.poll() is not None or time.perf_counter() - t0 > 60:
                        raise RuntimeError("the app did not start") from None
                    time.sleep(0.01)
            out["http_s"] = time.perf_counter() - t0
            page.goto(f"http://127.0.0.1:{port}", wait_until="commit")
            # the panel, filled in by the server: the opened example and the topology check
            page.get_by_text("topology: ok").first.wait_for(timeout=60000)
            assert bare or page.get_by_label("example").first.input_value() == "manta_ray.obj"
            out["panel_s"] = time.perf_counter() - t0
            page.get_by_label("click mode").first.click()
            page.get_by_role("option", name="move joint").click()
            page.get_by_text("then drag its handle").first.wait_for(timeout=60000)
            out["control_s"] = time.perf_counter() - t0
            while not _red_joints_on_left(page.screenshot()):
                if time.perf_counter() - t0 > 60:
                    raise RuntimeError("the flat layout never showed")
            out["flat_drawn_s"] = time.perf_counter() - t0
            out["interactive_s"] = max(out["control_s"], out["flat_drawn_s"])
            out["load_at_interactive"] = os.getloadavg()[0]
            if not bare:
                page.get_by_text(re.compile(r"deployed to [0-9.]+° in")).first.wait_for(timeout=120000)
                out["first_deployed_s"] = time.perf_counter() - t0
        finally:
            proc.terminate()
            proc.wait(10)
            browser.close()
    return out


def startup_steps() -> dict:
    """Each start-up step of the app in this process (run in a fresh one), then the solver's first steps."""
    t = {"start": time.perf_counter()}
    mark = lambda k: t.__setitem__(k, time.perf_counter())  # noqa: E731
    import numpy  # noqa: F401

    mark("numpy")
    from xshells.cli import _parser_for

    _parser_for(["app"])
    mark("xshells CLI")
    from xshells.app.ui import App, serve

    server = serve("127.0.0.1", 8793)
    mark("viser server listening")
    from xshells.app.loading import open_path
    from xshells.app.session import Session

    session = Session(open_path(CASES["manta_ray"][0]), out_dir="/tmp/xshells-bench-app")
    mark("design + session")
    app = App(session, server=server)
    mark("panels + flat layout")
    from xshells.app.sim import Simulation  # noqa: F401

    mark("solver import (JAX, SciPy)")
    material = session.material
    mark("section stiffnesses")
    sim = Simulation(session.layout, material, session.subdivision)
    mark("assembly state")
    session._view(sim, time.perf_counter())
    mark("flat swept mesh")
    sim.solve_to(46.0)
    mark("first deployment to 46°")
    app.stop()
    keys = list(t)
    return {k: t[k] - t[keys[i - 1]] for i, k in enumerate(keys) if i}


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


EDIT_CASES = {
    # the demo's material, k = 8; each case file's angle
    "manta_ray": (os.path.join(EXAMPLES, "manta_ray.obj"), 90.0),
    "elephant_ears": (os.path.join(HERE, "..", "..", "shared", "data", "elasticrods", "examples", "florin",
                                   "20181227_195542_meshID_40c44e5b-d610-4399-87e5-80c1281ee9f7.obj"), 85.0),
}


def edit_one(name: str, count: int = 10) -> dict:
    """Time edits through the ``Session`` API, as a user of it would: edit, ``request_angle``, wait until idle.

    Moves of one joint by 0.2 % of the span, brushes (radius 5 %, 0.2 %), drags (five previews of
    growing size, then the release), and a topology edit (a free-end segment added at a boundary joint,
    then undone).
    """
    import numpy as np

    from xshells.app import core
    from xshells.app.loading import open_path
    from xshells.app.session import Session

    path, angle = EDIT_CASES[name]
    s = Session(open_path(path), out_dir="/tmp/xshells-bench-edit")
    s.set_subdivision(8)
    t = time.perf_counter()
    s.request_angle(angle)
    s.worker.wait_idle(600)
    out = {"segments": s.layout.num_segments, "cold_s": time.perf_counter() - t}
    span = s.layout.span()
    rng = np.random.default_rng(0)
    warm = []

    def timed(fn, *args):
        t0 = time.perf_counter()
        s.edit(fn, *args)
        s.request_angle(angle)
        s.worker.wait_idle(600)
        warm.append(s.last_warm is not None)
        return time.perf_counter() - t0

    def step():
        return 0.002 * span * rng.normal(size=2) / np.sqrt(2)

    moves, brushes, drags = [], [], []
    for _ in range(count):
        v = int(rng.integers(s.layout.num_vertices))
        moves.append(timed(core.move_joint, v, s.layout.vertices[v] + step()))
    for _ in range(count):
        v = int(rng.integers(s.layout.num_vertices))
        brushes.append(timed(core.brush, s.layout.vertices[v], 0.05 * span, step()))
    for _ in range(count):
        v = int(rng.integers(s.layout.num_vertices))
        start, d = s.layout.vertices[v].copy(), step()
        for f in (0.2, 0.4, 0.6, 0.8):  # the drag's positions, the latest winning
            s.preview(core.move_joint(s.layout, v, start + f * d))
            time.sleep(0.05)
        drags.append(timed(core.move_joint, v, start + d))
    valence = np.bincount(s.layout.edges.ravel(), minlength=s.layout.num_vertices)
    boundary = int(np.flatnonzero(valence == 3)[0])
    c = s.layout.vertices.mean(axis=0)
    outward = s.layout.vertices[boundary] + 0.03 * span * (s.layout.vertices[boundary] - c) / np.linalg.norm(
        s.layout.vertices[boundary] - c)
    topo = timed(core.add_joint, outward, boundary)
    t0 = time.perf_counter()
    s.undo()  # back to the previous topology
    s.request_angle(angle)
    s.worker.wait_idle(600)
    undo = time.perf_counter() - t0
    s.close()
    med = lambda v: float(np.median(v))  # noqa: E731
    out.update(moves=(med(moves), max(moves)), brushes=(med(brushes), max(brushes)), drags=(med(drags), max(drags)),
               topology_s=topo, topology_undo_s=undo, warm=sum(warm[:-1]), edits=len(warm) - 1,
               peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--startup", action="store_true", help="time the start-up instead of slider moves")
    ap.add_argument("--repeat", type=int, default=3, help="start-up runs (default 3)")
    ap.add_argument("--edit", action="store_true", help="time edits (moves, brushes, drags, a topology edit) instead")
    ap.add_argument("--edit-one", help=argparse.SUPPRESS)
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--steps", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(run_one(args.one)))
        return
    if args.edit_one:
        print(json.dumps(edit_one(args.edit_one)))
        return
    if args.edit:
        cases = [c for c in args.cases if c in EDIT_CASES] if args.cases != list(CASES) else list(EDIT_CASES)
        print(f"{'case':14s} {'segs':>5s} {'cold s':>7s} {'move med/max s':>15s} {'brush med/max s':>16s} "
              f"{'drag med/max s':>15s} {'warm':>6s} {'topology s':>10s} {'undo s':>7s} {'peak MB':>8s}")
        for name in cases:
            if not os.path.exists(EDIT_CASES[name][0]):
                print(f"{name:14s} (data not found)")
                continue
            res = subprocess.run([sys.executable, __file__, "--edit-one", name], capture_output=True, text=True)
            line = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
            if not line:
                print(f"{name:14s} failed: {res.stderr.strip().splitlines()[-1:]}")
                continue
            r = json.loads(line[-1])
            fmt = lambda p: f"{p[0]:.2f} / {p[1]:.2f}"  # noqa: E731
            print(f"{name:14s} {r['segments']:5d} {r['cold_s']:7.1f} {fmt(r['moves']):>15s} {fmt(r['brushes']):>16s} "
                  f"{fmt(r['drags']):>15s} {r['warm']:>3d}/{r['edits']:<2d} {r['topology_s']:10.2f} {r['topology_undo_s']:7.2f} "
                  f"{r['peak_mb']:8.0f}")
        return
    if args.steps:
        print(json.dumps(startup_steps()))
        return
    if args.startup:
        import numpy as np

        runs = {"xshells app": [], "bare viser": []}
        for i in range(args.repeat):  # interleaved, so both see the same load
            for name, bare in (("xshells app", False), ("bare viser", True)):
                r = startup_once(bare=bare)
                runs[name].append(r)
                deployed = f"; first deployed state {r['first_deployed_s']:.2f} s" if "first_deployed_s" in r else ""
                print(f"{name} run {i + 1}: server {r['http_s']:.2f} s, panel {r['panel_s']:.2f} s, control answered "
                      f"{r['control_s']:.2f} s, flat layout drawn {r['flat_drawn_s']:.2f} s -> interactive "
                      f"{r['interactive_s']:.2f} s{deployed}  (load avg {r['load_before']:.1f} -> {r['load_at_interactive']:.1f})")
        for name, rs in runs.items():
            med = {k: np.median([r[k] for r in rs]) for k in ("http_s", "panel_s", "control_s", "interactive_s")}
            print(f"{name}: median over {len(rs)} runs: server {med['http_s']:.2f} s, panel {med['panel_s']:.2f} s, "
                  f"control {med['control_s']:.2f} s, interactive {med['interactive_s']:.2f} s (target 3 s)")
        res = subprocess.run([sys.executable, __file__, "--steps"], capture_output=True, text=True)
        line = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
        if line:
            print(f"start-up steps in one process (load avg {os.getloadavg()[0]:.1f}):")
            for k, v in json.loads(line[-1]).items():
                print(f"  {k:32s} {v:6.2f} s")
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
