"""Placing a logger's jittered samples on the nominal grid t_0 + k/f_s, one trial at a time.

A logger's loop runs at a nominal rate f_s but stamps each sample with jitter (tens of µs)
and now and then drops a sample.  Each sample i is assigned to the grid index

    k_i = round((t_i − t_0) f_s),   t_0 = t_first + median_i(t_i − t_first − round((t_i − t_first) f_s)/f_s),

and keeps its *value* unchanged: the jitter is treated as timestamp noise, so quantized
angles stay on their encoder grid (no interpolation of present samples).  Then:

- a sample with |t_i − (t_0 + k_i/f_s)| > ``max_jitter``/f_s is an error naming the row;
- two samples on one grid index (a step shorter than (1 − 2·max_jitter)/f_s) are an error;
- a run of at most ``max_fill`` missing grid indices (dropped samples) is filled by linear
  interpolation in time between its neighbours, and counted;
- a longer gap splits the trial in two segments (``on_gap="split"``) or is an error.

Time must increase strictly; a step ≤ 0 is an error naming the row.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bemlearn.data.trajectory import TrajectoryFormatError

__all__ = ["GridSegment", "place_on_grid"]


@dataclass(frozen=True)
class GridSegment:
    """One gap-free run of grid samples.

    Attributes:
        t: (K,) float64 grid times t_0 + k/f_s, s.
        values: (K, c) float64 the columns' values on the grid.
        filled: (K,) bool, True where a dropped sample was interpolated.
        first_row: input row of the segment's first sample.
    """

    t: np.ndarray
    values: np.ndarray
    filled: np.ndarray
    first_row: int


def place_on_grid(
    t: np.ndarray,
    values: np.ndarray,
    *,
    rate_hz: float,
    max_jitter: float = 0.25,
    max_fill: int = 2,
    on_gap: str = "split",
    where: Callable[[int], str] = lambda i: f"row {i}",
) -> list[GridSegment]:
    """Put one trial's samples on its nominal grid (module docstring).

    Args:
        t: (T,) float64 timestamps, s.
        values: (T, c) float64 samples (joints in their final units, inputs, channels).
        rate_hz: nominal sample rate f_s, Hz.
        max_jitter: largest accepted |t − grid time|, fraction of 1/f_s (< 0.5).
        max_fill: longest run of missing samples that is interpolated.
        on_gap: ``"split"`` or ``"error"`` for longer gaps.
        where: row index → text naming file, column and row for errors.

    Returns:
        The gap-free segments in time order (one when nothing was split).

    Raises:
        TrajectoryFormatError: time not increasing, jitter beyond ``max_jitter``, two samples
            on one grid point, or (``on_gap="error"``) a gap longer than ``max_fill``.
    """
    t = np.asarray(t, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if len(t) == 0:
        return []
    h = 1.0 / rate_hz
    steps = np.diff(t)
    back = np.flatnonzero(steps <= 0)
    if len(back):
        i = int(back[0]) + 1
        raise TrajectoryFormatError(
            f"{where(i)}: time {float(t[i])!r} s does not increase (previous {float(t[i - 1])!r} s)"
        )
    rel = t - t[0]
    t0 = t[0] + float(np.median(rel - np.round(rel * rate_hz) * h))
    kf = (t - t0) * rate_hz
    k = np.round(kf).astype(np.int64)
    jitter = kf - k
    bad = np.flatnonzero(np.abs(jitter) > max_jitter)
    if len(bad):
        i = int(bad[0])
        raise TrajectoryFormatError(
            f"{where(i)}: time {float(t[i])!r} s is {jitter[i] * h * 1e6:+.1f} µs off the {rate_hz:g} Hz grid "
            f"(more than max_jitter = {max_jitter:g} of a {h * 1e3:g} ms step)"
        )
    dk = np.diff(k)
    dup = np.flatnonzero(dk == 0)
    if len(dup):
        i = int(dup[0]) + 1
        raise TrajectoryFormatError(
            f"{where(i)}: time {float(t[i])!r} s falls on the same {rate_hz:g} Hz grid point as the previous "
            f"sample ({float(t[i - 1])!r} s): a step shorter than {(1 - 2 * max_jitter) * h * 1e3:g} ms"
        )
    long_gaps = np.flatnonzero(dk - 1 > max_fill)
    if len(long_gaps) and on_gap == "error":
        i = int(long_gaps[0]) + 1
        raise TrajectoryFormatError(
            f"{where(i)}: {int(dk[i - 1]) - 1} missing samples before time {float(t[i])!r} s (gap of "
            f"{steps[i - 1] * 1e3:g} ms; at most max_fill = {max_fill} are interpolated)"
        )
    bounds = np.concatenate([[0], long_gaps + 1, [len(t)]])
    segments = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        ks = k[a:b]
        grid = np.arange(ks[0], ks[-1] + 1)
        present = np.zeros(len(grid), dtype=bool)
        present[ks - ks[0]] = True
        out = np.empty((len(grid), values.shape[1]))
        out[ks - ks[0]] = values[a:b]
        if not present.all():
            missing = grid[~present]
            for c in range(values.shape[1]):
                out[~present, c] = np.interp(missing, ks, values[a:b, c])
        segments.append(GridSegment(t=t0 + grid * h, values=out, filled=~present, first_row=int(a)))
    return segments
