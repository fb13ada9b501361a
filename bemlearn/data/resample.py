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

A logger whose real-time loop *overruns* (a late sample, and the loop never catches up: all
later stamps shift) or whose clock drifts by more than the 1 % above fits no such grid.
:func:`resample_linear` (map key ``time.resample: linear``) interpolates every channel
linearly onto t₀ + k/f_s instead (t₀ the trial's first stamp, no extrapolation past its last
stamp), with the same gap rule: a step of n nominal steps, n = round(Δt f_s), leaves n − 1
samples missing; up to ``max_fill`` are bridged, a longer gap splits the trial (or is an
error).  Interpolated angles leave their encoder's grid, so the import keeps the step
detected before resampling (``meta.extra["import"]["quantization_step"]``).

Every error says which map key would fix it, where one would.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bemlearn.data.trajectory import TrajectoryFormatError

__all__ = ["GridSegment", "ResampleReport", "place_on_grid", "resample_linear"]


#: Largest accepted relative difference between the stamps' fitted step and 1 / rate_hz.
RATE_RTOL = 0.01

_BACK_HINT = ("; if the file holds several runs one after another, cut them with trials: {column: <episode column>} "
              "or give each run its own file (trials: per_file)")




def _long_gaps(n_steps: np.ndarray, steps: np.ndarray, t: np.ndarray, max_fill: int, on_gap: str, where) -> np.ndarray:
    """Indices of the steps that leave more than ``max_fill`` grid samples missing (n − 1 for a step of n
    nominal steps); an error naming the first when ``on_gap == "error"``."""
    long_gaps = np.flatnonzero(n_steps - 1 > max_fill)
    if len(long_gaps) and on_gap == "error":
        i = int(long_gaps[0]) + 1
        raise TrajectoryFormatError(
            f"{where(i)}: {int(n_steps[i - 1]) - 1} missing samples before time {float(t[i])!r} s (a step of "
            f"{steps[i - 1] * 1e3:g} ms; at most max_fill = {max_fill} are interpolated): raise time.max_fill to "
            f"bridge it, or set time.on_gap: split to cut the trial there"
        )
    return long_gaps

def _increasing_steps(t: np.ndarray, where) -> np.ndarray:
    """The time steps ``diff(t)`` (s, ``(N - 1,)``), after checking that ``t`` increases.

    Raises:
        TrajectoryFormatError: a stamp does not increase; the message names the place ``where(i)``.
    """
    steps = np.diff(t)
    back = np.flatnonzero(steps <= 0)
    if len(back):
        i = int(back[0]) + 1
        raise TrajectoryFormatError(
            f"{where(i)}: time {float(t[i])!r} s does not increase (previous {float(t[i - 1])!r} s){_BACK_HINT}"
        )
    return steps

def _rate_hint(steps: np.ndarray, h: float, max_jitter: float) -> str:
    """What to set when the stamps do not advance at 1/h: resampling (overruns, drift) or the rate."""
    median = float(np.median(steps))
    if abs(median / h - 1.0) <= RATE_RTOL:  # most steps are nominal: the mean is pulled by late samples
        late = steps > (1.0 + 2 * RATE_RTOL) * median
        return (f": most steps are {median * 1e3:.6g} ms, but {int(late.sum())} of {len(steps)} are longer (up to "
                f"{float(steps.max()) * 1e3:.4g} ms) and the stamps never catch up: the logger's loop overran. "
                f"Set time.resample: linear in the map to interpolate every channel onto the {1 / h:g} Hz grid")
    if np.mean(np.abs(steps / median - 1.0) <= max_jitter) >= 0.9:
        return (f": the steps are a steady {median * 1e3:.6g} ms. If that is the logger's rate, set "
                f"time.rate_hz: {1 / median:.6g} (or leave rate_hz out: the median step sets it); if its clock drifts "
                f"against {1 / h:g} Hz, set time.resample: linear")
    return (f": the steps vary (median {median * 1e3:.6g} ms, up to {float(steps.max()) * 1e3:.4g} ms): if the "
            f"logger's loop overruns or its clock drifts, set time.resample: linear; otherwise set time.rate_hz")


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
    steps = _increasing_steps(t, where)
    counts = np.round(steps * rate_hz).astype(np.int64)
    dup = np.flatnonzero(counts == 0)
    if len(dup):
        i = int(dup[0]) + 1
        raise TrajectoryFormatError(
            f"{where(i)}: time {float(t[i])!r} s falls on the same {rate_hz:g} Hz grid point as the previous "
            f"sample ({float(t[i - 1])!r} s): a step shorter than half of {h * 1e3:g} ms; if the logger's loop "
            f"catches up after an overrun, set time.resample: linear; if {rate_hz:g} Hz is not its rate, set time.rate_hz"
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
            f"{rate_hz:g} Hz (more than {RATE_RTOL:.0%} apart){_rate_hint(steps, h, max_jitter)}"
        )
    a = float(np.median(t - b * k))
    jitter = (t - a - b * k) / b
    bad = np.flatnonzero(np.abs(jitter) > max_jitter)
    if len(bad):
        i = int(bad[0])
        raise TrajectoryFormatError(
            f"{where(i)}: time {float(t[i])!r} s is {jitter[i] * b * 1e6:+.1f} µs off the {rate_hz:g} Hz grid "
            f"(more than max_jitter = {max_jitter:g} of a {h * 1e3:g} ms step): if the logger's loop overran or its "
            f"clock drifts, set time.resample: linear (every channel interpolated onto the grid); if this is stamp "
            f"jitter, raise time.max_jitter (below 0.5)"
        )
    long_gaps = _long_gaps(np.diff(k), steps, t, max_fill, on_gap, where)
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


@dataclass(frozen=True)
class ResampleReport:
    """What :func:`resample_linear` did to one trial.

    Attributes:
        stamps: logged samples in the trial.
        moved: logged samples whose stamp is farther than ``tolerance`` (fraction of a step)
            from the nearest grid time t₀ + k/f_s of their segment: their values now sit at
            other times (interpolated).
        largest_step_s: the largest step between two stamps that was bridged (not a gap that
            split the trial), s; ``largest_step_s − 1/f_s`` is the largest overrun.
        tolerance: the fraction of a step used for ``moved``.
    """

    stamps: int
    moved: int
    largest_step_s: float
    tolerance: float


def resample_linear(
    t: np.ndarray,
    values: np.ndarray,
    *,
    rate_hz: float,
    max_fill: int = 2,
    on_gap: str = "split",
    tolerance: float = 0.25,
    where: Callable[[int], str] = lambda i: f"row {i}",
) -> tuple[list[GridSegment], ResampleReport]:
    """Interpolate one trial's samples linearly onto t₀ + k/f_s (module docstring).

    Within each gap-free segment, t₀ is its first stamp and the grid ends at the last grid
    time not after its last stamp (no extrapolation).  A step of n = round(Δt f_s) nominal
    steps with n − 1 > ``max_fill`` is a gap: the trial is split there (``on_gap="split"``)
    or it is an error.

    Args:
        t: (T,) float64 timestamps, s, strictly increasing.
        values: (T, c) float64 samples (joints in their final units, inputs, channels).
        rate_hz: the grid's rate f_s, Hz.
        max_fill: the longest run of missing samples that is bridged.
        on_gap: ``"split"`` or ``"error"`` for longer gaps.
        tolerance: a stamp farther than this fraction of a step from its nearest grid time
            counts as moved.
        where: row index → text naming file, column and row for errors.

    Returns:
        The segments (``filled``: grid samples inside a bridged gap, i.e. within a step of
        more than 1.5 nominal steps; ``first_row``: the input row of the segment's first
        stamp) and the trial's :class:`ResampleReport`.

    Raises:
        TrajectoryFormatError: time not increasing, or (``on_gap="error"``) a long gap.
    """
    t = np.asarray(t, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if len(t) == 0:
        return [], ResampleReport(0, 0, 0.0, tolerance)
    h = 1.0 / rate_hz
    steps = _increasing_steps(t, where)
    long_gaps = _long_gaps(np.round(steps * rate_hz).astype(np.int64), steps, t, max_fill, on_gap, where)
    bridged = np.ones(len(steps), dtype=bool)
    bridged[long_gaps] = False
    largest = float(steps[bridged].max()) if bridged.any() else 0.0
    bounds = np.concatenate([[0], long_gaps + 1, [len(t)]])
    segments, moved = [], 0
    for first, stop in itertools.pairwise(bounds):
        ts = t[first:stop]
        t0 = ts[0]
        k = (ts - t0) * rate_hz
        moved += int(np.count_nonzero(np.abs(k - np.round(k)) > tolerance))
        n = int(np.floor(k[-1] + 1e-9)) + 1
        grid = t0 + np.arange(n) * h
        out = np.empty((n, values.shape[1]))
        for c in range(values.shape[1]):
            out[:, c] = np.interp(grid, ts, values[first:stop, c])
        # a grid sample more than half a step from both stamps around it stands for one the logger dropped
        j = np.clip(np.searchsorted(ts, grid, side="right") - 1, 0, max(len(ts) - 2, 0))
        filled = np.zeros(n, dtype=bool)
        if len(ts) > 1:
            filled = (grid - ts[j] > 0.5 * h) & (ts[j + 1] - grid > 0.5 * h)
        segments.append(GridSegment(t=grid, values=out, filled=filled, first_row=int(first)))
    return segments, ResampleReport(stamps=len(t), moved=moved, largest_step_s=largest, tolerance=tolerance)
