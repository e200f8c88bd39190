"""Forward simulation (paper §4): rest-length solve and deployment by joint torques.

The public names are imported lazily, so that registering ``xshells deploy``
(the full ``xshells`` parser registers every subcommand) does not load the
solver and JAX.
"""
from importlib import import_module

__all__ = ["DeployOptions", "DeploymentResult", "deploy", "rest_length_solve", "solve_equilibrium"]


def __getattr__(name):
    if name in __all__:
        return getattr(import_module(".simulate", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
