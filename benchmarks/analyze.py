"""Structural analysis benchmark (issue 20): deploy, then self-weight on 8 supports with the critical load factor.

One row per design: segments, the deployment's time, the analysis's time (loading, critical load factor),
their ratio (target: analysis ≤ 2 × deployment for the manta ray), peak memory, and the figures.

    python benchmarks/analyze.py [--designs manta_ray]
"""
from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
EXAMPLES = os.path.join(HERE, "..", "xshells", "data", "examples")
DESIGNS = {"manta_ray": (os.path.join(EXAMPLES, "manta_ray.obj"), 93.0, 8)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--designs", default="manta_ray")
    args = ap.parse_args()
    from xshells.analysis.run import run_analysis
    from xshells.analysis.static import Load
    from xshells.deploy.case import material_from_spec

    print(f"{'design':12} {'segs':>5} {'load N':>8} {'deploy s':>9} {'load s':>7} {'crit s':>7} {'ratio':>6} {'max disp':>9} "
          f"{'max util':>8} {'crit factor':>11} {'balance':>8} {'peak MB':>8}")
    for name in args.designs.split(","):
        path, angle, nsup = DESIGNS[name]
        spec = {"type": "rectangle", "params": [10.0, 7.0], "E": 20000.0, "nu": 0.3, "density": 1.9e-9}
        with tempfile.TemporaryDirectory() as tmp:
            import numpy as np

            r = run_analysis(path, material_from_spec(spec), out_dir=tmp, supports_spec=("lowest", nsup),
                             loads=[Load("self-weight")], strength=240.0, subdivision=8,
                             target_angle=np.radians(angle), steps=40, name=name, progress=False)
        t = r["timings_s"]
        crit = r["critical_load_factor"]
        print(f"{name:12} {r['segments']:5d} {abs(r['total_load'][2]):8.3g} {t['deploy']:9.1f} {t['load']:7.1f} {t['critical']:7.1f} "
              f"{(t['load'] + t['critical']) / t['deploy']:6.2f} {r['max_displacement']:9.3g} {r['max_utilization']:8.3g} "
              f"{(f'{crit:.4g}' if crit else 'none ≤ ' + format(r['critical_searched_to'], '.3g')):>11} "
              f"{r['equilibrium_error']:8.1e} {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:8.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
