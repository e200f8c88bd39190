"""Fabrication: the continuous beams of a design, their holes and cut lengths, nesting onto stock, drawings.

Data flow: :mod:`.beams` traces the strips and their holes from the design
graph and the rest lengths; :mod:`.nesting` packs the strips onto bars or
sheets; :mod:`.drawings` writes ``beams.svg``/``beams.dxf`` and
``assembly.svg``; :mod:`.run` puts them together as ``xshells fabricate``
(and the fabrication outputs of ``deploy``, ``optimize`` and ``inverse``).
Every length is in millimetres (``units`` converts a design drawn in other
units, and says so).
"""
from .beams import Beam, JointRow, Section, UNITS_TO_MM, beam_sections, joint_table, trace_beams, units_to_mm
from .nesting import Nesting, Placement, nest_bars, nest_sheets, no_nesting
from .run import FabricationOptions, FabricationPlan, fabrication_plan, write_fabrication

__all__ = ["Beam", "JointRow", "Section", "UNITS_TO_MM", "beam_sections", "joint_table", "trace_beams", "units_to_mm",
           "Nesting", "Placement", "nest_bars", "nest_sheets", "no_nesting",
           "FabricationOptions", "FabricationPlan", "fabrication_plan", "write_fabrication"]
