"""sweep: a grid of independent tasks written into one zarr group, in-process or through Dask, resumable.

Orchestration over ``warpchain``, not part of it: ``warpchain`` is the engine and the model (what one run
computes), ``sweep`` decides how many runs are laid out, handed to workers and resumed. The dependency is one
way: ``sweep`` imports ``warpchain`` (its zarr helpers), the engine package never imports ``sweep`` at module
level (``warpchain.reader`` reads the checksums of a sweep group through ``sweep.store``, as it reads branches
through ``continuation.branch_store``).

``sweep.runner`` runs the tasks (:func:`run_sweep`; its docstring describes the layout and the design);
``sweep.store`` describes the grid (:class:`SweepSpec`, :class:`Variable`) and writes and checks the group.
"""

from .runner import SweepReport, SweepTaskError, host_allocator, run_sweep
from .store import (
    CHECKSUM,
    COMPLETED,
    SweepMismatchError,
    SweepSpec,
    Variable,
    completed,
    damaged_tasks,
    open_sweep,
)

__all__ = [
    "CHECKSUM",
    "COMPLETED",
    "SweepMismatchError",
    "SweepReport",
    "SweepSpec",
    "SweepTaskError",
    "Variable",
    "completed",
    "damaged_tasks",
    "host_allocator",
    "open_sweep",
    "run_sweep",
]
