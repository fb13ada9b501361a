"""Titsias (2009) sparse GP regression (SGPR) of the BEM map, collapsed bound, dense Cholesky.

With M inducing inputs Z, K_ZZ = L Lᵀ, A = L⁻¹ K_ZX / σ_0 and B = I + A Aᵀ = L_B L_Bᵀ,
the collapsed evidence lower bound on log p(Y) of eq. (11) (Titsias, 2009, Eq. 9) is

    F = log N(Y | 0, Q + σ_0² I) − tr(K_XX − Q) / (2 σ_0²),   Q = K_XZ K_ZZ⁻¹ K_ZX
      = −N/2 log 2π − Σ log diag L_B − N/2 log σ_0² − YᵀY/(2σ_0²) + ½ cᵀc
        − N σ_f²/(2σ_0²) + ½ tr(A Aᵀ),       c = L_B⁻¹ A Y / σ_0,

and the posterior replacing eq. (12) is, with V = L⁻¹ k_Z(x), W = L_B⁻¹ V,

    μ(x) = Wᵀ c,    Σ(x) = σ_f² − VᵀV + WᵀW.

A Aᵀ and A Y are accumulated over chunks of the N training points (A is formed by a triangular
solve, so A Aᵀ is positive semi-definite by construction even when K_ZZ is ill-conditioned);
a fit costs O(N M²) time and O(N M) autograd memory; with Z = X (M = N) and no
jitter, F equals the exact log marginal likelihood and μ, Σ equal eq. (12).
"""

from __future__ import annotations

import math
from typing import ClassVar

import gpytorch
import torch
from linear_operator.operators import DiagLinearOperator

from bemlearn.errors import ArgumentError
from bemlearn.models.kernels import ard_se_kernel, kernel_matrix, se_cross_covariance
from bemlearn.models.solver import robust_cholesky
from bemlearn.models.validation import check_inputs, check_targets

__all__ = ["SGPRBEMGP"]


class SGPRBEMGP(gpytorch.Module):
    """Inducing-point sparse GP (collapsed Titsias bound), zero prior mean, ARD kernel (eq. 11).

    Train by maximizing :meth:`collapsed_bound`; predict with :meth:`posterior` (the posterior
    factors are cached in eval mode and dropped by ``model.train()``).  ``model(x)`` is the prior
    N(0, K_xx), as on every kind (:mod:`bemlearn.models.gp_kinds`).

    Args:
        train_x: ``(N, d)`` normalized inputs.
        train_y: ``(N,)`` normalized outputs.
        likelihood: Gaussian likelihood holding σ_0².
        inducing_points: ``(M, d)`` initial inducing inputs Z (normalized units).
        learn_inducing_locations: optimize Z together with the hyperparameters.
        jitter: constant added to the diagonal of K_ZZ (normalized output units squared); more
            is added, with a logged warning, only if the Cholesky still fails.
        chunk_size: training points per chunk when accumulating K_ZX K_XZ.
    """

    #: The registered name of the kind (``train.kind``, a checkpoint's ``kind``).
    kind: ClassVar[str] = "sgpr"
    #: The posterior lives on the M inducing inputs Z (S factored as L⁻ᵀ C L⁻¹).
    sparse: ClassVar[bool] = True

    def __init__(
        self,
        train_x: torch.Tensor,
        train_y: torch.Tensor,
        likelihood: gpytorch.likelihoods.GaussianLikelihood,
        inducing_points: torch.Tensor,
        *,
        learn_inducing_locations: bool = True,
        jitter: float = 1e-8,
        chunk_size: int = 8192,
    ) -> None:
        check_inputs(train_x, name="train_x")
        check_targets(train_y, name="train_y", n=train_x.shape[0], dtype=train_x.dtype)
        check_inputs(inducing_points, name="inducing_points", dim=train_x.shape[1], dtype=train_x.dtype)
        if jitter < 0.0:
            raise ArgumentError(f"jitter: expected a non-negative value, got {jitter}")
        if chunk_size < 1:
            raise ArgumentError(f"chunk_size: expected a positive integer, got {chunk_size}")
        super().__init__()
        self.register_buffer("train_x", train_x, persistent=False)
        self.register_buffer("train_y", train_y, persistent=False)
        self.likelihood = likelihood
        self.covar_module = ard_se_kernel(train_x.shape[1], dtype=train_x.dtype)
        self.inducing_points = torch.nn.Parameter(inducing_points.clone(), requires_grad=learn_inducing_locations)
        self.jitter = float(jitter)
        self.chunk_size = int(chunk_size)
        self._cache: dict[str, torch.Tensor] | None = None

    @property
    def dim(self) -> int:
        """Input dimension d."""
        return int(self.train_x.shape[1])

    @property
    def num_inducing(self) -> int:
        """Number of inducing points M."""
        return int(self.inducing_points.shape[0])

    def train(self, mode: bool = True) -> SGPRBEMGP:
        self._cache = None
        return super().train(mode)

    def _factors(self) -> dict[str, torch.Tensor]:
        """L, L_B, c and the scalar pieces of the bound, for the current hyperparameters."""
        Z, X, Y = self.inducing_points, self.train_x, self.train_y
        M = Z.shape[0]
        noise = self.likelihood.noise.squeeze()
        eye = torch.eye(M, dtype=Z.dtype, device=Z.device)
        Kzz = kernel_matrix(self.covar_module, Z, Z)
        L, _ = robust_cholesky(Kzz + self.jitter * eye, what="SGPR K_ZZ")
        sigma = noise.sqrt()
        AAt = torch.zeros(M, M, dtype=Z.dtype, device=Z.device)
        Ay = torch.zeros(M, 1, dtype=Z.dtype, device=Z.device)
        ls, sf2 = self.covar_module.base_kernel.lengthscale, self.covar_module.outputscale
        for start in range(0, X.shape[0], self.chunk_size):
            Kzx = se_cross_covariance(Z, X[start : start + self.chunk_size], ls, sf2)
            A = torch.linalg.solve_triangular(L, Kzx, upper=False) / sigma
            AAt = AAt + A @ A.mT
            Ay = Ay + A @ Y[start : start + self.chunk_size, None]
        LB, _ = robust_cholesky(eye + AAt, what="SGPR I + A Aᵀ")
        c = torch.linalg.solve_triangular(LB, Ay, upper=False) / sigma
        return {"L": L, "LB": LB, "c": c.squeeze(-1), "AAt": AAt, "noise": noise}

    def collapsed_bound(self) -> torch.Tensor:
        """The collapsed lower bound F on log p(Y) (module docstring), a ``()`` tensor (nats)."""
        f = self._factors()
        N = self.train_x.shape[0]
        noise = f["noise"]
        outputscale = self.covar_module.outputscale.squeeze()
        return (
            -0.5 * N * math.log(2.0 * math.pi)
            - torch.log(torch.diagonal(f["LB"])).sum()
            - 0.5 * N * torch.log(noise)
            - 0.5 * (self.train_y**2).sum() / noise
            + 0.5 * (f["c"] ** 2).sum()
            - 0.5 * N * outputscale / noise
            + 0.5 * torch.diagonal(f["AAt"]).sum()
        )

    def _posterior(self) -> dict[str, torch.Tensor]:
        if self.training or torch.is_grad_enabled():
            return self._factors()
        if self._cache is None:
            self._cache = self._factors()
        return self._cache

    def posterior_weights(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Z, α, S of the frozen form μ = k_Zᵀ α, Σ = σ_f² − k_Zᵀ S k_Z.

        α = L⁻ᵀ L_B⁻ᵀ c = Σ K_ZX Y / σ_0² and S = L⁻ᵀ (I − B⁻¹) L⁻¹ = K_ZZ⁻¹ − Σ with
        Σ = (K_ZZ + σ_0⁻² K_ZX K_XZ)⁻¹ (K_ZZ including the jitter actually used).

        Returns:
            ``(M, d)`` Z, ``(M,)`` α, ``(M, M)`` S, normalized units.
        """
        f = self._posterior()
        L, LB = f["L"], f["LB"]
        alpha = torch.linalg.solve_triangular(LB.mT, f["c"][:, None], upper=True)
        alpha = torch.linalg.solve_triangular(L.mT, alpha, upper=True).squeeze(-1)
        eye = torch.eye(L.shape[0], dtype=L.dtype, device=L.device)
        Li = torch.linalg.solve_triangular(L, eye, upper=False)
        LBiLi = torch.linalg.solve_triangular(LB, Li, upper=False)
        S = Li.mT @ Li - LBiLi.mT @ LBiLi
        return self.inducing_points.detach(), alpha, 0.5 * (S + S.mT)

    def variance_factor(self) -> tuple[torch.Tensor, torch.Tensor]:
        """L and C of the factored S = L⁻ᵀ C L⁻¹, C = I − B⁻¹ (eigenvalues in [0, 1)).

        σ_f² − vᵀ C v with v = L⁻¹ k_Z equals the forward's σ_f² − VᵀV + WᵀW; unlike the explicit
        S of :meth:`posterior_weights` it keeps the small variances when K_ZZ is ill-conditioned.

        Returns:
            ``(M, M)`` lower-triangular L (L Lᵀ = K_ZZ + jitter) and ``(M, M)`` symmetric C.
        """
        f = self._posterior()
        L, LB = f["L"], f["LB"]
        eye = torch.eye(L.shape[0], dtype=L.dtype, device=L.device)
        C = eye - torch.cholesky_inverse(LB)
        return L.detach(), (0.5 * (C + C.mT)).detach()

    def whitened_posterior(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The optimal q(u) in whitened form, u = L v: q(v) = N(m, S_v) with m = L_B⁻ᵀ c, S_v = B⁻¹.

        (Titsias's optimal q(u) = N(K_ZZ Σ K_ZX Y / σ_0², K_ZZ Σ K_ZZ), whitened by L⁻¹.)

        Returns:
            ``(M,)`` m and ``(M, M)`` S_v, normalized units.
        """
        f = self._posterior()
        LB = f["LB"]
        m = torch.linalg.solve_triangular(LB.mT, f["c"][:, None], upper=True).squeeze(-1)
        eye = torch.eye(LB.shape[0], dtype=LB.dtype, device=LB.device)
        LBi = torch.linalg.solve_triangular(LB, eye, upper=False)
        return m, LBi.mT @ LBi

    def forward(self, x: torch.Tensor) -> gpytorch.distributions.MultivariateNormal:
        """Prior N(0, K_xx) at ``x``: ``(B, d)`` normalized inputs."""
        return gpytorch.distributions.MultivariateNormal(torch.zeros_like(x[:, 0]), self.covar_module(x))

    def posterior(self, x: torch.Tensor) -> gpytorch.distributions.MultivariateNormal:
        """Posterior marginals of f at ``x``: ``(B, d)`` normalized inputs.

        Puts the model in eval mode (the factors are then computed once and cached).

        Returns:
            MultivariateNormal with ``(B,)`` mean μ and diagonal covariance Σ (module docstring).
        """
        if self.training:
            self.eval()
        f = self._posterior()
        Kzs = kernel_matrix(self.covar_module, self.inducing_points, x)
        V = torch.linalg.solve_triangular(f["L"], Kzs, upper=False)
        W = torch.linalg.solve_triangular(f["LB"], V, upper=False)
        mean = W.mT @ f["c"]
        var = self.covar_module.outputscale.squeeze() - (V**2).sum(0) + (W**2).sum(0)
        return gpytorch.distributions.MultivariateNormal(mean, DiagLinearOperator(var))
