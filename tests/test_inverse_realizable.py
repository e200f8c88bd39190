"""The realizable target of a design (``xshells.inverse.realizable``): the surface it deploys to, with the
spacing, angle and material that inverse design is given for it (issue 18's checks; the bar itself is checked in
``test_inverse_targets.py``)."""
from __future__ import annotations

import json

import numpy as np

from data_paths import EXAMPLES
from xshells.inverse.realizable import realizable_target

CASE = EXAMPLES / "asymm_wings_pointy" / "case.json"


def test_the_realizable_target_is_the_deployed_design_and_its_settings(tmp_path):
    from xshells.design.fitting import read_surface
    from xshells.io import read_design

    case = json.loads(CASE.read_text())
    info = realizable_target(str(CASE), str(tmp_path / "target.obj"))
    design = read_design(str(CASE.parent / case["file"]))
    drawn = np.linalg.norm(design.vertices[design.edges[:, 0]] - design.vertices[design.edges[:, 1]], axis=1)
    assert info["spacing"] == float(np.median(drawn))
    assert abs(info["angle"] - np.degrees(case["angle_rad"])) < 1e-9  # the case's deployed angle
    assert {k: info["material"][k] for k in case["material"]} == case["material"]
    V, F = read_surface(str(tmp_path / "target.obj"))
    # twice Loop-subdivided triangles: 16 for each triangle of the joint cells (whatever the cells' shapes)
    assert len(F) % 16 == 0 and np.isfinite(V).all()
    span = np.ptp(V, axis=0)
    assert span[2] > 0.05 * span[:2].max()  # the deployed surface, not the flat layout
