"""bemlearn.models: GP models of the BEM map (math only) and their frozen posterior form."""

from bemlearn.models.band import band_reference
from bemlearn.models.exact_gp import ExactBEMGP
from bemlearn.models.freeze import posterior_weights, predictor_state, variance_cholesky_factor
from bemlearn.models.gp_kinds import BEMGP, GP_KINDS, as_gp, gp_class, gp_kind_of
from bemlearn.models.gpdm import GPDM, GPDMObjective, LatentComparison, compare_latents, reconstruct_latent
from bemlearn.models.input_noise import mean_gradient
from bemlearn.models.kernels import ard_se_kernel, gaussian_likelihood, kernel_matrix, se_cross_covariance
from bemlearn.models.learned_bem import BEMPrediction, LearnedBEM, srinivas_kappa
from bemlearn.models.plane_posterior import with_plane_posterior
from bemlearn.models.predict import predict
from bemlearn.models.predictor_state import GPKind, PredictorState
from bemlearn.models.sgpr import SGPRBEMGP
from bemlearn.models.solver import cholesky_policy, robust_cholesky
from bemlearn.models.svgp import SVGPBEMGP

__all__ = [
    "GPDM",
    "GPDMObjective",
    "LatentComparison",
    "compare_latents",
    "reconstruct_latent",
    "LearnedBEM",
    "BEMPrediction",
    "srinivas_kappa",
    "band_reference",
    "mean_gradient",
    "with_plane_posterior",
    "PredictorState",
    "GPKind",
    "GP_KINDS",
    "BEMGP",
    "as_gp",
    "gp_class",
    "gp_kind_of",
    "ExactBEMGP",
    "SGPRBEMGP",
    "SVGPBEMGP",
    "ard_se_kernel",
    "gaussian_likelihood",
    "kernel_matrix",
    "se_cross_covariance",
    "cholesky_policy",
    "robust_cholesky",
    "predict",
    "predictor_state",
    "posterior_weights",
    "variance_cholesky_factor",
]
