"""One warning family for bemlearn: filter or escalate :class:`BemlearnWarning` (or one subclass).

A condition a caller may want to act on — data dropped, a fit that stopped on a numerical
failure, a jitter added to a Cholesky factor, a band calibration that fell back, a design
outside the actuator limits — is issued through :func:`warn`: a ``warnings.warn`` of one of
these classes, attributed to the caller's own code (the first frame outside the bemlearn
package), *and* the log line it always was, on the module's logger, for the console and the
run's logs.  docs/warnings.md lists every warning: when it is raised and what to do.

* :class:`DataWarning`: the data were usable, but part of them was dropped or adjusted (short
  trials or pieces, constant columns, a file tail not imported, resampled angles off their
  encoder grid, a logged torque on the unactuated joint).
* :class:`RobotModelWarning`: the robot model is used with an assumption (no upright
  equilibrium found, equality constraints ignored).
* :class:`DesignWarning`: a derived design is doubtful (an excitation that cannot reach the
  wanted q_u, an EIC unstable at upright with the derived gains, an LQR that needs more than the
  actuator limits).
* :class:`NumericalWarning` (also a ``RuntimeWarning``): the numbers needed help or lost
  precision, and the result was kept (jitter added to a matrix, negative variances rounded up,
  an ill-conditioned exact posterior, a frozen latent std that lost its digits).
* :class:`FitWarning` (also a ``RuntimeWarning``): a fit stopped on a numerical failure and kept
  the best parameters it had evaluated (as BoTorch's ``OptimizationWarning``).
* :class:`UncertaintyWarning`: the band calibration fell back (std_scale = 1) or left replica
  queries out.
* :class:`EnvironmentWarning` (also a ``RuntimeWarning``): the installation lacks something and
  bemlearn went on without it (Ray, an application plugin).

Escalate one in a script or a test with ``warnings.simplefilter("error", FitWarning)`` (or
``python -W error::bemlearn.warnings.FitWarning``); the ``bemlearn`` command then stops with a
one-line error.  Silence one with ``"ignore"``; its log line stays (lower the level of the
``bemlearn`` logger to drop it too).  The ``bemlearn`` command shows each warning once, as its
log line (:func:`shown_by_log`).
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = [
    "issued",
    "BemlearnWarning",
    "DataWarning",
    "RobotModelWarning",
    "DesignWarning",
    "NumericalWarning",
    "FitWarning",
    "UncertaintyWarning",
    "EnvironmentWarning",
    "warn",
    "shown_by_log",
]

#: The package's folder: frames of files under it are bemlearn's own.
_PACKAGE = str(Path(__file__).resolve().parent) + os.sep


class BemlearnWarning(UserWarning):
    """Base class of every warning bemlearn issues."""


class DataWarning(BemlearnWarning):
    """The data were usable, but part of them was dropped or adjusted; the message says what and why."""


class RobotModelWarning(BemlearnWarning):
    """The robot model is used with an assumption the message names (e.g. q_u = 0 taken as nominal)."""


class DesignWarning(BemlearnWarning):
    """A derived design (excitation, EIC gains, LQR) is doubtful: the message gives the figure."""


class NumericalWarning(BemlearnWarning, RuntimeWarning):
    """The numbers needed help (jitter) or lost precision; the result was kept."""


class FitWarning(BemlearnWarning, RuntimeWarning):
    """A fit stopped on a numerical failure and kept the best parameters it had evaluated."""


class UncertaintyWarning(BemlearnWarning):
    """The uncertainty band's calibration fell back or left queries out."""


class EnvironmentWarning(BemlearnWarning, RuntimeWarning):
    """The installation lacks something (Ray, an application plugin) and bemlearn went on without it."""


def _caller_stacklevel() -> int:
    """The ``stacklevel`` that attributes a warning issued by :func:`warn` to the first frame outside
    the bemlearn package (what Python 3.12's ``skip_file_prefixes`` does)."""
    import inspect  # on first use: a warning is rare, start-up is not

    frame = inspect.currentframe()
    level = 0
    while frame is not None and str(Path(frame.f_code.co_filename).resolve()).startswith(_PACKAGE):
        frame = frame.f_back
        level += 1
    return max(level, 1)


_ISSUED = [0]


def issued() -> int:
    """How many warnings :func:`warn` has issued in this process (a computation whose result is reused where it
    issued none need not replay any)."""
    return _ISSUED[0]


def warn(category: type[BemlearnWarning], logger: logging.Logger, msg: str, *args: object) -> None:
    """Issue ``msg % args`` as a ``category`` warning and log it at WARNING on ``logger``.

    The warning is attributed to the caller's code (the first frame outside bemlearn), so a
    filter on the category, or on the caller's module, applies.  An escalated warning
    (``simplefilter("error", ...)``) raises here, before the log line.

    Args:
        category: the :class:`BemlearnWarning` subclass.
        logger: the issuing module's logger (the console line, the run's log).
        msg: the message, with ``%`` placeholders as in ``logging``.
        args: the placeholders' values.
    """
    _ISSUED[0] += 1
    warnings.warn(category(msg % args if args else msg), stacklevel=_caller_stacklevel())
    logger.warning(msg, *args, stacklevel=2)


@contextmanager
def shown_by_log() -> Iterator[None]:
    """Inside, the ``warnings`` module does not print a :class:`BemlearnWarning`: its log line shows it
    (the ``bemlearn`` command's console).  Filters still apply: an escalated warning still raises;
    other warnings are shown as before.  Restores the previous ``warnings.showwarning`` and filters."""
    with warnings.catch_warnings():
        previous = warnings.showwarning

        def _show(message, category, filename, lineno, file=None, line=None):
            if not issubclass(category, BemlearnWarning):
                previous(message, category, filename, lineno, file, line)

        warnings.showwarning = _show
        yield
