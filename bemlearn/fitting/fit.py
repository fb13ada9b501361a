"""Fit any GP kind from a :class:`GPConfig` (dispatch to ``fit_exact`` / ``fit_sgpr`` / ``fit_svgp``)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import gpytorch
import torch

from bemlearn.errors import ConfigError
from bemlearn.fitting.build import build_gp
from bemlearn.fitting.exact import fit_exact
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.fitting.result import Callback, FitResult
from bemlearn.fitting.sgpr import fit_sgpr
from bemlearn.fitting.svgp import fit_svgp
from bemlearn.models.gp_kinds import gp_kind_of

if TYPE_CHECKING:
    from bemlearn.models.exact_gp import ExactBEMGP
    from bemlearn.models.sgpr import SGPRBEMGP
    from bemlearn.models.svgp import SVGPBEMGP

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
        config: optimizer, max_iter, lr, tol, fit_subset, batch_size, epochs, ngd_lr, seed, jitter.
        callback: ``callback(step, metrics)``.
        progress: show a progress bar.
    """
    kind = gp_kind_of(model)
    if kind != config.kind:
        raise ConfigError(f"config.kind: {config.kind!r} does not match the model kind {kind!r}")
    common: dict[str, Any] = dict(jitter=config.jitter, callback=callback, progress=progress)
    if kind == "exact":
        return fit_exact(cast("ExactBEMGP", model), likelihood, optimizer=config.optimizer, max_iter=config.resolved_max_iter, lr=config.resolved_lr, tol=config.tol, **common)
    if kind == "sgpr":
        return fit_sgpr(
            cast("SGPRBEMGP", model), likelihood, optimizer=config.optimizer, max_iter=config.resolved_max_iter, lr=config.resolved_lr, tol=config.tol,
            subset=config.fit_subset, seed=config.seed, **common,
        )
    return fit_svgp(
        cast("SVGPBEMGP", model), likelihood, train_x, train_y, batch_size=config.batch_size, epochs=config.epochs,
        lr=config.resolved_lr, ngd_lr=config.ngd_lr, refresh_q=config.refresh_q, seed=config.seed, **common,
    )


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
