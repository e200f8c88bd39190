"""Design-space sweeps: many independent deploy/optimize/sparsify runs on Dask.

``load_spec`` reads and checks a sweep file, ``run_sweep`` runs its tasks
(serially in-process, on a local Dask cluster, or on an existing scheduler)
and streams every result into an output folder; ``write_summary`` draws the
plots. Tasks live in a registry (:data:`xshells.sweeps.tasks.REGISTRY`).
"""
from .run import SweepSettings, run_sweep
from .spec import SweepSpec, Task, load_spec, spec_from_dict

__all__ = ["SweepSettings", "SweepSpec", "Task", "load_spec", "run_sweep", "spec_from_dict"]
