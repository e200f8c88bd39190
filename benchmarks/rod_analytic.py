"""Analytic NumPy rod stencil kernels against jitted JAX automatic differentiation.

Prints a table: kernel, N, median time of the analytic kernel and of the JAX
reference (:mod:`xshells.rod.autodiff`, jitted, after warm-up). Random bent
stencils with the source frame at the current frame (as the solver calls
them). Targets at N = 2808: vertex gradient <= 1 ms, vertex Hessian <= 6 ms.

    python benchmarks/rod_analytic.py [--repeats 50] [--sizes 2808 10000]
"""
from __future__ import annotations

import argparse

import numpy as np
from rod_kernels import median_ms  # same timing helper (this folder is on sys.path)


def random_stencils(n: int, seed: int = 0):
    """Vertex stencils (q (13, n), prm (23, n)) at their source frames, and edge stencils (7, n)."""
    rng = np.random.default_rng(seed)
    unit = lambda v: v / np.linalg.norm(v, axis=0)  # noqa: E731
    t0 = unit(rng.standard_normal((3, n)))
    t1 = unit(t0 + 0.5 * rng.standard_normal((3, n)))
    x1 = rng.standard_normal((3, n))
    l0, l1 = 0.5 + rng.random(n), 0.5 + rng.random(n)
    x0, x2 = x1 - l0 * t0, x1 + l1 * t1
    q = np.concatenate([x0, x1, x2, rng.uniform(-np.pi, np.pi, (2, n)), 0.5 + rng.random((2, n))])
    e0, e1 = x1 - x0, x2 - x1
    prm = np.empty((23, n))
    for k, e in enumerate((e0, e1)):
        t = unit(e)
        prm[6 * k:6 * k + 3] = t
        prm[6 * k + 3:6 * k + 6] = unit(np.cross(t, rng.standard_normal((3, n)), axis=0))
    prm[12:16] = 1.0 + rng.random((4, n))
    prm[16] = 1.0 + rng.random(n)
    prm[17:21] = 0.3 * rng.standard_normal((4, n))
    prm[21] = 0.1 * rng.standard_normal(n)
    prm[22] = 0.0
    edge = np.concatenate([x0, x1, l0[None] * (1 + 0.1 * rng.random(n))])
    return q, prm, edge


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--sizes", type=int, nargs="+", default=[2808])
    args = parser.parse_args(argv)

    from xshells.rod import analytic, autodiff

    print(f"{'kernel':<28} {'N':>7} {'median ms':>10} {'vs JAX ms':>10}")
    for n in args.sizes:
        q, prm, edge = random_stencils(n)
        ks = np.full(n, 100.0)
        rows = []
        for variant in ("2008", "2010"):
            rows.append((f"vertex_gradient {variant}", lambda v=variant: analytic.vertex_gradient(q, prm, v),
                         lambda v=variant: autodiff.vertex_gradient(q, prm, v)))
            rows.append((f"energy_and_gradient {variant}",
                         lambda v=variant: analytic.vertex_energy_and_gradient(q, prm, v), None))
            rows.append((f"vertex_hessian {variant}", lambda v=variant: analytic.vertex_hessian(q, prm, v),
                         lambda v=variant: autodiff.vertex_hessian(q, prm, v)))
        rows.append(("edge_energy_gradient_hessian", lambda: analytic.edge_energy_gradient_hessian(edge, ks), None))
        # all analytic timings first: JAX's worker threads would share the CPU with them
        fast_ms = [median_ms(fast, args.repeats) for _, fast, _ in rows]
        ref_ms = [median_ms(ref, args.repeats) if ref is not None else None for _, _, ref in rows]
        for (name, _, _), t, tj in zip(rows, fast_ms, ref_ms):
            tj = f"{tj:10.2f}" if tj is not None else f"{'-':>10}"
            print(f"{name:<28} {n:>7} {t:10.2f} {tj}")

if __name__ == "__main__":
    main()
