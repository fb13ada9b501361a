"""bemlearn.data: trajectory files, derivative estimation and GP datasets (eq. 11).

- :class:`Trajectory` / :class:`TrajectoryMeta`: samples t, trial, q, u (+ true qd, qdd);
  :func:`read_trajectory`, :func:`write_trajectory` (NPZ / CSV, ``docs/trajectory-format.md``),
  :func:`validate`.
- :data:`DERIVATIVE_ESTIMATORS` (``"central"``, ``"savgol"``), :func:`make_estimator`,
  :func:`estimate_derivatives` (per trial).
- :func:`gp_inputs`, :func:`gp_input_names`: x = [q̈_a, q̇_a, q_a, q̈_u, q̇_u] of eq. (11).
- :class:`DatasetConfig`, :func:`build_datasets` → :class:`GPDatasets` of :class:`BEMDataset`.
"""

from bemlearn.data.dataset import DatasetConfig, build_datasets, split_trials
from bemlearn.data.dataset_types import BEMDataset, GPDatasets
from bemlearn.data.derivatives import DERIVATIVE_ESTIMATORS, DerivativeEstimator, estimate_derivatives, make_estimator
from bemlearn.data.features import gp_input_names, gp_inputs, gp_output_name
from bemlearn.data.finite_difference import CentralDifference
from bemlearn.data.normalization import Normalization
from bemlearn.data.quantization import counts_per_revolution, detect_quantization_step
from bemlearn.data.savitzky_golay import SavitzkyGolay
from bemlearn.data.trajectory import DEFAULT_UNITS, Trajectory, TrajectoryFormatError, TrajectoryMeta, TrialSlice
from bemlearn.data.trajectory_io import ground_truth_path, read_ground_truth, read_trajectory, write_trajectory
from bemlearn.data.validation import MIN_TRIAL_SAMPLES, RATE_RTOL, RobotLike, check_robot, column_names, validate

__all__ = [
    # trajectories
    "Trajectory",
    "TrajectoryMeta",
    "TrialSlice",
    "TrajectoryFormatError",
    "DEFAULT_UNITS",
    "read_trajectory",
    "read_ground_truth",
    "write_trajectory",
    "ground_truth_path",
    "validate",
    "check_robot",
    "column_names",
    "RobotLike",
    "MIN_TRIAL_SAMPLES",
    "RATE_RTOL",
    "detect_quantization_step",
    "counts_per_revolution",
    # derivatives
    "DerivativeEstimator",
    "DERIVATIVE_ESTIMATORS",
    "make_estimator",
    "estimate_derivatives",
    "CentralDifference",
    "SavitzkyGolay",
    # GP datasets
    "gp_inputs",
    "gp_input_names",
    "gp_output_name",
    "Normalization",
    "DatasetConfig",
    "build_datasets",
    "split_trials",
    "BEMDataset",
    "GPDatasets",
]
