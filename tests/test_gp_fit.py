"""Fitting recovers a known function; callbacks report every hyperparameter; seeds reproduce."""

from __future__ import annotations

import pytest
import torch

from bemlearn.fitting import GPConfig, build_gp, fit_gp, train_gp
from bemlearn.models import predict

F64 = torch.float64
NOISE_STD = 0.01


def _target(x: torch.Tensor) -> torch.Tensor:
    return torch.sin(x[:, 0]) + 0.5 * x[:, 1]


def _data(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    x = torch.rand(n, 5, generator=gen, dtype=F64) * 4 - 2
    return x, _target(x) + NOISE_STD * torch.randn(n, generator=gen, dtype=F64)


def _test_points() -> torch.Tensor:
    gen = torch.Generator().manual_seed(99)
    return torch.rand(1000, 5, generator=gen, dtype=F64) * 3.6 - 1.8  # inside the data cube


def test_exact_fit_recovers_sin_plus_linear() -> None:
    x, y = _data(300, seed=0)
    steps: list[int] = []
    metrics: list[dict[str, float]] = []
    model, lik, result = train_gp(
        x, y, config=GPConfig(kind="exact"), callback=lambda s, m: (steps.append(s), metrics.append(m))
    )
    xs = _test_points()
    mean, _var = predict(model, lik, xs)
    rmse = float((mean - _target(xs)).pow(2).mean().sqrt())
    assert rmse < 0.005  # measured 0.0017; the data noise std is 0.01
    assert float(lik.noise.detach()) < 10 * NOISE_STD**2  # noise level recovered to within an order of magnitude
    # x2..x4 are irrelevant: their ARD lengthscales grow far beyond the relevant x0's
    ls = model.covar_module.base_kernel.lengthscale.detach().reshape(-1)
    assert ls[2:].min() > 5 * ls[0]
    assert steps == list(range(len(steps))) and result.steps == len(steps)
    assert set(metrics[-1]) == {"loss", "noise", "outputscale", "lr"} | {f"lengthscale_{j}" for j in range(5)}
    assert result.loss <= metrics[0]["loss"]


def test_adam_reaches_a_worse_or_equal_loss_than_lbfgs() -> None:
    x, y = _data(120, seed=1)
    _, _, lbfgs = train_gp(x, y, config=GPConfig(kind="exact", optimizer="lbfgs", max_iter=60))
    _, _, adam = train_gp(x, y, config=GPConfig(kind="exact", optimizer="adam", max_iter=40))
    assert lbfgs.loss <= adam.loss + 1e-6


def test_sgpr_fit_recovers_function() -> None:
    x, y = _data(2000, seed=2)
    config = GPConfig(kind="sgpr", n_inducing=64, max_iter=15, init_subset=200)
    model, lik, result = train_gp(x, y, config=config)
    mean, _ = predict(model, lik, _test_points())
    assert float((mean - _target(_test_points())).pow(2).mean().sqrt()) < 0.003  # measured 0.0009
    assert result.stop_reason in ("converged", "max_iter")


def test_svgp_fit_recovers_function_and_is_reproducible() -> None:
    x, y = _data(3000, seed=3)
    config = GPConfig(kind="svgp", n_inducing=64, batch_size=500, epochs=2, init_subset=100, seed=7)
    runs = []
    for _ in range(2):
        model, lik = build_gp(x, y, config=config)
        result = fit_gp(model, lik, x, y, config=config)
        runs.append((model, lik, result))
    (m1, l1, r1), (m2, _l2, _r2) = runs
    assert r1.steps == 2 * 6
    for p1, p2 in zip(m1.parameters(), m2.parameters()):
        assert torch.equal(p1, p2)
    mean, _ = predict(m1, l1, _test_points())
    assert float((mean - _target(_test_points())).pow(2).mean().sqrt()) < 0.003  # measured 0.0009


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_exact_fit_on_cuda_matches_cpu() -> None:
    x, y = _data(200, seed=4)
    cpu_model, cpu_lik, _ = train_gp(x, y, config=GPConfig(kind="exact", max_iter=30))
    gpu_model, gpu_lik, _ = train_gp(x, y, config=GPConfig(kind="exact", max_iter=30, device="cuda"))
    xs = _test_points()
    mean_cpu, _ = predict(cpu_model, cpu_lik, xs)
    mean_gpu, _ = predict(gpu_model, gpu_lik, xs.cuda())
    assert float((mean_gpu.cpu() - mean_cpu).abs().max()) < 1e-6
