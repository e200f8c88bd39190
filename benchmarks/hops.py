"""Grasshopper Hops benchmark (issue 23): the Deploy component against ``xshells deploy`` on the same lines.

Rows: ``xshells deploy`` as a user runs it (a fresh process, imports included), the Hops Deploy component's
first solve through HTTP on a warm server (lines sent as Grasshopper sends them), and a re-solve of the same
inputs (answered from the cache). Targets: the component within 10 % of ``xshells deploy``; the cached
re-solve ≤ 50 ms. Peak memory: of the server's process (this one) and of the command's.

    python benchmarks/hops.py [--design manta_ray] [--angle 93] [--steps 40] [--subdivision 8]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request

HERE = os.path.dirname(os.path.abspath(__file__))
EXAMPLES = os.path.join(HERE, "..", "xshells", "data", "examples")


def _payload(design_path: str, angle: float, steps: int, subdivision: int) -> dict:
    import rhino3dm

    from xshells.io import read_design

    d = read_design(design_path)
    V = d.vertices
    items = [{"type": "Rhino.Geometry.LineCurve",
              "data": json.dumps(rhino3dm.LineCurve(rhino3dm.Point3d(*map(float, V[a])),
                                                    rhino3dm.Point3d(*map(float, V[b]))).Encode())}
             for a, b in d.edges]
    num = lambda t, v: {"InnerTree": {"{0}": [{"type": t, "data": json.dumps(v)}]}}  # noqa: E731
    return {"pointer": "/deploy", "modelunits": "Millimeters", "absolutetolerance": 1e-6,
            "values": [{"ParamName": "Lines", "InnerTree": {"{0}": items}},
                       {"ParamName": "Angle", **num("System.Double", angle)},
                       {"ParamName": "Steps", **num("System.Int32", steps)},
                       {"ParamName": "Subdivision", **num("System.Int32", subdivision)}], "segments": len(d.edges)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--design", default="manta_ray")
    ap.add_argument("--angle", type=float, default=93.0)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--subdivision", type=int, default=8)
    args = ap.parse_args()
    path = os.path.join(EXAMPLES, f"{args.design}.obj")

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        p = subprocess.run([sys.executable, "-m", "xshells.cli", "deploy", path, "--angle", str(args.angle),
                            "--steps", str(args.steps), "--subdivision", str(args.subdivision), "--out",
                            os.path.join(tmp, "cli"), "--no-progress"], capture_output=True, text=True)
        cli_s = time.perf_counter() - t
        if p.returncode:
            print(p.stderr.strip().splitlines()[-1], file=sys.stderr)
            return 1
        child_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024

        from xshells.rhino.components import components
        from xshells.rhino.hops import HopsService, make_server

        service = HopsService(components(), log=lambda m: None)
        httpd = make_server(service, "127.0.0.1", 0)
        threading.Thread(target=httpd.serve_forever, daemon=True).start()
        url = f"http://127.0.0.1:{httpd.server_address[1]}/solve"
        payload = _payload(path, args.angle, args.steps, args.subdivision)
        segments = payload.pop("segments")
        body = json.dumps(payload).encode()

        def post():
            req = urllib.request.Request(url, data=body, method="POST", headers={"Content-Type": "application/json"})
            t0 = time.perf_counter()
            with urllib.request.urlopen(req) as r:
                reply = json.loads(r.read())
            return time.perf_counter() - t0, reply

        first_s, reply = post()
        if reply["errors"]:
            print(reply["errors"][0], file=sys.stderr)
            return 1
        cached = [post()[0] for _ in range(5)]
        httpd.shutdown()
        server_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    rows.append(("xshells deploy (fresh process)", cli_s, child_mb))
    rows.append(("Hops Deploy, first solve", first_s, server_mb))
    rows.append(("Hops Deploy, cached (median of 5)", sorted(cached)[2], server_mb))
    print(f"{'case':12} {'segs':>5} {'run':36} {'time s':>8} {'peak MB':>8}")
    for name, s, mb in rows:
        print(f"{args.design:12} {segments:5d} {name:36} {s:8.3f} {mb:8.0f}")
    print(f"Hops / xshells deploy: {first_s / cli_s:.2f} (target ≤ 1.10); cached: {1000 * sorted(cached)[2]:.1f} ms "
          f"(target ≤ 50 ms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
