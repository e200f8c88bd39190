"""Beam cross-sections: profiles, meshes, torsion and stiffness (issue 3)."""
