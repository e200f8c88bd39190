"""Where a deployment's time goes, per Newton iteration.

Runs the deploy phase of one ``cases.json`` design (after its rest-length
solve, as ``xshells deploy`` does) with timers around the solver's parts and
prints, per part: calls, total seconds, milliseconds per Newton iteration
and share of the deploy phase. Times are exclusive (a part called inside
another counts once, in the inner one):

- gradient: rod stencil energies+gradients and the joint map (``Linkage.gradient``,
  and the energy/gradient evaluation a line-search trial triggers);
- hessian: the Hessian blocks and their assembly (``Linkage.hessian``, ``hessian_lower``);
- factorization / solve: CHOLMOD (``SparseCholesky``);
- eigen-solves: ARPACK and dense LAPACK (``eigsh``, ``eigh``);
- set_vars: the joint map to rod variables for a trial point;
- frames: ``update_source_frame`` after each accepted step;
- sparse bookkeeping: free-variable submatrix, pattern sums (``_Workspace``);
- the rest: Newton's own arithmetic, predictor bookkeeping, step records.

    python benchmarks/deploy_profile.py [--case manta_ray] [--steps N]
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from deploy import DATA  # noqa: E402

_stack: list = []
TOTALS: dict = {}


def timed(part: str, fn):
    """``fn`` with its exclusive time added to ``TOTALS[part]``."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        _stack.append(0.0)
        try:
            return fn(*args, **kwargs)
        finally:
            inner = _stack.pop()
            dt = time.perf_counter() - t
            calls, total = TOTALS.get(part, (0, 0.0))
            TOTALS[part] = (calls + 1, total + dt - inner)
            if _stack:
                _stack[-1] += dt

    return wrapper


def instrument() -> None:
    import scipy.linalg
    import scipy.sparse.linalg

    import xshells.solve.newton as newton
    from xshells.linkage.linkage import Linkage
    from xshells.solve.cholesky import SparseCholesky

    Linkage.gradient = timed("gradient", Linkage.gradient)
    Linkage._rod_terms = timed("gradient", Linkage._rod_terms)
    if hasattr(Linkage, "_rod_energies"):  # a line-search trial's energies alone
        Linkage._rod_energies = timed("gradient", Linkage._rod_energies)
    Linkage.hessian = timed("hessian", Linkage.hessian)
    Linkage.hessian_lower = timed("hessian", Linkage.hessian_lower)
    Linkage.set_vars = timed("set_vars", Linkage.set_vars)
    Linkage.update_source_frame = timed("frames", Linkage.update_source_frame)
    SparseCholesky.factorize = timed("factorization", SparseCholesky.factorize)
    SparseCholesky.solve = timed("solve", SparseCholesky.solve)
    newton._Workspace.free_part = timed("sparse bookkeeping", newton._Workspace.free_part)
    newton._Workspace.combine = timed("sparse bookkeeping", newton._Workspace.combine)
    scipy.sparse.linalg.eigsh = timed("eigen-solves", scipy.sparse.linalg.eigsh)
    newton.spla.eigsh = scipy.sparse.linalg.eigsh
    scipy.linalg.eigh = timed("eigen-solves", scipy.linalg.eigh)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="manta_ray")
    ap.add_argument("--steps", type=int, help="override the case's steps")
    args = ap.parse_args(argv)
    import numpy as np

    from xshells.deploy.case import material_from_spec
    from xshells.deploy.simulate import DeployOptions, deploy, rest_length_solve
    from xshells.io import read_design
    from xshells.linkage.linkage import Linkage

    cases = {c["name"]: c for c in json.load(open(os.path.join(DATA, "cases.json")))["cases"]}
    case = cases[args.case]
    design = read_design(os.path.join(DATA, case.get("flat_file") or case["file"]))
    material = dict(case["material"])
    if material.get("contour_file"):
        material["contour_file"] = os.path.join(DATA, material["contour_file"])
    L = Linkage(design, material_from_spec(material), subdivision=case.get("subdivision", 10))
    rest_length_solve(L)
    angle = np.radians(case["angle_deg"]) if case.get("angle_deg") is not None else \
        L.average_angle() + np.radians(case.get("open_by_deg") or 60.0)
    steps = args.steps or case.get("steps") or 40
    instrument()
    t = time.perf_counter()
    res = deploy(L, angle, DeployOptions(steps=steps))
    total = time.perf_counter() - t
    it = max(res.newton_iterations, 1)
    print(f"{args.case}: {L.num_segments} segments, {L.num_vars} DoF, {steps} steps, {res.newton_iterations} Newton iterations, "
          f"deploy {total:.2f} s ({1e3 * total / it:.1f} ms per iteration); {res.message}")
    print(f"{'part':<20} {'calls':>6} {'total s':>8} {'ms/iter':>8} {'share':>6}")
    accounted = 0.0
    for part, (calls, tot) in sorted(TOTALS.items(), key=lambda kv: -kv[1][1]):
        accounted += tot
        print(f"{part:<20} {calls:>6} {tot:>8.3f} {1e3 * tot / it:>8.2f} {100 * tot / total:>5.1f}%")
    rest = total - accounted
    print(f"{'the rest':<20} {'':>6} {rest:>8.3f} {1e3 * rest / it:>8.2f} {100 * rest / total:>5.1f}%")


if __name__ == "__main__":
    main()
