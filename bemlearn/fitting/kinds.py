"""How each GP kind is built and fitted: one :class:`FitRecipe` per model class of
:data:`~bemlearn.models.gp_kinds.GP_KINDS`.

The models know their math (prior ``forward``, ``posterior``, frozen weights); how a kind is
initialized from data and which loop trains it is fitting's part, kept here and looked up by
the model's class, never by the kind's name (as BoTorch's ``fit_gpytorch_mll`` dispatches on
the model's type):

* exact: θ from the data statistics; L-BFGS (or Adam) on −log p(Y | X, θ) (:func:`fit_exact`);
* sgpr: θ from a small exact GP on a subset, Z by k-means++; L-BFGS on the collapsed bound
  (:func:`fit_sgpr`), 30 iterations by default (each costs O(fit_subset · M²));
* svgp: as sgpr, q(v) started at its optimum; natural gradients on q(v) and Adam on θ, Z
  (:func:`fit_svgp`), step 0.003 by default.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import torch
from gpytorch.likelihoods import GaussianLikelihood

from bemlearn.errors import ArgumentError
from bemlearn.fitting.exact import fit_exact
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.fitting.init import data_hyperparameters, initial_hyperparameters, select_inducing_points, set_hyperparameters
from bemlearn.fitting.optimize import default_lr
from bemlearn.fitting.result import Callback, FitResult
from bemlearn.fitting.sgpr import fit_sgpr
from bemlearn.fitting.svgp import fit_svgp
from bemlearn.fitting.variational import optimal_variational
from bemlearn.models.exact_gp import ExactBEMGP
from bemlearn.models.gp_kinds import BEMGP
from bemlearn.models.sgpr import SGPRBEMGP
from bemlearn.models.svgp import SVGPBEMGP

__all__ = ["FitRecipe", "FIT_RECIPES", "fit_recipe"]


@dataclass(frozen=True)
class FitRecipe:
    """How one GP kind is built and trained.

    Attributes:
        build: ``build(train_x, train_y, config, likelihood)``: the model on ``config.device``,
            initialized from the ``(N, d)`` normalized inputs and ``(N,)`` outputs (already checked),
            not yet fitted; ``likelihood`` is already on the device.
        fit: ``fit(model, likelihood, train_x, train_y, config, max_iter=, lr=, callback=, progress=)``
            with ``max_iter`` and ``lr`` resolved: the :class:`FitResult`.
        max_iter: ``max_iter`` when ``config.max_iter`` is ``None``.
        lr: the learning rate when ``config.lr`` is ``None`` (``None``: the optimizer's default,
            :func:`~bemlearn.fitting.optimize.default_lr`).
    """

    build: Callable[[torch.Tensor, torch.Tensor, GPConfig, GaussianLikelihood], torch.nn.Module]
    fit: Callable[..., FitResult]
    max_iter: int
    lr: float | None = None

    def resolved_max_iter(self, config: GPConfig) -> int:
        """``config.max_iter``, or this kind's default."""
        return config.max_iter if config.max_iter is not None else self.max_iter

    def resolved_lr(self, config: GPConfig) -> float:
        """``config.lr``, or this kind's default, or the optimizer's."""
        return config.lr if config.lr is not None else self.lr if self.lr is not None else default_lr(config.optimizer, None)


def _build_exact(train_x: torch.Tensor, train_y: torch.Tensor, config: GPConfig, lik: GaussianLikelihood) -> torch.nn.Module:
    device = torch.device(config.device)
    x, y = train_x.to(device), train_y.to(device)
    model = ExactBEMGP(x, y, lik).to(device)
    set_hyperparameters(model, lik, **data_hyperparameters(x, y, min_noise=config.min_noise))
    return model


def _build_sgpr(train_x: torch.Tensor, train_y: torch.Tensor, config: GPConfig, lik: GaussianLikelihood) -> torch.nn.Module:
    device = torch.device(config.device)
    theta = initial_hyperparameters(train_x, train_y, config=config)
    Z = select_inducing_points(train_x, config.n_inducing, method=config.inducing_init, seed=config.seed).to(device)
    x, y = train_x.to(device), train_y.to(device)
    model = SGPRBEMGP(x, y, lik, Z, learn_inducing_locations=config.learn_inducing, jitter=config.jitter).to(device)
    set_hyperparameters(model, lik, **theta)
    return model


def _build_svgp(train_x: torch.Tensor, train_y: torch.Tensor, config: GPConfig, lik: GaussianLikelihood) -> torch.nn.Module:
    device = torch.device(config.device)
    theta = initial_hyperparameters(train_x, train_y, config=config)
    Z = select_inducing_points(train_x, config.n_inducing, method=config.inducing_init, seed=config.seed).to(device)
    model = SVGPBEMGP(Z, learn_inducing_locations=config.learn_inducing, jitter=config.jitter).to(device)
    set_hyperparameters(model, lik, **theta)
    optimal_variational(model, lik, train_x.to(device), train_y.to(device))
    return model


def _fit_exact(model: Any, lik: GaussianLikelihood, x: torch.Tensor, y: torch.Tensor, config: GPConfig, *,
               max_iter: int, lr: float, callback: Callback | None, progress: bool) -> FitResult:
    return fit_exact(model, lik, optimizer=config.optimizer, max_iter=max_iter, lr=lr, tol=config.tol,
                     jitter=config.jitter, callback=callback, progress=progress)


def _fit_sgpr(model: Any, lik: GaussianLikelihood, x: torch.Tensor, y: torch.Tensor, config: GPConfig, *,
              max_iter: int, lr: float, callback: Callback | None, progress: bool) -> FitResult:
    return fit_sgpr(model, lik, optimizer=config.optimizer, max_iter=max_iter, lr=lr, tol=config.tol,
                    subset=config.fit_subset, seed=config.seed, jitter=config.jitter, callback=callback, progress=progress)


def _fit_svgp(model: Any, lik: GaussianLikelihood, x: torch.Tensor, y: torch.Tensor, config: GPConfig, *,
              max_iter: int, lr: float, callback: Callback | None, progress: bool) -> FitResult:
    # svgp counts epochs, not iterations: max_iter does not apply
    return fit_svgp(model, lik, x, y, batch_size=config.batch_size, epochs=config.epochs, lr=lr, ngd_lr=config.ngd_lr,
                    refresh_q=config.refresh_q, seed=config.seed, jitter=config.jitter, callback=callback, progress=progress)


#: The recipe of each registered GP kind, by model class.
FIT_RECIPES: dict[type[BEMGP], FitRecipe] = {
    cast(type[BEMGP], ExactBEMGP): FitRecipe(_build_exact, _fit_exact, max_iter=300),
    cast(type[BEMGP], SGPRBEMGP): FitRecipe(_build_sgpr, _fit_sgpr, max_iter=30),
    cast(type[BEMGP], SVGPBEMGP): FitRecipe(_build_svgp, _fit_svgp, max_iter=300, lr=0.003),
}


def fit_recipe(cls: type) -> FitRecipe:
    """The recipe of the GP kind whose model class is ``cls`` (or a subclass of it).

    Raises:
        ArgumentError: (a TypeError) ``cls`` is none of the registered classes.
    """
    for registered, recipe in FIT_RECIPES.items():
        if issubclass(cls, registered):
            return recipe
    raise ArgumentError(f"model: expected one of {[c.__name__ for c in FIT_RECIPES]}, got {cls.__name__}")
