"""Prompt stops: SIGINT (Ctrl-C) and SIGTERM end the long step soon and keep its best state; a second signal exits at once.

SIGTERM is what ``timeout``, batch schedulers (Slurm, PBS) and ``docker stop`` send; it is
handled exactly like Ctrl-C.  :func:`sigint_handling` (installed by the ``bemlearn`` command
around every subcommand) replaces Python's handlers of both signals with one that

- records the request (and which signal it was, :func:`interrupt_signal`) and restores the
  default handlers, so a second signal of either kind ends the process immediately; a
  watcher thread reading Python's signal wake-up fd does the same when the first signal is
  still pending because the main thread is inside a long native call (torch releases the
  GIL there), so the second signal never waits for it;
- outside an :func:`interruptible` region raises :class:`KeyboardInterrupt` at once (as
  Python does for SIGINT);
- inside one (the optimizer loops) only records the request: the loop calls
  :func:`check_interrupt` between evaluations (inside the L-BFGS closure), restores the
  best parameters so far and raises :class:`KeyboardInterrupt` there, so the caller can
  write the best checkpoint.

A signal that was ignored when the block began (``nohup`` ignores SIGHUP, a shell's
background job SIGINT) stays ignored.  Without :func:`sigint_handling` (library use)
Python's own handler raises :class:`KeyboardInterrupt` on SIGINT wherever the program is,
SIGTERM kills the process, and the loops still restore their best parameters.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
from collections.abc import Iterator

__all__ = ["sigint_handling", "interruptible", "check_interrupt", "interrupt_requested", "interrupt_signal",
           "HANDLED_SIGNALS", "exit_status"]

log = logging.getLogger(__name__)

#: The signals that stop a command soon, keeping its best state.
HANDLED_SIGNALS: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM)

_state: dict = {"requested": False, "regions": 0, "installed": False, "signal": None, "handled": ()}


def interrupt_requested() -> bool:
    """Whether a SIGINT or SIGTERM arrived while :func:`sigint_handling` was active."""
    return bool(_state["requested"])


def interrupt_signal() -> signal.Signals | None:
    """The first handled signal that arrived (``SIGINT`` or ``SIGTERM``), or ``None``."""
    return _state["signal"]


def exit_status(signum: int | None) -> int:
    """The shell's exit status for a command ended by ``signum``: 128 + signum (130 for SIGINT, 143 for SIGTERM)."""
    return 128 + int(signum if signum is not None else signal.SIGINT)


def check_interrupt() -> None:
    """Raise :class:`KeyboardInterrupt` if a SIGINT or SIGTERM is pending (call between optimizer evaluations)."""
    if _state["requested"]:
        raise KeyboardInterrupt


def _handler(signum, frame) -> None:  # the signal handler signature
    _state["requested"] = True
    if _state["signal"] is None:
        _state["signal"] = signal.Signals(signum)
    for sig in _state["handled"]:  # a second signal of either kind ends the process at once
        signal.signal(sig, signal.SIG_DFL)
    name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
    log.warning("interrupted (%s): stopping after the current step and keeping the best state "
                "(a second signal exits at once)", name)
    if _state["regions"] == 0:
        raise KeyboardInterrupt


@contextlib.contextmanager
def sigint_handling() -> Iterator[None]:
    """Install the two-stage handler of SIGINT and SIGTERM for the block (main thread only; else a no-op)."""
    if threading.current_thread() is not threading.main_thread() or _state["installed"]:
        yield
        return
    previous = {sig: signal.getsignal(sig) for sig in HANDLED_SIGNALS}
    handled = tuple(sig for sig in HANDLED_SIGNALS if previous[sig] is not signal.SIG_IGN)
    _state.update(requested=False, regions=0, installed=True, signal=None, handled=handled)
    for sig in handled:
        signal.signal(sig, _handler)
    watcher = _Watcher(handled)
    try:
        yield
    finally:
        watcher.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        _state.update(requested=False, regions=0, installed=False, signal=None, handled=())


class _Watcher:
    """Counts handled signals from the signal wake-up fd in a thread; the second one exits the process at once."""

    def __init__(self, handled: tuple[signal.Signals, ...]) -> None:
        self.codes = {int(sig).to_bytes(1, "little"): sig for sig in handled}
        self.read_fd, self.write_fd = os.pipe()
        os.set_blocking(self.write_fd, False)
        try:
            self.previous_fd: int | None = signal.set_wakeup_fd(self.write_fd, warn_on_full_buffer=False)
        except ValueError:  # pragma: no cover - not the main thread
            self.previous_fd = None
        self.thread = threading.Thread(target=self._run, name="bemlearn-signal-watcher", daemon=True)
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
            for byte in data:
                sig = self.codes.get(bytes([byte]))
                if sig is None:
                    continue
                count += 1
                if count >= 2:
                    try:
                        sys.stderr.write(f"interrupted twice ({sig.name}): exiting now\n")
                        sys.stderr.flush()
                    finally:
                        os._exit(exit_status(sig))

    def stop(self) -> None:
        if self.previous_fd is not None:
            signal.set_wakeup_fd(self.previous_fd)
        os.close(self.write_fd)
        self.thread.join(1.0)
        os.close(self.read_fd)


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """A region that polls :func:`check_interrupt` itself (SIGINT and SIGTERM only set the flag inside it)."""
    check_interrupt()
    _state["regions"] += 1
    try:
        yield
    finally:
        _state["regions"] -= 1
