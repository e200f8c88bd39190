"""Beam cross-sections: profiles, meshes, torsion and stiffness (issue 3).

Public API (imported lazily, so ``xshells --help`` does not load scikit-fem):

* :class:`Material` -- a profile of an isotropic material in a rod's frame:
  ``stretching_stiffness``, ``bending_stiffness`` (B1, B2),
  ``twisting_stiffness``, ``area``, ``density``, ``outline``, ...
* :func:`expand_materials` -- per-edge arrays ``ks, B1, B2, kt, area, density``.
* :func:`analyse` -- geometric properties of a :class:`Profile`.
* :func:`load_section`, :func:`load_contour` -- JSON, OBJ and gmsh input.
* :mod:`profiles` -- ``rectangle``, ``ellipse``, ``i_beam``, ``l_angle``,
  ``plus``, ``polygon``, ``make_profile``.

See ``docs/sections.md``.
"""
from importlib import import_module

_EXPORTS = {
    "Material": "material",
    "expand_materials": "material",
    "analyse": "properties",
    "SectionProperties": "properties",
    "Profile": "profiles",
    "make_profile": "profiles",
    "polygon": "profiles",
    "load_section": "io",
    "load_contour": "io",
}

__all__ = sorted(_EXPORTS) + ["profiles"]


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
    if name == "profiles":
        return import_module(".profiles", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
