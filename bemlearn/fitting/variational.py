"""The optimal variational distribution of an SVGP for fixed hyperparameters (Titsias, 2009)."""

from __future__ import annotations

import gpytorch
import torch

from bemlearn.models.sgpr import SGPRBEMGP
from bemlearn.models.solver import cholesky_policy
from bemlearn.models.svgp import SVGPBEMGP

__all__ = ["optimal_variational"]


def optimal_variational(
    model: SVGPBEMGP, likelihood: gpytorch.likelihoods.GaussianLikelihood, train_x: torch.Tensor, train_y: torch.Tensor
) -> None:
    """Set q(v) of an SVGP to the optimum for its current θ and Z (Titsias, 2009).

    The optimal q(u) is the SGPR posterior at Z; whitened with K_ZZ + jI = L Lᵀ it is
    m = L_B⁻ᵀ c, S_v = B⁻¹ (:meth:`SGPRBEMGP.whitened_posterior`).  Costs O(N M²) time
    (chunked, no autograd) and O(chunk · M + M²) memory.

    Args:
        model: the SVGP whose q(v) is replaced.
        likelihood: its Gaussian likelihood (σ_0²).
        train_x: ``(N, d)`` normalized inputs on the model's device.
        train_y: ``(N,)`` normalized outputs.
    """
    Z = model.variational_strategy.inducing_points.detach()
    likelihood_mode = likelihood.training
    with torch.no_grad(), cholesky_policy():
        sgpr = SGPRBEMGP(train_x, train_y, likelihood, Z, jitter=model.jitter).to(Z.device)
        sgpr.covar_module.load_state_dict(model.covar_module.state_dict())
        sgpr.eval()
        mean, covariance = sgpr.whitened_posterior()
        model.set_variational(mean, covariance)
    likelihood.train(likelihood_mode)
