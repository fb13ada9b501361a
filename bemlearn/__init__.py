"""bemlearn: learn the balance equilibrium manifold (BEM) of underactuated balance robots.

Layout (each layer only imports the ones before it):
``robots`` (models, dynamics, model-based BEM, zero dynamics) → ``data`` (excitation,
trajectory files, derivatives, GP datasets) → ``models`` (GPs, GPDM: math only) →
``fitting`` (training loops, logging) → ``export`` (TorchScript / torch.export
predictors) → ``control`` / ``sim`` (EIC controller, closed loop) → ``cli``.
"""

from bemlearn._version import __version__
from bemlearn.errors import (
    ArgumentError,
    BemlearnError,
    CheckpointError,
    ConfigError,
    DataError,
    EnvironmentProblem,
    MissingFileError,
    NumericalError,
    OutputBusyError,
    OutputExistsError,
    PredictorInputError,
    RobotModelError,
    StalePredictorError,
    SweepError,
    TrajectoryFormatError,
)
from bemlearn.warnings import (
    BemlearnWarning,
    DataWarning,
    DesignWarning,
    EnvironmentWarning,
    FitWarning,
    NumericalWarning,
    RobotModelWarning,
    UncertaintyWarning,
)

__all__ = [
    "__version__",
    "ArgumentError",
    "BemlearnError",
    "CheckpointError",
    "ConfigError",
    "DataError",
    "EnvironmentProblem",
    "MissingFileError",
    "NumericalError",
    "OutputBusyError",
    "OutputExistsError",
    "PredictorInputError",
    "RobotModelError",
    "StalePredictorError",
    "SweepError",
    "TrajectoryFormatError",
    "BemlearnWarning",
    "DataWarning",
    "DesignWarning",
    "EnvironmentWarning",
    "FitWarning",
    "NumericalWarning",
    "RobotModelWarning",
    "UncertaintyWarning",
]
