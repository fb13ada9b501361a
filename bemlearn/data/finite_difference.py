"""Central finite differences for q̇ and q̈ of uniformly sampled angles.

Interior samples (second order, step h = 1/f_s):

    q̇_i = (q_{i+1} − q_{i−1}) / (2h),       q̈_i = (q_{i+1} − 2 q_i + q_{i−1}) / h².

Edges use the second-order one-sided stencils

    q̇_0 = (−3 q_0 + 4 q_1 − q_2) / (2h),     q̈_0 = (2 q_0 − 5 q_1 + 4 q_2 − q_3) / h²,

mirrored at the last sample, so every sample gets an estimate and the truncation error is
O(h²) everywhere.  With encoder quantization δ (2π/4096 rad) the rounding error alone is
up to δ/h in q̇ and 2δ/h² in q̈ (≈ 0.6 rad/s and ≈ 490 rad/s² at 400 Hz): unusable
accelerations, which is why :class:`~bemlearn.data.savitzky_golay.SavitzkyGolay` exists.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from bemlearn.errors import ArgumentError

__all__ = ["CentralDifference"]


@dataclass(frozen=True)
class CentralDifference:
    """Second-order central differences (see module docstring); no options."""

    name: ClassVar[str] = "central"

    def min_samples(self, sample_rate_hz: float) -> int:
        """Shortest trial the edge stencils need: 4 samples."""
        return 4

    def edge_samples(self, sample_rate_hz: float) -> int:
        """Samples at each trial end that use one-sided stencils: 1."""
        return 1

    def neighbours(self, sample_rate_hz: float) -> tuple:
        """None: the stencil has no options (its error is the quantization noise it passes
        through, the input-noise term of the band)."""
        return ()

    def __call__(self, q: np.ndarray, *, sample_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """q̇ and q̈ of one trial.

        Args:
            q: (T, n) float64 angles of one trial, rad, uniformly sampled (T ≥ 4).
            sample_rate_hz: f_s = 1/h, Hz.

        Returns:
            qd (T, n) rad/s and qdd (T, n) rad/s².
        """
        q = np.asarray(q, dtype=np.float64)
        if q.ndim != 2 or q.shape[0] < 4:
            raise ArgumentError(f"CentralDifference: q must have shape (T >= 4, n), got {q.shape}")
        dt = 1.0 / sample_rate_hz
        qd = np.empty_like(q)
        qdd = np.empty_like(q)
        qd[1:-1] = (q[2:] - q[:-2]) / (2.0 * dt)
        qdd[1:-1] = (q[2:] - 2.0 * q[1:-1] + q[:-2]) / dt**2
        qd[0] = (-3.0 * q[0] + 4.0 * q[1] - q[2]) / (2.0 * dt)
        qd[-1] = (3.0 * q[-1] - 4.0 * q[-2] + q[-3]) / (2.0 * dt)
        qdd[0] = (2.0 * q[0] - 5.0 * q[1] + 4.0 * q[2] - q[3]) / dt**2
        qdd[-1] = (2.0 * q[-1] - 5.0 * q[-2] + 4.0 * q[-3] - q[-4]) / dt**2
        return qd, qdd
