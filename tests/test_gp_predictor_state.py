"""predictor_state(...).predict_reference equals the model's own prediction, for every GP kind."""

from __future__ import annotations

import pytest
import torch

from bemlearn.fitting import GPConfig, build_gp, fit_svgp, optimal_variational, set_hyperparameters
from bemlearn.fitting.init import select_inducing_points
from bemlearn.models import SGPRBEMGP, SVGPBEMGP, PredictorState, gaussian_likelihood, predict, predictor_state

F64 = torch.float64
X_MEAN = torch.tensor([0.5, -1.0, 2.0, 0.0, 3.0], dtype=F64)
X_STD = torch.tensor([2.0, 0.5, 1.5, 3.0, 0.25], dtype=F64)
Y_MEAN, Y_STD = 0.1, 0.3
NAMES = ("qdd_theta", "qd_theta", "q_theta", "qdd_alpha", "qd_alpha")
THETA = {
    "lengthscale": torch.tensor([1.0, 1.5, 2.0, 2.5, 3.0], dtype=F64),
    "outputscale": torch.tensor(1.3, dtype=F64),
    "noise": torch.tensor(1e-2, dtype=F64),
}


def _data(n: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    x = torch.rand(n, 5, generator=gen, dtype=F64) * 4 - 2
    y = torch.sin(x[:, 0]) + 0.5 * x[:, 1] + 0.05 * torch.randn(n, generator=gen, dtype=F64)
    xs = torch.rand(200, 5, generator=gen, dtype=F64) * 4 - 2
    return x, y, xs


def _model(kind: str) -> tuple[torch.nn.Module, object, torch.Tensor, int]:
    x, y, xs = _data(300)
    if kind == "exact":
        model, lik = build_gp(x, y, config=GPConfig(kind="exact"))
        set_hyperparameters(model, lik, **THETA)
    elif kind == "sgpr":
        lik = gaussian_likelihood()
        model = SGPRBEMGP(x, y, lik, select_inducing_points(x, 40, seed=0))
        set_hyperparameters(model, lik, **THETA)
    else:
        lik = gaussian_likelihood()
        model = SVGPBEMGP(select_inducing_points(x, 30, seed=0))
        set_hyperparameters(model, lik, **THETA)
        optimal_variational(model, lik, x, y)
        # a few minibatch steps so q(v) is a generic (not exactly optimal) Gaussian
        fit_svgp(model, lik, x, y, batch_size=64, epochs=1, lr=0.01, seed=0)
    return model, lik, xs, x.shape[0]


@pytest.mark.parametrize("kind", ["exact", "sgpr", "svgp"])
def test_state_matches_model(kind: str) -> None:
    model, lik, xs, n = _model(kind)
    state = predictor_state(model, lik, x_mean=X_MEAN, x_std=X_STD, y_mean=Y_MEAN, y_std=Y_STD, input_names=NAMES, n_train=n)
    assert isinstance(state, PredictorState) and state.kind == kind and state.n_train == n
    assert state.Z.dtype == F64 and state.S.shape == (state.n_support, state.n_support)
    mean, var = predict(model, lik, xs)
    assert var.min() > 1e-4  # std well above round-off, so a relative comparison is meaningful
    x_phys = X_MEAN + X_STD * xs
    mean_ref, std_ref = state.predict_reference(x_phys)
    assert (mean_ref - (Y_MEAN + Y_STD * mean)).abs().max() <= 1e-10
    std = Y_STD * var.sqrt()
    assert ((std_ref - std) / std).abs().max() <= 1e-8


def test_state_hyperparameters_are_the_model_ones() -> None:
    model, lik, _, n = _model("exact")
    state = predictor_state(model, lik, x_mean=X_MEAN, x_std=X_STD, y_mean=Y_MEAN, y_std=Y_STD, input_names=NAMES, n_train=n)
    torch.testing.assert_close(state.lengthscale, THETA["lengthscale"], rtol=1e-12, atol=0)
    torch.testing.assert_close(state.outputscale, THETA["outputscale"], rtol=1e-12, atol=0)
    torch.testing.assert_close(state.noise, THETA["noise"], rtol=1e-12, atol=0)
    assert state.input_names == NAMES
