"""The X-shell linkage: graph analysis of a design (joints, beams) and, on top, the reduced-variable model."""
