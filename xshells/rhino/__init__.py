"""Rhino files: designs and target surfaces read from ``.3dm`` through rhino3dm (OpenNURBS)."""
from .read import RHINO_UNITS_TO_MM, read_3dm_design, read_3dm_surface, set_defaults

__all__ = ["RHINO_UNITS_TO_MM", "read_3dm_design", "read_3dm_surface", "set_defaults"]
