"""Prompt Ctrl-C: the first SIGINT ends the long step soon and keeps its best state; a second exits at once.

:func:`sigint_handling` (installed by the ``bemlearn`` command around every subcommand)
replaces Python's SIGINT handler with one that

- records the request and restores the default handler, so a second Ctrl-C ends the
  process immediately; a watcher thread reading Python's signal wake-up fd does the same
  when the first signal is still pending because the main thread is inside a long native
  call (torch releases the GIL there), so the second Ctrl-C never waits for it;
- outside an :func:`interruptible` region raises :class:`KeyboardInterrupt` at once (as
  Python would);
- inside one (the optimizer loops) only records the request: the loop calls
  :func:`check_interrupt` between evaluations (inside the L-BFGS closure), restores the
  best parameters so far and raises :class:`KeyboardInterrupt` there, so the caller can
  write the best checkpoint.

Without :func:`sigint_handling` (library use) Python's own handler raises
:class:`KeyboardInterrupt` wherever the program is, and the loops still restore their
best parameters.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
from collections.abc import Iterator

__all__ = ["sigint_handling", "interruptible", "check_interrupt", "interrupt_requested"]

log = logging.getLogger(__name__)

_state = {"requested": False, "regions": 0, "installed": False}


def interrupt_requested() -> bool:
    """Whether a SIGINT arrived while :func:`sigint_handling` was active."""
    return bool(_state["requested"])


def check_interrupt() -> None:
    """Raise :class:`KeyboardInterrupt` if a SIGINT is pending (call between optimizer evaluations)."""
    if _state["requested"]:
        raise KeyboardInterrupt


def _handler(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    _state["requested"] = True
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a second Ctrl-C ends the process at once
    log.warning("interrupted: stopping after the current step and keeping the best state (Ctrl-C again to exit at once)")
    if _state["regions"] == 0:
        raise KeyboardInterrupt


@contextlib.contextmanager
def sigint_handling() -> Iterator[None]:
    """Install the two-stage SIGINT handler for the block (main thread only; else a no-op)."""
    if threading.current_thread() is not threading.main_thread() or _state["installed"]:
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    _state.update(requested=False, regions=0, installed=True)
    signal.signal(signal.SIGINT, _handler)
    watcher = _Watcher()
    try:
        yield
    finally:
        watcher.stop()
        signal.signal(signal.SIGINT, previous)
        _state.update(requested=False, regions=0, installed=False)


class _Watcher:
    """Counts SIGINTs from the signal wake-up fd in a thread; the second one exits the process at once."""

    def __init__(self) -> None:
        self.read_fd, self.write_fd = os.pipe()
        os.set_blocking(self.write_fd, False)
        try:
            self.previous_fd = signal.set_wakeup_fd(self.write_fd, warn_on_full_buffer=False)
        except ValueError:  # pragma: no cover - not the main thread
            self.previous_fd = None
        self.thread = threading.Thread(target=self._run, name="bemlearn-sigint-watcher", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        count = 0
        while True:
            try:
                data = os.read(self.read_fd, 64)
            except OSError:
                return
            if not data:
                return
            count += data.count(signal.SIGINT.to_bytes(1, "little"))
            if count >= 2:
                try:
                    sys.stderr.write("interrupted twice: exiting now\n")
                    sys.stderr.flush()
                finally:
                    os._exit(130)

    def stop(self) -> None:
        if self.previous_fd is not None:
            signal.set_wakeup_fd(self.previous_fd)
        os.close(self.write_fd)
        self.thread.join(1.0)
        os.close(self.read_fd)


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """A region that polls :func:`check_interrupt` itself (SIGINT only sets the flag inside it)."""
    check_interrupt()
    _state["regions"] += 1
    try:
        yield
    finally:
        _state["regions"] -= 1
