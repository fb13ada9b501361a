"""MAP training of :class:`bemlearn.models.gpdm.GPDM`: minimize the modified eq. (17).

    min_{X, α, β, W, c̃}  −log p(Ỹ | X, β, W) + (D/d)(−log p(X | α)) + λ ‖X − Ỹc̃‖²

Two phases, both run by the project's :func:`bemlearn.fitting.optimize.minimize` (L-BFGS
with strong-Wolfe line search, or Adam; best parameters kept on a numerical failure): a
warm-up that moves only the kernel hyperparameters (α, β, W) with the latents X and c̃
frozen at their initialization, then the joint MAP over everything.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Literal

import torch

from bemlearn.errors import ConfigError
from bemlearn.fitting.optimize import minimize
from bemlearn.fitting.result import Callback
from bemlearn.models.gpdm import GPDM, GPDMObjective

__all__ = ["GPDMConfig", "fit_gpdm", "gpdm_metrics"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class GPDMConfig:
    """Options of :func:`fit_gpdm` (parse YAML with ``bemlearn.config.from_dict``).

    Attributes:
        order: dynamics order p: 1 (χ_{t−1} → χ_t) or 2 ([χ_{t−1}, χ_{t−2}] → χ_t).
        penalty: λ, weight of ‖X − Ỹc̃‖² (normalized joint units; c̃ has unit norm).
        dynamics_weight: weight of −log p(X | α); ``None`` is the balanced D/d = n.
        scale_joints: divide each centered joint by its standard deviation.
        init: start of c̃: ``"slow"`` (slowest linear projection within sequences),
            ``"pca"`` (first principal direction) or ``"random"`` (seeded).
        seed: seed of the random initialization and of torch's RNG during the fit.
        optimizer: ``"lbfgs"`` or ``"adam"``.
        max_iter: iterations (L-BFGS) or steps (Adam) of the joint MAP phase.
        warmup_iter: hyperparameter-only iterations before it (0 skips the warm-up).
        lr: step size; ``None`` is 1.0 for L-BFGS and 0.01 for Adam.
        tolerance: L-BFGS stops when the objective or the parameters change by less than
            this in an iteration; Adam after 50 steps without an improvement larger than it.
        jitter: first diagonal jitter when a kernel matrix fails to factorize.
    """

    order: Literal[1, 2] = 1
    penalty: float = 100.0
    dynamics_weight: float | None = None
    scale_joints: bool = True
    init: Literal["slow", "pca", "random"] = "slow"
    seed: int = 0
    optimizer: Literal["lbfgs", "adam"] = "lbfgs"
    max_iter: int = 500
    warmup_iter: int = 50
    lr: float | None = None
    tolerance: float = 1e-9
    jitter: float = 1e-8

    def __post_init__(self) -> None:
        for name in ("max_iter", "warmup_iter", "penalty", "tolerance", "jitter"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"{name}: expected ≥ 0, got {getattr(self, name)}")
        if self.dynamics_weight is not None and not self.dynamics_weight >= 0:
            raise ConfigError(f"dynamics_weight: expected ≥ 0 or null, got {self.dynamics_weight}")
        if self.lr is not None and not self.lr > 0:
            raise ConfigError(f"lr: expected > 0 or null, got {self.lr}")


def gpdm_metrics(model: GPDM, terms: GPDMObjective | None = None) -> dict[str, float]:
    """Objective terms (of ``terms``, else evaluated now), hyperparameters and c of ``model`` as floats."""
    with torch.no_grad():
        terms = model.objective() if terms is None else terms
        out = {name: float(value.detach()) for name, value in terms._asdict().items() if name != "total"}
        for name in ("obs_lengthscale", "obs_noise", "dyn_outputscale", "dyn_noise"):
            out[name] = float(getattr(model, name))
        for name in ("dyn_lengthscale", "dyn_linear", "c"):
            for k, value in enumerate(getattr(model, name).tolist()):
                out[f"{name}_{k}"] = float(value)
    return out


@contextmanager
def _train_only(model: GPDM, params: list[torch.nn.Parameter]) -> Iterator[None]:
    """Turn off gradients of the parameters of ``model`` not in ``params`` (restored on exit)."""
    frozen = [p for p in model.parameters() if not any(p is q for q in params)]
    for p in frozen:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in frozen:
            p.requires_grad_(True)


def _shifted(callback: Callback | None, offset: int) -> Callback | None:
    """``callback`` with its step counted from ``offset`` (so the phases number steps consecutively)."""
    if callback is None:
        return None
    return lambda step, metrics: callback(offset + step, metrics)


def fit_gpdm(
    Q_list: Sequence,
    *,
    config: GPDMConfig = GPDMConfig(),
    callback: Callback | None = None,
    progress: bool = False,
) -> GPDM:
    """Fit a GPDM with the χ = c·q penalty to joint sequences by MAP (modified eq. 17).

    Args:
        Q_list: one (T_i, n) array per sequence, joint angles in rad; sequences are
            independent dynamics chains (no transition across a boundary).
        config: model and optimizer options (:class:`GPDMConfig`).
        callback: ``callback(step, metrics)`` after every objective evaluation (L-BFGS
            line-search trials included), steps numbered across both phases; ``metrics``
            holds ``loss`` (the objective), ``observation``, ``dynamics``, ``penalty``,
            the hyperparameters (``obs_lengthscale``, ``dyn_lengthscale_0``, …), the
            gait vector ``c_0`` … ``c_{n−1}`` (physical units) and ``lr``.
        progress: show tqdm progress bars.

    Returns:
        The fitted :class:`GPDM` (sign canonicalized: the largest |c̃_j| is positive).
    """
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = GPDM(
            Q_list,
            order=config.order,
            penalty=config.penalty,
            dynamics_weight=config.dynamics_weight,
            scale_joints=config.scale_joints,
            init=config.init,
            seed=config.seed,
            jitter=config.jitter,
        )
        last: dict[str, GPDMObjective] = {}

        def loss_fn() -> torch.Tensor:
            last["terms"] = model.objective()
            return last["terms"].total

        def metrics_fn() -> dict[str, float]:
            return gpdm_metrics(model, last.get("terms"))

        lr = config.lr or (1.0 if config.optimizer == "lbfgs" else 0.01)
        phases = (
            ("warm-up", [p for name, p in model.named_parameters() if name.startswith("raw_")], config.warmup_iter),
            ("MAP", list(model.parameters()), config.max_iter),
        )
        evaluations = 0
        for phase, params, n_iter in phases:
            if n_iter == 0:
                continue
            with _train_only(model, params):
                result = minimize(
                    loss_fn,
                    params,
                    optimizer=config.optimizer,
                    max_iter=n_iter,
                    lr=lr,
                    tol=config.tolerance,
                    metrics_fn=metrics_fn,
                    callback=_shifted(callback, evaluations),
                    progress=progress,
                    desc=f"GPDM {phase}",
                    kind="gpdm",
                )
            evaluations += result.steps
            logger.info("GPDM %s: objective %.6g after %d evaluations (%s)", phase, result.loss, result.steps, result.stop_reason)
    model.canonicalize_sign_()
    return model
