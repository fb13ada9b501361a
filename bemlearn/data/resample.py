"""Placing a logger's jittered samples on the nominal grid t_0 + k/f_s, one trial at a time.

A logger's loop runs at a nominal rate f_s but stamps each sample with jitter (tens of µs)
and now and then drops a sample; its clock may also drift against f_s by a few ppm.  Each
sample i is assigned a grid index by counting whole steps,

    k_0 = 0,   k_i = k_{i−1} + round((t_i − t_{i−1}) f_s),

the trial's grid t ≈ a + b k is fitted to the stamps (b by least squares, a as the median
offset), so clock drift does not accumulate, and each sample keeps its *value* unchanged:
the jitter is treated as timestamp noise, so quantized angles stay on their encoder grid (no
interpolation of present samples).  The grid times a + b k are the output times.  Then:

- a fitted step b off 1/f_s by more than ``rate_rtol`` (1 %) is an error (wrong rate);
- a sample with |t_i − (a + b k_i)| > ``max_jitter`` · b is an error naming the row;
- two samples on one grid index (a step shorter than half a step) are an error;
- a run of at most ``max_fill`` missing grid indices (dropped samples) is filled by linear
  interpolation in time between its neighbours, and counted;
- a longer gap splits the trial in two segments (``on_gap="split"``) or is an error.

Time must increase strictly; a step ≤ 0 is an error naming the row.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bemlearn.data.trajectory import TrajectoryFormatError

__all__ = ["GridSegment", "place_on_grid"]


#: Largest accepted relative difference between the stamps' fitted step and 1 / rate_hz.
RATE_RTOL = 0.01


@dataclass(frozen=True)
class GridSegment:
    """One gap-free run of grid samples.

    Attributes:
        t: (K,) float64 grid times a + b k, s (b within 1 % of 1/f_s).
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
        TrajectoryFormatError: time not increasing, stamps advancing at another rate, jitter
            beyond ``max_jitter``, two samples on one grid point, or (``on_gap="error"``) a gap
            longer than ``max_fill``.
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
    counts = np.round(steps * rate_hz).astype(np.int64)
    dup = np.flatnonzero(counts == 0)
    if len(dup):
        i = int(dup[0]) + 1
        raise TrajectoryFormatError(
            f"{where(i)}: time {float(t[i])!r} s falls on the same {rate_hz:g} Hz grid point as the previous "
            f"sample ({float(t[i - 1])!r} s): a step shorter than half of {h * 1e3:g} ms"
        )
    k = np.concatenate([[0], np.cumsum(counts)])
    if k[-1] > 0:
        kc = k - k.mean()
        b = float(np.dot(kc, t - t.mean()) / np.dot(kc, kc))
    else:
        b = h
    if abs(b * rate_hz - 1.0) > RATE_RTOL:
        raise TrajectoryFormatError(
            f"{where(0)}: the time stamps advance by {b * 1e3:.6g} ms per sample, not the {h * 1e3:g} ms of "
            f"{rate_hz:g} Hz (more than {RATE_RTOL:.0%} apart; set time.rate_hz in the map)"
        )
    a = float(np.median(t - b * k))
    jitter = (t - a - b * k) / b
    bad = np.flatnonzero(np.abs(jitter) > max_jitter)
    if len(bad):
        i = int(bad[0])
        raise TrajectoryFormatError(
            f"{where(i)}: time {float(t[i])!r} s is {jitter[i] * b * 1e6:+.1f} µs off the {rate_hz:g} Hz grid "
            f"(more than max_jitter = {max_jitter:g} of a {h * 1e3:g} ms step)"
        )
    dk = np.diff(k)
    long_gaps = np.flatnonzero(dk - 1 > max_fill)
    if len(long_gaps) and on_gap == "error":
        i = int(long_gaps[0]) + 1
        raise TrajectoryFormatError(
            f"{where(i)}: {int(dk[i - 1]) - 1} missing samples before time {float(t[i])!r} s (gap of "
            f"{steps[i - 1] * 1e3:g} ms; at most max_fill = {max_fill} are interpolated)"
        )
    bounds = np.concatenate([[0], long_gaps + 1, [len(t)]])
    segments = []
    for first, stop in itertools.pairwise(bounds):
        ks = k[first:stop]
        grid = np.arange(ks[0], ks[-1] + 1)
        present = np.zeros(len(grid), dtype=bool)
        present[ks - ks[0]] = True
        out = np.empty((len(grid), values.shape[1]))
        out[ks - ks[0]] = values[first:stop]
        if not present.all():
            missing = grid[~present]
            for c in range(values.shape[1]):
                out[~present, c] = np.interp(missing, ks, values[first:stop, c])
        segments.append(GridSegment(t=a + grid * b, values=out, filled=~present, first_row=int(first)))
    return segments
