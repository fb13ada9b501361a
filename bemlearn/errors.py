"""One exception family for bemlearn: catch :class:`BemlearnError` to catch them all.

Every subclass that describes bad input is also a :class:`ValueError` (and
:class:`OutputExistsError` a :class:`FileExistsError`), so code written against the older
``except ValueError`` keeps working.  Messages name the file, key, column or argument and
what was expected.
"""

from __future__ import annotations

__all__ = [
    "BemlearnError",
    "ConfigError",
    "TrajectoryFormatError",
    "RobotModelError",
    "CheckpointError",
    "OutputExistsError",
    "OutputBusyError",
    "PredictorInputError",
    "StalePredictorError",
    "EnvironmentProblem",
    "SweepError",
]


class BemlearnError(Exception):
    """Base class of every error bemlearn raises on purpose."""


class ConfigError(BemlearnError, ValueError):
    """A configuration value is missing, unknown or of the wrong type."""


class TrajectoryFormatError(BemlearnError, ValueError):
    """A trajectory file or array set is malformed; the message names file, column and row."""


class RobotModelError(BemlearnError, ValueError):
    """The model is not an underactuated balance robot bemlearn can handle."""


class CheckpointError(BemlearnError, ValueError):
    """A checkpoint or predictor file cannot be read, or its contents are inconsistent."""


class OutputExistsError(BemlearnError, FileExistsError):
    """A command would replace existing outputs; the message lists them and says ``use --force``."""


class OutputBusyError(OutputExistsError):
    """Another bemlearn command is writing the same output folder right now; the message names it."""


class PredictorInputError(BemlearnError, ValueError):
    """A predictor was called with an input of the wrong rank, width, dtype, size or values."""


class StalePredictorError(BemlearnError, ValueError):
    """A run folder's predictor file was exported from a different checkpoint than the one beside it."""


class EnvironmentProblem(BemlearnError, RuntimeError):
    """The machine cannot do what was asked (no CUDA device, no offscreen GL backend, unwritable folder)."""


class SweepError(BemlearnError, RuntimeError):
    """A sweep cannot start or go on: its folder is being written by another ``bemlearn sweep``,
    or its cells ask for more CPUs or GPUs than the Ray cluster has."""
