"""bemlearn.data: trajectory files, derivative estimation and GP datasets (eq. 11).

- :class:`Trajectory` / :class:`TrajectoryMeta`: samples t, trial, q, u (+ true qd, qdd);
  :func:`read_trajectory`, :func:`write_trajectory` (NPZ / CSV, ``docs/trajectory-format.md``),
  :func:`validate`.
- :data:`DERIVATIVE_ESTIMATORS` (``"central"``, ``"savgol"``), :func:`make_estimator`,
  :func:`estimate_derivatives` (per trial).
- :func:`gp_inputs`, :func:`gp_input_names`: x = [q̈_a, q̇_a, q_a, q̈_u, q̇_u] of eq. (11).
- :class:`DatasetConfig`, :func:`build_datasets` → :class:`GPDatasets` of :class:`BEMDataset`.
- :func:`import_logs` by an :class:`ImportMap` (:func:`load_import_map`): a logger's CSV files →
  a trajectory (``docs/log-import.md``); :func:`place_on_grid` (jittered stamps → nominal grid);
  :func:`write_rig_logs` (logger-style test logs); units by joint kind (:func:`joint_unit`).
"""

from bemlearn.data.dataset import DatasetConfig, build_datasets, split_trials
from bemlearn.data.dataset_types import BEMDataset, GPDatasets
from bemlearn.data.derivatives import (
    DERIVATIVE_ESTIMATORS,
    DerivativeEstimator,
    estimate_derivatives,
    make_estimator,
)
from bemlearn.data.features import gp_input_names, gp_inputs, gp_output_name
from bemlearn.data.finite_difference import CentralDifference
from bemlearn.data.import_map import ImportMap, load_import_map
from bemlearn.data.log_import import import_logs
from bemlearn.data.log_table import LogTable, read_log_table
from bemlearn.data.normalization import Normalization
from bemlearn.data.quantization import (
    counts_per_revolution,
    detect_quantization_step,
    snap_to_grid,
)
from bemlearn.data.resample import GridSegment, place_on_grid
from bemlearn.data.rig_logs import RigLogStyle, rig_log_map, write_rig_logs
from bemlearn.data.savitzky_golay import SavitzkyGolay
from bemlearn.data.trajectory import (
    DEFAULT_UNITS,
    Trajectory,
    TrajectoryFormatError,
    TrajectoryMeta,
    TrialSlice,
)
from bemlearn.data.trajectory_io import (
    ground_truth_path,
    read_ground_truth,
    read_trajectory,
    write_trajectory,
)
from bemlearn.data.validation import (
    JITTER_RTOL,
    MIN_TRIAL_SAMPLES,
    RATE_RTOL,
    RobotLike,
    check_robot,
    column_names,
    validate,
)
from bemlearn.units import JOINT_KINDS, gp_input_units, joint_unit

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
    "snap_to_grid",
    "JITTER_RTOL",
    "JOINT_KINDS",
    "joint_unit",
    "gp_input_units",
    # logger import
    "ImportMap",
    "load_import_map",
    "import_logs",
    "read_log_table",
    "LogTable",
    "GridSegment",
    "place_on_grid",
    "RigLogStyle",
    "write_rig_logs",
    "rig_log_map",
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
