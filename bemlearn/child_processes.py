"""Worker processes that end with their parent, whatever ends the parent (SIGTERM, ``kill -9``, a crash).

:func:`die_with_parent` is called first thing in a worker process (e.g. as the
``initializer`` of a :class:`concurrent.futures.ProcessPoolExecutor`).  Two mechanisms, so
that neither a missed kernel notification nor a platform without it leaves an orphan:

- on Linux the kernel delivers SIGKILL to the worker when its parent exits
  (``prctl(PR_SET_PDEATHSIG, SIGKILL)``, set through ``ctypes``); a parent that died before
  the call is caught by comparing ``os.getppid()`` with the expected parent right after;
- everywhere, a daemon thread polls ``os.getppid()`` every ``poll_s`` seconds and ends the
  worker with ``os._exit`` once the parent is gone (an orphan is re-parented to PID 1 or a
  subreaper).

The worker also drops the parent's Python handlers of SIGINT / SIGTERM and its signal
wake-up fd (inherited through ``fork``): the parent handles Ctrl-C and ends its workers.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import signal
import sys
import threading
import time

__all__ = ["die_with_parent"]

#: ``PR_SET_PDEATHSIG`` of ``<linux/prctl.h>``.
_PR_SET_PDEATHSIG = 1


def _set_parent_death_signal(sig: int) -> bool:
    """Ask the Linux kernel to send ``sig`` to this process when its parent exits; whether it worked."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):  # no libc or no prctl: the polling thread still works
        return False


def _watch_parent(parent_pid: int, poll_s: float) -> None:
    while True:
        if os.getppid() != parent_pid:
            os._exit(1)
        time.sleep(poll_s)


def die_with_parent(parent_pid: int, *, poll_s: float = 0.25) -> None:
    """End this (worker) process as soon as the process ``parent_pid`` is gone.

    Args:
        parent_pid: the parent's PID, taken in the parent (``os.getpid()``) and passed to
            the worker, so a parent that is already gone when the worker starts is noticed.
        poll_s: seconds between two checks of the polling thread.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # the parent handles Ctrl-C and ends the workers
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # terminate() from the parent ends the worker at once
    with contextlib.suppress(ValueError):  # not the main thread
        signal.set_wakeup_fd(-1)                   # the parent's wake-up pipe is the parent's
    _set_parent_death_signal(signal.SIGKILL)
    if os.getppid() != parent_pid:                 # the parent died before the kernel was told
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid, poll_s), name="bemlearn-parent-watch", daemon=True).start()
