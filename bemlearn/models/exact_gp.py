"""Exact GP of the BEM map q_u = f(x) + w (eq. 11) with the posterior of eq. (12)."""

from __future__ import annotations

import gpytorch
import torch

from bemlearn.models.kernels import ard_se_kernel
from bemlearn.models.validation import check_inputs, check_targets

__all__ = ["ExactBEMGP"]


class ExactBEMGP(gpytorch.models.ExactGP):
    r"""Exact GP, zero prior mean, ARD squared-exponential kernel (eq. 11).

    Hyperparameters θ = {W, σ_f, σ_0} maximize log p(Y | X, θ) (eq. 11); the posterior
    at x* is (eq. 12)

        μ(x*) = kᵀ K⁻¹ Y,   Σ(x*) = k* − kᵀ K⁻¹ k,   K = K_XX + σ_0² I.

    Train/predict inside :func:`bemlearn.models.solver.cholesky_policy` so that K⁻¹ is a
    Cholesky solve at every N.

    Args:
        train_x: ``(N, d)`` float64 normalized inputs x = [q̈_a, q̇_a, q_a, q̈_u, q̇_u].
        train_y: ``(N,)`` float64 normalized outputs q_u.
        likelihood: the Gaussian likelihood holding σ_0².
    """

    def __init__(
        self,
        train_x: torch.Tensor,
        train_y: torch.Tensor,
        likelihood: gpytorch.likelihoods.GaussianLikelihood,
    ) -> None:
        check_inputs(train_x, name="train_x")
        check_targets(train_y, name="train_y", n=train_x.shape[0], dtype=train_x.dtype)
        super().__init__(train_x, train_y, likelihood)
        self.mean_module = gpytorch.means.ZeroMean()
        self.covar_module = ard_se_kernel(train_x.shape[1], dtype=train_x.dtype)

    @property
    def dim(self) -> int:
        """Input dimension d."""
        return int(self.train_inputs[0].shape[-1])

    def forward(self, x: torch.Tensor) -> gpytorch.distributions.MultivariateNormal:
        """Prior N(0, K_xx) at ``x``: ``(B, d)`` normalized inputs."""
        return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))
