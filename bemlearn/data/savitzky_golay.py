"""Savitzky–Golay derivatives: local least-squares polynomial fits.

For each sample i a polynomial p of degree ``polyorder`` is fitted by least squares to the
w = 2k + 1 samples q_{i−k} … q_{i+k} (w odd, t measured from t_i), and

    q̇_i = p'(0),    q̈_i = p''(0),

which is a fixed linear filter (Savitzky & Golay, 1964).  Averaging over w samples divides
the quantization noise δ/√12 (δ = 2π/4096 rad for a 4096-count encoder) by roughly
w^{3/2} h in q̇ and w^{5/2} h² in q̈, at the price of a bias that grows with the window
for fast motions; a ~0.2 s window suits 400 Hz data of a balancing pendulum.

Edges (the first and last k samples of a trial): the polynomial fitted to the first (last)
w samples is evaluated at each edge sample (``scipy.signal.savgol_filter`` with
``mode="interp"``), so no sample is padded or taken from a neighbouring trial; edge
estimates are noisier than interior ones.  A trial needs at least w samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.signal import savgol_filter

from bemlearn.errors import ArgumentError, ConfigError

__all__ = ["SavitzkyGolay"]

#: Window used when neither ``window_s`` nor ``window`` is given, s.
DEFAULT_WINDOW_S = 0.2


@dataclass(frozen=True)
class SavitzkyGolay:
    """Savitzky–Golay q̇, q̈ (see module docstring).

    Attributes:
        window_s: window length in seconds; w = 2⌊f_s · window_s / 2⌋ + 1 samples
            (0.2 s at 400 Hz → 81) (default 0.2 s when ``window`` is not given either).
        window: window length in samples (odd, ≥ 3); give this or ``window_s``, not both.
        polyorder: polynomial degree, 2 ≤ polyorder < window (q̈ needs degree ≥ 2).
    """

    name: ClassVar[str] = "savgol"

    window_s: float | None = None
    window: int | None = None
    polyorder: int = 3

    def __post_init__(self) -> None:
        if self.window_s is not None and self.window is not None:
            raise ConfigError("SavitzkyGolay: give window_s (seconds) or window (samples), not both")
        if self.window_s is not None and not (math.isfinite(self.window_s) and self.window_s > 0):
            raise ConfigError(f"SavitzkyGolay.window_s: expected a positive number of seconds, got {self.window_s!r}")
        if self.window is not None and (self.window < 3 or self.window % 2 == 0):
            raise ConfigError(f"SavitzkyGolay.window: expected an odd number of samples >= 3, got {self.window}")
        if self.polyorder < 2:
            raise ConfigError(f"SavitzkyGolay.polyorder: q̈ needs a polynomial degree >= 2, got {self.polyorder}")
        if self.window is not None and self.polyorder >= self.window:
            raise ConfigError(f"SavitzkyGolay: polyorder {self.polyorder} must be below window {self.window}")

    def window_samples(self, sample_rate_hz: float) -> int:
        """The odd window length w in samples at ``sample_rate_hz``."""
        if self.window is not None:
            return self.window
        seconds = DEFAULT_WINDOW_S if self.window_s is None else self.window_s
        w = 2 * int(math.floor(seconds * sample_rate_hz / 2.0 + 1e-9)) + 1
        if w <= self.polyorder or w < 3:
            raise ConfigError(
                f"SavitzkyGolay: window_s = {seconds} s is only {w} samples at {sample_rate_hz} Hz; "
                f"need more than polyorder = {self.polyorder} and at least 3"
            )
        return w

    def min_samples(self, sample_rate_hz: float) -> int:
        """Shortest trial: one window."""
        return self.window_samples(sample_rate_hz)

    def edge_samples(self, sample_rate_hz: float) -> int:
        """Samples at each trial end estimated from the edge polynomial: (w − 1) / 2."""
        return self.window_samples(sample_rate_hz) // 2

    def neighbours(self, sample_rate_hz: float) -> tuple[SavitzkyGolay, ...]:
        """The four filters next to this one: window w·2/3 and w·3/2 (odd, in samples) at the same
        degree, and degree p − 1 and p + 1 at the same window (each only where valid: w > p ≥ 2).

        They are the choices a user would equally have made; the BEM's spread over them is the
        estimator term of the calibrated band (:mod:`bemlearn.fitting.estimator_sensitivity`).
        """
        w, p = self.window_samples(sample_rate_hz), self.polyorder
        out: list[SavitzkyGolay] = []
        for wk in (2 * round((w * 2 / 3 - 1) / 2) + 1, 2 * round((w * 3 / 2 - 1) / 2) + 1):
            if wk != w and wk > p and wk >= 3:
                out.append(SavitzkyGolay(window=wk, polyorder=p))
        for pk in (p - 1, p + 1):
            if 2 <= pk < w:
                out.append(SavitzkyGolay(window=w, polyorder=pk))
        return tuple(out)

    def __call__(self, q: np.ndarray, *, sample_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """q̇ and q̈ of one trial.

        Args:
            q: (T, n) float64 angles of one trial, rad, uniformly sampled (T ≥ w).
            sample_rate_hz: f_s = 1/h, Hz.

        Returns:
            qd (T, n) rad/s and qdd (T, n) rad/s².
        """
        q = np.asarray(q, dtype=np.float64)
        w = self.window_samples(sample_rate_hz)
        dt = 1.0 / sample_rate_hz
        if q.ndim != 2 or q.shape[0] < w:
            raise ArgumentError(f"SavitzkyGolay: q must have shape (T >= window = {w}, n), got {q.shape}")
        qd = savgol_filter(q, w, self.polyorder, deriv=1, delta=dt, axis=0, mode="interp")
        qdd = savgol_filter(q, w, self.polyorder, deriv=2, delta=dt, axis=0, mode="interp")
        return qd, qdd
