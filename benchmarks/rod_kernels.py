"""Rod kernel benchmark: energy, gradient and assembled sparse Hessian.

Prints a table: case, DoF, median time of each operation and peak memory of
a Hessian assembly; then the JIT start-up time cold (empty persistent cache)
and warm. Targets (issue 2): the authors' C++ takes 0.46 ms (gradient) and
6.3 ms (Hessian) at 312 segments × 10 edges, 2.4 ms and 34 ms at 1,532.

    python benchmarks/rod_kernels.py [--repeats 20]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import tracemalloc

import numpy as np

from timing import median_ms


def make_rods(num_rods: int, edges: int = 10, seed: int = 0):
    from xshells.rod import ElasticRods

    rng = np.random.default_rng(seed)
    s = np.linspace(0, 100.0, edges + 1)
    rods = []
    for r in range(num_rods):
        pts = np.stack([s, 5 * np.sin(s / 30 + r), 3 * np.cos(s / 20 + 2 * r)], 1) + rng.standard_normal((edges + 1, 3))
        rods.append(pts + 200.0 * np.array([r % 40, r // 40, 0]))
    E = num_rods * edges
    obj = ElasticRods(
        rods,
        stretching=1.4e6,
        bending=np.tile([5.8e6, 1.2e7], (E, 1)),
        twisting=5e6,
        rest_lengths=10.0 * (1 + 0.05 * rng.random(E)),
        thetas=0.1 * rng.standard_normal(E),
    )
    obj.update_source_frame()
    return obj


def peak_mb(fn) -> float:
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 2**20


STARTUP = r"""
import time; t = time.perf_counter()
import sys; sys.path.insert(0, {here!r})
from rod_kernels import make_rods
rods = make_rods(312)
rods.energy(); rods.gradient(); rods.hessian()
print(time.perf_counter() - t)
"""


def startup_seconds(cache: str) -> float:
    env = dict(os.environ, XSHELLS_JAX_CACHE=cache)
    code = STARTUP.format(here=os.path.dirname(os.path.abspath(__file__)))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--no-startup", action="store_true", help="skip the cold/warm start-up measurement")
    args = ap.parse_args(argv)
    print(f"{'case':<22} {'DoF':>7} {'energy ms':>10} {'gradient ms':>12} {'Hessian ms':>11} {'peak MB':>8}")
    for num_rods in (312, 1532):
        rods = make_rods(num_rods)
        e = median_ms(rods.energy, args.repeats)
        g = median_ms(rods.gradient, args.repeats)
        h = median_ms(rods.hessian, args.repeats)
        mem = peak_mb(rods.hessian)
        print(f"{f'{num_rods} rods x 10 edges':<22} {rods.num_vars:>7} {e:>10.2f} {g:>12.2f} {h:>11.2f} {mem:>8.1f}")
    if not args.no_startup:
        with tempfile.TemporaryDirectory() as cache:
            cold = startup_seconds(cache)
            warm = startup_seconds(cache)
        print(f"start-up to first energy+gradient+Hessian (312 rods, incl. imports): cold {cold:.1f} s, warm cache {warm:.1f} s")


if __name__ == "__main__":
    main()
