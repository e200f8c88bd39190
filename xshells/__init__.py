"""xshells: design, simulation and fabrication of X-shells.

Units follow the input: the bundled designs are in millimetres and Young's
moduli in MPa, so energies come out in N·mm (mJ) and forces in N.
"""
from . import _jaxconfig  # noqa: F401  (float64 + persistent compilation cache)

__version__ = "0.1.0"
