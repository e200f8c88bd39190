"""Fabrication benchmark (issue 21): ``xshells fabricate`` on real designs, with nesting onto bars and onto sheets.

One row per design and stock: segments, beams, rivets, the rest-length time (solve, or the design's file), the
fabrication time beyond it (tracing, nesting, every file; target ≤ 10 s for the hourglass), stock used and its
utilization, and the peak memory of the process (each design runs in a fresh one).

    python benchmarks/fabricate.py [--designs manta_ray,hourglass,...]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
EXAMPLES = os.path.join(HERE, "..", "xshells", "data", "examples")
SHARED = os.path.join(HERE, "..", "..", "shared", "data", "elasticrods")
DEFAULT = "manta_ray,hourglass,boat,neg_curvature_breather_hole,legged_pavilion,asymm_wings_pointy,wiggly_banana_optimized"


def _case(name: str) -> dict:
    if name == "manta_ray" and not os.path.isdir(SHARED):
        return {"file": os.path.join(EXAMPLES, "manta_ray.obj"), "material": {"type": "rectangle", "params": [10, 7],
                                                                              "E": 20000, "nu": 0.3}}
    with open(os.path.join(SHARED, "cases.json")) as fh:
        case = next(c for c in json.load(fh)["cases"] if c["name"] == name)
    out = {"file": os.path.join(SHARED, case.get("flat_file") or case["file"]),
           "material": case.get("material") or {"type": "rectangle", "params": [10, 7], "E": 20000, "nu": 0.3}}
    if case.get("rest_lengths"):
        out["rest_lengths"] = os.path.join(SHARED, case["rest_lengths"])
    if out["material"].get("contour_file"):
        out["material"]["contour_file"] = os.path.join(SHARED, out["material"]["contour_file"])
    return out


def one(name: str) -> None:
    """Run one design in this process; print its rows as JSON lines."""
    from xshells.deploy.case import material_from_spec
    from xshells.fabrication.run import FabricationOptions, run_fabrication

    c = _case(name)
    mat = material_from_spec(c["material"])
    with tempfile.TemporaryDirectory() as tmp:
        r = run_fabrication(c["file"], mat, out_dir=tmp, rest_lengths_path=c.get("rest_lengths"), progress=False)
        longest, width = r["bom"]["longest_beam_mm"], r["bom"]["sections"][0]["width_mm"]
        bar = 500 * math.ceil(1.05 * longest / 500)
        side = 250 * math.ceil(1.05 * longest / 250)
        for kind, opts in (("none", FabricationOptions()), (f"bars {bar:g}", FabricationOptions(stock_length=bar)),
                           (f"sheet {side:g}x{side / 2:g}", FabricationOptions(sheet=(side, side / 2)))):
            r = run_fabrication(c["file"], mat, out_dir=tmp, rest_lengths_path=c.get("rest_lengths"), options=opts,
                                progress=False)
            b = r["bom"]
            print(json.dumps({"design": name, "segments": r["segments"], "beams": b["beams"], "rivets": b["rivets"],
                              "stock": kind, "width": width, "rest_s": r["timings_s"]["rest_lengths"],
                              "fab_s": r["timings_s"]["fabrication"], "count": b["stock"]["stock_count"],
                              "util": b["stock"]["utilization"],
                              "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--designs", default=DEFAULT)
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        one(args.one)
        return 0
    names = args.designs.split(",") if os.path.isdir(SHARED) else ["manta_ray"]
    print(f"{'design':28} {'segs':>5} {'beams':>5} {'rivets':>6} {'stock':>18} {'rest s':>7} {'fab s':>6} {'used':>5} "
          f"{'util %':>6} {'peak MB':>8}")
    for name in names:
        out = subprocess.run([sys.executable, __file__, "--one", name], capture_output=True, text=True)
        if out.returncode:
            print(f"{name:28} failed: {out.stderr.strip().splitlines()[-1] if out.stderr.strip() else out.returncode}")
            continue
        for line in out.stdout.splitlines():
            r = json.loads(line)
            util = "" if r["util"] is None else f"{100 * r['util']:.1f}"
            used = "" if r["stock"] == "none" else str(r["count"])
            print(f"{name:28} {r['segments']:5d} {r['beams']:5d} {r['rivets']:6d} {r['stock']:>18} {r['rest_s']:7.2f} "
                  f"{r['fab_s']:6.2f} {used:>5} {util:>6} {r['peak_mb']:8.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
