"""Stochastic variational GP (SVGP, Hensman et al. 2013) of the BEM map, for 10⁵–10⁶ points.

Whitened inducing values u = L v, K_ZZ + j I = L Lᵀ, q(v) = N(m, S_v) held in natural
parameters (S_v⁻¹ m and a triangular factor of S_v⁻¹) so that q can be trained by natural
gradient steps (Salimbeni et al., 2018) while θ and Z use Adam; the ELBO Σ_i E_q[log N(y_i | f(x_i), σ_0²)] − KL(q(v) ‖ N(0, I)) is an unbiased
minibatch objective, so the data can be streamed.  The posterior replacing eq. (12) is

    μ(x) = k_Z(x)ᵀ L⁻ᵀ m,    Σ(x) = σ_f² − k_Z(x)ᵀ L⁻ᵀ (I − S_v) L⁻¹ k_Z(x).

GPyTorch adds the jitter j to the test-test variance too; :meth:`SVGPBEMGP.posterior` removes
it so that Σ(x) is exactly the formula above.
"""

from __future__ import annotations

from typing import ClassVar

import gpytorch
import torch
from gpytorch.variational import TrilNaturalVariationalDistribution, VariationalStrategy

from bemlearn.errors import ArgumentError
from bemlearn.models.kernels import ard_se_kernel, kernel_matrix
from bemlearn.models.solver import robust_cholesky
from bemlearn.models.validation import check_inputs

__all__ = ["SVGPBEMGP"]


class SVGPBEMGP(gpytorch.models.ApproximateGP):
    """SVGP with a full-rank natural-parameter q(v), zero prior mean and the ARD kernel of eq. (11).

    ``forward`` is the prior N(0, K_xx), as on every kind (:mod:`bemlearn.models.gp_kinds`);
    :meth:`posterior` is q(f(x)) (module docstring).

    Args:
        inducing_points: ``(M, d)`` initial inducing inputs Z, normalized units (float64).
        learn_inducing_locations: optimize Z with the other parameters.
        jitter: j added to the diagonal of K_ZZ (normalized output units squared).
    """

    #: The registered name of the kind (``train.kind``, a checkpoint's ``kind``).
    kind: ClassVar[str] = "svgp"
    #: The posterior lives on the M inducing inputs Z (S factored as L⁻ᵀ C L⁻¹).
    sparse: ClassVar[bool] = True

    def __init__(
        self,
        inducing_points: torch.Tensor,
        *,
        learn_inducing_locations: bool = True,
        jitter: float = 1e-8,
    ) -> None:
        check_inputs(inducing_points, name="inducing_points")
        if not jitter > 0.0:
            raise ArgumentError(f"jitter: expected a positive value, got {jitter}")
        M, d = inducing_points.shape
        dtype = inducing_points.dtype
        q = TrilNaturalVariationalDistribution(M).to(dtype=dtype)
        strategy = VariationalStrategy(
            self, inducing_points.clone(), q, learn_inducing_locations=learn_inducing_locations, jitter_val=jitter
        )
        super().__init__(strategy)
        self.mean_module = gpytorch.means.ZeroMean()
        self.covar_module = ard_se_kernel(d, dtype=dtype)
        # q(v) is parametrized whitened from the start: N(0, I) here is the whitened prior, so
        # GPyTorch's one-time conversion of an un-whitened q (for old checkpoints) must not run.
        strategy.updated_strategy.fill_(True)

    def set_variational(self, mean: torch.Tensor, covariance: torch.Tensor) -> None:
        """Set the whitened q(v) = N(m, S_v).

        Args:
            mean: ``(M,)`` whitened mean m.
            covariance: ``(M, M)`` symmetric positive definite S_v (stored as natural parameters).
        """
        M = self.num_inducing
        if tuple(mean.shape) != (M,):
            raise ArgumentError(f"mean: expected shape ({M},), got {tuple(mean.shape)}")
        if tuple(covariance.shape) != (M, M):
            raise ArgumentError(f"covariance: expected shape ({M}, {M}), got {tuple(covariance.shape)}")
        covariance = 0.5 * (covariance + covariance.mT)
        if bool(torch.linalg.cholesky_ex(covariance)[1].any()):
            raise ArgumentError("covariance: not positive definite")
        strategy = self.variational_strategy
        # the natural-parameter module of q(v) (the strategy's child module; its public property
        # ``variational_distribution`` returns the distribution N(m, S_v), not the module)
        q = next(m for m in strategy.children() if isinstance(m, TrilNaturalVariationalDistribution))
        std, q.mean_init_std = q.mean_init_std, 0.0
        with torch.no_grad():
            q.initialize_variational_distribution(gpytorch.distributions.MultivariateNormal(mean, covariance))
            # GPyTorch initializes q from the prior on the first call unless told it is set.
            strategy.variational_params_initialized.fill_(1)
        q.mean_init_std = std
        # drop GPyTorch's memoized q and Cholesky factor (kept across calls in eval mode)
        mode = self.training
        self.train()
        self.train(mode)

    @property
    def dim(self) -> int:
        """Input dimension d."""
        return int(self.variational_strategy.inducing_points.shape[-1])

    @property
    def num_inducing(self) -> int:
        """Number of inducing points M."""
        return int(self.variational_strategy.inducing_points.shape[-2])

    @property
    def jitter(self) -> float:
        """The jitter j on K_ZZ (and on GPyTorch's test variance)."""
        return float(self.variational_strategy.jitter_val)

    def forward(self, x: torch.Tensor) -> gpytorch.distributions.MultivariateNormal:
        """Prior N(0, K_xx) at ``x``: ``(B, d)`` normalized inputs."""
        return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))

    def posterior(self, x: torch.Tensor) -> gpytorch.distributions.MultivariateNormal:
        """q(f(x)) at ``x: (B, d)`` normalized inputs: μ(x) = k_Zᵀ L⁻ᵀ m, Σ(x) = K_xx − k_Zᵀ L⁻ᵀ (I − S_v) L⁻¹ k_Z.

        GPyTorch's predictive covariance carries the jitter j on its diagonal; it is taken off, so
        the variances are exactly the module docstring's.  Puts the model in eval mode.
        """
        if self.training:
            self.eval()
        out = self(x)
        jitter = torch.full(out.mean.shape, -self.jitter, dtype=out.mean.dtype, device=out.mean.device)
        return gpytorch.distributions.MultivariateNormal(out.mean, out.lazy_covariance_matrix.add_diagonal(jitter))

    def _kzz_cholesky(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Z ``(M, d)`` and L ``(M, M)`` with L Lᵀ = K_ZZ + j I (retry jitter from the active policy)."""
        Z = self.variational_strategy.inducing_points
        eye = torch.eye(Z.shape[0], dtype=Z.dtype, device=Z.device)
        L, _ = robust_cholesky(kernel_matrix(self.covar_module, Z, Z) + self.jitter * eye, what="SVGP K_ZZ")
        return Z, L

    def posterior_weights(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Z, α = L⁻ᵀ m and S = L⁻ᵀ (I − S_v) L⁻¹ of the frozen form μ = k_Zᵀ α, Σ = σ_f² − k_Zᵀ S k_Z.

        Returns:
            ``(M, d)`` Z, ``(M,)`` α, ``(M, M)`` S, normalized units.
        """
        Z, L = self._kzz_cholesky()
        eye = torch.eye(Z.shape[0], dtype=Z.dtype, device=Z.device)
        q = self.variational_strategy.variational_distribution
        m, Sv = q.mean, q.covariance_matrix
        alpha = torch.linalg.solve_triangular(L.mT, m[:, None], upper=True).squeeze(-1)
        Li = torch.linalg.solve_triangular(L, eye, upper=False)
        S = Li.mT @ (eye - Sv) @ Li
        return Z.detach().clone(), alpha, 0.5 * (S + S.mT)

    def variance_factor(self) -> tuple[torch.Tensor, torch.Tensor]:
        """L and C = I − S_v of the factored S = L⁻ᵀ C L⁻¹ (L Lᵀ = K_ZZ + j I; C possibly indefinite).

        Returns:
            ``(M, M)`` lower-triangular L and ``(M, M)`` symmetric C, normalized units.
        """
        Z, L = self._kzz_cholesky()
        eye = torch.eye(Z.shape[0], dtype=Z.dtype, device=Z.device)
        C = eye - self.variational_strategy.variational_distribution.covariance_matrix
        return L.detach(), (0.5 * (C + C.mT)).detach()
