"""Benchmark GP training: build + fit time, accuracy on held-out points, peak memory.

``bemlearn bench train`` calls :func:`bench_train` with the training arrays; the synthetic
5-D smooth function :func:`smooth_target` gives a reproducible stand-in for BEM data.
"""

from __future__ import annotations

import dataclasses
import logging
import resource
import sys
import time

import numpy as np
import torch

from bemlearn.errors import ArgumentError
from bemlearn.fitting.build import build_gp
from bemlearn.fitting.fit import fit_gp
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.fitting.result import Callback
from bemlearn.models.gp_kinds import gp_class
from bemlearn.models.predict import predict

__all__ = ["smooth_target", "synthetic_data", "bench_train", "peak_rss_mib", "config_for"]

logger = logging.getLogger(__name__)


def smooth_target(x: torch.Tensor) -> torch.Tensor:
    """f(x) = sin(1.5 x₀) + 0.5 x₁ + 0.3 x₂ x₃ + 0.2 cos(2 x₄) (+ 0.1 Σ_{j≥5} sin x_j).

    Args:
        x: ``(N, d)`` inputs, d ≥ 5.

    Returns:
        ``(N,)`` values.
    """
    if x.ndim != 2 or x.shape[1] < 5:
        raise ArgumentError(f"x: expected shape (N, d) with d >= 5, got {tuple(x.shape)}")
    y = torch.sin(1.5 * x[:, 0]) + 0.5 * x[:, 1] + 0.3 * x[:, 2] * x[:, 3] + 0.2 * torch.cos(2.0 * x[:, 4])
    if x.shape[1] > 5:
        y = y + 0.1 * torch.sin(x[:, 5:]).sum(1)
    return y


def synthetic_data(
    n: int, *, dim: int = 5, noise_std: float = 0.01, seed: int = 0, dtype: torch.dtype = torch.float64
) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` standard-normal inputs ``(n, dim)`` and noisy targets ``(n,)`` = :func:`smooth_target` + N(0, noise_std²)."""
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(n, dim, generator=gen, dtype=dtype)
    y = smooth_target(x) + noise_std * torch.randn(n, generator=gen, dtype=dtype)
    return x, y


def peak_rss_mib() -> float:
    """Peak resident set size of this process so far, MiB (``resource.getrusage``)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1024.0 if sys.platform != "darwin" else rss / 2**20


def _as_tensor(a: object, name: str, dtype: torch.dtype) -> torch.Tensor:
    if isinstance(a, np.ndarray):
        a = torch.from_numpy(a)
    if not isinstance(a, torch.Tensor):
        raise ArgumentError(f"{name}: expected a numpy array or torch tensor, got {type(a).__name__}")
    return a.to(dtype)


def bench_train(
    train_x: torch.Tensor | np.ndarray,
    train_y: torch.Tensor | np.ndarray,
    *,
    config: GPConfig,
    test_x: torch.Tensor | np.ndarray | None = None,
    test_y: torch.Tensor | np.ndarray | None = None,
    callback: Callback | None = None,
    progress: bool = False,
) -> dict[str, float | int | str]:
    """Build and fit one GP of ``config.kind`` and report times, accuracy and memory.

    Args:
        train_x: ``(N, d)`` normalized inputs.
        train_y: ``(N,)`` normalized outputs.
        config: the GP configuration (kind, M, optimizer, …).
        test_x: ``(T, d)`` held-out normalized inputs (optional).
        test_y: ``(T,)`` held-out targets (e.g. the noise-free function).
        callback: passed to the fit.
        progress: show progress bars.

    Returns:
        a flat dict: ``kind``, ``n_train``, ``n_inducing``, ``build_s``, ``fit_s``, ``total_s``,
        ``steps``, ``stop_reason``, ``loss``, ``noise``, ``outputscale``, ``peak_rss_mib``, and
        with test data ``test_rmse``, ``predict_s`` (time to predict all test points),
        ``mean_std`` (mean predictive latent std).
    """
    x = _as_tensor(train_x, "train_x", config.torch_dtype)
    y = _as_tensor(train_y, "train_y", config.torch_dtype)
    t0 = time.perf_counter()
    model, likelihood = build_gp(x, y, config=config)
    t1 = time.perf_counter()
    result = fit_gp(model, likelihood, x, y, config=config, callback=callback, progress=progress)
    t2 = time.perf_counter()
    out: dict[str, float | int | str] = {
        "kind": config.kind,
        "n_train": int(x.shape[0]),
        "n_inducing": min(config.n_inducing, int(x.shape[0])) if gp_class(config.kind).sparse else int(x.shape[0]),
        "build_s": t1 - t0,
        "fit_s": t2 - t1,
        "total_s": t2 - t0,
        "steps": result.steps,
        "stop_reason": result.stop_reason,
        "loss": result.loss,
        "noise": result.metrics.get("noise", float("nan")),
        "outputscale": result.metrics.get("outputscale", float("nan")),
    }
    if test_x is not None:
        if test_y is None:
            raise ArgumentError("test_y: required when test_x is given")
        tx = _as_tensor(test_x, "test_x", config.torch_dtype).to(config.device)
        ty = _as_tensor(test_y, "test_y", config.torch_dtype).to(config.device)
        t3 = time.perf_counter()
        mean, var = predict(model, likelihood, tx)
        out["predict_s"] = time.perf_counter() - t3
        out["test_rmse"] = float((mean - ty).pow(2).mean().sqrt())
        out["mean_std"] = float(var.sqrt().mean())
    out["peak_rss_mib"] = peak_rss_mib()
    logger.info("bench %s", out)
    return out


def config_for(kind: str, **overrides: object) -> GPConfig:
    """A :class:`GPConfig` of ``kind`` with field overrides (convenience for the CLI)."""
    return dataclasses.replace(GPConfig(kind=kind), **overrides)  # type: ignore[arg-type]
