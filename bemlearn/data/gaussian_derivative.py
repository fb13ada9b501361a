"""Gaussian-kernel derivatives: one smoothing filter for q, q̇, q̈ and the label alike.

With the Gaussian g_σ(t) = exp(−t²/2σ²) / (σ√(2π)) and the smoothed signal
S[f](t) = ∫ f(τ) g_σ(t − τ) dτ, integration by parts gives

    S[q̇] = g_σ' ∗ q,     S[q̈] = g_σ'' ∗ q                                     (G1)

so the estimates of q̇ and q̈ are *the derivatives of the smoothed angle*, S[q] = g_σ ∗ q.  The
unactuated row of the dynamics (eq. 2b) is linear in q̈ and, near upright, in q; a linear
time-invariant filter applied to every term keeps it:

    D_uu S[q̈_u] + D_ua S[q̈_a] + … + G_u(S[q]) ≈ 0                            (G2)

up to the smoothing of the products and of the nonlinearity (second order in the fast part of
the motion).  The GP of eq. (11) is therefore trained on (S[x], S[q_u]) pairs: inputs and label
through the same filter.  An estimator whose q̈ filter is *not* the second derivative of the
filter its label went through (a raw label with any smoothing q̈; Savitzky–Golay, whose q̈ and
smoothing filters agree only in the passband) breaks (G2) wherever the true accelerations have
content beyond the passband, as they do under a zero-order-hold input: the BEM's slope is then
biased (docs/derivatives.md).

Discretely, at samples q_k = q(kh), S[q]_i = Σ_k w0_k q_{i−k} with w0_k = h g_σ(kh) and
likewise w1 = h g_σ', w2 = h g_σ'' (``scipy.ndimage.convolve1d``), truncated at |t| ≤ r σ
(r = ``truncate``, 5 by default: the tail beyond it is 6·10⁻⁷ of the kernel's mass) and
normalised so that constants and ramps are smoothed to themselves and parabolas differentiated
exactly; a sine is then smoothed and differentiated to ~5·10⁻⁵ of its smoothed amplitude.

Edges: within ⌈r σ f_s⌉ samples of a trial's ends the kernel would need samples the trial does
not have; those estimates are not valid (``edges_valid = False``) and
:func:`~bemlearn.data.build_datasets` drops them.  Choose σ by hand (``sigma_s``) or leave it
``None``: :func:`bemlearn.data.derivative_choice.choose_sigma` then picks it from the data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.ndimage import convolve1d
from scipy.signal import oaconvolve

from bemlearn.errors import ArgumentError, ConfigError

__all__ = ["GaussianDerivative", "gaussian_kernels", "apply_kernel"]


def gaussian_kernels(sigma_s: float, sample_rate_hz: float, truncate: float = 5.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The discrete kernels (w0, w1, w2) of (G1), each ``(2K + 1,)``, K = ⌈truncate · σ · f_s⌉.

    Index K + k holds the weight of q_{i−k}: ``convolve1d(q, w)`` gives S[q], S[q̇] (per second),
    S[q̈] (per second²).  Normalised so that Σ w0 = 1, Σ w1 (−t) = 1, Σ w2 = 0 and Σ w2 t²/2 = 1
    (t = kh): constants and ramps are smoothed to themselves, and a polynomial of degree ≤ 2 is
    differentiated exactly (its smoothed value is q + q̈ Σ w0 t²/2, as S of a parabola is).
    """
    h = 1.0 / sample_rate_hz
    K = int(math.ceil(truncate * sigma_s * sample_rate_hz))
    t = np.arange(-K, K + 1) * h
    g = np.exp(-0.5 * (t / sigma_s) ** 2)
    w0 = g / g.sum()
    w1 = -t / sigma_s**2 * g
    w1 = w1 / float(np.sum(-t * w1))
    w2 = (t**2 / sigma_s**4 - 1.0 / sigma_s**2) * g
    w2 = w2 - w0 * float(w2.sum())
    w2 = w2 / float(np.sum(w2 * t**2 / 2.0))
    return w0, w1, w2


def apply_kernel(q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``(T, n)`` Σ_k w[K + k] q_{i−k}, the ends padded with the end values; overlap-add FFT for
    long kernels (the same numbers to rounding, faster beyond ~100 taps)."""
    K = w.size // 2
    if K <= 64 or q.shape[0] < 4 * K:
        return convolve1d(q, w, axis=0, mode="nearest")
    padded = np.pad(q, ((K, K), (0, 0)), mode="edge")
    return oaconvolve(padded, w[:, None], mode="valid", axes=0)


@dataclass(frozen=True)
class GaussianDerivative:
    """Derivatives of the Gaussian-smoothed angles, with the smoothed angles (module docstring).

    Attributes:
        sigma_s: the kernel's standard deviation σ, s; ``None``: chosen from the data by
            :func:`~bemlearn.data.derivative_choice.choose_sigma` (what ``build_datasets`` does).
        truncate: the kernel is cut at ±truncate · σ (default 5).
    """

    name: ClassVar[str] = "gaussian"
    smooths: ClassVar[bool] = True          # q and the label go through the same filter as q̇, q̈
    edges_valid: ClassVar[bool] = False     # within the kernel's half width of a trial end: dropped

    sigma_s: float | None = None
    truncate: float = 5.0

    def __post_init__(self) -> None:
        if self.sigma_s is not None and not (isinstance(self.sigma_s, (int, float)) and math.isfinite(self.sigma_s)
                                             and self.sigma_s > 0):
            raise ConfigError(f"GaussianDerivative.sigma_s: expected a positive number of seconds or null, got {self.sigma_s!r}")
        if not (math.isfinite(self.truncate) and 2.0 <= self.truncate <= 8.0):
            raise ConfigError(f"GaussianDerivative.truncate: expected a number of σ in [2, 8], got {self.truncate!r}")

    @property
    def resolved(self) -> bool:
        """Whether σ is set (``False``: it is to be chosen from the data)."""
        return self.sigma_s is not None

    def _sigma(self, sample_rate_hz: float) -> float:
        if self.sigma_s is None:
            raise ConfigError("GaussianDerivative: sigma_s is null (to be chosen from the data); resolve it first with "
                              "bemlearn.data.derivative_choice.resolve_estimator(estimator, trajectory), as "
                              "build_datasets does, or give derivative_options: {sigma_s: …}")
        if self.sigma_s * sample_rate_hz < 1.0:
            raise ConfigError(f"GaussianDerivative: sigma_s = {self.sigma_s:g} s is less than one sample at "
                              f"{sample_rate_hz:g} Hz; give at least {1.0 / sample_rate_hz:g} s")
        return float(self.sigma_s)

    def half_width(self, sample_rate_hz: float) -> int:
        """K = ⌈truncate · σ · f_s⌉, the kernel's half width in samples."""
        return int(math.ceil(self.truncate * self._sigma(sample_rate_hz) * sample_rate_hz))

    def min_samples(self, sample_rate_hz: float) -> int:
        """Shortest trial with a valid sample: 2K + 1."""
        return 2 * self.half_width(sample_rate_hz) + 1

    def edge_samples(self, sample_rate_hz: float) -> int:
        """Samples at each trial end without a full kernel: K (not valid, dropped by the datasets)."""
        return self.half_width(sample_rate_hz)

    def neighbours(self, sample_rate_hz: float) -> tuple[GaussianDerivative, ...]:
        """σ · 2/3 and σ · 3/2 (each only if at least one sample wide): equally plausible choices
        whose BEM spread is the estimator term of the calibrated band."""
        s = self._sigma(sample_rate_hz)
        return tuple(GaussianDerivative(sigma_s=float(f"{s * f:.6g}"), truncate=self.truncate)
                     for f in (2.0 / 3.0, 1.5) if s * f * sample_rate_hz >= 1.0)

    def filter(self, q: np.ndarray, *, sample_rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """S[q], S[q̇], S[q̈] of one trial (eq. G1).

        Args:
            q: ``(T, n)`` float64 coordinates of one trial (rad or m per joint), uniformly sampled.
            sample_rate_hz: f_s = 1/h, Hz.

        Returns:
            ``(T, n)`` each: smoothed q (joint unit), q̇ (unit/s), q̈ (unit/s²).  The first and last
            :meth:`edge_samples` rows are not valid (computed with the end values repeated).
        """
        q = np.asarray(q, dtype=np.float64)
        if q.ndim != 2 or q.shape[0] < 1:
            raise ArgumentError(f"GaussianDerivative: q must have shape (T, n), got {q.shape}")
        w0, w1, w2 = gaussian_kernels(self._sigma(sample_rate_hz), sample_rate_hz, self.truncate)
        return tuple(apply_kernel(q, w) for w in (w0, w1, w2))  # type: ignore[return-value]

    def __call__(self, q: np.ndarray, *, sample_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """S[q̇] and S[q̈] of one trial (see :meth:`filter`, which also gives S[q])."""
        _, qd, qdd = self.filter(q, sample_rate_hz=sample_rate_hz)
        return qd, qdd
