"""Entry point of the ``bemlearn`` command.

Each subcommand lives in its own module of this package exposing
``add_parser(subparsers)``, which registers the parser and sets ``func`` (a callable
taking the parsed namespace and returning an exit code).

Errors: a :class:`~bemlearn.errors.BemlearnError` (a bad config, a missing file, data that
cannot be used, ...) is one line ``bemlearn COMMAND: error: MESSAGE`` and exit status 2, as is a
:class:`~bemlearn.warnings.BemlearnWarning` escalated to an error (``python -W error::bemlearn.warnings.FitWarning -m bemlearn ...``); any
other exception is a bug and keeps its traceback (exit status 1).  A bemlearn warning is shown
once, as its log line (:func:`~bemlearn.warnings.shown_by_log`).  A closed standard output
(``bemlearn config show X | head -1``) ends the command quietly with status 141 (128 + SIGPIPE).  ``-v`` prints the traceback
of every error.  Ctrl-C / SIGTERM exit with 130 / 143; a command's own status (e.g. 3 or 4
for a verdict) is returned as it is.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import signal
import sys
import traceback

from bemlearn._version import __version__
from bemlearn.applications import applications
from bemlearn.errors import BemlearnError
from bemlearn.interrupts import exit_status, interrupt_signal, sigint_handling
from bemlearn.warnings import BemlearnWarning, shown_by_log

__all__ = ["main", "build_parser"]

#: Subcommand modules, in the order they appear in ``bemlearn --help``.
SUBCOMMANDS: tuple[str, ...] = (
    "bemlearn.cli.robot_cmd",
    "bemlearn.cli.config_cmd",
    "bemlearn.cli.collect_cmd",
    "bemlearn.cli.train_cmd",
    "bemlearn.cli.evaluate_cmd",
    "bemlearn.cli.run_cmd",
    "bemlearn.cli.sweep_cmd",
    "bemlearn.cli.data_cmd",
    "bemlearn.cli.excite_cmd",
    "bemlearn.cli.export_cmd",
    "bemlearn.cli.examples_cmd",
    "bemlearn.cli.bench_cmd",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bemlearn",
        description="Learn the balance equilibrium manifold of underactuated balance robots "
        "and use it in an EIC control loop.",
    )
    parser.add_argument("--version", action="version", version=f"bemlearn {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="debug logging, and the traceback of every error (not only of bugs)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        importlib.import_module(name).add_parser(sub)
    for app in applications().values():  # robot applications add their own commands
        if app.add_cli is not None:
            app.add_cli(sub)
    return parser


#: Exit status when the reader of standard output went away (`bemlearn config show X | head -1`): 128 + SIGPIPE,
#: what a shell reports for a program that SIGPIPE ended.
CLOSED_PIPE_STATUS = 128 + 13


def _stdout_closed() -> bool:
    """Whether standard output is a pipe whose reading end is closed (poll reports an error on it)."""
    import select

    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(ev & (select.POLLERR | select.POLLHUP) for _, ev in poller.poll(0))
    except (OSError, ValueError, AttributeError):  # no real file behind stdout (captured, closed)
        return False


def main(argv: list[str] | None = None) -> int:
    """Run ``bemlearn`` with ``argv``; its exit status.  A reader of standard output that leaves early
    (``… | head -1``) ends the command quietly with :data:`CLOSED_PIPE_STATUS`, no traceback."""
    try:
        try:
            return _main(argv)
        finally:
            sys.stdout.flush()  # a reader that left shows here, not at the interpreter's exit
    except BrokenPipeError:
        if not _stdout_closed():
            raise
        with contextlib.suppress(OSError, ValueError, AttributeError):  # what is still buffered goes nowhere
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return CLOSED_PIPE_STATUS


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    received = None
    try:
        # Ctrl-C or SIGTERM: stop soon keeping the best state; a second signal: exit at once.  A bemlearn
        # warning shows once, as its log line (bemlearn.warnings.shown_by_log)
        with sigint_handling(), shown_by_log():
            try:
                return int(args.func(args) or 0)
            except KeyboardInterrupt:
                received = interrupt_signal()
                raise
    except (BemlearnError, BemlearnWarning) as exc:  # a deliberate error, or a warning escalated by -W error::…: one line
        if args.verbose:
            traceback.print_exc()
        print(f"bemlearn {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:
        if isinstance(exc, BrokenPipeError) and _stdout_closed():
            raise  # the reader of our output left: main() ends quietly
        traceback.print_exc()
        print(f"bemlearn {args.command}: internal error ({type(exc).__name__}), a bug in bemlearn: "
              "please report it with the traceback above", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        status = exit_status(received)
        what = "interrupted" if received in (None, signal.SIGINT) else f"terminated ({received.name})"
        print(f"bemlearn {args.command}: {what}", file=sys.stderr)
        if argv is None:  # the real command line: outputs are written and closed, skip the slow teardown
            logging.shutdown()
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(status)
        return status


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
