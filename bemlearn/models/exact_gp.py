"""Exact GP of the BEM map q_u = f(x) + w (eq. 11) with the posterior of eq. (12)."""

from __future__ import annotations

from typing import Any, ClassVar

import gpytorch
import torch

from bemlearn.models.kernels import ard_se_kernel, se_gram
from bemlearn.models.solver import robust_cholesky
from bemlearn.models.validation import check_inputs, check_targets

__all__ = ["ExactBEMGP"]


class ExactBEMGP(gpytorch.models.ExactGP):
    r"""Exact GP, zero prior mean, ARD squared-exponential kernel (eq. 11).

    Hyperparameters θ = {W, σ_f, σ_0} maximize log p(Y | X, θ) (eq. 11); the posterior
    at x* is (eq. 12)

        μ(x*) = kᵀ K⁻¹ Y,   Σ(x*) = k* − kᵀ K⁻¹ k,   K = K_XX + σ_0² I.

    Train/predict inside :func:`bemlearn.models.solver.cholesky_policy` so that K⁻¹ is a
    Cholesky solve at every N.  ``forward`` is the prior (as on every kind, :mod:`bemlearn.models.gp_kinds`);
    :meth:`posterior` is eq. (12).

    Args:
        train_x: ``(N, d)`` float64 normalized inputs x = [q̈_a, q̇_a, q_a, q̈_u, q̇_u].
        train_y: ``(N,)`` float64 normalized outputs q_u.
        likelihood: the Gaussian likelihood holding σ_0².
    """

    #: The registered name of the kind (``train.kind``, a checkpoint's ``kind``).
    kind: ClassVar[str] = "exact"
    #: The posterior lives on the N training inputs (S = K⁻¹, solved with K's Cholesky factor).
    sparse: ClassVar[bool] = False

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

    def posterior(self, x: torch.Tensor) -> gpytorch.distributions.MultivariateNormal:
        """Posterior of f at ``x`` (eq. 12): μ = kᵀ K⁻¹ Y, Σ = K_xx − kᵀ K⁻¹ k, full ``(B, B)`` covariance.

        Puts the model in eval mode (GPyTorch's cached prediction strategy); call inside
        :func:`~bemlearn.models.solver.cholesky_policy`.

        Args:
            x: ``(B, d)`` normalized inputs.
        """
        if self.training:
            self.eval()
        return self(x)

    def posterior_weights(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Z = X, α = K⁻¹ Y, S = K⁻¹ with K = K_XX + σ_0² I (eq. 12 in frozen form).

        K is the Gram matrix exactly as the frozen state rebuilds it
        (:meth:`~bemlearn.models.predictor_state.PredictorState.gram`): with κ(K) ~ 1e8 (near-noise-free
        labels) GPyTorch's ‖a‖² + ‖b‖² − 2aᵀb distances would differ from it by far more than ε.  Its
        Cholesky factor follows the active jitter policy (:func:`~bemlearn.models.solver.robust_cholesky`).

        Returns:
            ``(N, d)`` Z, ``(N,)`` α, ``(N, N)`` S, normalized units.
        """
        X, Y = self.train_inputs[0], self.train_targets
        kern: Any = self.covar_module  # a gpytorch ScaleKernel: nn.Module attributes are untyped
        K = se_gram(X, kern.base_kernel.lengthscale.reshape(-1), kern.outputscale.reshape(()))
        lik: Any = self.likelihood  # a gpytorch GaussianLikelihood
        K = K + lik.noise.squeeze() * torch.eye(X.shape[0], dtype=K.dtype, device=K.device)
        L, _ = robust_cholesky(K, what="exact GP K_XX + σ_0² I")
        alpha = torch.cholesky_solve(Y[:, None], L).squeeze(-1)
        S = torch.cholesky_inverse(L)
        return X, alpha, 0.5 * (S + S.mT)

    def variance_factor(self) -> None:
        """``None``: an exact posterior's variance is solved with the Cholesky factor of K, which the
        frozen state rebuilds (:meth:`~bemlearn.models.predictor_state.PredictorState.gram_cholesky`)."""
        return None
