"""A failing Cholesky recovers with increasing, logged jitter: no crash, no NaN."""

from __future__ import annotations

import logging

import pytest
import torch

from bemlearn.errors import NumericalError
from bemlearn.fitting import fit_exact, set_hyperparameters
from bemlearn.models import SGPRBEMGP, ExactBEMGP, gaussian_likelihood, predict, predictor_state, robust_cholesky

F64 = torch.float64


def _near_singular(n_unique: int = 40, copies: int = 5) -> tuple[torch.Tensor, torch.Tensor]:
    """Every input repeated ``copies`` times: K_XX has rank ≤ n_unique."""
    gen = torch.Generator().manual_seed(0)
    xu = torch.rand(n_unique, 5, generator=gen, dtype=F64)
    x = xu.repeat(copies, 1)
    y = torch.sin(3 * x[:, 0]) + x[:, 1]
    return x, y


def _near_singular_exact_gp():
    """``(x, y, model, lik)``: an exact GP on :func:`_near_singular` data with noise 1e-16.

    A noise of 1e-16 is below float64's resolution on the unit diagonal (1 + 1e-16 == 1), so every
    duplicated row's pivot is zero to rounding and the Cholesky fails whatever the thread count;
    with 1e-15 a one-thread factorisation happened to succeed (a positive rounding residue).
    """
    x, y = _near_singular()
    lik = gaussian_likelihood(min_noise=1e-16)
    model = ExactBEMGP(x, y, lik)
    set_hyperparameters(
        model, lik, lengthscale=torch.full((5,), 0.7, dtype=F64),
        outputscale=torch.tensor(1.0, dtype=F64), noise=torch.tensor(1e-16, dtype=F64),
    )
    return x, y, model, lik


def test_robust_cholesky_adds_increasing_jitter(caplog: pytest.LogCaptureFixture) -> None:
    v = torch.tensor([[1.0, 2.0, 3.0]], dtype=F64)
    A = v.T @ v  # rank 1
    with caplog.at_level(logging.WARNING, logger="bemlearn.models.solver"):
        L, j = robust_cholesky(A, what="rank-1 test matrix")
    assert j > 0.0
    torch.testing.assert_close(L @ L.T, A + j * torch.eye(3, dtype=F64), rtol=0, atol=1e-12)
    jitters = [r.getMessage() for r in caplog.records if "rank-1 test matrix" in r.getMessage()]
    assert len(jitters) >= 1 and "1.0e-08" in jitters[0]


def test_robust_cholesky_rejects_nan() -> None:
    A = torch.eye(3, dtype=F64)
    A[1, 1] = float("nan")
    with pytest.raises(NumericalError, match="K_test"):
        robust_cholesky(A, what="K_test")


def test_exact_gp_duplicated_inputs_tiny_noise(caplog: pytest.LogCaptureFixture) -> None:
    x, y, model, lik = _near_singular_exact_gp()
    with caplog.at_level(logging.WARNING):
        mean, var = predict(model, lik, x[:40])
        state = predictor_state(
            model, lik, x_mean=torch.zeros(5), x_std=torch.ones(5), y_mean=0.0, y_std=1.0,
            input_names=[f"x{i}" for i in range(5)], n_train=x.shape[0],
        )
    assert any("jitter" in r.getMessage() for r in caplog.records)
    assert torch.isfinite(mean).all() and torch.isfinite(var).all()
    assert torch.isfinite(state.alpha).all() and torch.isfinite(state.S).all()
    # the jittered posterior still interpolates the (noise-free, consistent) duplicated data
    assert (mean - y[:40]).abs().max() < 1e-3


def test_exact_fit_on_near_singular_data_stays_finite(caplog: pytest.LogCaptureFixture) -> None:
    _x, _y, model, lik = _near_singular_exact_gp()
    with caplog.at_level(logging.WARNING):
        result = fit_exact(model, lik, max_iter=5)
    assert result.steps >= 1
    assert all(torch.isfinite(p).all() for p in model.parameters())
    assert torch.isfinite(torch.tensor(result.loss))


def test_sgpr_duplicated_inducing_points_recover(caplog: pytest.LogCaptureFixture) -> None:
    x, y = _near_singular()
    Z = torch.cat([x[:10], x[:10]])  # every inducing point twice: K_ZZ singular
    lik = gaussian_likelihood()
    model = SGPRBEMGP(x, y, lik, Z, jitter=0.0)
    with caplog.at_level(logging.WARNING, logger="bemlearn.models.solver"):
        bound = model.collapsed_bound()
        mean, var = predict(model, lik, x[:20])
    assert any("SGPR K_ZZ" in r.getMessage() for r in caplog.records)
    assert torch.isfinite(bound) and torch.isfinite(mean).all() and torch.isfinite(var).all()
