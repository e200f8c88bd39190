"""Issue 18's check on a realizable target, designed whole.

Darth Vader (bundled) is deployed, its deployed joint quads triangulated and Loop-subdivided
(:mod:`xshells.inverse.realizable`), and designed with its own median segment length as the spacing and its own
angle, as ``benchmarks/inverse.py`` runs it, on the net that the default command (``auto``) keeps for it: the even
net about the bisector that :func:`~xshells.inverse.run.even_bisector` chooses (the same design, 266 segments, as
the benchmark's). The bar is the issue's for realizable targets: fit mean ≤ 0.5 % and max ≤ 2 % of the surface's
diagonal, coverage ≥ 90 %, and the design complete and valid (flat state planar, no joint folded, no beams
overlapping, stable at its angle).

Its first design misses the bar on its maximum (0.547 % / 2.63 %), so it is designed again with a heavier fit
weight (step 11 of docs/inverse.md's Method): 16β, which meets the bar closely (0.292 % / 1.41 %, coverage
100 %, measured 2026-12-07 with NumPy 2.4.6 and SciPy 1.17.1), so 4β is not run. It takes about four minutes
(a deployment from flat after every stage), so the other targets, the analytic ones among them, are measured
by the benchmark (the bundled cap is designed whole, at a coarser spacing, in ``test_inverse_run.py``). The
method's outcome can move with rounding-level changes (docs/inverse.md, Results).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from data_paths import EXAMPLES
from xshells.inverse.realizable import realizable_target
from xshells.inverse.run import InverseOptions, run_inverse

DARTH_VADER = EXAMPLES / "darth_vader" / "case.json"


def _figures(r: dict) -> str:
    return (f"{r.get('status')}: fit mean {100 * r.get('fit_mean', np.nan):.3f} %, max "
            f"{100 * r.get('fit_max', np.nan):.2f} %, coverage {100 * r.get('coverage', np.nan):.1f} %")


def _within(r: dict, mean: float, top: float, coverage: float) -> None:
    assert r["status"] == "complete" and r["valid"] and r["reached"], _figures(r)
    assert r["fit_mean"] <= mean and r["fit_max"] <= top and r["coverage"] >= coverage, _figures(r)
    assert r["flat_planarity"] <= 1e-6 and not r["folded"] and not r["overlap"], _figures(r)
    assert r["min_eigenvalue_at_fixed_angle"] >= 0.0, _figures(r)


def test_darth_vaders_deployed_surface_is_reached_within_the_realizable_bar(tmp_path):
    from xshells.inverse.run import even_bisector
    from xshells.inverse.surface import load_target

    info = realizable_target(str(DARTH_VADER), str(tmp_path / "target.obj"))
    options = InverseOptions(spacing=info["spacing"], angle=info["angle"])
    # auto's even net, the design that auto keeps here, alone: the fanned candidate and the fan screen beside it
    # would double the test's time in CI (5 minutes of the suite's 17 with them)
    orientation, _ = even_bisector(load_target(str(tmp_path / "target.obj")), options)
    r = run_inverse(str(tmp_path / "target.obj"), str(tmp_path / "out"), info["material"],
                    replace(options, beams="even", orientation=orientation), progress=False)
    _within(r, 0.005, 0.02, 0.90)
    # the path this test is here for: the first design misses on its maximum (0.547 % / 2.63 %), the 16β design
    # meets the bar closely (0.292 % / 1.41 %), and 4β is not run
    h = r["heavier"]
    assert h["kept"] == "16" and [d["status"] for d in h["designs"]] == ["not run", "complete"], h
