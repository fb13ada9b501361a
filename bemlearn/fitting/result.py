"""What a fit returns, and the scalar metrics a fit reports to its callback."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch

__all__ = ["FitResult", "Callback", "hyperparameter_metrics"]

#: ``callback(step, metrics)``; metrics holds ``loss``, ``noise``, ``outputscale``,
#: ``lengthscale_0`` … ``lengthscale_{d-1}`` and ``lr`` (all floats).
Callback = Callable[[int, dict[str, float]], None]


@dataclass(frozen=True)
class FitResult:
    """Summary of one fit.

    Attributes:
        kind: what was fitted: the GP kind (``exact``, ``sgpr``, ``svgp``), or e.g. ``gpdm``.
        loss: final loss (negative log marginal likelihood or bound per training point, nats).
        steps: loss evaluations (L-BFGS, including line-search trials), Adam steps or minibatches.
        seconds: wall-clock time of the fit.
        stop_reason: ``"converged"``, ``"max_iter"``, ``"epochs"`` or ``"numerical failure"``.
        metrics: the last metrics passed to the callback.
    """

    kind: str
    loss: float
    steps: int
    seconds: float
    stop_reason: str
    metrics: dict[str, float]


def hyperparameter_metrics(model: torch.nn.Module, likelihood: torch.nn.Module) -> dict[str, float]:
    """Current σ_0², σ_f² and every ℓ_j as floats (normalized units)."""
    kernel: Any = model.covar_module  # a gpytorch ScaleKernel: nn.Module attributes are untyped
    noise: Any = likelihood.noise  # a gpytorch likelihood: nn.Module attributes are untyped
    out = {"noise": float(noise.detach().reshape(())), "outputscale": float(kernel.outputscale.detach().reshape(()))}
    for j, ls in enumerate(kernel.base_kernel.lengthscale.detach().reshape(-1).tolist()):
        out[f"lengthscale_{j}"] = float(ls)
    return out
