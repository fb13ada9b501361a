"""One exception family for bemlearn: catch :class:`BemlearnError` to catch them all.

bemlearn raises only these classes (an ``ast`` test, ``tests/test_errors.py``, checks every
``raise`` under ``bemlearn/``).  Each one also derives from the built-in exception it stands
for, so code written against ``except ValueError`` (or ``TypeError``, ``FileNotFoundError``,
``FileExistsError``, ``RuntimeError``) keeps working.  Messages name the file, key, column or
argument and what was expected.

* :class:`ConfigError` (``ValueError``): a config file is missing or not YAML, or a config key
  (or the config-section object that holds it) is missing, unknown, of the wrong type or out of
  range.
* :class:`ArgumentError` (``ValueError`` and ``TypeError``): a function argument or
  command-line option has the wrong type, shape or value.
* :class:`DataError` (``ValueError``): well-formed data cannot give what was asked (too few
  samples or trials, nothing left after a window, non-finite values).
* :class:`TrajectoryFormatError` (``ValueError``): a trajectory, log or gait file (or array
  set) is malformed.
* :class:`RobotModelError` (``ValueError``): the model is not a balance robot bemlearn can handle.
* :class:`CheckpointError` (``ValueError``): a checkpoint, predictor file or posterior state is
  unreadable or inconsistent; :class:`StalePredictorError` (``ValueError``): a predictor was
  exported from another checkpoint.
* :class:`PredictorInputError` (``ValueError``): a predictor was called with a bad input.
* :class:`MissingFileError` (``FileNotFoundError``): a file or folder the call needs is missing.
* :class:`OutputExistsError` (``FileExistsError``): outputs would be replaced without
  ``--force``; :class:`OutputBusyError`, one of them: another command writes the same output.
* :class:`NumericalError` (``RuntimeError``): the numbers failed (no positive-definite factor
  even with jitter, no convergence, a non-finite value where none may be).
* :class:`EnvironmentProblem` (``RuntimeError``): the machine lacks what was asked (CUDA, a C
  compiler, OpenGL, a writable folder).
* :class:`SweepError` (``RuntimeError``): a sweep cannot start or go on.

:class:`bemlearn.fitting.NumericalFailure` (a :class:`NumericalError`) is what a loss evaluation
raises inside the optimizers; they catch it and keep the best parameters.

Three built-ins are still raised on purpose, and the ``ast`` test allows exactly these:

* ``KeyboardInterrupt`` without arguments: the signal protocol (a SIGINT / SIGTERM handler, or a
  stage that stopped early on one and hands it on to the command).
* ``ValueError`` inside ``if torch.jit.is_scripting():`` of a TorchScript-compiled predictor:
  the exported artifact runs without bemlearn (libtorch, another Python), and its contract
  (docs/predictor-contract.md) is a ``ValueError`` message.
* ``AssertionError`` for an internal invariant (two results bemlearn computed itself that must
  agree): it is a bug in bemlearn, not a user error, so it stays outside the family and the
  ``bemlearn`` command shows its traceback.

The ``bemlearn`` command prints a :class:`BemlearnError` as one line on stderr,
``bemlearn COMMAND: error: MESSAGE``, and exits with status 2.  Anything else that escapes
bemlearn — a ``KeyError``, an ``IndexError``, a ``ValueError`` from a shape mismatch, a
``TypeError`` from a wrong call inside bemlearn — is a bug: the command prints its traceback and
``bemlearn COMMAND: internal error (...)`` and exits with status 1.  ``bemlearn -v`` prints the
traceback of every error, family ones included (docs/safety.md).
"""

from __future__ import annotations

__all__ = [
    "BemlearnError",
    "ConfigError",
    "ArgumentError",
    "DataError",
    "TrajectoryFormatError",
    "RobotModelError",
    "CheckpointError",
    "StalePredictorError",
    "PredictorInputError",
    "MissingFileError",
    "OutputExistsError",
    "OutputBusyError",
    "NumericalError",
    "EnvironmentProblem",
    "SweepError",
]


class BemlearnError(Exception):
    """Base class of every error bemlearn raises on purpose."""


class ConfigError(BemlearnError, ValueError):
    """A configuration value is missing, unknown, of the wrong type or out of range.

    Raised for the keys of a config file and for the config-section objects that hold them
    (``CollectConfig``, ``GPConfig``, ``ImportMap``, ``SavitzkyGolay``, …), including a registry
    name a key selects (robot, application, GP kind, derivative estimator, BEM source).
    """


class ArgumentError(BemlearnError, ValueError, TypeError):
    """A function argument or command-line option has the wrong type, shape or value.

    Also a ``TypeError`` (where an argument of the wrong type used to raise one) and a
    ``ValueError``.  Includes options that exclude each other and queries for which the asked
    quantity does not exist (a BEM query with no root in the search interval).
    """


class DataError(BemlearnError, ValueError):
    """Well-formed data cannot give what was asked.

    Too few samples or trials (to split, to estimate a derivative, to fit), nothing left after
    the ``q_u`` window or the skips, non-finite or constant training columns, data of another
    robot than the one asked for.
    """


class TrajectoryFormatError(BemlearnError, ValueError):
    """A trajectory, log or gait file (or array set) is malformed; the message names file, column and row."""


class RobotModelError(BemlearnError, ValueError):
    """The model is not an underactuated balance robot bemlearn can handle (joint or actuator
    types, no BEM near upright, a controller built for another robot)."""


class CheckpointError(BemlearnError, ValueError):
    """A checkpoint or predictor file cannot be read, or its contents (the posterior state, the
    metadata, the exported programs) are inconsistent."""


class StalePredictorError(BemlearnError, ValueError):
    """A run folder's predictor file was exported from a different checkpoint than the one beside it."""


class PredictorInputError(BemlearnError, ValueError):
    """A predictor was called with an input of the wrong rank, width, dtype, size or values."""


class MissingFileError(BemlearnError, FileNotFoundError):
    """A file or folder the call needs does not exist; the message names it and how to make it."""


class OutputExistsError(BemlearnError, FileExistsError):
    """A command would replace existing outputs; the message lists them and says ``use --force``."""


class OutputBusyError(OutputExistsError):
    """Another bemlearn command is writing the same output folder right now; the message names it."""


class NumericalError(BemlearnError, RuntimeError):
    """The numbers failed: a matrix not positive definite even after jitter, a Newton or boundary
    value solve that did not converge, a non-finite value where none may be."""


class EnvironmentProblem(BemlearnError, RuntimeError):
    """The machine cannot do what was asked (no CUDA device, no C compiler, no offscreen GL
    backend, an unwritable folder)."""


class SweepError(BemlearnError, RuntimeError):
    """A sweep cannot start or go on: its folder is being written by another ``bemlearn sweep``,
    or its cells ask for more CPUs or GPUs than the Ray cluster has."""
