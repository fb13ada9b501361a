"""Worker processes for the stages of a run that can overlap: :func:`default_jobs` and :func:`worker_pool`.

A run's closed loops (one per BEM source) and its ``.pt2`` export depend on nothing but the robot
and the checkpoint, so they can run beside the stages that remain (:mod:`bemlearn.pipeline.run`,
:func:`~bemlearn.pipeline.simulate.simulate_stage`).  ``jobs`` is the number of worker processes
doing that work; ``jobs = 1`` runs everything in the calling process, in order (the behaviour
before workers existed).  The results do not depend on ``jobs``: every loop and export is seeded
by its own config and computes the same numbers in any process.

The workers are forked (``multiprocessing`` start method ``"fork"``, Linux): they inherit the
loaded robot and need nothing pickled but the configs and the results.  Where ``fork`` is not
offered (Windows) or not the platform's safe default (macOS), :func:`worker_pool` gives no pool
and the callers run serially.
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
import os
import sys
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, ProcessPoolExecutor
from typing import Any

from bemlearn.errors import ArgumentError

__all__ = ["MAX_JOBS", "check_jobs", "default_jobs", "derivation_jobs", "fork_available", "stop_pool", "usable_cpus",
           "using_jobs", "worker_pool"]

log = logging.getLogger(__name__)

#: The most work a run can overlap: the model, zero and learned closed loops and the ``.pt2`` export.
MAX_JOBS = 4


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity mask where the platform has one, else ``os.cpu_count()``)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def default_jobs() -> int:
    """The default ``--jobs``: the usable CPUs, at most :data:`MAX_JOBS` (a run has no more to overlap)."""
    return min(usable_cpus(), MAX_JOBS)


#: The workers the derivations that play MuJoCo trials may fork (the excitation amplitude check's trials):
#: :func:`using_jobs` sets it for a block (``bemlearn run --jobs``); unset, :func:`usable_cpus`.
_DERIVATION_JOBS: contextvars.ContextVar[int | None] = contextvars.ContextVar("bemlearn_derivation_jobs", default=None)


def derivation_jobs() -> int:
    """The worker processes a derivation's independent MuJoCo trials may use: the count :func:`using_jobs` set, else
    :func:`usable_cpus` (a derivation's result never depends on it: each trial plays its own seed)."""
    jobs = _DERIVATION_JOBS.get()
    return usable_cpus() if jobs is None else jobs


@contextlib.contextmanager
def using_jobs(jobs: int) -> Iterator[None]:
    """Within the block, :func:`derivation_jobs` is ``jobs`` (checked by :func:`check_jobs`): ``1`` keeps every
    derivation in the calling process."""
    token = _DERIVATION_JOBS.set(check_jobs(jobs))
    try:
        yield
    finally:
        _DERIVATION_JOBS.reset(token)


def check_jobs(jobs: int, *, where: str = "--jobs") -> int:
    """``jobs`` when it is an integer ≥ 1; else an :class:`~bemlearn.errors.ArgumentError` naming ``where``."""
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ArgumentError(f"{where}: expected a positive integer (1 runs the stages one after the other), got {jobs!r}")
    return jobs


def fork_available() -> bool:
    """Whether :func:`worker_pool` can fork workers here (Linux with the ``"fork"`` start method)."""
    import multiprocessing as mp

    return sys.platform.startswith("linux") and "fork" in mp.get_all_start_methods()


def _worker_init(parent_pid: int, initializer: Callable[..., None] | None, initargs: tuple[Any, ...]) -> None:
    """First thing in a worker: end with the parent, compute on one thread, then the caller's initializer."""
    from bemlearn.child_processes import die_with_parent

    die_with_parent(parent_pid)
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[name] = "1"             # libraries that start their thread pools in the worker
    if "torch" in sys.modules:             # torch loaded by the parent: one intra-op thread per worker
        import torch

        torch.set_num_threads(1)
    if initializer is not None:
        initializer(*initargs)


@contextlib.contextmanager
def worker_pool(jobs: int, *, initializer: Callable[..., None] | None = None,
                initargs: tuple[Any, ...] = ()) -> Iterator[Executor | None]:
    """A pool of ``jobs`` forked worker processes, or ``None`` where the work runs serially.

    ``None`` when ``jobs == 1`` or where fork is not available (:func:`fork_available`: the
    fallback is serial, not ``spawn``, because the workers get the robot by inheritance).  Each
    worker ends with its parent (:func:`~bemlearn.child_processes.die_with_parent`), runs torch
    on one thread (``torch.set_num_threads(1)``; BLAS/OpenMP thread variables set to 1), then
    calls ``initializer(*initargs)`` (the arguments are inherited, not pickled).

    Leaving the block normally waits for the submitted work; leaving it by an exception
    (a failed stage, Ctrl-C) ends the workers at once and drops the work not started.
    """
    check_jobs(jobs)
    if jobs == 1 or not fork_available():
        if jobs > 1:
            log.info("no fork on %s: the %d jobs run one after the other", sys.platform, jobs)
        yield None
        return
    import multiprocessing as mp

    pool = ProcessPoolExecutor(jobs, mp_context=mp.get_context("fork"), initializer=_worker_init,
                               initargs=(os.getpid(), initializer, initargs))
    try:
        yield pool
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)


def stop_pool(pool: Executor) -> None:
    """End ``pool``'s workers now (running work included) and drop the queued work.

    ``ProcessPoolExecutor`` has no public way to stop running work; its process table is read as
    :func:`bemlearn.sim.collect.collect` does (an empty table where a future version renames it:
    ``shutdown`` still drops the queued work).
    """
    procs: dict = getattr(pool, "_processes", None) or {}
    for proc in list(procs.values()):
        with contextlib.suppress(Exception):
            proc.terminate()
    pool.shutdown(wait=False, cancel_futures=True)
