"""Design-optimization benchmark: the wiggly banana before optimization (paper Figs. 6, 7).

Runs Newton-CG and the BFGS baseline on the bundled case
``wiggly_banana_preopt`` (264 segments, k = 10, 8,970 DoF per state) with
the default weights, and evaluates the paper's own optimized rest lengths
(``wiggly_banana_5``, from ``../shared``) in the same objective. Prints, per
run: iterations, time, time per iteration, J, how many times lower the flat
and deployed energies are than before, the fitting term, the flat state's
planarity (max |z| / span), and peak memory; then the iteration at which
each method first reaches given fractions of the initial J (Fig. 7).

Targets (issue 6): deployed energy > 5× lower and flat energy > 7× lower,
the flat state planar to 1e-6 of the span, ≤ 98 s, Newton-CG reaching a
given J in ≥ 3× fewer iterations than BFGS.

    python benchmarks/design.py [--max-iters 25] [--bfgs-iters 75]
"""
from __future__ import annotations

import argparse
import os
import resource
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
CASE = os.path.join(HERE, "..", "xshells", "data", "examples", "wiggly_banana_preopt", "case.json")
PAPER = os.path.join(HERE, "..", "..", "shared", "data", "elasticrods", "python", "examples", "optimized", "data", "wiggly_banana_5")


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def flatness(problem) -> float:
    P = problem.flat.L.joint_positions()
    span = float(np.ptp(P, axis=0).max())
    return float(np.abs(P[:, 2] - P[:, 2].mean()).max() / span)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-iters", type=int, default=25)
    ap.add_argument("--bfgs-iters", type=int, default=75)
    args = ap.parse_args(argv)
    from xshells.design.objective import DesignWeights
    from xshells.design.optimize import OptimizeOptions, optimize
    from xshells.design.run import build_problem

    rows, histories = [], {}
    for method, iters in (("newton-cg", args.max_iters), ("bfgs", args.bfgs_iters)):
        t0 = time.perf_counter()
        problem, _ = build_problem(CASE, weights=DesignWeights())
        build = time.perf_counter() - t0
        q0 = np.ones(len(problem.p0))
        e2, e3 = problem.flat.L.energy(), problem.deployed.L.energy()
        res = optimize(problem, OptimizeOptions(method=method, max_iterations=iters))
        t = problem.terms(res.q)
        rows.append((method, problem.flat.L.num_vars, res.iterations, res.time_s, res.time_s / max(res.iterations, 1),
                     t["J"], e2 / problem.flat.L.energy(), e3 / problem.deployed.L.energy(), t["fit"], flatness(problem),
                     build, peak_mb()))
        histories[method] = [r.J for r in res.history]
        print(f"{method}: {res.message}", flush=True)
        if method == "newton-cg" and os.path.isdir(PAPER):
            from xshells.io import read_design, read_rest_lengths

            d = read_design(os.path.join(PAPER, "flat_opt.msh"))
            p_paper = read_rest_lengths(os.path.join(PAPER, "design_parameters.txt"), d.num_segments)
            ours_deployed = problem.deployed.L.joint_positions()
            ours_q = res.q.copy()
            # continuation along the straight line to the paper's rest lengths (a jump to them stalls the Newton solves)
            fresh, _ = build_problem(CASE, weights=DesignWeights())
            for s in np.linspace(0.1, 1.0, 10):
                tp = fresh.terms(q0 + s * (p_paper / fresh.p0 - 1))
            diag = float(np.linalg.norm(np.ptp(fresh.deployed.L.joint_positions(), axis=0)))
            rows.append(("paper (wiggly_banana_5)", fresh.flat.L.num_vars, 0, 0.0, 0.0, tp["J"], e2 / fresh.flat.L.energy(),
                         e3 / fresh.deployed.L.energy(), tp["fit"], flatness(fresh), 0.0, peak_mb()))
            dev = np.linalg.norm(ours_deployed - fresh.deployed.L.joint_positions(), axis=1).max() / diag
            dq = np.abs(ours_q * fresh.p0 / p_paper - 1)
            print(f"ours vs paper: deployed joints differ by at most {dev:.2%} of the bounding-box diagonal; "
                  f"rest lengths differ by {np.median(dq):.1%} (median), {dq.max():.1%} (max)", flush=True)

    print(f"\n{'case':<24} {'DoF':>6} {'iters':>5} {'time s':>7} {'s/iter':>6} {'J':>8} {'flat ×':>7} {'deployed ×':>10} "
          f"{'fit':>9} {'max|z|/span':>11} {'setup s':>7} {'peak MB':>7}")
    for r in rows:
        print(f"{r[0]:<24} {r[1]:>6} {r[2]:>5} {r[3]:>7.1f} {r[4]:>6.2f} {r[5]:>8.4f} {r[6]:>7.2f} {r[7]:>10.2f} "
              f"{r[8]:>9.2e} {r[9]:>11.1e} {r[10]:>7.1f} {r[11]:>7.0f}")
    J0 = histories["newton-cg"][0]
    print("\nfirst iteration reaching J ≤ fraction × J₀ (Fig. 7):")
    print(f"{'fraction':>8} {'Newton-CG':>10} {'BFGS':>6} {'ratio':>6}")
    for frac in (0.8, 0.6, 0.4, 0.3, 0.25):
        its = [next((i for i, J in enumerate(histories[m]) if J <= frac * J0), None) for m in ("newton-cg", "bfgs")]
        ratio = f"{its[1] / its[0]:.1f}" if None not in its and its[0] else "-"
        print(f"{frac:>8} {str(its[0]):>10} {str(its[1]):>6} {ratio:>6}")


if __name__ == "__main__":
    main()
