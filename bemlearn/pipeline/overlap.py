"""The work a run overlaps with its serial stages (``bemlearn run --jobs N``, N > 1).

A run's stages are serial (collect → train → export → simulate → report), but parts of them
depend on less than their place in that order suggests:

- the **model** and **zero** closed loops need only the robot: they start in worker processes
  right after the model checks, beside collection and training;
- the **learned** closed loop needs only the TorchScript predictor, and the ``.pt2`` export only
  the checkpoint: once training writes ``checkpoint.pt`` (before its evaluation) the TorchScript
  predictor is serialized and checked in the run's process, then the ``.pt2`` export and the
  learned loop (flying a private temporary copy of the checked TorchScript bytes) start in
  workers, beside the evaluation of the trained GP.

The run takes their results at the stage where the serial run computes them: both predictor files
are written at the export stage, all or none (a failed overlapped export is the ``export`` stage's
failure, recorded as in the serial run), the loops' results and figures at the simulate stage.  A
run folder therefore holds the same files at every stage, and on every failure, as with ``jobs = 1``;
a loop or an export computes the same numbers in a worker as in the run's process (each is seeded
by its own config).
"""

from __future__ import annotations

import contextlib
import logging
import tempfile
from collections.abc import Callable
from concurrent.futures import Executor, Future
from pathlib import Path
from typing import TYPE_CHECKING

from bemlearn.files import atomic_write_bytes
from bemlearn.pipeline.workers import check_jobs, stop_pool

if TYPE_CHECKING:
    from bemlearn.pipeline.config import PipelineConfig
    from bemlearn.pipeline.simulate import LoopOutput
    from bemlearn.robots.protocol import BalanceRobot

__all__ = ["RunOverlap"]

log = logging.getLogger(__name__)


class RunOverlap(contextlib.AbstractContextManager):
    """The overlapped work of one run (module docstring); ``jobs = 1`` (or no fork) overlaps nothing.

    Use as a context manager around the run's stages: leaving it by an exception ends the workers at
    once (their results are not written); leaving it normally waits for them.

    Args:
        config: the run's resolved config.
        out: the run folder.
        jobs: worker processes (:func:`~bemlearn.pipeline.workers.worker_pool`).
    """

    def __init__(self, config: PipelineConfig, out: Path, *, jobs: int) -> None:
        self.config, self.out, self.jobs = config, out, check_jobs(jobs)
        self._stack = contextlib.ExitStack()
        self._pool: Executor | None = None
        self._opened = False
        self.loops: dict[str, Future[LoopOutput]] = {}
        self._pt2: Future[dict[Path, bytes]] | None = None
        self._torchscript: dict[Path, bytes] = {}
        self._export_error: Exception | None = None

    def __enter__(self) -> RunOverlap:
        self._stack.__enter__()
        return self

    def __exit__(self, *exc) -> bool | None:
        return self._stack.__exit__(*exc)

    @property
    def predictor(self) -> Path:
        """The TorchScript predictor the learned loop flies (``bem_predictor.pt`` in the run folder)."""
        return self.out / "bem_predictor.pt"

    def _open(self, robot: BalanceRobot | None) -> Executor | None:
        """The pool, forked at the first call (``None``: nothing overlaps)."""
        if not self._opened and self.jobs > 1:
            from bemlearn.pipeline.simulate import loop_pool

            self._opened = True
            self._pool = self._stack.enter_context(loop_pool(robot, self.jobs))
        return self._pool

    def cancel(self) -> None:
        """End the workers now, dropping their results (a run that stops before its closed loops)."""
        if self._pool is not None:
            stop_pool(self._pool)
            self.loops.clear()

    def start_model_loops(self, robot: BalanceRobot) -> None:
        """Start the model and zero closed loops of ``robot`` (they need no training)."""
        pool = self._open(robot)
        if pool is not None:
            from bemlearn.pipeline.simulate import start_loops

            self.loops.update(start_loops(pool, self.config, self.out, sources=("model", "zero"), predictor=self.predictor))

    def hook(self, robot: BalanceRobot | None) -> Callable[[Path], None] | None:
        """The ``on_checkpoint`` of :func:`~bemlearn.pipeline.train.train_run` (``None`` when nothing overlaps).

        It serializes and checks the TorchScript predictor here (in memory), then starts the ``.pt2`` export
        and (with a robot) the learned closed loop in workers.  A failed export is kept for :meth:`export` to raise,
        so that the run records it at its export stage, not as a training failure.
        """
        pool = self._open(robot)
        if pool is None:
            return None

        def on_checkpoint(checkpoint: Path) -> None:
            from bemlearn.export.export_run import export_files

            try:
                self._torchscript = export_files(self.out, fmt="torchscript")
            except Exception as exc:  # noqa: BLE001 - raised again, traceback kept, by export(): the export stage fails
                self._export_error = exc
                return
            self._pt2 = pool.submit(export_files, self.out, fmt="pt2")
            if robot is not None:
                from bemlearn.pipeline.simulate import start_loops

                folder = Path(self._stack.enter_context(tempfile.TemporaryDirectory(prefix="bemlearn-run-")))
                flown = atomic_write_bytes(folder / self.predictor.name, self._torchscript[self.predictor])
                self.loops.update(start_loops(pool, self.config, self.out, sources=("predictor",), predictor=flown))

        return on_checkpoint

    def export(self) -> list[Path]:
        """The export stage: the predictor files written (TorchScript first), as ``export_run(fmt="both")`` returns them.

        Without overlap it runs :func:`~bemlearn.export.export_run.export_run`; with it, it raises the
        overlapped export's error or writes the files checked beside the evaluation (the ``.pt2`` by its worker).
        """
        from bemlearn.export.export_run import export_run, write_exported

        if self._export_error is not None:
            raise self._export_error
        if self._pt2 is None:      # nothing overlapped (jobs = 1, or training wrote no checkpoint through the hook)
            return export_run(self.out, fmt="both")
        return write_exported({**self._torchscript, **self._pt2.result()})   # a failure in the worker is raised here
