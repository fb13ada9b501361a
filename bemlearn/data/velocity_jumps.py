"""Velocity jumps in sampled angles: where a log's motion is not smooth (impacts, scuffs, stops).

A derivative estimator assumes the angles are smooth over its window; an impact (a foot strike,
a hard stop, a collision) changes the velocity within one sample interval and every window that
spans it smears the jump over its whole width.  This module finds such jumps from the angles
alone, so that the estimation can be split there (:mod:`bemlearn.data.segmented_derivatives`).

The statistic.  With h = 1/f_s, the velocity change across four samples,

    S_k = (q_{k+2} − q_{k+1} − q_k + q_{k−1}) / h,                                   (J1)

is v(t_{k+3/2}) − v(t_{k−1/2}) for a piecewise-linear q: for a velocity jump Δv anywhere between
t_k and t_{k+1} it is exactly Δv (the two second differences that see the kink split it as
(1 − θ) Δv h and θ Δv h), and for smooth motion it is 2h q̈ + O(h³).  Removing the smooth part
with the same statistic two samples either side,

    D_k = S_k − (S_{k−2} + S_{k+2}) / 2,                                               (J2)

leaves Δv for an isolated jump (S_{k±2} do not span the interval k … k+1) and O(h³ q⁽⁴⁾) for
smooth motion: D is exact (zero) on cubics.  D_k is attributed to the interval between samples k
and k + 1; a jump there starts a new segment at k + 1.

The threshold.  D is a fixed linear combination of eight samples with coefficient norm √10, so
white measurement noise of std σ_q (an encoder step δ: σ_q = δ/√12) gives D a std of √10 σ_q / h.
Smooth but fast motion is the other source; the scale of D in the data is taken robustly
(1.4826 × median absolute value, per joint), and a jump is an interval where

    |D_k| > ``factor`` × max(robust scale of D, √10 σ_q / h)                              (J3)

in any joint (``factor`` = 12 by default: Gaussian noise exceeds it with probability ~10⁻³³, the
heavy tail of a walking controller's D, e.g. a swing-foot scuff, is what it is meant to find).
Of a run of consecutive intervals above the threshold the largest is reported (one jump).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bemlearn.errors import ArgumentError

__all__ = ["JUMP_FACTOR", "jump_statistic", "JumpDetection", "detect_velocity_jumps"]

#: Default ``factor`` of (J3): an interval is a jump where |D| exceeds this many robust scales.
JUMP_FACTOR = 12.0
#: ‖c‖ of (J2)'s coefficients on q_{k−3} … q_{k+4}: ½, ½, 3/2, 3/2, 3/2, 3/2, ½, ½ in magnitude.
_NORM = math.sqrt(10.0)


def jump_statistic(q: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """D_k of (J2) for one uniformly sampled segment.

    Args:
        q: ``(T, n)`` angles (rad, m for slides).
        sample_rate_hz: f_s, Hz.

    Returns:
        ``(T, n)`` D in rad/s (m/s): row k is the velocity change attributed to the interval
        between samples k and k + 1; NaN where the eight samples k − 3 … k + 4 are not all there
        (the first three and last four rows, or all rows when T < 8).
    """
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2:
        raise ArgumentError(f"jump_statistic: q must have shape (T, n), got {q.shape}")
    T = q.shape[0]
    out = np.full(q.shape, np.nan)
    if T < 8:
        return out
    S = np.full(q.shape, np.nan)
    S[1:T - 2] = (q[3:] - q[2:-1] - q[1:-2] + q[:-3]) * sample_rate_hz        # (J1), k = 1 … T − 3
    out[3:T - 4] = S[3:T - 4] - 0.5 * (S[1:T - 6] + S[5:T - 2])             # (J2), k = 3 … T − 5
    return out


@dataclass(frozen=True)
class JumpDetection:
    """The result of :func:`detect_velocity_jumps`.

    Attributes:
        starts: ``(T,)`` bool, True at row k + 1 for a jump in the interval k … k + 1 (a segment
            starts there).
        size: ``(T,)`` float, the largest |D| over the joints at those rows (rad/s; 0 elsewhere).
        threshold: per joint, the threshold of (J3) used (rad/s).
        factor: ``factor`` of (J3).
    """

    starts: np.ndarray
    size: np.ndarray
    threshold: np.ndarray
    factor: float

    @property
    def count(self) -> int:
        """Number of jumps found."""
        return int(self.starts.sum())


def detect_velocity_jumps(q: np.ndarray, sample_rate_hz: float, *, trial: np.ndarray | None = None,
                          noise_std: np.ndarray | float | None = None, factor: float = JUMP_FACTOR) -> JumpDetection:
    """Velocity jumps of (J3) in a log (module docstring).

    Args:
        q: ``(T, n)`` angles (rad, m for slides), uniformly sampled within each trial.
        sample_rate_hz: f_s, Hz.
        trial: ``(T,)`` trial id per row (contiguous); the statistic never spans two trials and a
            trial start is not itself reported.  ``None``: one trial.
        noise_std: per joint (or one for all), the measurement noise std σ_q (an encoder step δ:
            δ/√12) that bounds the threshold from below; ``None``: no floor.
        factor: ``factor`` of (J3), > 0.

    Returns:
        :class:`JumpDetection`.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2:
        raise ArgumentError(f"detect_velocity_jumps: q must have shape (T, n), got {q.shape}")
    if not (math.isfinite(factor) and factor > 0):
        raise ArgumentError(f"detect_velocity_jumps: factor must be positive, got {factor!r}")
    T, n = q.shape
    trial = np.zeros(T, dtype=np.int64) if trial is None else np.asarray(trial)
    cuts = np.flatnonzero(np.diff(trial) != 0) + 1
    bounds = list(zip(np.r_[0, cuts], np.r_[cuts, T]))
    D = np.full((T, n), np.nan)
    for a, b in bounds:
        D[a:b] = jump_statistic(q[a:b], sample_rate_hz)
    finite = np.isfinite(D).all(axis=1)
    scale = 1.4826 * np.median(np.abs(D[finite]), axis=0) if finite.any() else np.zeros(n)
    floor = np.zeros(n) if noise_std is None else np.broadcast_to(np.asarray(noise_std, dtype=np.float64), (n,)) * _NORM * sample_rate_hz
    threshold = factor * np.maximum(scale, floor)
    over: np.ndarray = np.asarray(np.where(finite[:, None], np.abs(D) > threshold, False).any(axis=1))
    ratio: np.ndarray = np.where(finite[:, None], np.abs(D) / np.where(threshold > 0, threshold, np.inf), 0.0).max(axis=1)
    starts = np.zeros(T, dtype=bool)
    size = np.zeros(T)
    k = 0
    while k < T:                                   # one jump per run of consecutive intervals above
        if not over[k]:
            k += 1
            continue
        e = k
        while e + 1 < T and over[e + 1] and trial[e + 1] == trial[k]:
            e += 1
        j = k + int(np.argmax(ratio[k:e + 1]))
        starts[j + 1] = True
        size[j + 1] = float(np.nanmax(np.abs(D[j])))
        k = e + 1
    return JumpDetection(starts, size, threshold, float(factor))
