"""Run a sweep: :func:`run_sweep`, what ``bemlearn sweep`` calls.

1. Parse the sweep file and resolve every cell (:func:`~bemlearn.sweep.cells.expand_cells`);
   a bad cell fails here, before any folder is created.
2. Prepare ``DIR``: a new or empty folder; an existing sweep folder only with ``resume`` (its
   complete cells are kept and skipped) or ``force`` (every cell runs again, each folder
   replaced when its cell starts).  ``DIR/.sweep.lock`` keeps a second driver out.
   ``DIR/sweep.yaml`` records the sweep as run (the base config inline, with its overrides).
3. Hand the cells that are not complete to the backend, at most ``slots`` at a time; a failed
   cell runs again up to ``retries`` times, then is recorded, and the sweep goes on.
   ``results.csv`` / ``results.json`` are rewritten (atomically) after every cell, so they are
   current whenever the driver stops; ``summary.png`` is drawn at the end.
4. Ctrl-C or SIGTERM: the outstanding cells are cancelled (Ray: their workers are killed;
   serial: the running stage is interrupted), the folders they left without ``cell.json`` are
   removed, the results are written, and :class:`KeyboardInterrupt` propagates.  Complete cells
   are never touched; ``--resume`` continues.  A driver killed outright (SIGKILL) leaves at most
   the running cells' folders without ``cell.json``; they run again on ``--resume``, and the cell
   lock (:func:`~bemlearn.sweep.cell_runner.cell_lock`) keeps a task that outlived its driver
   from running at the same time as its replacement.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import shutil
import signal
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from bemlearn.errors import ArgumentError, EnvironmentProblem, OutputExistsError, SweepError
from bemlearn.files import atomic_write_text, check_writable, first_new_folder, new_run_dir, write_problem
from bemlearn.sweep.backends import make_backend
from bemlearn.sweep.cell_runner import MARKER, CellJob, CellOutcome, cell_folder, cell_lock, read_outcome
from bemlearn.sweep.cells import Cell, expand_cells
from bemlearn.sweep.config import LoadedSweep, load_sweep
from bemlearn.sweep.results import result_rows, summary_figure, write_results

__all__ = ["SweepResult", "CellTiming", "run_sweep"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CellTiming:
    """One attempt as the driver saw it (Unix times; ``started``/``finished`` from the cell's host).

    The backend's overhead on the attempt is ``(started − submitted) + (received − finished)``:
    dispatch, a worker's start-up and imports, and the return of the record.
    """

    cell_id: str
    attempt: int
    submitted: float
    started: float
    finished: float
    received: float

    @property
    def overhead_s(self) -> float:
        return (self.started - self.submitted) + (self.received - self.finished)


@dataclass(frozen=True)
class SweepResult:
    """What :func:`run_sweep` did.

    Attributes:
        out_dir: the sweep folder.
        backend: ``"ray"`` or ``"serial"`` (the one that ran; ``"none"`` when nothing had to).
        cells: every cell, in grid order.
        outcomes: cell id → its record (cells not run yet are missing).
        ran: ids of the cells run by this call (their last attempt).
        timings: every attempt of this call.
        wall_s: this call's wall time, s (validation included).
        backend_startup_s: the backend's start, s (Ray: ``ray.init``).
        columns: the header of ``results.csv``.
        rows: its rows.
    """

    out_dir: Path
    backend: str
    cells: list[Cell]
    outcomes: dict[str, CellOutcome]
    ran: list[str]
    timings: list[CellTiming]
    wall_s: float
    backend_startup_s: float
    columns: list[str] = field(default_factory=list)
    rows: list[dict[str, Any]] = field(default_factory=list)

    @property
    def n_ok(self) -> int:
        return sum(o.status == "ok" for o in self.outcomes.values())

    @property
    def n_failed(self) -> int:
        return sum(o.status == "failed" for o in self.outcomes.values())


def _prepare(out: Path, *, resume: bool, force: bool) -> None:
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        return
    if not out.is_dir():
        raise OutputExistsError(f"--out {out}: is a file; a sweep writes a folder")
    is_sweep = (out / "sweep.yaml").is_file()
    if (resume or force) and not is_sweep:
        raise OutputExistsError(f"--out {out}: not a sweep folder (no sweep.yaml) and not empty; "
                                "refusing to write into it")
    if not resume and not force:
        raise OutputExistsError(f"--out {out}: would overwrite the sweep folder; use --resume to continue it "
                                "(complete cells are kept) or --force to run every cell again")


@contextlib.contextmanager
def _driver_lock(out: Path) -> Iterator[None]:
    """``DIR/.sweep.lock`` held for the driver's lifetime (released by the OS if it dies)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    try:
        fd = os.open(out / ".sweep.lock", os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise (write_problem(out / ".sweep.lock", exc) or EnvironmentProblem(f"--out {out}: cannot write there ({exc})")) from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            raise SweepError(f"--out {out}: another bemlearn sweep is running into this folder (pid {holder}); "
                             "wait for it or stop it") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield
    finally:
        os.close(fd)


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises :class:`KeyboardInterrupt` in the main thread for the block (as Ctrl-C does)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _record(loaded: LoadedSweep, cells: list[Cell]) -> str:
    spec = dataclasses.asdict(loaded.spec)
    spec["base"] = loaded.base
    spec.pop("overrides")
    spec["source"] = loaded.source
    spec["cells"] = {c.cell_id: c.grid for c in cells}
    return "# the sweep as run (base config inline, overrides applied); results.csv holds the cells\n" + \
        yaml.safe_dump(spec, sort_keys=False, allow_unicode=True)


def _remove_unfinished(sweep_dir: Path, jobs: list[CellJob]) -> None:
    """Remove the folders cancelled jobs left without ``cell.json`` (when no process holds their lock)."""
    for job in jobs:
        folder = cell_folder(sweep_dir, job.cell.cell_id)
        if not folder.exists() or (folder / MARKER).exists():
            continue
        with cell_lock(sweep_dir, job.cell.cell_id, blocking=False) as free:
            if free and not (folder / MARKER).exists():
                shutil.rmtree(folder, ignore_errors=True)


def run_sweep(sweep: str | Path | dict[str, Any], out_dir: str | Path | None = None, *, backend: str = "ray",
              address: str | None = None, resume: bool = False, force: bool = False, max_parallel: int | None = None,
              progress: bool = True) -> SweepResult:
    """Run every cell of ``sweep`` (a sweep file or mapping) into ``out_dir`` (module docstring).

    Args:
        sweep: the sweep file (:mod:`bemlearn.sweep.config`).
        out_dir: the sweep folder (default: a new ``runs/<sweep file stem>-<timestamp>``).
        backend: ``"ray"`` (Ray tasks; serial with a warning when Ray is not installed) or ``"serial"``.
        address: the Ray cluster to use (default: a local instance with this machine's cores).
        resume: continue the sweep in ``out_dir``: complete cells are kept and not run.
        force: run every cell again, replacing its folder.
        max_parallel: at most this many cells at once (Ray).
        progress: a progress bar over the cells.

    Raises:
        ConfigError: the sweep file or a cell's config is invalid (nothing has run).
        OutputExistsError: ``out_dir`` holds something and neither ``resume`` nor ``force`` is set.
        SweepError: another driver is running into ``out_dir``, or no cell fits on the cluster.
        KeyboardInterrupt: Ctrl-C or SIGTERM (outstanding cells cancelled, results written).
    """
    t0 = time.perf_counter()
    if max_parallel is not None and max_parallel < 1:
        raise ArgumentError(f"--max-parallel: expected a positive integer, got {max_parallel}")
    loaded = load_sweep(sweep)
    cells = expand_cells(loaded)
    stem = Path(loaded.source).stem if loaded.source != "<dict>" else "sweep"
    out = Path(out_dir if out_dir is not None else new_run_dir(stem)).absolute()
    _prepare(out, resume=resume, force=force)
    check_writable(out)   # a read-only or missing disk: one line, before anything is created
    first_new = first_new_folder(out)
    try:
        try:
            out.mkdir(parents=True, exist_ok=True)
            (out / "cells").mkdir(exist_ok=True)
        except OSError as exc:
            raise (write_problem(out, exc) or EnvironmentProblem(f"--out {out}: cannot create it ({exc})")) from None
        return _run_in(out, loaded, cells, t0, backend=backend, address=address, force=force, max_parallel=max_parallel,
                       progress=progress)
    except BaseException:
        # a sweep that fails before any cell left its record leaves no folder it created (a cell's
        # record, complete or failed, is worth keeping: --resume continues from it)
        if first_new is not None and not _holds_a_cell(out):
            shutil.rmtree(first_new, ignore_errors=True)
            log.info("removed %s after the failure", first_new)
        raise


def _holds_a_cell(out: Path) -> bool:
    cells = out / "cells"
    return cells.is_dir() and any((c / MARKER).exists() for c in cells.iterdir())


def _run_in(out: Path, loaded: LoadedSweep, cells: list[Cell], t0: float, *, backend: str, address: str | None,
            force: bool, max_parallel: int | None, progress: bool) -> SweepResult:
    """The sweep into the prepared folder ``out`` (:func:`run_sweep`, steps 2–4)."""
    with _driver_lock(out):
        atomic_write_text(out / "sweep.yaml", _record(loaded, cells))
        outcomes: dict[str, CellOutcome] = {}
        todo: list[Cell] = []
        for cell in cells:
            done = read_outcome(cell_folder(out, cell.cell_id))
            if done is not None and done.status == "ok" and not force:
                outcomes[cell.cell_id] = done
            else:
                todo.append(cell)
        if outcomes:
            log.info("%s: %d of %d cells complete; running the other %d", out, len(outcomes), len(cells), len(todo))
        columns, rows = result_rows(cells, outcomes)
        write_results(out, columns, rows)
        ran: list[str] = []
        timings: list[CellTiming] = []
        name, startup = "none", 0.0
        if todo:
            be = make_backend(backend, loaded.spec.resources, address=address, max_parallel=max_parallel)
            name, startup = be.name, be.startup_s
            try:
                with _sigterm_as_interrupt():
                    _schedule(be, todo, out, loaded, cells, outcomes, ran, timings, force=force, progress=progress)
            except KeyboardInterrupt:
                jobs = be.cancel()
                be.close()
                _remove_unfinished(out, jobs)
                columns, rows = result_rows(cells, outcomes)
                write_results(out, columns, rows)
                log.warning("interrupted: %d of %d cells complete in %s; continue with `bemlearn sweep %s --out %s --resume`",
                            sum(o.status == "ok" for o in outcomes.values()), len(cells), out, loaded.source, out)
                raise
            be.close()
        columns, rows = result_rows(cells, outcomes)
        write_results(out, columns, rows)
        summary_figure(out / "summary.png", columns, rows, list(loaded.spec.grid))
    return SweepResult(out, name, cells, outcomes, ran, timings, time.perf_counter() - t0, startup, columns, rows)


def _schedule(be, todo: list[Cell], out: Path, loaded: LoadedSweep, cells: list[Cell], outcomes: dict[str, CellOutcome],
              ran: list[str], timings: list[CellTiming], *, force: bool, progress: bool) -> None:
    from tqdm.auto import tqdm

    cpus, retries = loaded.spec.resources.cpus, loaded.spec.retries
    queue = [CellJob(c, str(out), cpus, 1, force) for c in todo]
    queue.reverse()  # pop() from the end: grid order
    running: dict[Any, tuple[CellJob, float]] = {}
    bar = tqdm(total=len(cells), initial=len(cells) - len(todo), desc="sweep cells", unit="cell", disable=not progress)
    n_failed = 0
    try:
        while queue or running:
            while queue and len(running) < be.slots:
                job = queue.pop()
                submitted = time.time()
                running[be.submit(job)] = (job, submitted)
            for handle, outcome in be.wait(timeout=0.5):
                job, submitted = running.pop(handle)
                timings.append(CellTiming(job.cell.cell_id, job.attempt, submitted, outcome.started or submitted,
                                          outcome.finished or submitted, time.time()))
                if outcome.status == "failed" and job.attempt <= retries:
                    log.warning("cell %s (%s) failed (attempt %d): %s; running it again", job.cell.cell_id, job.cell.label,
                                job.attempt, outcome.error)
                    queue.append(dataclasses.replace(job, attempt=job.attempt + 1))
                    continue
                if outcome.status == "failed":
                    n_failed += 1
                    log.warning("cell %s (%s) failed: %s (recorded in %s)", job.cell.cell_id, job.cell.label, outcome.error,
                                cell_folder(out, job.cell.cell_id) / MARKER)
                outcomes[job.cell.cell_id] = outcome
                ran.append(job.cell.cell_id)
                columns, rows = result_rows(cells, outcomes)
                write_results(out, columns, rows)
                bar.update()
                bar.set_postfix(failed=n_failed)
    finally:
        bar.close()
