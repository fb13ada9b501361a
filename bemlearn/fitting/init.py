"""Data-driven initialization: hyperparameters from data statistics (refined by a small exact GP),
inducing points by k-means++."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import torch

from bemlearn.errors import ArgumentError
from bemlearn.fitting.exact import fit_exact
from bemlearn.models.exact_gp import ExactBEMGP
from bemlearn.models.kernels import gaussian_likelihood
from bemlearn.models.validation import check_inputs, check_targets

if TYPE_CHECKING:
    from bemlearn.fitting.gp_config import GPConfig

__all__ = ["data_hyperparameters", "initial_hyperparameters", "set_hyperparameters", "select_inducing_points"]

logger = logging.getLogger(__name__)


def data_hyperparameters(
    train_x: torch.Tensor, train_y: torch.Tensor, *, noise_fraction: float = 0.01, min_noise: float = 1e-6
) -> dict[str, torch.Tensor]:
    """Initial θ of eq. (11) from the data spread.

    ℓ_j = std(x_j) (1 for a constant column), σ_f² = Var(y), σ_0² = max(noise_fraction · Var(y), 2 · min_noise).

    Args:
        train_x: ``(N, d)`` normalized inputs.
        train_y: ``(N,)`` normalized outputs.
        noise_fraction: initial σ_0² as a fraction of Var(y).
        min_noise: the likelihood's noise floor.

    Returns:
        ``{"lengthscale": (d,), "outputscale": (), "noise": ()}`` tensors of the input dtype.
    """
    check_inputs(train_x, name="train_x")
    check_targets(train_y, name="train_y", n=train_x.shape[0])
    spread = train_x.std(dim=0) if train_x.shape[0] > 1 else torch.ones_like(train_x[0])
    lengthscale = torch.where(spread > 1e-12, spread, torch.ones_like(spread))
    var_y = train_y.var() if train_y.shape[0] > 1 else torch.ones((), dtype=train_y.dtype)
    var_y = var_y.clamp_min(1e-6)
    noise = torch.clamp_min(noise_fraction * var_y, 2.0 * min_noise)
    return {"lengthscale": lengthscale, "outputscale": var_y, "noise": noise}


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


def set_hyperparameters(
    model: torch.nn.Module,
    likelihood: torch.nn.Module,
    *,
    lengthscale: torch.Tensor,
    outputscale: torch.Tensor,
    noise: torch.Tensor,
) -> None:
    """Write ℓ ``(d,)``, σ_f² ``()`` and σ_0² ``()`` into a model's kernel and likelihood.

    Values are set through the GPyTorch constraints in the model's dtype; a noise at or below the
    likelihood's floor is raised to 1.5 × the floor (with a debug log).
    """
    kernel: Any = model.covar_module  # a gpytorch ScaleKernel: nn.Module attributes are untyped
    ref = kernel.raw_outputscale
    kernel.base_kernel.lengthscale = torch.as_tensor(lengthscale).to(ref).reshape(1, -1)
    kernel.outputscale = torch.as_tensor(outputscale).to(ref).reshape(())
    noise_covar: Any = likelihood.noise_covar  # gpytorch module: nn.Module attributes are untyped
    floor = float(noise_covar.raw_noise_constraint.lower_bound)
    noise_t = torch.as_tensor(noise).to(ref).reshape(1)
    if float(noise_t) <= floor:
        logger.debug("initial noise %.3g at or below the floor %.3g; using 1.5 × floor", float(noise_t), floor)
        noise_t = torch.full_like(noise_t, 1.5 * floor)
    likelihood.noise = noise_t


def select_inducing_points(
    train_x: torch.Tensor, num: int, *, method: str = "kmeans++", seed: int = 0, max_candidates: int = 200_000
) -> torch.Tensor:
    """Choose ``num`` inducing inputs among the training inputs.

    ``"kmeans++"``: D² seeding (each next point drawn with probability ∝ squared distance to the
    nearest chosen one), spreading Z over the data; ``"random"``: a uniform subset.  With
    ``num ≥ N`` all inputs are returned.  Above ``max_candidates`` rows a random subset of
    candidates is used.

    Args:
        train_x: ``(N, d)`` normalized inputs.
        num: M, the number of inducing points.
        method: ``"kmeans++"`` or ``"random"``.
        seed: seed of the draw.
        max_candidates: cap on the rows considered by k-means++.

    Returns:
        ``(min(M, N), d)`` inducing inputs (copies).
    """
    check_inputs(train_x, name="train_x")
    if num < 1:
        raise ArgumentError(f"num: expected a positive number of inducing points, got {num}")
    if method not in ("kmeans++", "random"):
        raise ArgumentError(f"method: unknown inducing-point method {method!r}; valid are ['kmeans++', 'random']")
    N = train_x.shape[0]
    if num >= N:
        return train_x.clone()
    gen = torch.Generator(device="cpu").manual_seed(seed)
    if method == "random":
        return train_x[torch.randperm(N, generator=gen)[:num].to(train_x.device)].clone()
    cand = train_x
    if max_candidates < N:
        cand = train_x[torch.randperm(N, generator=gen)[:max_candidates].to(train_x.device)]
    n = cand.shape[0]
    chosen = [int(torch.randint(n, (1,), generator=gen))]
    d2 = ((cand - cand[chosen[0]]) ** 2).sum(-1)
    for _ in range(1, num):
        total = d2.sum()
        if not bool(total > 0):  # every candidate already chosen (duplicates): fill randomly
            idx = int(torch.randint(n, (1,), generator=gen))
        else:
            idx = int(torch.multinomial((d2 / total).cpu(), 1, generator=gen))
        chosen.append(idx)
        d2 = torch.minimum(d2, ((cand - cand[idx]) ** 2).sum(-1))
    return cand[torch.tensor(chosen, device=cand.device)].clone()
