"""Where cells run: in this process (:class:`SerialBackend`) or as Ray tasks (:class:`RayBackend`).

Both take :class:`~bemlearn.sweep.cell_runner.CellJob` s and hand back
:class:`~bemlearn.sweep.cell_runner.CellOutcome` s of the same function,
:func:`~bemlearn.sweep.cell_runner.run_cell`; the driver (:mod:`bemlearn.sweep.driver`) does
the rest (retries, results, progress) the same way for both.

:class:`RayBackend` connects to the cluster at ``address`` (``ray start --head`` on one node,
``ray start --address HEAD:6379`` on the others; or ``ray://HEAD:10001``), or starts a local
Ray instance with this machine's cores (``os.cpu_count()``) when no address is given; a Ray
instance already initialised in this process is used as it is and left running.  Ray starts its
workers at niceness 15 (background priority); the local instance starts them at niceness 0
(``RAY_worker_niceness=0`` unless the environment sets it), the priority of the driver and of a
``--backend serial`` cell: on a machine shared with other work, niceness-15 cells get only what
that work leaves (docs/sweeps.md has the measurement).  A cluster's own setting is left alone.
Each cell is a task declaring ``num_cpus = resources.cpus`` and ``num_gpus = resources.gpus``; Ray's own
retries are off (the driver retries a failed cell itself, ``retries:``), a crashed worker is
a failed attempt.  Ray is imported only here, and only when this backend is asked for: the
core runs without it.
"""

from __future__ import annotations

import collections
import logging
import os
import signal
import threading
import time
from typing import Any

from bemlearn.errors import ArgumentError, EnvironmentProblem, SweepError
from bemlearn.sweep.cell_runner import CellJob, CellOutcome, failed_outcome, run_cell, warm_worker
from bemlearn.sweep.config import SweepResources
from bemlearn.warnings import EnvironmentWarning, warn

__all__ = ["SerialBackend", "RayBackend", "make_backend", "ray_available", "probe_address", "CONNECT_TIMEOUT_S"]

log = logging.getLogger(__name__)


def ray_available() -> bool:
    """Whether ``import ray`` works."""
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


class SerialBackend:
    """Run the cells one after another in this process (``--backend serial``)."""

    name = "serial"

    def __init__(self) -> None:
        self.slots = 1
        self.startup_s = 0.0
        self._queue: collections.deque[tuple[int, CellJob]] = collections.deque()
        self._current: CellJob | None = None
        self._next = 0

    def submit(self, job: CellJob) -> int:
        """Queue ``job``; returns its handle."""
        self._next += 1
        self._queue.append((self._next, job))
        return self._next

    def wait(self, timeout: float) -> list[tuple[int, CellOutcome]]:
        """Run the next queued job; returns ``[(handle, outcome)]`` (empty when nothing is queued)."""
        if not self._queue:
            return []
        handle, job = self._queue.popleft()
        self._current = job
        outcome = run_cell(job)
        self._current = None
        return [(handle, outcome)]

    def cancel(self) -> list[CellJob]:
        """Drop the queued jobs; returns them and the one a signal interrupted, if any."""
        jobs = ([self._current] if self._current is not None else []) + [job for _, job in self._queue]
        self._queue.clear()
        self._current = None
        return jobs

    def close(self) -> None:
        """Nothing to release."""


class RayBackend:
    """Run each cell as a Ray task (module docstring).

    Args:
        resources: what each cell declares.
        address: a running cluster (``auto``, ``HOST:6379``, ``ray://HOST:10001``); ``None``
            starts a new local instance with ``os.cpu_count()`` CPUs (never joins a cluster
            ``ray start`` left on the machine or ``RAY_ADDRESS`` names: give ``--address`` for that).
        max_parallel: at most this many cells at once (default: as many as the cluster's CPUs
            and GPUs hold).

    Raises:
        SweepError: a cell asks for more CPUs or GPUs than the cluster has (it would wait forever).
    """

    name = "ray"

    def __init__(self, resources: SweepResources, *, address: str | None = None, max_parallel: int | None = None) -> None:
        import ray

        self._ray = ray
        t0 = time.perf_counter()
        self.started_here = not ray.is_initialized()
        self._handlers: dict = {}
        if self.started_here:
            kwargs: dict[str, Any] = dict(include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING)
            niceness_set = False
            if address is None:  # "local": a new instance, even when RAY_ADDRESS or a `ray start` cluster is around
                kwargs["num_cpus"] = os.cpu_count() or 1
                if "RAY_worker_niceness" not in os.environ:  # the raylet reads it when it starts
                    os.environ["RAY_worker_niceness"] = "0"
                    niceness_set = True
            if address is not None:
                probe_address(address)
            self._handlers = _signal_handlers()   # ray.init installs its own SIGTERM handler and leaves it after shutdown
            try:
                ray.init(address=address or "local", **kwargs)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                _restore_signal_handlers(self._handlers)
                cause = str(exc.__cause__ or exc).strip().splitlines()[0][:400]  # Ray's reason (e.g. a missing auth token)
                what = f"--address {address}: cannot connect to a Ray cluster there" if address else \
                    "--backend ray: cannot start a local Ray instance"
                raise EnvironmentProblem(f"{what} ({cause})") from exc
            finally:
                if niceness_set:
                    del os.environ["RAY_worker_niceness"]
        elif address is not None:
            log.info("Ray is already initialised in this process; --address %s is not used", address)
        self.startup_s = time.perf_counter() - t0
        total = ray.cluster_resources()
        cpus, gpus = float(total.get("CPU", 0.0)), float(total.get("GPU", 0.0))
        if resources.cpus > cpus or resources.gpus > gpus:
            self.close()
            raise SweepError(f"resources: a cell asks for {resources.cpus} CPU(s) and {resources.gpus:g} GPU(s); the Ray "
                             f"cluster has {cpus:g} CPU(s) and {gpus:g} GPU(s) in all, so no cell could ever start")
        fit = int(cpus // resources.cpus)
        if resources.gpus > 0:
            fit = min(fit, int(gpus // resources.gpus))
        self.slots = max(1, min(fit, max_parallel) if max_parallel else fit)
        self._remote = ray.remote(run_cell).options(num_cpus=resources.cpus, num_gpus=resources.gpus, max_retries=0,
                                                    name="bemlearn-sweep-cell")
        t1 = time.perf_counter()  # start the workers and their imports once, before any cell (counted in startup_s)
        warm = ray.remote(warm_worker).options(num_cpus=resources.cpus, num_gpus=resources.gpus, max_retries=0,
                                               name="bemlearn-sweep-warm-up")
        pids = ray.get([warm.remote() for _ in range(self.slots)])
        self.startup_s += time.perf_counter() - t1
        log.info("Ray: %d worker(s) ready in %.1f s", len(set(pids)), time.perf_counter() - t1)
        self._pending: dict[Any, CellJob] = {}
        self._submitted: dict[Any, float] = {}
        log.info("Ray: %g CPU(s), %g GPU(s); %d cell(s) at once", cpus, gpus, self.slots)

    def submit(self, job: CellJob):
        """Start ``job`` as a task; returns its object ref."""
        ref = self._remote.remote(job)
        self._pending[ref] = job
        self._submitted[ref] = time.time()
        return ref

    def wait(self, timeout: float) -> list[tuple[Any, CellOutcome]]:
        """The jobs that finished within ``timeout`` s, each with its outcome (a crashed worker: ``failed``)."""
        if not self._pending:
            return []
        ready, _ = self._ray.wait(list(self._pending), num_returns=1, timeout=timeout)
        out = []
        for ref in ready:
            job = self._pending.pop(ref)
            submitted = self._submitted.pop(ref)
            try:
                outcome = self._ray.get(ref)
            except self._ray.exceptions.RayError as exc:  # the worker died or the task could not run
                first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                outcome = failed_outcome(job, f"{type(exc).__name__}: {first}", started=submitted, details=str(exc))
            out.append((ref, outcome))
        return out

    def cancel(self) -> list[CellJob]:
        """Cancel every outstanding task (their workers are killed); returns their jobs."""
        jobs = list(self._pending.values())
        for ref in list(self._pending):
            try:
                self._ray.cancel(ref, force=True)
            except Exception as exc:  # noqa: BLE001 - cancelling is best effort; the job ends with the driver anyway
                log.debug("cancel %s: %s", ref, exc)
        self._pending.clear()
        self._submitted.clear()
        return jobs

    def close(self) -> None:
        """Shut the Ray instance down if this backend started it."""
        if self.started_here and self._ray.is_initialized():
            self._ray.shutdown()
        if self.started_here:
            _restore_signal_handlers(self._handlers)


def _signal_handlers() -> dict:
    """The process's SIGINT and SIGTERM handlers (restored by :func:`_restore_signal_handlers`)."""
    return {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}


def _restore_signal_handlers(handlers: dict) -> None:
    """Put back handlers saved before ``ray.init`` (which leaves its own SIGTERM handler behind, so a later
    SIGTERM in a process that goes on after the sweep would run Ray's); only the main thread may set them."""
    if threading.current_thread() is threading.main_thread():
        for sig, handler in handlers.items():
            if handler is not None:
                signal.signal(sig, handler)


#: Seconds to wait for a TCP connection to a Ray cluster's address before giving up.
CONNECT_TIMEOUT_S = 10.0


def probe_address(address: str, *, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Fail at once when nothing listens at ``address`` (``HOST:PORT`` or ``ray://HOST:PORT``): Ray itself
    retries an unreachable cluster for minutes.  ``auto`` (a cluster Ray finds itself) is left to Ray.

    Raises:
        EnvironmentProblem: the address has no port, or no TCP connection within ``timeout`` s.
    """
    import socket

    if address in ("auto", "local"):
        return
    hostport = address.split("://", 1)[-1].rstrip("/")
    host, sep, port = hostport.rpartition(":")
    if not sep or not port.isdigit() or not host:
        raise EnvironmentProblem(f"--address {address}: expected HOST:PORT or ray://HOST:PORT (or auto)")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout):
            pass
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__ if not isinstance(exc, TimeoutError) else f"no answer within {timeout:g} s"
        raise EnvironmentProblem(f"--address {address}: cannot connect to a Ray cluster there ({reason}); start one with "
                                 "`ray start --head` or give the address it printed") from None


def make_backend(kind: str, resources: SweepResources, *, address: str | None = None, max_parallel: int | None = None):
    """The backend ``kind`` (``"ray"`` or ``"serial"``); ``"ray"`` without Ray installed falls back
    to ``"serial"`` with a warning, unless ``address`` names a cluster.

    Raises:
        EnvironmentProblem: ``address`` is given but Ray is not installed.
    """
    if kind not in ("ray", "serial"):
        raise ArgumentError(f"--backend: expected 'ray' or 'serial', got {kind!r}")
    if kind == "ray" and not ray_available():
        if address is not None:
            raise EnvironmentProblem(f"--address {address}: Ray is not installed (pip install 'bemlearn[ray]')")
        warn(EnvironmentWarning, log, "Ray is not installed (pip install 'bemlearn[ray]'): running the cells one after another in this "
                                      "process (--backend serial)")
        kind = "serial"
    if kind == "serial":
        if max_parallel not in (None, 1):
            log.info("--max-parallel %d: the serial backend runs one cell at a time", max_parallel)
        return SerialBackend()
    return RayBackend(resources, address=address, max_parallel=max_parallel)
