"""Saving and reloading a linkage's full state, bit for bit (``.npz``).

The file holds the design, the subdivision, the materials (profile, E, ν,
density, stiff axis), the per-segment rest lengths, the reduced variables
and every source frame (joints and rods), so a reloaded linkage has the same
energy, gradient and Hessian to the last bit.
"""
from __future__ import annotations

import json
import os
import tempfile

import numpy as np

from ..errors import InputError
from ..io.design import design_from_arrays
from .linkage import Linkage

FORMAT = "xshells-linkage-state/1"


def _material_spec(m) -> dict:
    prof = m.profile
    return {
        "kind": prof.kind,
        "params": list(prof.params),
        "outer": np.asarray(prof.outer).tolist(),
        "holes": [np.asarray(h).tolist() for h in prof.holes],
        "name": prof.name,
        "E": m.E,
        "nu": m.nu,
        "density": m.density,
        "stiff_axis": m.stiff_axis,
        "rtol": m.rtol,
    }


def _material_from_spec(spec: dict):
    from ..section.material import Material
    from ..section.profiles import Profile, make_profile

    if spec["kind"] != "polygon":
        profile = make_profile(spec["kind"], spec["params"])
    else:
        profile = Profile(np.asarray(spec["outer"], float), tuple(np.asarray(h, float) for h in spec["holes"]), name=spec["name"])
    return Material(profile, spec["E"], spec["nu"], density=spec["density"], stiff_axis=spec["stiff_axis"], rtol=spec["rtol"])


def save_linkage(path, linkage: Linkage) -> None:
    """Write the linkage's state to ``path`` (.npz), atomically."""
    meta = {
        "format": FORMAT,
        "subdivision": linkage.subdivision,
        "section_angle": linkage.section_angle,
        "bending_energy": linkage.rods.bending_energy,
        "materials": [_material_spec(m) for m in linkage.materials],
    }
    arrays = dict(
        meta=np.array(json.dumps(meta)),
        vertices=np.asarray(linkage.design.vertices),
        edges=np.asarray(linkage.design.edges),
        rest_lengths=linkage.rest_lengths,
        x=linkage.get_vars(),
        joint_b0=linkage.joint_b0,
        joint_n0=linkage.joint_n0,
        rod_t_src=linkage.rods.t_src,
        rod_d1_src=linkage.rods.d1_src,
        rod_ref_twist_src=linkage.rods.ref_twist_src,
        theta_prev=linkage._inst_prm[14],
    )
    from ..io.export import output_target, replace_with

    target = output_target(path)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(target), suffix=".npz.tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
        replace_with(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def load_linkage(path) -> Linkage:
    """Rebuild a linkage saved by :func:`save_linkage`."""
    try:
        data = np.load(path, allow_pickle=False)
        meta = json.loads(str(data["meta"]))
    except (OSError, ValueError, KeyError) as exc:
        raise InputError(f"{path}: not a saved linkage state ({exc})") from None
    if meta.get("format") != FORMAT:
        raise InputError(f"{path}: unknown state format {meta.get('format')!r} (expected {FORMAT})")
    design = design_from_arrays(data["vertices"], data["edges"], source=str(path))
    mats = [_material_from_spec(s) for s in meta["materials"]]
    L = Linkage(design, mats[0] if len(mats) == 1 else mats, subdivision=meta["subdivision"],
                rest_lengths=data["rest_lengths"], section_angle=meta["section_angle"],
                bending_energy=meta["bending_energy"])
    L.joint_b0 = data["joint_b0"].copy()
    L.joint_n0 = data["joint_n0"].copy()
    L.rods.t_src = data["rod_t_src"].copy()
    L.rods.d1_src = data["rod_d1_src"].copy()
    L.rods.ref_twist_src = data["rod_ref_twist_src"].copy()
    L._refresh_instance_sources(theta_prev=data["theta_prev"].copy())
    L.set_vars(data["x"])
    return L


def snapshot(linkage: Linkage) -> dict:
    """An in-memory copy of the linkage's state (variables, rest lengths and frames)."""
    return dict(
        x=linkage.get_vars(),
        rest_lengths=linkage.rest_lengths,
        joint_b0=linkage.joint_b0.copy(),
        joint_n0=linkage.joint_n0.copy(),
        rod_t_src=linkage.rods.t_src.copy(),
        rod_d1_src=linkage.rods.d1_src.copy(),
        rod_ref_twist_src=linkage.rods.ref_twist_src.copy(),
        theta_prev=linkage._inst_prm[14].copy(),
    )


def restore(linkage: Linkage, snap: dict) -> None:
    """Put the linkage back in a state taken by :func:`snapshot` (bit for bit)."""
    linkage.set_rest_lengths(snap["rest_lengths"])
    linkage.joint_b0 = snap["joint_b0"].copy()
    linkage.joint_n0 = snap["joint_n0"].copy()
    linkage.rods.t_src = snap["rod_t_src"].copy()
    linkage.rods.d1_src = snap["rod_d1_src"].copy()
    linkage.rods.ref_twist_src = snap["rod_ref_twist_src"].copy()
    linkage._refresh_instance_sources(theta_prev=snap["theta_prev"].copy())
    linkage.set_vars(snap["x"])
