"""SGPR against the exact GP (M = N) and against a dense Titsias computation; SVGP at its optimum."""

from __future__ import annotations

import math

import gpytorch
import torch

from bemlearn.fitting import optimal_variational, select_inducing_points, set_hyperparameters
from bemlearn.models import SGPRBEMGP, SVGPBEMGP, ExactBEMGP, cholesky_policy, gaussian_likelihood, predict
from bemlearn.models.kernels import se_kernel

F64 = torch.float64
THETA = {
    "lengthscale": torch.tensor([1.0, 1.5, 2.0, 2.5, 3.0], dtype=F64),
    "outputscale": torch.tensor(1.3, dtype=F64),
    "noise": torch.tensor(1e-2, dtype=F64),
}


def _data(n: int = 300) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(1)
    x = torch.rand(n, 5, generator=gen, dtype=F64) * 4 - 2
    y = torch.sin(x[:, 0]) + 0.5 * x[:, 1] + 0.05 * torch.randn(n, generator=gen, dtype=F64)
    return x, y, torch.rand(150, 5, generator=gen, dtype=F64) * 4 - 2


def _se(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return se_kernel(a, b, THETA["lengthscale"], THETA["outputscale"])


def test_sgpr_with_all_training_inputs_is_the_exact_gp() -> None:
    x, y, xs = _data()
    lik_e = gaussian_likelihood()
    exact = ExactBEMGP(x, y, lik_e)
    set_hyperparameters(exact, lik_e, **THETA)
    lik_s = gaussian_likelihood()
    sgpr = SGPRBEMGP(x, y, lik_s, x, jitter=0.0)
    set_hyperparameters(sgpr, lik_s, **THETA)
    exact.train()
    lik_e.train()
    with torch.no_grad(), cholesky_policy():
        log_marginal = gpytorch.mlls.ExactMarginalLogLikelihood(lik_e, exact)(exact(x), y) * x.shape[0]
        bound = sgpr.collapsed_bound()
    assert abs(float(bound - log_marginal)) <= 1e-9 * abs(float(log_marginal))
    mean_e, var_e = predict(exact, lik_e, xs)
    mean_s, var_s = predict(sgpr, lik_s, xs)
    assert (mean_s - mean_e).abs().max() <= 1e-8
    assert (var_s - var_e).abs().max() <= 1e-8


def test_sgpr_equals_dense_titsias_formulas() -> None:
    x, y, xs = _data()
    Z = select_inducing_points(x, 30, seed=0)
    lik = gaussian_likelihood()
    model = SGPRBEMGP(x, y, lik, Z, jitter=0.0)
    set_hyperparameters(model, lik, **THETA)
    s2 = float(THETA["noise"])
    N = x.shape[0]
    Kzz, Kzx = _se(Z, Z), _se(Z, x)
    Q = Kzx.T @ torch.linalg.solve(Kzz, Kzx)
    C = Q + s2 * torch.eye(N, dtype=F64)
    logdet = torch.linalg.slogdet(C)[1]
    bound_ref = (
        -0.5 * N * math.log(2 * math.pi) - 0.5 * logdet - 0.5 * y @ torch.linalg.solve(C, y)
        - 0.5 * (N * float(THETA["outputscale"]) - torch.trace(Q)) / s2
    )
    with torch.no_grad():
        bound = model.collapsed_bound()
    assert abs(float(bound - bound_ref)) <= 1e-8 * abs(float(bound_ref))
    Sigma = torch.linalg.inv(Kzz + Kzx @ Kzx.T / s2)
    ksz = _se(xs, Z)
    mean_ref = ksz @ Sigma @ Kzx @ y / s2
    var_ref = float(THETA["outputscale"]) - (ksz * (ksz @ (torch.linalg.inv(Kzz) - Sigma))).sum(-1)
    mean, var = predict(model, lik, xs)
    assert (mean - mean_ref).abs().max() <= 1e-9
    assert (var - var_ref).abs().max() <= 1e-9


def test_svgp_at_the_optimal_q_is_sgpr() -> None:
    x, y, xs = _data()
    Z = select_inducing_points(x, 30, seed=0)
    lik_s = gaussian_likelihood()
    sgpr = SGPRBEMGP(x, y, lik_s, Z, jitter=1e-8)
    set_hyperparameters(sgpr, lik_s, **THETA)
    lik_v = gaussian_likelihood()
    svgp = SVGPBEMGP(Z, jitter=1e-8)
    set_hyperparameters(svgp, lik_v, **THETA)
    optimal_variational(svgp, lik_v, x, y)
    mean_s, var_s = predict(sgpr, lik_s, xs)
    mean_v, var_v = predict(svgp, lik_v, xs)
    assert (mean_v - mean_s).abs().max() <= 1e-8
    assert (var_v - var_s).abs().max() <= 1e-8
