"""The discrete elastic rod (paper §3; Bergou et al. 2008, 2010)."""
from .rods import ElasticRod, ElasticRods, EnergyParts, rods_with_materials

__all__ = ["ElasticRod", "ElasticRods", "EnergyParts", "rods_with_materials"]
