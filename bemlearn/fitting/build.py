"""Build a GP of the configured kind with data-driven initial hyperparameters and inducing points."""

from __future__ import annotations

import logging
from typing import cast

import gpytorch
import torch

from bemlearn.fitting.exact import fit_exact
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.fitting.init import data_hyperparameters, select_inducing_points, set_hyperparameters
from bemlearn.fitting.variational import optimal_variational
from bemlearn.models.exact_gp import ExactBEMGP
from bemlearn.models.gp_kinds import gp_class
from bemlearn.models.kernels import gaussian_likelihood
from bemlearn.models.sgpr import SGPRBEMGP
from bemlearn.models.svgp import SVGPBEMGP
from bemlearn.models.validation import check_inputs, check_targets

__all__ = ["build_gp", "initial_hyperparameters"]

logger = logging.getLogger(__name__)


def initial_hyperparameters(train_x: torch.Tensor, train_y: torch.Tensor, *, config: GPConfig) -> dict[str, torch.Tensor]:
    """θ₀ = (ℓ, σ_f², σ_0²): data statistics, refined by an exact GP on a random subset.

    With ``config.init_subset > 0`` an exact GP (L-BFGS, ≤ 50 iterations, tol 1e-6) is fitted on
    min(init_subset, N) random points, starting from the data statistics; its θ is returned.

    Args:
        train_x: ``(N, d)`` normalized inputs.
        train_y: ``(N,)`` normalized outputs.
        config: the GP configuration (``init_subset``, ``min_noise``, ``seed``, ``jitter``).

    Returns:
        ``{"lengthscale": (d,), "outputscale": (), "noise": ()}``.
    """
    theta = data_hyperparameters(train_x, train_y, min_noise=config.min_noise)
    if config.init_subset == 0:
        return theta
    gen = torch.Generator(device="cpu").manual_seed(config.seed)
    idx = torch.randperm(train_x.shape[0], generator=gen)[: config.init_subset].to(train_x.device)
    xs, ys = train_x[idx], train_y[idx]
    lik = gaussian_likelihood(min_noise=config.min_noise, dtype=train_x.dtype).to(train_x.device)
    small = ExactBEMGP(xs, ys, lik).to(train_x.device)
    set_hyperparameters(small, lik, **theta)
    result = fit_exact(small, lik, max_iter=50, tol=1e-6, jitter=config.jitter)
    logger.info("initial exact GP on %d points: loss %.5f after %d evaluations (%s)", xs.shape[0], result.loss, result.steps, result.stop_reason)
    kernel = small.covar_module
    return {
        "lengthscale": kernel.base_kernel.lengthscale.detach().reshape(-1),
        "outputscale": kernel.outputscale.detach().reshape(()),
        "noise": lik.noise.detach().reshape(()),
    }


def build_gp(
    train_x: torch.Tensor, train_y: torch.Tensor, *, config: GPConfig
) -> tuple[torch.nn.Module, gpytorch.likelihoods.GaussianLikelihood]:
    """A model of kind ``config.kind`` and its likelihood, initialized from the data, not yet fitted.

    exact: θ from data statistics.  sgpr/svgp: θ from :func:`initial_hyperparameters`,
    Z from :func:`~bemlearn.fitting.init.select_inducing_points`; svgp also starts from
    the optimal q(v) (:func:`optimal_variational`).

    Args:
        train_x: ``(N, d)`` normalized inputs, dtype ``config.dtype``.
        train_y: ``(N,)`` normalized outputs, dtype ``config.dtype``.
        config: the GP configuration.

    Raises:
        ValueError / TypeError: unknown kind, bad shapes, dtypes or non-finite data (named).
    """
    cls = gp_class(config.kind)
    check_inputs(train_x, name="train_x", dtype=config.torch_dtype)
    check_targets(train_y, name="train_y", n=train_x.shape[0], dtype=config.torch_dtype)
    device = torch.device(config.device)
    lik = gaussian_likelihood(min_noise=config.min_noise, dtype=config.torch_dtype).to(device)
    if cls is ExactBEMGP:
        x, y = train_x.to(device), train_y.to(device)
        model: torch.nn.Module = ExactBEMGP(x, y, lik).to(device)
        set_hyperparameters(model, lik, **data_hyperparameters(x, y, min_noise=config.min_noise))
        return model, lik
    theta = initial_hyperparameters(train_x, train_y, config=config)
    Z = select_inducing_points(train_x, config.n_inducing, method=config.inducing_init, seed=config.seed).to(device)
    if cls is SGPRBEMGP:
        x, y = train_x.to(device), train_y.to(device)
        model = SGPRBEMGP(x, y, lik, Z, learn_inducing_locations=config.learn_inducing, jitter=config.jitter).to(device)
        set_hyperparameters(model, lik, **theta)
        return model, lik
    model = SVGPBEMGP(Z, learn_inducing_locations=config.learn_inducing, jitter=config.jitter).to(device)
    set_hyperparameters(model, lik, **theta)
    optimal_variational(cast(SVGPBEMGP, model), lik, train_x.to(device), train_y.to(device))
    return model, lik
