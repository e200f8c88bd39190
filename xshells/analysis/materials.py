"""Named materials a designer would pick: elastic constants, density and strength, each with its source.

Units: MPa and t/mm³ (so that a design in millimetres, with gravity
9810 mm/s², gives forces in N). ``strength`` is the allowable stress the
utilization is measured against: the characteristic (5 % fractile) or
minimum specified bending strength of the source, *without* a partial
safety factor, load-duration or moisture modification: a designer applies
their code's factors on top (``--strength`` overrides it).

The beam model is isotropic (shear modulus ``E / 2(1 + ν)``). For timber and
plywood, whose real shear modulus is much lower (C24: G = 690 MPa against
E = 11000 MPa), this overestimates the torsional stiffness; the bending
stiffness, which dominates X-shells, is right.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

from ..errors import InputError


@dataclass(frozen=True)
class NamedMaterial:
    """One entry of :data:`LIBRARY`."""

    name: str
    description: str
    E: float  # MPa
    nu: float
    density: float  # t/mm³
    strength: float  # MPa
    source: str


LIBRARY = {m.name: m for m in (
    NamedMaterial("gfrp-e23", "glass-fibre pultrusion, EN 13706 grade E23 (the paper's fiberglass prototypes)",
                  E=23000.0, nu=0.3, density=1.9e-9, strength=240.0,
                  source="EN 13706-3:2002 Table 1, grade E23 minima: modulus 23 GPa, longitudinal bending strength "
                         "240 MPa; density 1900 kg/m³, typical of polyester/glass pultrusions"),
    NamedMaterial("softwood-c24", "structural softwood, strength class C24 (the paper's wooden slats)",
                  E=11000.0, nu=0.3, density=4.2e-10, strength=24.0,
                  source="EN 338 strength class C24: characteristic bending strength f_m,k = 24 MPa, mean modulus "
                         "parallel to the grain E_0,mean = 11 GPa, mean density 420 kg/m³"),
    NamedMaterial("aluminium-6063-t6", "aluminium alloy EN AW-6063 T6, extruded profiles (the paper's L profiles)",
                  E=70000.0, nu=0.3, density=2.7e-9, strength=170.0,
                  source="EN 755-2: 0.2 % proof strength R_p0.2 ≥ 170 MPa for T6 profiles up to 3 mm wall "
                         "(160 MPa up to 25 mm); E = 70 GPa, ν = 0.3, 2700 kg/m³ from EN 1999-1-1 (Eurocode 9) §3.2.5"),
    NamedMaterial("birch-plywood", "birch plywood, bending along the face grain, EN 636 classes F40/30 E60/40",
                  E=6000.0, nu=0.3, density=6.8e-10, strength=40.0,
                  source="EN 636 bending classes F40/30 (f_m = 40 MPa along the face grain) and E60/40 "
                         "(E_m = 6000 MPa), a class birch plywood is commonly declared in; 680 kg/m³, typical of "
                         "birch plywood. Check the supplier's declared classes: thin panels are often stronger"),
)}


def named_material(name: str) -> NamedMaterial:
    """The library entry ``name`` (case-insensitive); one-line error naming the known ones."""
    key = str(name).strip().lower()
    if key not in LIBRARY:
        import difflib

        close = difflib.get_close_matches(key, list(LIBRARY), n=1, cutoff=0.5)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise InputError(f"unknown material grade {name!r}{hint}; known: {', '.join(LIBRARY)}")
    return LIBRARY[key]


def as_dict(m: NamedMaterial) -> dict:
    return asdict(m)
