"""The calibrated BEM band: latent std scaled by c, plus the larger of two models of the
derivative estimates' effect on μ (input noise through the mean's gradient; the mean's spread
over the neighbouring derivative estimators).

    σ_band(x)² = c² σ(x)² + max(σ_in²(x), σ_est²(x))                                      (B1)
    σ_in²(x)  = Σ_{i < n} (s_i ∂μ/∂x_i (x))²                                               (N1)
    σ_est²(x) = (1/K) Σ_k (y_std k_Z(x̃)ᵀ δ_k)²                                            (E2)

σ_in and σ_est are two estimates of the same error (the estimator spread already holds the
noise a narrower window lets through), so the band takes the larger, not the sum (the two
compared on trained runs: docs/uncertainty.md).

σ the latent posterior std of eq. (12) (physical units), c = ``PredictorState.std_scale``
(trial-split replica calibration), s = ``PredictorState.input_std`` (Savitzky–Golay
quantization model, eq. N3 of :mod:`bemlearn.models.input_noise`), ∂μ/∂x of eq. (N2),
δ = ``PredictorState.estimator_delta`` (eq. E2 of :mod:`bemlearn.fitting.estimator_sensitivity`;
no term when K = 0; a training run appends one column, μ's deviation from other draws of its training
rows, eq. R2 of :mod:`bemlearn.fitting.resample_sensitivity`, scaled so that the mean square is
σ_est² + σ_rs²), and n the number of columns the caller supplies: 3m for the BEM query x_0^e of eq. (14)
(q̈_u = q̇_u = 0 are exact there), all d for the full map of eq. (11).  This module is
the dense reference; the exported predictor folds the same formula
(:class:`~bemlearn.export.folded_posterior.FoldedPosterior`).
"""

from __future__ import annotations

import torch

from bemlearn.errors import ArgumentError
from bemlearn.models.input_noise import mean_gradient_from_row
from bemlearn.models.predictor_state import PredictorState

__all__ = ["band_and_gradient", "band_extra_variance", "band_reference", "BAND_FORMULA"]

#: Eq. (B1) as computed by :func:`band_extra_variance`, in plain ASCII: the one text of the formula that
#: the exported C header (and any other plain-text description of the band) prints.
BAND_FORMULA = ("std^2 = std_scale^2 latent_std^2 + max(sum_i (input_std_i dmean/dx_i)^2, "
                "(1/K) sum_k (mean's shift column k: derivative estimators, resampled training rows)^2)")


def band_reference(state: PredictorState, x: torch.Tensor, *, n_inputs: int | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(μ, σ_band, σ) of (B1), each ``(B,)`` in q_u's unit (rad or m), for physical ``x (B, d)``.

    Args:
        n_inputs: columns 0..n−1 carry input noise (default d); the rest are exact.
    """
    mean, band, latent, _ = _band(state, x, n_inputs, gradient=False)
    return mean, band, latent


def band_and_gradient(state: PredictorState, x: torch.Tensor, *, n_inputs: int | None = None
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`band_reference`'s (μ, σ_band, σ) with ∂μ/∂x of (N2) ``(B, d)``, all from one kernel row k_Z(x̃)."""
    mean, band, latent, grad = _band(state, x, n_inputs, gradient=True)
    assert grad is not None
    return mean, band, latent, grad


def _band(state: PredictorState, x: torch.Tensor, n_inputs: int | None, *, gradient: bool
          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    mean, latent, k = state.reference_terms(x)
    s = _noisy_inputs(state, n_inputs)
    grad = mean_gradient_from_row(state, x, k) if gradient or s is not None else None
    extra = _extra_variance(state, s, k, grad)
    assert state.std_scale is not None  # filled by PredictorState.__post_init__
    return mean, torch.sqrt(state.std_scale**2 * latent**2 + extra), latent, grad


def band_extra_variance(state: PredictorState, x: torch.Tensor, *, n_inputs: int | None = None) -> torch.Tensor:
    """The term of (B1) beyond the scaled latent variance, ``(B,)`` in q_u's unit squared, for physical ``x (B, d)``:
    max(Σ_{i < n} (s_i ∂μ/∂x_i)², (1/K) Σ_k (y_std k_Z(x̃)ᵀ δ_k)²)."""
    k = state.kernel_row(x.to(torch.float64))
    s = _noisy_inputs(state, n_inputs)
    return _extra_variance(state, s, k, mean_gradient_from_row(state, x, k) if s is not None else None)


def _noisy_inputs(state: PredictorState, n_inputs: int | None) -> torch.Tensor | None:
    """s of (N1) with the exact columns (≥ n) zeroed, or ``None`` when no column carries input noise."""
    n = state.dim if n_inputs is None else n_inputs
    if not 1 <= n <= state.dim:
        raise ArgumentError(f"band_reference: n_inputs: expected 1..{state.dim}, got {n}")
    assert state.input_std is not None  # filled by PredictorState.__post_init__
    s = state.input_std.clone()
    s[n:] = 0.0
    return s if bool((s > 0).any()) else None


def _extra_variance(state: PredictorState, s: torch.Tensor | None, k: torch.Tensor, grad: torch.Tensor | None) -> torch.Tensor:
    """max(σ_in², σ_est²) of (B1) from s (:func:`_noisy_inputs`), the kernel row k ``(B, M)`` and ∂μ/∂x ``(B, d)``."""
    assert state.estimator_delta is not None  # filled by PredictorState.__post_init__
    var_in = torch.zeros(k.shape[0], dtype=torch.float64, device=k.device)
    var_est = torch.zeros_like(var_in)
    if s is not None:
        assert grad is not None
        var_in = ((grad * s) ** 2).sum(-1)
    if state.n_estimators:
        var_est = (state.y_std * (k @ state.estimator_delta)).square().mean(-1)
    return torch.maximum(var_in, var_est)
