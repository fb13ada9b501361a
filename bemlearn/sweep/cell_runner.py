"""One cell, run the same way by every backend: :func:`run_cell`.

The serial backend calls :func:`run_cell` in the driver's process; the Ray backend calls the
same function as a Ray task.  It

1. takes the cell's lock (``DIR/cells/.<id>.lock``, ``flock``): two drivers, or a driver and
   a task left over from a killed one, never run the same cell at once; whoever gets the lock
   second finds the cell complete and returns its record without running it again;
2. removes what an unfinished earlier attempt left in ``DIR/cells/<id>/`` and runs the stage
   into it with torch's threads set to the cell's CPUs and every global generator seeded from
   the cell id (the same numbers whichever process runs it), the cell's log going to
   ``cell.log`` (warnings still reach the console);
3. writes ``cell.json`` (:class:`CellOutcome`) atomically, last: a folder without it, or with
   ``"status": "failed"``, is not complete, and ``--resume`` runs it again.

A failing stage is caught here (any ``Exception``, programming errors included: one cell must not
stop a sweep of hundreds) and recorded with its traceback in ``cell.json`` and ``cell.log``;
``KeyboardInterrupt`` is not caught, and leaves the folder without ``cell.json``.
Every start and end is appended to ``DIR/log.jsonl`` (host, pid, attempt), the record of
which process ran which cell.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import random
import shutil
import socket
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bemlearn.sweep.cells import Cell
from bemlearn.threads import torch_threads

__all__ = ["CellJob", "CellOutcome", "run_cell", "read_outcome", "failed_outcome", "append_event",
           "cell_folder", "cell_lock", "MARKER"]

log = logging.getLogger(__name__)

#: The completion record of a cell, written atomically last.
MARKER = "cell.json"


@dataclass(frozen=True)
class CellJob:
    """One attempt at a cell, as a backend ships it.

    Attributes:
        cell: the cell.
        sweep_dir: the sweep folder (absolute; on a cluster, a path every node sees).
        cpus: the cell's declared cores (torch threads, collection processes).
        attempt: 1 for the first run, 2 for the retry, ….
        rerun: run even if the cell is complete (``--force``).
    """

    cell: Cell
    sweep_dir: str
    cpus: int
    attempt: int = 1
    rerun: bool = False


@dataclass(frozen=True)
class CellOutcome:
    """What ``cell.json`` holds.

    Attributes:
        cell_id: the cell's id.
        index: its index in the grid.
        grid: its grid values.
        stage: the stage it ran.
        status: ``"ok"`` or ``"failed"``.
        error: the error's first line (``failed``), else ``None``.
        traceback: the full traceback (``failed``), else ``None``.
        verdict: the run's own verdict (``metrics.json["verdict"]``) where it has one.
        verdict_reasons: that verdict's reasons.
        metrics: the stage's headline figures (:attr:`~bemlearn.sweep.stage.SweepStage.headline`).
        attempt: the attempt that produced this record.
        wall_s: the stage's wall time, s.
        cpu_s: the CPU time the stage used (user + system, its threads and finished child
            processes), s; ``wall_s`` above it on a cell declaring one CPU means the core was shared.
        started: Unix time of the stage's start (the host's clock).
        finished: Unix time of its end.
        host: the host it ran on.
        pid: the process it ran in.
        reused: ``True`` when the cell was already complete and nothing ran (see :func:`run_cell`).
    """

    cell_id: str
    index: int
    grid: dict[str, Any]
    stage: str
    status: str
    error: str | None = None
    traceback: str | None = None
    verdict: str | None = None
    verdict_reasons: list[str] = field(default_factory=list)
    metrics: dict[str, Any] = field(default_factory=dict)
    attempt: int = 1
    wall_s: float = 0.0
    cpu_s: float = 0.0
    started: float = 0.0
    finished: float = 0.0
    host: str = ""
    pid: int = 0
    reused: bool = False

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, default=_json_default)


def _json_default(value: Any) -> Any:
    if hasattr(value, "item"):  # numpy / torch scalars
        return value.item()
    return str(value)


def cell_folder(sweep_dir: str | Path, cell_id: str) -> Path:
    """``DIR/cells/<cell_id>``."""
    return Path(sweep_dir) / "cells" / cell_id


def read_outcome(folder: str | Path) -> CellOutcome | None:
    """The ``cell.json`` of a cell folder, or ``None`` when it has none (or an unreadable one)."""
    path = Path(folder) / MARKER
    try:
        data = json.loads(path.read_text())
        names = {f.name for f in dataclasses.fields(CellOutcome)}
        outcome = CellOutcome(**{k: v for k, v in data.items() if k in names})
    except (OSError, ValueError, TypeError):
        return None
    return outcome if outcome.cell_id == Path(folder).name else None


def failed_outcome(job: CellJob, error: str, *, started: float | None = None, details: str | None = None) -> CellOutcome:
    """A ``failed`` record of ``job`` for an error outside the stage (e.g. a crashed Ray worker)."""
    now = time.time()
    c = job.cell
    return CellOutcome(c.cell_id, c.index, c.grid, c.stage, "failed", error=error.splitlines()[0] if error else "failed",
                       traceback=details, attempt=job.attempt, started=started or now, finished=now)


def append_event(path: str | Path, record: dict[str, Any]) -> None:
    """Append one JSON line to ``path`` with a single ``write`` in append mode (lines of
    concurrent writers do not interleave on a local file system)."""
    line = (json.dumps(record, default=_json_default) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line)
    finally:
        os.close(fd)


@contextlib.contextmanager
def cell_lock(sweep_dir: str | Path, cell_id: str, *, blocking: bool = True) -> Iterator[bool]:
    """Hold ``DIR/cells/.<id>.lock`` (``flock``, released when the holder dies); yields whether it
    was taken (always ``True`` when ``blocking``).  A no-op yielding ``True`` where ``fcntl`` is missing."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield True
        return
    path = Path(sweep_dir) / "cells" / f".{cell_id}.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
        except BlockingIOError:
            yield False
            return
        yield True
    finally:
        os.close(fd)  # releases the lock


@contextlib.contextmanager
def _cell_environment(threads: int, seed: int) -> Iterator[None]:
    """torch threads = ``threads`` and every global generator seeded with ``seed``; restored afterwards."""
    import numpy as np
    import torch

    saved = (torch.get_rng_state(), np.random.get_state(), random.getstate())
    torch.manual_seed(seed)
    np.random.seed(seed)
    random.seed(seed)
    try:
        with torch_threads(threads):
            yield
    finally:
        torch.set_rng_state(saved[0])
        np.random.set_state(saved[1])
        random.setstate(saved[2])


@contextlib.contextmanager
def _cell_logging(path: Path) -> Iterator[None]:
    """The cell's log records (INFO and up) go to ``path``; the console handlers show only warnings meanwhile."""
    root = logging.getLogger()
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    handler.setLevel(logging.INFO)
    saved_level = root.level
    saved = [(h, h.level) for h in root.handlers]
    for h, level in saved:
        h.setLevel(max(level, logging.WARNING))
    root.addHandler(handler)
    root.setLevel(min(saved_level, logging.INFO) if saved_level else logging.INFO)
    try:
        yield
    finally:
        root.removeHandler(handler)
        handler.close()
        root.setLevel(saved_level)
        for h, level in saved:
            h.setLevel(level)


def _cpu_seconds() -> float:
    """User + system CPU time of this process and its finished children, s."""
    import resource

    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _verdict(metrics: dict[str, Any]) -> tuple[str | None, list[str]]:
    from bemlearn.pipeline.run_metrics import written_verdict

    return written_verdict(metrics)


def warm_worker() -> int:
    """Import what every cell needs (torch, the stages and the pipeline) in this worker process.

    Run once per Ray worker when the backend starts, so that a cell's wall time holds its own
    work and not the worker's one-time imports; returns the worker's process id.
    """
    import numpy  # noqa: F401
    import torch  # noqa: F401

    import bemlearn.pipeline.run
    import bemlearn.sweep.stage  # noqa: F401

    return os.getpid()


def run_cell(job: CellJob) -> CellOutcome:
    """Run one attempt at a cell (module docstring); returns its record (also in ``cell.json``)."""
    from bemlearn.files import atomic_write_text
    from bemlearn.sweep.stage import get_stage

    cell = job.cell
    folder = cell_folder(job.sweep_dir, cell.cell_id)
    events = Path(job.sweep_dir) / "log.jsonl"
    who: dict[str, Any] = {"cell": cell.cell_id, "host": socket.gethostname(), "pid": os.getpid(), "attempt": job.attempt}
    with cell_lock(job.sweep_dir, cell.cell_id):
        done = read_outcome(folder)
        if done is not None and done.status == "ok" and not job.rerun:
            return dataclasses.replace(done, reused=True)
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        stage = get_stage(cell.stage, cell.application)
        append_event(events, {"event": "started", "time": time.time(), **who})
        started = time.time()
        t0, c0 = time.perf_counter(), _cpu_seconds()
        error = details = None
        metrics: dict[str, Any] = {}
        with _cell_logging(folder / "cell.log"), _cell_environment(job.cpus, int(cell.cell_id[:8], 16)):
            log.info("cell %s (%s), stage %s, attempt %d on %s pid %d", cell.cell_id, cell.label, cell.stage, job.attempt,
                     who["host"], who["pid"])
            try:
                stage.execute(cell.config, folder, job.cpus)
                metrics_path = folder / stage.metrics_file
                metrics = json.loads(metrics_path.read_text()) if metrics_path.is_file() else {}
            except Exception as exc:  # noqa: BLE001 - one cell never stops the sweep; recorded with its traceback
                details = traceback.format_exc()
                error = f"{type(exc).__name__}: {str(exc).strip()}".splitlines()[0]
                log.error("cell %s failed:\n%s", cell.cell_id, details)
        wall, cpu = time.perf_counter() - t0, _cpu_seconds() - c0
        verdict, reasons = _verdict(metrics)
        outcome = CellOutcome(cell.cell_id, cell.index, cell.grid, cell.stage, "failed" if error else "ok", error=error,
                              traceback=details, verdict=verdict, verdict_reasons=reasons,
                              metrics=stage.headline(metrics) if not error else {}, attempt=job.attempt, wall_s=wall,
                              cpu_s=cpu, started=started, finished=time.time(), host=who["host"], pid=who["pid"])
        atomic_write_text(folder / MARKER, outcome.to_json())  # last: the cell is complete from here on
        append_event(events, {"event": "completed" if outcome.status == "ok" else "failed", "time": outcome.finished,
                              "wall_s": wall, **who})
    return outcome
