"""Parity of the compiled C export with the TorchScript predictor, for ``bemlearn bench predict``.

The C functions are called one query at a time through ctypes on in-range inputs (the
support points' box, :func:`~bemlearn.export.c_posterior.support_box`) and compared with the
TorchScript methods they mirror:

    bem_forward          vs forward              mean and calibrated band (eq. 14, B1)
    bem_forward_latent   vs forward_latent       latent std (eq. 12)
    bem_predict_full     vs predict_full         full map f (eq. 11), band over all 3m + 2 inputs
    bem_predict_full_latent vs predict_full_latent
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bemlearn.export.c_build import CPredictorLibrary, compile_shared
from bemlearn.export.c_export import write_files
from bemlearn.export.c_posterior import support_box
from bemlearn.models.predictor_state import PredictorState

__all__ = ["c_parity", "in_range_inputs"]


def in_range_inputs(state: PredictorState, n: int, *, seed: int = 0) -> np.ndarray:
    """``(n, d)`` physical inputs x_mean + 1.5 x_std N(0, 1), clipped to the accepted range."""
    lo, hi = support_box(state.Z, state.x_mean, state.x_std, state.lengthscale)
    g = np.random.default_rng(seed)
    x = state.x_mean.numpy() + 1.5 * state.x_std.numpy() * g.standard_normal((n, state.dim))
    return np.clip(x, lo, hi)


def c_parity(sources: dict[str, str], ts: Any, x: np.ndarray, *, n_bem: int, prefix: str = "bem") -> dict[str, float]:
    """Largest C-vs-TorchScript differences on ``x (B, 3m + 2)`` (the BEM uses its first ``n_bem`` columns).

    Args:
        sources: the C export's ``{file name: text}`` (float64).
        ts: the loaded TorchScript predictor of the same posterior.

    Returns:
        ``{"n", "forward_mean_abs" (rad), "forward_std_rel", "forward_latent_std_rel",
        "full_mean_abs", "full_std_rel", "full_latent_std_rel"}``.
    """
    out: dict[str, float] = {"n": float(len(x))}
    with tempfile.TemporaryDirectory() as tmp:
        files = write_files(sources, tmp)
        lib = CPredictorLibrary(compile_shared([files[1]], Path(tmp) / f"lib{prefix}.so"), prefix=prefix)
        for key, cols, band, latent in (("forward", n_bem, ts.forward, ts.forward_latent),
                                        ("full", x.shape[1], ts.predict_full, ts.predict_full_latent)):
            xi = np.ascontiguousarray(x[:, :cols])
            with torch.no_grad():
                ref_mean, ref_std = (t.numpy() for t in band(torch.from_numpy(xi)))
                ref_latent = latent(torch.from_numpy(xi))[1].numpy()
            mean, std, _ = lib.forward(xi, full=key == "full")
            _, lat, _ = lib.forward(xi, full=key == "full", latent=True)
            out[f"{key}_mean_abs"] = float(np.abs(mean - ref_mean).max())
            out[f"{key}_std_rel"] = float(np.abs(std / ref_std - 1).max())
            out[f"{key}_latent_std_rel"] = float(np.abs(lat / ref_latent - 1).max())
    return out
