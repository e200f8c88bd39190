"""Linkage benchmark: reduced gradient and Hessian on real designs.

Prints case, segments, DoF, median gradient and Hessian times, the peak
memory allocated by one Hessian (tracemalloc) and the process's peak
resident set so far (RSS, cumulative over the cases). Targets (issue 4): the authors' C++ takes 0.46 ms
(gradient) and 6.3 ms (Hessian) at 312 segments, k = 10 (10.6k DoF), and
2.4 ms / 34 ms at 1,532 segments (52k DoF). A Hessian directional
derivative (``xshells.linkage.derivatives``) should cost no more than one
Hessian: columns "dH c ms" (central scheme) and "dH f ms" (forward scheme,
reusing the Hessian at the state) for the matrix; "dH·w ms" for the
directional derivative applied to a vector, matrix-free (what the design
optimization and the sparse actuation use, and what the reference code
computes), "dH·w p ms" the same along (δx, δp) applied to (w_x, w_p). Both
are timed at a new state, so they include the joint Jacobian and the rods'
gradient there. "dHf/H" and "dH·w/H": the ratios to a Hessian from
interleaved pairs (a Hessian at a new state, then the derivative there).

    python benchmarks/linkage.py [--repeats 10]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import time
import tracemalloc

from timing import median_ms

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "shared", "data", "elasticrods")
BUNDLED = os.path.join(HERE, "..", "xshells", "data", "examples")


def cases():
    """(name, design path, material spec) for the benchmark sizes."""
    found = [("manta_ray (312 seg)", os.path.join(BUNDLED, "manta_ray.obj"), ("rectangle", [10, 7]))]
    spec = os.path.join(DATA, "cases.json")
    if os.path.exists(spec):
        for c in json.load(open(spec))["cases"]:
            if c["name"] == "hourglass":
                found.append(("hourglass (1532 seg)", os.path.join(DATA, c["file"]), ("rectangle", c["material"]["params"])))
    return found


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--subdivision", type=int, default=10)
    args = ap.parse_args(argv)
    from xshells.io import read_design
    import numpy as np

    from xshells.linkage.derivatives import hessian_derivative, hessian_derivative_product
    from xshells.linkage.linkage import Linkage
    from xshells.section import Material

    print(f"{'case':<22} {'segments':>8} {'DoF':>7} {'build s':>8} {'set_vars ms':>11} {'gradient ms':>12} {'Hessian ms':>11} {'dH c ms':>8} {'dH f ms':>8} {'dH·w ms':>8} {'dH·w p ms':>9} {'dHf/H':>6} {'dH·w/H':>7} {'peak MB':>8} {'RSS MB':>7}")
    for name, path, (kind, params) in cases():
        t = time.perf_counter()
        L = Linkage(read_design(path), Material.uniform(kind, params, E=20000, nu=0.3), subdivision=args.subdivision)
        build = time.perf_counter() - t
        # The linkage caches its stencil evaluations per state (keyed on the
        # state's content), so every timed call first moves to a new state;
        # the cost of that move (set_vars) is measured alone and subtracted.
        x0 = L.get_vars()
        rng = np.random.default_rng(0)
        states = [x0 + 1e-9 * rng.standard_normal(L.num_vars) for _ in range(2)]
        flip = [0]

        def move():
            flip[0] ^= 1
            L.set_vars(states[flip[0]])

        t_move = median_ms(move, args.repeats)
        g = median_ms(lambda: (move(), L.gradient()), args.repeats) - t_move
        h = median_ms(lambda: (move(), L.hessian()), args.repeats) - t_move
        L.set_vars(x0)
        d = rng.standard_normal(L.num_vars) * 1e-2
        dhc = median_ms(lambda: (move(), hessian_derivative(L, d)), args.repeats) - t_move
        def forward():
            move()
            hessian_derivative(L, d, scheme="forward", hessian=H0)

        H0 = L.hessian()
        dhf = median_ms(forward, args.repeats) - t_move
        # the ratios that the target is about, from interleaved pairs (a Hessian after a move,
        # then the derivative from there): separate medians drift with the machine's load by ±10 %
        def ratio_to_hessian(derivative):
            ratios = []
            for _ in range(max(args.repeats, 20)):
                move()
                t = time.perf_counter()
                H = L.hessian()
                t_h = time.perf_counter() - t
                t = time.perf_counter()
                derivative(H)
                ratios.append((time.perf_counter() - t) / t_h)
            return float(np.median(ratios))

        ratio = ratio_to_hessian(lambda H: hessian_derivative(L, d, scheme="forward", hessian=H))
        w = rng.standard_normal(L.num_vars) * 1e-2
        dp = rng.standard_normal(L.num_segments) * 1e-2
        wp = np.concatenate([w, rng.standard_normal(L.num_segments) * 1e-2])
        # at a new state: includes the joint Jacobian and the rods' gradient there
        dhu = median_ms(lambda: (move(), hessian_derivative_product(L, d, None, w)), args.repeats) - t_move
        dhp = median_ms(lambda: (move(), hessian_derivative_product(L, d, dp, wp, with_rest_lengths=True)),
                        args.repeats) - t_move
        ratio_u = ratio_to_hessian(lambda H: hessian_derivative_product(L, d, None, w))
        L.set_vars(x0 + 1e-9 * rng.standard_normal(L.num_vars))  # a state never seen: nothing cached
        tracemalloc.start()
        L.hessian()
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        print(f"{name:<22} {L.num_segments:>8} {L.num_vars:>7} {build:>8.2f} {t_move:>11.2f} {g:>12.2f} {h:>11.2f} {dhc:>8.2f} {dhf:>8.2f} {dhu:>8.2f} {dhp:>9.2f} {ratio:>6.3f} {ratio_u:>7.3f} {peak:>8.1f} {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:>7.0f}")


if __name__ == "__main__":
    main()
