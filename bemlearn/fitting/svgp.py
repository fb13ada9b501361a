"""Fit an SVGP model by minibatch maximization of the ELBO (Hensman et al., 2013)."""

from __future__ import annotations

import logging
import math
import time

import gpytorch
import torch
from tqdm.auto import tqdm

from bemlearn.errors import ArgumentError
from bemlearn.fitting.optimize import KeptParameters, NumericalFailure, checked_loss
from bemlearn.fitting.result import Callback, FitResult, hyperparameter_metrics
from bemlearn.fitting.variational import optimal_variational
from bemlearn.interrupts import check_interrupt
from bemlearn.models.solver import DEFAULT_JITTER, DEFAULT_MAX_TRIES, cholesky_policy
from bemlearn.models.svgp import SVGPBEMGP
from bemlearn.models.validation import check_inputs, check_targets

__all__ = ["fit_svgp"]

logger = logging.getLogger(__name__)


def fit_svgp(
    model: SVGPBEMGP,
    likelihood: gpytorch.likelihoods.GaussianLikelihood,
    train_x: torch.Tensor,
    train_y: torch.Tensor,
    *,
    batch_size: int = 4096,
    epochs: int = 10,
    lr: float = 0.003,
    ngd_lr: float = 0.01,
    refresh_q: bool = True,
    seed: int = 0,
    jitter: float = DEFAULT_JITTER,
    max_tries: int = DEFAULT_MAX_TRIES,
    callback: Callback | None = None,
    progress: bool = False,
) -> FitResult:
    """Maximize the minibatch ELBO  (N/B) Σ_{i∈batch} E_q[log N(y_i | f_i, σ_0²)] − KL(q(v) ‖ p(v)).

    q(v) takes natural-gradient steps and θ, Z take Adam steps on the same minibatch (plain
    Adam on the parameters of q would undo a good, e.g. optimal, :func:`optimal_variational`
    initialization).  With small noise (σ_0² ~ 1e-4 Var(y)) q is sharply peaked and a
    stochastic q lags behind θ; hence the small default steps and the final exact refresh of
    q, which makes the returned posterior the optimal one for the learned θ and Z.

    The data stay where they are (e.g. CPU, even for a GPU model) and only each shuffled
    minibatch is moved to the model's device, so memory is O(B M + M²) beyond the data.

    Args:
        model: the SVGP model.
        likelihood: its Gaussian likelihood.
        train_x: ``(N, d)`` normalized inputs.
        train_y: ``(N,)`` normalized outputs.
        batch_size: minibatch size B.
        epochs: passes over the data.
        lr: Adam step size for θ = (ℓ, σ_f², σ_0²) and Z.
        ngd_lr: natural-gradient step size for q(v) (1 would jump to the optimal q of the
            minibatch; 0.1 averages over minibatches).
        refresh_q: after the last epoch, set q(v) to its optimum for the final θ and Z
            (:func:`~bemlearn.fitting.variational.optimal_variational`, one streamed O(N M²) pass).
        seed: seed of the minibatch order.
        jitter: Cholesky retry policy: the first jitter j₀ (:func:`~bemlearn.models.solver.robust_cholesky`).
        max_tries: Cholesky retry policy: the number of jittered retries.
        callback: ``callback(step, metrics)`` after every minibatch (metrics also has ``epoch``).
        progress: show a progress bar.

    Returns:
        a :class:`FitResult` whose loss is the mean −ELBO per point over the last epoch.
    """
    if not isinstance(model, SVGPBEMGP):
        raise ArgumentError(f"model: expected SVGPBEMGP, got {type(model).__name__}")
    dtype = next(model.parameters()).dtype
    check_inputs(train_x, name="train_x", dim=model.dim, dtype=dtype)
    check_targets(train_y, name="train_y", n=train_x.shape[0], dtype=dtype)
    for name, count in (("batch_size", batch_size), ("epochs", epochs)):
        if count < 1:
            raise ArgumentError(f"{name}: expected a positive integer, got {count}")
    device = next(model.parameters()).device
    N = train_x.shape[0]
    model.train()
    likelihood.train()
    elbo = gpytorch.mlls.VariationalELBO(likelihood, model, num_data=N)
    for name, value in (("lr", lr), ("ngd_lr", ngd_lr)):
        if not value > 0.0:
            raise ArgumentError(f"{name}: expected a positive step size, got {value}")
    step = _MinibatchStep(model, likelihood, elbo, lr=lr, ngd_lr=ngd_lr)
    kept = KeptParameters(step.params, desc="SVGP", kept="last good", unit="steps")
    gen = torch.Generator(device="cpu").manual_seed(seed)
    epoch_loss = math.nan
    metrics: dict[str, float] = {}
    start = time.perf_counter()
    with (tqdm(total=epochs * math.ceil(N / batch_size), desc="SVGP", disable=not progress, leave=False) as bar,
          kept.guard(), cholesky_policy(jitter=jitter, max_tries=max_tries)):
        for epoch in range(epochs):
            total = 0.0
            for idx in torch.randperm(N, generator=gen).split(batch_size):
                check_interrupt()  # between mini-batch steps
                value = step(train_x[idx.to(train_x.device)].to(device), train_y[idx.to(train_y.device)].to(device))
                kept.keep()
                total += value * idx.numel()
                metrics = {"loss": value, **hyperparameter_metrics(model, likelihood), "lr": lr, "epoch": float(epoch)}
                if callback is not None:
                    callback(kept.count, metrics)
                kept.count += 1
                bar.update(1)
                bar.set_postfix(epoch=epoch, loss=f"{value:.4f}")
            epoch_loss = total / N
            logger.debug("SVGP epoch %d: mean -ELBO per point %.6f", epoch, epoch_loss)
    if refresh_q:
        optimal_variational(model, likelihood, train_x.to(device), train_y.to(device))
        model.train()
    metrics = {**metrics, "loss": epoch_loss, **hyperparameter_metrics(model, likelihood)}
    stop = "numerical failure" if kept.failed else "epochs"
    return FitResult(model.kind, epoch_loss, kept.count, time.perf_counter() - start, stop, metrics)


class _MinibatchStep:
    """One minibatch step: natural gradient on q(v) (``variational``), Adam on θ and Z (``hyper``).

    ``step(x_b, y_b)`` returns the minibatch's −ELBO per point before the step.

    Raises:
        NumericalFailure: the loss is not finite, its Cholesky failed, or a parameter is not finite after the step.
    """

    def __init__(self, model: SVGPBEMGP, likelihood: gpytorch.likelihoods.GaussianLikelihood,
                 elbo: gpytorch.mlls.VariationalELBO, *, lr: float, ngd_lr: float) -> None:
        variational = list(model.variational_parameters())
        hyper = list(model.hyperparameters()) + [p for p in likelihood.parameters() if all(p is not q for q in model.parameters())]
        self.model, self.elbo = model, elbo
        self.params = variational + hyper
        self.ngd = gpytorch.optim.NGD(variational, num_data=elbo.num_data, lr=ngd_lr)
        self.adam = torch.optim.Adam(hyper, lr=lr)

    def __call__(self, xb: torch.Tensor, yb: torch.Tensor) -> float:
        self.ngd.zero_grad(set_to_none=True)
        self.adam.zero_grad(set_to_none=True)
        loss = checked_loss(lambda: -self.elbo(self.model(xb), yb))
        loss.backward()
        self.ngd.step()
        self.adam.step()
        if any(not bool(torch.isfinite(p).all()) for p in self.params):
            raise NumericalFailure("non-finite parameters after an Adam step")
        return float(loss.detach())
