"""Structural analyses of a linkage state: stresses and utilization (:mod:`.stress`), named materials
with strength and density (:mod:`.materials`)."""
