"""Build a GP of the configured kind with data-driven initial hyperparameters and inducing points."""

from __future__ import annotations

import gpytorch
import torch

from bemlearn.fitting.gp_config import GPConfig
from bemlearn.fitting.kinds import fit_recipe
from bemlearn.models.gp_kinds import gp_class
from bemlearn.models.kernels import gaussian_likelihood
from bemlearn.models.validation import check_inputs, check_targets

__all__ = ["build_gp"]


def build_gp(
    train_x: torch.Tensor, train_y: torch.Tensor, *, config: GPConfig
) -> tuple[torch.nn.Module, gpytorch.likelihoods.GaussianLikelihood]:
    """A model of kind ``config.kind`` and its likelihood, initialized from the data, not yet fitted.

    The kind's :class:`~bemlearn.fitting.kinds.FitRecipe` builds it: exact: θ from data statistics;
    sgpr/svgp: θ from :func:`~bemlearn.fitting.init.initial_hyperparameters`, Z from
    :func:`~bemlearn.fitting.init.select_inducing_points`; svgp also starts from the optimal q(v)
    (:func:`~bemlearn.fitting.variational.optimal_variational`).

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
    lik = gaussian_likelihood(min_noise=config.min_noise, dtype=config.torch_dtype).to(torch.device(config.device))
    return fit_recipe(cls).build(train_x, train_y, config, lik), lik
