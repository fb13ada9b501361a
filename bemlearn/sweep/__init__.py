"""Sweeps: a grid of configs run as cells, on this machine or a Ray cluster (``bemlearn sweep``).

A sweep file (:mod:`~bemlearn.sweep.config`) names a base config, a grid of dotted keys and the
stage each cell runs (:mod:`~bemlearn.sweep.stage`); every cell is resolved and validated
before anything runs (:mod:`~bemlearn.sweep.cells`), then run by one function,
:func:`~bemlearn.sweep.cell_runner.run_cell`, in this process or as a Ray task
(:mod:`~bemlearn.sweep.backends`), into ``DIR/cells/<cell id>/`` — a normal run folder plus
``cell.json``.  :func:`run_sweep` (:mod:`~bemlearn.sweep.driver`) schedules, retries, resumes
and writes ``results.csv`` / ``results.json`` / ``summary.png`` (:mod:`~bemlearn.sweep.results`).
Ray is optional (``pip install "bemlearn[ray]"``) and imported only by the Ray backend.
"""

from typing import TYPE_CHECKING

from bemlearn._lazy import lazy_namespace

if TYPE_CHECKING:  # imported on first use: bemlearn._lazy
    from bemlearn.sweep.backends import RayBackend, SerialBackend, make_backend, ray_available
    from bemlearn.sweep.cell_runner import CellJob, CellOutcome, read_outcome, run_cell
    from bemlearn.sweep.cells import Cell, cell_id, expand_cells
    from bemlearn.sweep.config import LoadedSweep, SweepConfig, SweepResources, load_sweep
    from bemlearn.sweep.driver import CellTiming, SweepResult, run_sweep
    from bemlearn.sweep.results import result_rows, summary_figure, write_results
    from bemlearn.sweep.stage import SweepStage, core_stages, get_stage, stage_names

__all__ = [
    "Cell",
    "CellJob",
    "CellOutcome",
    "CellTiming",
    "LoadedSweep",
    "RayBackend",
    "SerialBackend",
    "SweepConfig",
    "SweepResources",
    "SweepResult",
    "SweepStage",
    "cell_id",
    "core_stages",
    "expand_cells",
    "get_stage",
    "load_sweep",
    "make_backend",
    "ray_available",
    "read_outcome",
    "result_rows",
    "run_cell",
    "run_sweep",
    "stage_names",
    "summary_figure",
    "write_results",
]

__getattr__, __dir__ = lazy_namespace(__name__, __file__)
