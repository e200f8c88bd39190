"""Realizable targets: the surface a design deploys to, as issue 18's checks build it.

A design is deployed as its case says; its deployed joint quads are
triangulated and Loop-subdivided twice (the surface ``xshells optimize``
fits by default, :func:`xshells.design.fitting.target_surface`). An X-shell
reaches that surface by construction, so inverse design run on it, with the
design's own median segment length as the spacing and its own deployed angle,
measures the method rather than the physics. ``benchmarks/inverse.py`` and
the tests (``test_inverse_realizable.py``, ``test_inverse_targets.py``) build
their targets here.
"""
from __future__ import annotations

import json
import os

import numpy as np


def realizable_target(case, out_obj: str) -> dict:
    """Deploy a case and write its deployed joint-quad surface to ``out_obj`` (OBJ, 9 significant figures).

    Parameters
    ----------
    case : str or dict
        A case file's path, or a case's settings (written beside ``out_obj`` as ``NAME_case.json``, paths in it
        absolute).
    out_obj : str
        Where the target surface is written.

    Returns
    -------
    dict
        ``spacing`` (the design's median segment length, drawn), ``angle`` (the deployed average angle,
        degrees) and ``material`` (the case's material spec): what the inverse design of the target is given.
    """
    from ..deploy.case import load_case, material_from_spec, target_angle
    from ..deploy.simulate import DeployOptions, deploy, rest_length_solve
    from ..design.fitting import target_surface
    from ..io import read_design, read_rest_lengths
    from ..linkage.linkage import Linkage

    if isinstance(case, dict):
        spec, case = case, os.path.splitext(out_obj)[0] + "_case.json"
        with open(case, "w") as fh:
            json.dump(spec, fh)
    c = load_case(case)
    d = read_design(c.design_path)
    p = read_rest_lengths(c.rest_lengths_path, d.num_segments) if c.rest_lengths_path else None
    L = Linkage(d, material_from_spec(c.material), subdivision=c.subdivision, rest_lengths=p)
    if p is None:
        rest_length_solve(L)
    angle = target_angle(c, L)
    deploy(L, angle, DeployOptions(steps=c.steps))
    V, F = target_surface(L)
    with open(out_obj, "w") as fh:
        fh.writelines(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in V)
        fh.writelines(f"f {a + 1} {b + 1} {k + 1}\n" for a, b, k in F)
    seg = float(np.median(np.linalg.norm(d.vertices[d.edges[:, 0]] - d.vertices[d.edges[:, 1]], axis=1)))
    return {"spacing": seg, "angle": float(np.degrees(angle)), "material": c.material}
