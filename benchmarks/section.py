"""Benchmark the cross-section solver: time, peak memory and torsion-constant error.

    python benchmarks/section.py [--repeat 3]

Each row is one full `analyse` (mesh, adaptive refinement to a 1e-5 relative
change in J, properties) with the cache cleared. The J error is against a
closed form where one exists, else against a reference solve refined to a
1e-7 change (marked "ref").

Targets (issue 3): rectangle or ellipse to 1e-4 in <= 0.2 s; a custom
contour of about 100 points in <= 1 s.
"""
from __future__ import annotations

import argparse
import time
import tracemalloc
from pathlib import Path

import numpy as np

import xshells
from xshells.section import profiles, properties
from xshells.section.io import load_contour

REFERENCE_RTOL = 1e-7
EXAMPLES = Path(xshells.__file__).parent / "data" / "examples" / "cross_sections"


def rectangle_J(b: float, t: float, terms: int = 200) -> float:
    """Saint-Venant series for a b x t rectangle (validation.md §5)."""
    long, short = max(b, t), min(b, t)
    n = np.arange(1, 2 * terms, 2)
    r = long / short
    return (1 - 192 / (np.pi ** 5 * r) * np.sum(np.tanh(n * np.pi * r / 2) / n ** 5)) / 3 * long * short ** 3


def ellipse_J(a: float, b: float) -> float:
    return np.pi * a ** 3 * b ** 3 / (a ** 2 + b ** 2)


def wavy_contour(n: int = 100) -> profiles.Profile:
    """A custom profile of ``n`` points: a five-lobed blob with a round canal."""
    theta = 2 * np.pi * np.arange(n) / n
    radius = 10 * (1 + 0.25 * np.cos(5 * theta))
    outer = np.column_stack((radius * np.cos(theta), radius * np.sin(theta)))
    return profiles.polygon(outer, name=f"contour {n} pts")


def canal_contour(n_outer: int = 80, n_hole: int = 20) -> profiles.Profile:
    """A rounded-square extrusion of ``n_outer`` points with a cable canal of ``n_hole`` points."""
    theta = 2 * np.pi * np.arange(n_outer) / n_outer
    c, s = np.cos(theta), np.sin(theta)
    outer = 10 * np.column_stack((np.sign(c) * np.abs(c) ** 0.5, np.sign(s) * np.abs(s) ** 0.5))
    phi = -2 * np.pi * np.arange(n_hole) / n_hole
    hole = np.column_stack((3 + 2 * np.cos(phi), 2 * np.sin(phi)))
    return profiles.polygon(outer, holes=[hole], name=f"canal {n_outer}+{n_hole} pts")


CASES = [
    ("rectangle 2x1", lambda: profiles.rectangle(2, 1), rectangle_J(2, 1)),
    ("rectangle 12x8", lambda: profiles.rectangle(12, 8), rectangle_J(12, 8)),
    ("rectangle 15x3", lambda: profiles.rectangle(15, 3), rectangle_J(15, 3)),
    ("rectangle 0.02x0.002", lambda: profiles.rectangle(0.02, 0.002), rectangle_J(0.02, 0.002)),
    ("ellipse 2x1", lambda: profiles.ellipse(2, 1), ellipse_J(2, 1)),
    ("ellipse 0.02x0.002", lambda: profiles.ellipse(0.02, 0.002), ellipse_J(0.02, 0.002)),
    ("circle r=1", lambda: profiles.ellipse(1, 1), np.pi / 2),
    ("L 20x20x2x2", lambda: profiles.l_angle(20, 20, 2, 2), None),
    ("I 10,5,10,5,15,5", lambda: profiles.i_beam(10, 5, 10, 5, 15, 5), None),
    ("+ 20x20x2x2", lambda: profiles.plus(20, 20, 2, 2), None),
    ("contour 100 pts", wavy_contour, None),
    ("canal 80+20 pts", canal_contour, None),
    ("custom_A.obj", lambda: load_contour(EXAMPLES / "custom_A.obj"), None),
    ("custom_profile.msh", lambda: load_contour(EXAMPLES / "custom_profile.msh"), None),
]


def timed_analysis(profile: profiles.Profile, repeat: int):
    """Best wall time of ``repeat`` uncached analyses, and peak traced memory of one."""
    times = []
    for _ in range(repeat):
        properties._CACHE.clear()
        start = time.perf_counter()
        section = properties.analyse(profile)
        times.append(time.perf_counter() - start)
    properties._CACHE.clear()
    tracemalloc.start()
    properties.analyse(profile)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return section, min(times), peak


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    properties.analyse(profiles.rectangle(1, 1))  # imports and first-call costs out of the timings
    header = f"{'case':22s} {'boundary pts':>12s} {'triangles':>9s} {'P2 dofs':>8s} {'levels':>6s} " \
             f"{'time [s]':>9s} {'peak MB':>8s} {'J':>14s} {'J rel. error':>14s}"
    print(header)
    print("-" * len(header))
    for name, build, exact in CASES:
        profile = build()
        section, seconds, peak = timed_analysis(profile, args.repeat)
        J = section.torsion_constant
        if exact is None:
            properties._CACHE.clear()
            exact = properties.analyse(profile, rtol=REFERENCE_RTOL).torsion_constant
            label = " ref"
        else:
            label = ""
        solution = section.torsion.solution
        points = sum(len(loop) for loop in profile.loops)
        print(f"{name:22s} {points:12d} {solution.n_triangles:9d} {solution.n_dofs:8d} "
              f"{len(section.torsion.history):6d} {seconds:9.3f} {peak / 2 ** 20:8.1f} {J:14.8g} "
              f"{(J - exact) / exact:+11.2e}{label}")


if __name__ == "__main__":
    main()
