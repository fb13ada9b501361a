"""Fit any GP kind from a :class:`GPConfig`, by the recipe of the model's class
(:mod:`bemlearn.fitting.kinds`: ``fit_exact`` / ``fit_sgpr`` / ``fit_svgp``)."""

from __future__ import annotations

import gpytorch
import torch

from bemlearn.errors import ConfigError
from bemlearn.fitting.build import build_gp
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.fitting.kinds import fit_recipe
from bemlearn.fitting.result import Callback, FitResult
from bemlearn.models.gp_kinds import as_gp, gp_class

__all__ = ["fit_gp", "train_gp"]


def fit_gp(
    model: torch.nn.Module,
    likelihood: gpytorch.likelihoods.GaussianLikelihood,
    train_x: torch.Tensor,
    train_y: torch.Tensor,
    *,
    config: GPConfig,
    callback: Callback | None = None,
    progress: bool = False,
) -> FitResult:
    """Fit ``model`` with the optimizer settings of ``config`` (svgp streams ``train_x``, ``train_y``).

    Args:
        model: from :func:`~bemlearn.fitting.build.build_gp`.
        likelihood: from :func:`~bemlearn.fitting.build.build_gp`.
        train_x: ``(N, d)`` normalized inputs (used by svgp; exact/sgpr hold their data).
        train_y: ``(N,)`` normalized outputs.
        config: optimizer, max_iter, lr, tol, fit_subset, batch_size, epochs, ngd_lr, seed, jitter
            (``max_iter`` and ``lr`` default by kind: :class:`~bemlearn.fitting.kinds.FitRecipe`).
        callback: ``callback(step, metrics)``.
        progress: show a progress bar.
    """
    gp = as_gp(model)
    if not isinstance(gp, gp_class(config.kind)):
        raise ConfigError(f"config.kind: {config.kind!r} does not match the model kind {gp.kind!r}")
    recipe = fit_recipe(type(gp))
    return recipe.fit(model, likelihood, train_x, train_y, config, max_iter=recipe.resolved_max_iter(config),
                      lr=recipe.resolved_lr(config), callback=callback, progress=progress)


def train_gp(
    train_x: torch.Tensor,
    train_y: torch.Tensor,
    *,
    config: GPConfig,
    callback: Callback | None = None,
    progress: bool = False,
) -> tuple[torch.nn.Module, gpytorch.likelihoods.GaussianLikelihood, FitResult]:
    """:func:`build_gp` then :func:`fit_gp`; returns ``(model, likelihood, result)``."""
    model, likelihood = build_gp(train_x, train_y, config=config)
    result = fit_gp(model, likelihood, train_x, train_y, config=config, callback=callback, progress=progress)
    return model, likelihood, result
