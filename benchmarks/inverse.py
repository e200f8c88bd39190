"""Target-first design benchmark (issue 18): ``xshells inverse`` on analytic and realizable targets.

One row per target, each run in its own process (its peak memory is its own):
segments, fit mean / max (share of the surface's diagonal), coverage, whether
it meets the bar, and the time of each stage.

* analytic: the shared targets (spherical cap, hyperbolic paraboloid, barrel
  vault) at the default spacing (diagonal / 12) and angle (90°);
* realizable: a bundled design is deployed, its deployed joint quads are
  triangulated and Loop-subdivided twice (the surface ``xshells optimize``
  fits by default), and inverse design runs on that surface with the
  design's own median segment length as the spacing and its own angle.

    python benchmarks/inverse.py [--targets cap,hypar,barrel,wings,arch,breather] [--grading DEG]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
EXAMPLES = os.path.join(HERE, "..", "xshells", "data", "examples")
SHARED = os.path.join(HERE, "..", "..", "shared", "data", "targets")
ANALYTIC = {
    "cap": os.path.join(SHARED, "spherical_cap_R2000_30deg.obj"),
    "hypar": os.path.join(SHARED, "hypar_1200x1200x350.obj"),
    "barrel": os.path.join(SHARED, "barrel_vault_R1500_120deg.obj"),
}
REALIZABLE = {
    "wings": os.path.join(EXAMPLES, "asymm_wings_pointy", "case.json"),
    "arch": os.path.join(EXAMPLES, "two_bumps_architectural", "case.json"),
    "breather": os.path.join(EXAMPLES, "breather_hole", "case.json"),
}
BARS = {"analytic": (0.01, 0.03, 0.90), "realizable": (0.005, 0.02, 0.90)}


def realizable_surface(case_path: str, out_obj: str) -> dict:
    """Deploy a case and write its deployed joint-quad surface; returns the spacing and angle to use."""
    from xshells.deploy.case import load_case, material_from_spec, target_angle
    from xshells.deploy.simulate import DeployOptions, deploy, rest_length_solve
    from xshells.design.fitting import target_surface
    from xshells.io import read_design, read_rest_lengths
    from xshells.linkage.linkage import Linkage

    case = load_case(case_path)
    d = read_design(case.design_path)
    p = read_rest_lengths(case.rest_lengths_path, d.num_segments) if case.rest_lengths_path else None
    L = Linkage(d, material_from_spec(case.material), subdivision=case.subdivision, rest_lengths=p)
    if p is None:
        rest_length_solve(L)
    angle = target_angle(case, L)
    deploy(L, angle, DeployOptions(steps=case.steps))
    V, F = target_surface(L)
    with open(out_obj, "w") as fh:
        fh.writelines(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in V)
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F)
    seg = float(np.median(np.linalg.norm(d.vertices[d.edges[:, 0]] - d.vertices[d.edges[:, 1]], axis=1)))
    return {"spacing": seg, "angle": float(np.degrees(angle)), "material": case.material}


def one(name: str, tmp: str, grading: float = 0.0, beams: str = "auto") -> dict:
    """Runs in a child process."""
    from xshells.deploy.case import DEFAULT_MATERIAL
    from xshells.inverse.run import InverseOptions, run_inverse

    if name in ANALYTIC:
        surface, kind, opts, material = ANALYTIC[name], "analytic", InverseOptions(grading=grading, beams=beams), dict(DEFAULT_MATERIAL)
    else:
        surface = os.path.join(tmp, f"{name}_target.obj")
        info = realizable_surface(REALIZABLE[name], surface)
        kind, material = "realizable", info["material"]
        opts = InverseOptions(spacing=info["spacing"], angle=info["angle"], grading=grading, beams=beams)
    r = run_inverse(surface, os.path.join(tmp, name), material, opts, progress=False)
    bar = BARS[kind]
    ok = r.get("status") in ("complete", "missed") and r.get("fit_mean", 1) <= bar[0] and r.get("fit_max", 1) <= bar[1] \
        and r.get("coverage", 0) >= bar[2]
    return {"target": name, "kind": kind, "segments": r["segments"], "fit_mean": r.get("fit_mean", float("nan")),
            "fit_max": r.get("fit_max", float("nan")), "coverage": r.get("coverage", float("nan")), "meets_bar": ok,
            "valid": r.get("valid", False), "tracked_rms": r.get("tracked_rms", float("nan")),
            "times": r["stage_times_s"], "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--targets", default="cap,hypar,barrel,wings,arch,breather")
    ap.add_argument("--grading", type=float, default=0.0, help="the automatic net's grading, degrees (default 0)")
    ap.add_argument("--beams", default="auto", choices=("auto", "even", "geodesic"), help="the automatic net's beams (default auto)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        with tempfile.TemporaryDirectory() as tmp:
            print(json.dumps(one(args.child, tmp, args.grading, args.beams)))
        return 0
    rows = []
    for name in args.targets.split(","):
        if name in ANALYTIC and not os.path.exists(ANALYTIC[name]):
            print(f"{name}: skipped (shared targets not found)", file=sys.stderr)
            continue
        p = subprocess.run([sys.executable, __file__, "--child", name, "--grading", str(args.grading), "--beams", args.beams], capture_output=True,
                           text=True)
        if p.returncode:
            print(f"{name}: failed: {p.stderr.strip().splitlines()[-1] if p.stderr.strip() else p.returncode}", file=sys.stderr)
            continue
        rows.append(json.loads(p.stdout.strip().splitlines()[-1]))
    head = (f"{'target':10} {'kind':10} {'segs':>5} {'fit mean':>9} {'fit max':>8} {'cover':>6} {'bar':>4} {'valid':>5} "
            f"{'net':>5} {'deploy':>6} {'hold':>5} {'optim':>6} {'verify':>6} {'total s':>7} {'peak MB':>7}")
    print(head)
    for r in rows:
        t = r["times"]
        print(f"{r['target']:10} {r['kind']:10} {r['segments']:5d} {100 * r['fit_mean']:8.2f}% {100 * r['fit_max']:7.2f}% "
              f"{100 * r['coverage']:5.1f}% {'yes' if r['meets_bar'] else 'no':>4} {'yes' if r['valid'] else 'no':>5} "
              f"{t.get('net_s', 0):5.1f} {t.get('deploy_s', 0):6.1f} {t.get('hold_s', 0):5.1f} {t.get('optimize_s', 0):6.1f} "
              f"{t.get('verify_s', 0):6.1f} {t.get('total_s', 0):7.1f} {r['peak_mb']:7.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
