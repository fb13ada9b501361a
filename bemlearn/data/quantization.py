"""Detection of an encoder's quantization step in recorded angles.

An incremental encoder with N counts per revolution reports q = q_0 + k δ, k ∈ Z,
δ = 2π / N rad (4096 counts/rev → δ ≈ 1.534e-3 rad).  Given samples of q, the step is
recovered as the smallest gap between distinct values, accepted only if every sample
lies on the grid q_0 + k δ.
"""

from __future__ import annotations

import numpy as np

__all__ = ["detect_quantization_step", "counts_per_revolution"]


def detect_quantization_step(values: np.ndarray, *, rtol: float = 1e-6, min_levels: int = 3) -> float | None:
    """The grid step δ of ``values`` if they all lie on q_0 + k δ, else ``None``.

    Args:
        values: (T,) float64 samples of one joint, rad.
        rtol: allowed distance from the grid, as a fraction of δ.
        min_levels: fewer distinct values than this gives ``None`` (nothing to detect).

    Returns:
        δ in the units of ``values`` (rad), or ``None`` when the samples are not quantized.
    """
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    levels = np.unique(v)
    if len(levels) < min_levels:
        return None
    gaps = np.diff(levels)
    scale = max(float(np.abs(levels).max()), 1.0)
    step = float(gaps.min())
    # A step at the level of float64 round-off means "continuous" values.
    if step <= 1e-12 * scale:
        return None
    # Refine δ by least squares over all levels (the smallest gap carries round-off),
    # then require every level to sit on the grid.
    offsets = levels - levels[0]
    k = np.round(offsets / step)
    step = float(np.dot(k, offsets) / np.dot(k, k))
    if np.abs(offsets / step - k).max() > rtol:
        return None
    return step


def counts_per_revolution(step: float, *, tol: float = 1e-3) -> int | None:
    """N = 2π / δ if that is within ``tol`` of an integer, else ``None``."""
    n = 2.0 * np.pi / step
    return int(round(n)) if abs(n - round(n)) <= tol * max(1.0, n) else None
