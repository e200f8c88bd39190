"""Forward simulation (paper §4): rest-length solve and deployment by joint torques."""
from .simulate import DeployOptions, DeploymentResult, deploy, rest_length_solve, solve_equilibrium

__all__ = ["DeployOptions", "DeploymentResult", "deploy", "rest_length_solve", "solve_equilibrium"]
