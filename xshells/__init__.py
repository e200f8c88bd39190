"""xshells: design, simulation and fabrication of X-shells.

Units follow the input: the bundled designs are in millimetres and Young's
moduli in MPa, so energies come out in N·mm (mJ) and forces in N.
"""
# JAX (float64, persistent compilation cache) is configured by ``_jaxconfig``,
# which every module that uses JAX imports first: importing the package itself
# stays light (``xshells app`` serves its page before the solver loads).

__version__ = "0.1.0"
