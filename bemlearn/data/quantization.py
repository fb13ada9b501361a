"""Detection of an encoder's quantization step in recorded angles, robust to round-off.

An incremental encoder with N counts per revolution reports q = q_0 + k δ, k ∈ Z,
δ = 2π / N rad (2048 counts/rev → δ ≈ 3.068e-3 rad).  A logger rarely writes k δ exactly:
it prints degrees with a few decimals, stores float32, or converts counts with its own
constant, so each level carries a small deterministic round-off ε_k and neighbouring
distinct values may be near-duplicates of one level.  The step is found as follows:

1. candidate steps are the gaps between sorted distinct values that recur (at least
   2 % of the gaps lie within 10 % of the candidate) and are not near-duplicates (at
   least a quarter of the median gap), smallest first;
2. for each candidate δ₀, the sorted values get k_i = k_{i−1} + round((v_i − v_{i−1}) / δ₀)
   (so an error of δ₀ does not build up) and (δ, q_0) are fitted by least squares to
   v ≈ q_0 + k δ;
3. the grid is accepted if every value lies within ``tol`` · δ of it (5 %: printing
   0.17578125° with 4 decimals is off by ≤ 0.03 % of δ, with 2 decimals by ≤ 2.8 %) and
   the values are *deterministic* per level, as round-off is and noise is not: values
   sharing a level differ by at most ``level_spread`` · δ (near-duplicates, 1 %), and
   there are at most ``max_values_per_level`` distinct values per level on average;
4. δ is multiplied by the gcd of the level differences (a grid with every second level
   empty is the coarser grid).

Continuous values, or quantized values with additive noise, give ``None``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["counts_per_revolution", "detect_quantization_step", "snap_to_grid"]


def _fit_grid(levels: np.ndarray, step0: float) -> tuple[float, float, np.ndarray, np.ndarray]:
    """(δ, q_0, k, residual) of the least-squares grid v ≈ q_0 + k δ with k from ``step0``."""
    # k by accumulating rounded gaps: an error of step0 does not build up over many levels
    k = np.concatenate([[0.0], np.cumsum(np.round(np.diff(levels) / step0))])
    kc = k - k.mean()
    step = float(np.dot(kc, levels - levels.mean()) / np.dot(kc, kc))
    q0 = float(levels.mean() - step * k.mean())
    return step, q0, k, levels - (q0 + k * step)


def detect_quantization_step(
    values: np.ndarray,
    *,
    tol: float = 0.05,
    level_spread: float = 0.01,
    max_values_per_level: float = 3.0,
    min_levels: int = 3,
    max_candidates: int = 8,
) -> float | None:
    """The grid step δ of ``values`` if they lie on q_0 + k δ up to round-off, else ``None``.

    Args:
        values: (T,) float64 samples of one joint, rad (or m).
        tol: largest accepted distance from the grid, as a fraction of δ.
        level_spread: largest accepted spread of the values sharing one level, as a fraction of δ.
        max_values_per_level: largest accepted mean number of distinct values per grid level
            (round-off is deterministic per level; noise is not).
        min_levels: fewer grid levels than this gives ``None`` (nothing to detect).
        max_candidates: candidate steps tried, smallest first.

    Returns:
        δ in the units of ``values``, or ``None`` when the samples are not quantized.
    """
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    levels = np.unique(v)
    if len(levels) < min_levels:
        return None
    scale = max(float(np.abs(levels).max()), 1.0)
    gaps = np.diff(levels)
    gaps = np.sort(gaps[gaps > 1e-12 * scale])  # below: float64 round-off, the same level
    if len(gaps) < min_levels - 1:
        return None
    gaps = gaps[gaps >= 0.25 * np.median(gaps)]  # near-duplicates are no step
    # gaps that recur: at least 2 % of all gaps within +10 % of g
    support = np.searchsorted(gaps, gaps * 1.1, side="right") - np.arange(len(gaps))
    recurring = gaps[support >= max(2, int(0.02 * len(gaps)))]
    tried: list[float] = []
    for step0 in recurring:
        if tried and step0 <= tried[-1] * 1.1:
            continue
        if len(tried) >= max_candidates:
            break
        tried.append(float(step0))
        step, _, k, resid = _fit_grid(levels, float(step0))
        if not step > 0 or np.abs(resid).max() > tol * step:
            continue
        distinct_k = np.unique(k)
        if len(distinct_k) < min_levels or len(levels) > max_values_per_level * len(distinct_k):
            continue
        same = np.diff(k) == 0  # sorted levels: values of one level are neighbours
        if same.any() and np.diff(levels)[same].max() > level_spread * step:
            continue
        g = int(np.gcd.reduce(np.diff(distinct_k).astype(np.int64)))
        if g > 1:
            step, _, _, resid = _fit_grid(levels, step * g)
            if np.abs(resid).max() > tol * step:  # pragma: no cover - a gcd grid fits as well as its divisor
                continue
        return step
    return None


def counts_per_revolution(step: float, *, tol: float = 1e-3) -> int | None:
    """N = 2π / δ if that is within ``tol`` of an integer, else ``None``."""
    n = 2.0 * math.pi / step
    return int(round(n)) if abs(n - round(n)) <= tol * max(1.0, n) else None


def snap_to_grid(values: np.ndarray, step: float, reference: np.ndarray) -> np.ndarray:
    """``values`` rounded to the grid q_0 + k δ on which ``reference`` lies.

    q_0 is the median of r − δ·round(r/δ) over the reference samples r (the grid's offset,
    robust to round-off).  Used to put interpolated samples back on an encoder's grid.

    Args:
        values: (K,) float64, same units as ``reference``.
        step: δ > 0, e.g. from :func:`detect_quantization_step`.
        reference: (R,) float64 samples that lie on the grid.

    Returns:
        (K,) float64 q_0 + δ·round((v − q_0)/δ).
    """
    ref = np.asarray(reference, dtype=np.float64)
    q0 = float(np.median(ref - step * np.round(ref / step)))
    v = np.asarray(values, dtype=np.float64)
    return q0 + step * np.round((v - q0) / step)
