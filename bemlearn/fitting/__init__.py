"""bemlearn.fitting: build, initialize and fit the BEM GPs (functions, not model methods)."""

from typing import TYPE_CHECKING

from bemlearn._lazy import lazy_namespace

if TYPE_CHECKING:  # imported on first use: bemlearn._lazy
    from bemlearn.fitting.build import build_gp
    from bemlearn.fitting.calibration import ReplicaCalibration, calibrate_replicas
    from bemlearn.fitting.exact import fit_exact
    from bemlearn.fitting.fit import fit_gp, train_gp
    from bemlearn.fitting.gp_config import GPConfig
    from bemlearn.fitting.gpdm_fit import GPDMConfig, fit_gpdm, gpdm_metrics
    from bemlearn.fitting.init import data_hyperparameters, initial_hyperparameters, select_inducing_points, set_hyperparameters
    from bemlearn.fitting.kinds import FIT_RECIPES, FitRecipe, fit_recipe
    from bemlearn.fitting.linear_mean import choose_prior_mean, least_squares_slope
    from bemlearn.fitting.optimize import NumericalFailure, minimize
    from bemlearn.fitting.result import Callback, FitResult, hyperparameter_metrics
    from bemlearn.fitting.sgpr import fit_sgpr
    from bemlearn.fitting.svgp import fit_svgp
    from bemlearn.fitting.variational import optimal_variational

__all__ = [
    "ReplicaCalibration",
    "calibrate_replicas",
    "GPDMConfig",
    "fit_gpdm",
    "gpdm_metrics",
    "GPConfig",
    "FitResult",
    "Callback",
    "NumericalFailure",
    "build_gp",
    "FitRecipe",
    "FIT_RECIPES",
    "fit_recipe",
    "train_gp",
    "fit_gp",
    "fit_exact",
    "fit_sgpr",
    "fit_svgp",
    "minimize",
    "initial_hyperparameters",
    "optimal_variational",
    "data_hyperparameters",
    "set_hyperparameters",
    "select_inducing_points",
    "hyperparameter_metrics",
    "least_squares_slope",
    "choose_prior_mean",
]

__getattr__, __dir__ = lazy_namespace(__name__, __file__)
