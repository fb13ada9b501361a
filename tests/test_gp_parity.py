"""Exact GP posterior (GPyTorch under the Cholesky policy) vs a dense torch.linalg eq. (12)."""

from __future__ import annotations

import gpytorch
import pytest
import torch

from bemlearn.fitting import set_hyperparameters
from bemlearn.models import ExactBEMGP, gaussian_likelihood, kernel_matrix, predict, se_cross_covariance

F64 = torch.float64
LENGTHSCALE = torch.tensor([1.0, 1.5, 2.0, 2.5, 3.0], dtype=F64)
OUTPUTSCALE = 1.3
NOISE = 1e-3  # small noise: the regime where CG above N = 800 goes wrong


def _problem(n: int, seed: int = 0) -> tuple[ExactBEMGP, gpytorch.likelihoods.GaussianLikelihood, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    x = torch.rand(n, 5, generator=gen, dtype=F64) * 4 - 2
    y = torch.sin(x[:, 0]) + 0.5 * x[:, 1] + 0.01 * torch.randn(n, generator=gen, dtype=F64)
    lik = gaussian_likelihood(min_noise=1e-8)
    model = ExactBEMGP(x, y, lik)
    set_hyperparameters(model, lik, lengthscale=LENGTHSCALE, outputscale=torch.tensor(OUTPUTSCALE, dtype=F64), noise=torch.tensor(NOISE, dtype=F64))
    xs = torch.rand(300, 5, generator=gen, dtype=F64) * 4 - 2
    return model, lik, xs


def _se(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """eq. (11) written out: σ_f² exp(−½ Σ_j (a_j − b_j)² / ℓ_j²)."""
    return OUTPUTSCALE * torch.exp(-0.5 * (((a[:, None, :] - b[None, :, :]) / LENGTHSCALE) ** 2).sum(-1))


def _dense_posterior(model: ExactBEMGP, xs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """μ = kᵀK⁻¹Y, Σ = k* − kᵀK⁻¹k (eq. 12) with torch.linalg.solve (LU), K = K_XX + σ_0² I."""
    x, y = model.train_inputs[0], model.train_targets
    K = _se(x, x) + NOISE * torch.eye(x.shape[0], dtype=F64)
    k = _se(xs, x)
    return k @ torch.linalg.solve(K, y), OUTPUTSCALE - (k * torch.linalg.solve(K, k.T).T).sum(-1)


def test_kernel_matches_eq11() -> None:
    model, _, xs = _problem(50)
    K = kernel_matrix(model.covar_module, xs, model.train_inputs[0])
    torch.testing.assert_close(K, _se(xs, model.train_inputs[0]), rtol=0, atol=1e-13)


def test_fused_cross_covariance_matches_eq11() -> None:
    model, _, xs = _problem(50)
    kernel = model.covar_module
    K = se_cross_covariance(xs, model.train_inputs[0], kernel.base_kernel.lengthscale, kernel.outputscale)
    torch.testing.assert_close(K, _se(xs, model.train_inputs[0]), rtol=0, atol=1e-13)


@pytest.mark.parametrize("n", [800, 801])
def test_exact_posterior_equals_dense_solve(n: int) -> None:
    model, lik, xs = _problem(n)
    mean, var = predict(model, lik, xs)
    mean_ref, var_ref = _dense_posterior(model, xs)
    assert (mean - mean_ref).abs().max() <= 1e-10
    assert (var - var_ref).abs().max() <= 1e-10


def test_default_gpytorch_settings_drift_above_800() -> None:
    """Why the policy exists: GPyTorch's defaults switch to CG at N = 801 and the mean drifts.

    If this starts failing, GPyTorch changed its default solver; the policy is then harmless.
    """
    model, lik, xs = _problem(801)
    mean_ref, _ = _dense_posterior(model, xs)
    model.eval()
    lik.eval()
    with torch.no_grad():
        mean_default = model(xs).mean
    assert (mean_default - mean_ref).abs().max() > 1e-4
