"""The training stage's check of a sparse posterior's frozen latent std against the fitted model's.

Reference: the fitted SGPR's own factored predictive variance (GPyTorch module, Titsias 2009).
A faithful (factored, S = L⁻ᵀ C L⁻¹) freeze agrees to rounding; an unfactored frozen S that has lost its digits (emulated by scaling
S, as an ill-conditioned K_ZZ does) is reported with the factor and a warning.
"""

from __future__ import annotations

import dataclasses
import logging

import pytest
import torch

from bemlearn.fitting import build_gp, fit_gp
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.models import predictor_state
from bemlearn.pipeline.gp_stage import _frozen_latent_check


@pytest.fixture(scope="module")
def sgpr():
    g = torch.Generator().manual_seed(0)
    x = torch.randn(300, 5, generator=g, dtype=torch.float64)
    y = torch.sin(x[:, 0]) + 0.3 * x[:, 2] + 0.05 * torch.randn(300, generator=g, dtype=torch.float64)
    cfg = GPConfig(kind="sgpr", n_inducing=24, max_iter=40)
    model, lik = build_gp(x, y, config=cfg)
    fit_gp(model, lik, x, y, config=cfg, progress=False)
    model.eval()
    lik.eval()
    zeros, ones = torch.zeros(5, dtype=torch.float64), torch.ones(5, dtype=torch.float64)
    state = predictor_state(model, lik, x_mean=zeros, x_std=ones, y_mean=torch.tensor(0.0, dtype=torch.float64),
                            y_std=torch.tensor(1.0, dtype=torch.float64), input_names=tuple(f"c{i}" for i in range(5)), n_train=300)
    return state, model, lik, x


def test_faithful_freeze_agrees(sgpr, caplog):
    state, model, lik, x = sgpr
    with caplog.at_level(logging.WARNING):
        out = _frozen_latent_check(state, model, lik, x, torch.float64, "cpu")
    assert out["median_ratio"] == pytest.approx(1.0, rel=1e-6) and out["n_queries"] == 256
    assert "lost its digits" not in caplog.text


def test_frozen_latent_std_within_1e8_of_the_fitted_model(sgpr):
    """At every training input (not only the median): the factored freeze (σ_f² − vᵀCv, v = L⁻¹k)
    against the model's σ_f² − VᵀV + WᵀW, 1e-8 relative in the std (σ̃² ≫ ε σ_f² here)."""
    from bemlearn.models.predict import predict

    state, model, lik, x = sgpr
    assert state.factored
    _, var = predict(model, lik, x)
    frozen = state.predict_reference(x * state.x_std + state.x_mean)[1] / state.y_std
    assert float((frozen / var.sqrt() - 1).abs().max()) <= 1e-8


def test_frozen_variance_that_lost_its_digits_is_reported(sgpr, caplog):
    state, model, lik, x = sgpr
    # an unfactored S (as frozen before S_chol/S_inner) with kᵀSk too small: frozen latent std too large
    broken = dataclasses.replace(state, S=0.5 * state.S, S_chol=None, S_inner=None)
    with caplog.at_level(logging.WARNING):
        out = _frozen_latent_check(broken, model, lik, x, torch.float64, "cpu")
    assert out["median_ratio"] > 2.0
    assert "lost its digits" in caplog.text


def test_exact_posteriors_are_not_checked(sgpr):
    state, model, lik, x = sgpr
    assert _frozen_latent_check(dataclasses.replace(state, kind="exact", S_chol=None, S_inner=None), model, lik, x, torch.float64, "cpu") is None
