"""Fit an SGPR model by maximizing the collapsed Titsias bound (Titsias, 2009, Eq. 9)."""

from __future__ import annotations

import gpytorch
import torch

from bemlearn.errors import ArgumentError
from bemlearn.fitting.optimize import default_lr, minimize
from bemlearn.fitting.result import Callback, FitResult, hyperparameter_metrics
from bemlearn.models.sgpr import SGPRBEMGP
from bemlearn.models.solver import DEFAULT_JITTER, DEFAULT_MAX_TRIES, cholesky_policy

__all__ = ["fit_sgpr"]


def fit_sgpr(
    model: SGPRBEMGP,
    likelihood: gpytorch.likelihoods.GaussianLikelihood,
    *,
    optimizer: str = "lbfgs",
    max_iter: int = 50,
    lr: float | None = None,
    tol: float = 1e-9,
    jitter: float = DEFAULT_JITTER,
    max_tries: int = DEFAULT_MAX_TRIES,
    subset: int = 0,
    seed: int = 0,
    callback: Callback | None = None,
    progress: bool = False,
) -> FitResult:
    """Minimize −F / N, F the collapsed bound of :class:`~bemlearn.models.sgpr.SGPRBEMGP`.

    Each evaluation costs O(N M²); L-BFGS from a good start (hyperparameters of a small
    exact GP, k-means++ inducing points) needs few of them.  With ``0 < subset < N`` the
    hyperparameters and Z are optimized on ``subset`` random training points (the bound of that
    subset), and the model's posterior is then conditioned on all N points again (each
    evaluation then costs O(subset · M²) instead of O(N M²)).

    Args:
        model: the SGPR model (holds X, Y, Z and ``likelihood``).
        likelihood: its Gaussian likelihood (must be ``model.likelihood``).
        optimizer: ``"lbfgs"`` or ``"adam"``.
        max_iter: iterations / steps.
        lr: learning rate (``None``: 1.0 for L-BFGS, 0.05 for Adam).
        tol: convergence tolerance on the loss (nats per point).
        jitter: Cholesky retry policy: the first jitter j₀ (:func:`~bemlearn.models.solver.robust_cholesky`).
        max_tries: Cholesky retry policy: the number of jittered retries.
        subset: optimize on this many random points (0: all N).
        seed: seed of the subset draw.
        callback: ``callback(step, metrics)`` after every step.
        progress: show a progress bar.

    Returns:
        a :class:`FitResult`; the model is left in train mode.
    """
    if not isinstance(model, SGPRBEMGP):
        raise ArgumentError(f"model: expected SGPRBEMGP, got {type(model).__name__}")
    if likelihood is not model.likelihood:
        raise ArgumentError("likelihood: must be the likelihood the SGPR model was built with")
    model.train()
    likelihood.train()
    if subset < 0:
        raise ArgumentError(f"subset: expected a non-negative integer, got {subset}")
    full_x, full_y = model.train_x, model.train_y
    if 0 < subset < full_x.shape[0]:
        gen = torch.Generator(device="cpu").manual_seed(seed)
        idx = torch.randperm(full_x.shape[0], generator=gen)[:subset].to(full_x.device)
        model.train_x, model.train_y = full_x[idx], full_y[idx]

    def loss_fn() -> torch.Tensor:
        return -model.collapsed_bound() / model.train_x.shape[0]

    try:
        with cholesky_policy(jitter=jitter, max_tries=max_tries):
            return minimize(
                loss_fn, list(model.parameters()), optimizer=optimizer, max_iter=max_iter, lr=default_lr(optimizer, lr), tol=tol,
                metrics_fn=lambda: hyperparameter_metrics(model, likelihood), callback=callback,
                progress=progress, desc="SGPR", kind=model.kind,
            )
    finally:
        model.train_x, model.train_y = full_x, full_y
