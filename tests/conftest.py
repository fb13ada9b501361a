"""Shared fixtures: deterministic seeds, restored global torch state."""

from __future__ import annotations

import random
import signal

import numpy as np
import pytest
import torch


def pytest_configure(config):
    """One torch (OpenMP) thread per test process.

    pytest-xdist runs one worker per core; a worker with more threads than its core waits on the others'
    (a 300 × 300 ``cholesky_inverse``: 0.19 s with two threads while the other core is busy, 0.001 s with one).
    The pipeline's own heavy stages run on one thread for the same reason (``train_run(threads=1)``).
    """
    torch.set_num_threads(1)
    # A shell without job control starts a background command (`cmd &`, `nohup cmd &`) with SIGINT ignored, and
    # every process it starts inherits that: the Ctrl-C tests (tests/test_interrupts.py, tests/test_signals.py)
    # would then test an ignored signal. The suite tests bemlearn's handling of a delivered SIGINT, so it
    # restores Python's own handler (subprocesses the tests start then get SIGINT's default action too).
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(autouse=True)
def _deterministic():
    """Seed every generator; restore torch's global defaults and the process's signal handlers after each test.

    Under pytest-xdist one worker runs many test files in an order that changes from run to run: a test that leaves
    SIGINT or SIGTERM handled otherwise (a Ray instance, an interrupt context left open) would break the interrupt
    tests that happen to run after it in the same worker, so it fails here, by name.
    """
    dtype = torch.get_default_dtype()
    threads = torch.get_num_threads()
    handlers = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    random.seed(0)
    np.random.seed(0)
    torch.manual_seed(0)
    yield
    changed = [signal.Signals(signum).name for signum, h in handlers.items() if signal.getsignal(signum) is not h]
    for signum, h in handlers.items():
        if h is not None:  # None: a handler not installed from Python, which Python cannot put back
            signal.signal(signum, h)
    assert torch.get_default_dtype() == dtype, "a test changed torch's default dtype"
    torch.set_default_dtype(dtype)
    torch.set_num_threads(threads)
    assert not changed, f"a test left the process's {changed} handler changed"


FURUTA_CONFIG = __import__("pathlib").Path(__file__).resolve().parents[1] / "configs" / "furuta.yaml"


def furuta_section(name: str, **overrides):
    """A section of the shipped ``configs/furuta.yaml`` (resolved), with ``overrides`` replaced."""
    import dataclasses

    from bemlearn.pipeline.resolve import load_pipeline_config

    return dataclasses.replace(getattr(load_pipeline_config(FURUTA_CONFIG), name), **overrides)
