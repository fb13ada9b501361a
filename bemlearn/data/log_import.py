"""Importing a logger's CSV files into a trajectory (``bemlearn data import``), by an :class:`ImportMap`.

Each file is read by :func:`~bemlearn.data.log_table.read_log_table`.  Joints are converted to rad / m
(:class:`~bemlearn.data.import_map.JointMap`), trials are cut (per file or by an episode
column), each trial is placed on its nominal time grid (:mod:`bemlearn.data.resample`), and
kept columns become the trajectory's extra channels.  Each joint's encoder step is detected
in the logged values (:func:`~bemlearn.data.quantization.detect_quantization_step`) and
stored in ``meta.extra["import"]["quantization_step"]`` (read back by
:meth:`~bemlearn.data.trajectory.Trajectory.quantization_steps`).  Samples the logger dropped
(filled by interpolation) are rounded back onto that grid.  With ``time.resample: linear``
every channel is interpolated onto the grid instead
(:func:`~bemlearn.data.resample.resample_linear`): the angles leave their encoder grid, and
the stored step is the one detected before resampling.  Every error names the file, the
column and the row (0-based data row and 1-based file line).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bemlearn._version import __version__
from bemlearn.config import to_dict
from bemlearn.data.import_map import TIME_UNITS, TORQUE_UNITS, ImportMap, delimiter_name
from bemlearn.data.log_table import LogTable, check_finite, read_log_table
from bemlearn.data.quantization import counts_per_revolution, detect_quantization_step, snap_to_grid
from bemlearn.data.resample import GridSegment, ResampleReport, place_on_grid, resample_linear
from bemlearn.data.trajectory import Trajectory, TrajectoryFormatError, TrajectoryMeta
from bemlearn.data.validation import MIN_TRIAL_SAMPLES
from bemlearn.errors import ArgumentError, ConfigError
from bemlearn.units import q_unit_label
from bemlearn.warnings import DataWarning, warn

__all__ = ["import_logs"]

logger = logging.getLogger(__name__)


def _trial_blocks(table: LogTable, imap: ImportMap) -> list[tuple[int, int, int | None]]:
    """(first row, stop row, episode value or None) of each trial in one file, inside the file's time window
    (``table.window``: from its first to its last row inside the window; a trial outside it is left out)."""
    blocks = _episode_blocks(table, imap)
    if table.window is None:
        return blocks
    out = []
    for a, b, episode in blocks:
        inside = np.flatnonzero(table.window[a:b])
        if len(inside):
            out.append((a + int(inside[0]), a + int(inside[-1]) + 1, episode))
    return out


def _episode_blocks(table: LogTable, imap: ImportMap) -> list[tuple[int, int, int | None]]:
    col = imap.trial_column
    if col is None:
        return [(0, table.n_rows, None)]
    ep = table.columns[col]
    frac = np.flatnonzero(ep != np.round(ep))
    if len(frac):
        raise TrajectoryFormatError(f"{table.where(col, int(frac[0]))}: episode {ep[frac[0]]!r} is not an integer")
    starts = np.concatenate([[0], np.flatnonzero(np.diff(ep)) + 1])
    stops = np.concatenate([starts[1:], [len(ep)]])
    seen: dict[int, int] = {}
    blocks: list[tuple[int, int, int | None]] = []
    for a, b in zip(starts, stops):
        value = int(ep[a])
        if value in seen:
            raise TrajectoryFormatError(
                f"{table.where(col, int(a))}: episode {value} resumes after another episode (it began at row {seen[value]})"
            )
        seen[value] = int(a)
        blocks.append((int(a), int(b), value))
    return blocks


def _snap_filled_joints(v: np.ndarray, filled: np.ndarray, steps: list[float | None]) -> dict[int, float]:
    """Round interpolated joint samples onto the joint's encoder grid (``steps``: detected in the logged values).

    Modifies ``v`` (T, ·) in place; returns joint column → step for the joints snapped.
    """
    out = {}
    for c, step in enumerate(steps):
        if step is not None:
            v[filled, c] = snap_to_grid(v[filled, c], step, v[~filled, c])
            out[c] = step
    return out


def _logged_steps(tables: list[LogTable], imap: ImportMap) -> list[float | None]:
    """Each joint's encoder step in the logged values (all files, in rad / m), or ``None``."""
    out = []
    for j in imap.joints:
        scale = j.sign * j.kind_and_scale()[1]
        out.append(detect_quantization_step(np.concatenate([t.columns[j.column] for t in tables]) * scale + j.offset))
    return out


def _step_text(step: float | None) -> str:
    if step is None:
        return "none"
    counts = counts_per_revolution(step)
    return f"{step:.6g}" + (f" (2π/{counts})" if counts else "")


def _sample_rate(tables: list[LogTable], imap: ImportMap) -> float:
    """The map's ``time.rate_hz``, or 1 / the median step over all files (rounded to a whole Hz within 0.1 %)."""
    if imap.time.rate_hz is not None:
        return float(imap.time.rate_hz)
    assert imap.time.column is not None  # the import map gives rate_hz or a time column
    scale = TIME_UNITS[imap.time.unit]
    steps = []
    for table in tables:
        for a, b, _ in _trial_blocks(table, imap):
            d = np.diff(table.columns[imap.time.column][a:b]) * scale
            steps.append(d[d > 0])
    allsteps = np.concatenate(steps) if steps else np.zeros(0)
    if len(allsteps) == 0:
        raise TrajectoryFormatError(
            f"{tables[0].path}: cannot estimate the sample rate (no increasing time steps); set time.rate_hz in the map"
        )
    rate = 1.0 / float(np.median(allsteps))
    if abs(rate - round(rate)) <= 1e-3 * rate:
        rate = float(round(rate))
    logger.info("sample rate %g Hz (1 / median time step)", rate)
    return rate


def import_logs(paths: Sequence[str | Path], imap: ImportMap, *, min_trial_samples: int = MIN_TRIAL_SAMPLES) -> Trajectory:
    """One trajectory from a logger's files (module docstring; map format ``docs/log-import.md``).

    Args:
        paths: the log files, in trial order (``per_file``: file i is trial i).
        imap: the column map.
        min_trial_samples: segments shorter than this (after splitting at long gaps) are
            dropped, counted and logged.

    Returns:
        The trajectory: q (T, n) rad / m by joint kind, u (T, n − 1) in the inputs' units,
        the kept columns as channels, every trial on its nominal grid.  ``meta.extra["import"]``
        holds the provenance: files and their delimiters, per-trial source rows, filled
        samples, splits, last lines left out as cut mid-write (``cut_last_lines``), each
        joint's encoder step detected in the logged values (``quantization_step``, rad or m,
        ``None`` where none) and, with ``time.resample: linear``, ``resample``: ``{"method",
        "rate_hz", "stamps", "samples", "moved", "tolerance_steps", "largest_step_s",
        "largest_overrun_s", "stamp_rate_hz"}``.

    Raises:
        TrajectoryFormatError: naming file, column and row (see :func:`read_log_table`,
            :func:`bemlearn.data.resample.place_on_grid`).
    """
    if not paths:
        raise ArgumentError("import_logs: no input files")
    tables = [read_log_table(p, imap) for p in paths]
    value_cols = ([j.column for j in imap.joints] + [u.column for u in imap.inputs] + list(imap.keep)
                  + [tq.column for tq in imap.torques])
    for table in tables:
        check_finite(table, value_cols + ([imap.time.column] if imap.time.column else []))
    unmatched = imap.unmatched_windows(list(paths))
    if unmatched:
        raise ConfigError(f"windows[{unmatched[0]!r}]: matches none of the files "
                          f"{[Path(p).name for p in paths][:8]} (a file name or glob, e.g. 'episode_00*.csv')")
    windows: list[dict] = []
    tables = [_apply_window(t, imap, min_trial_samples, windows) for t in tables]
    rate = _sample_rate(tables, imap)
    resampling = imap.time.resample == "linear"
    logged_steps = _logged_steps(tables, imap)
    scales = [j.sign * j.kind_and_scale()[1] for j in imap.joints]
    offsets = [j.offset for j in imap.joints] + [0.0] * (len(imap.inputs) + len(imap.keep) + len(imap.torques))
    mult = np.asarray(scales + [1.0] * (len(imap.inputs) + len(imap.keep)) + [tq.factor for tq in imap.torques])
    pieces = _Pieces()
    reports: list[ResampleReport] = []
    for table in tables:
        raw = np.stack([table.columns[c] for c in value_cols], axis=1)
        values = raw * mult + np.asarray(offsets)
        for a, b, episode in _trial_blocks(table, imap):
            segs = _grid_segments(table, a, values[a:b], imap, rate, reports)
            pieces.splits += len(segs) - 1
            for seg in segs:
                pieces.add(seg, table, a, episode, min_trial_samples)
    trials_info, failed = pieces.trials, pieces.failed
    filled_total, splits, dropped = pieces.filled_total, pieces.splits, pieces.dropped
    if not trials_info:
        hint = (" (every trial was split at gaps into shorter pieces: raise time.max_fill to bridge them)"
                if splits else "")
        raise TrajectoryFormatError(f"{tables[0].path}: no trial with at least {min_trial_samples} samples{hint}")
    if filled_total or splits or dropped:
        logger.info("import: %d %s, %d trials split at gaps, %d short pieces dropped", filled_total,
                    "grid samples more than ½ step from any stamp" if resampling else "dropped samples interpolated",
                    splits, dropped)
    v = np.concatenate(pieces.v)
    n, m, k = len(imap.joints), len(imap.inputs), len(imap.keep)
    snapped = (_snap_filled_joints(v, np.concatenate(pieces.filled), logged_steps)
               if filled_total and not resampling else {})
    resample_info = _resample_summary(reports, rate, len(v), tables, imap, logged_steps) if resampling else None
    provenance = {
        "generator": f"bemlearn {__version__} data import",
        "map": to_dict(imap),
        "files": [str(p) for p in paths],
        "delimiters": [delimiter_name(t.delimiter) for t in tables],
        "filled_samples": filled_total, "split_gaps": splits, "dropped_pieces": dropped,
        "filled_snapped_to_grid": {imap.joints[c].name: step for c, step in snapped.items()},
        "quantization_step": {j.name: step for j, step in zip(imap.joints, logged_steps)},
        "resample": resample_info,
        "cut_last_lines": [{"file": str(t.path), **t.cut_line} for t in tables if t.cut_line is not None],
        "windows": windows,
        "torques": _torque_summary(v[:, n + m + k:], imap),
        "trials": trials_info,
    }
    meta = _import_meta(imap, rate, failed, provenance)
    return Trajectory(
        t=np.concatenate(pieces.t), trial=np.concatenate(pieces.trial), q=v[:, :n], u=v[:, n:n + m],
        meta=meta, channels=v[:, n + m:n + m + k], tau=v[:, n + m + k:],
    )


@dataclass
class _Pieces:
    """The trial pieces kept so far (arrays in trial order), their provenance, and the counts of
    filled samples, splits at gaps and pieces dropped as too short."""

    t: list[np.ndarray] = field(default_factory=list)
    trial: list[np.ndarray] = field(default_factory=list)
    v: list[np.ndarray] = field(default_factory=list)
    filled: list[np.ndarray] = field(default_factory=list)
    trials: list[dict] = field(default_factory=list)
    failed: dict[int, bool] = field(default_factory=dict)
    filled_total: int = 0
    splits: int = 0
    dropped: int = 0

    def add(self, seg: GridSegment, table: LogTable, a: int, episode: int | None, min_samples: int) -> None:
        """Keep ``seg`` (of the block starting at row ``a``) as the next trial, or drop it when shorter than ``min_samples``."""
        if len(seg.t) < min_samples:
            self.dropped += 1
            warn(DataWarning, logger, "%s: dropped a %d-sample piece at row %d (shorter than %d samples)",
                                      table.path, len(seg.t), a + seg.first_row, min_samples)
            return
        tid = len(self.trials)
        self.t.append(seg.t)
        self.trial.append(np.full(len(seg.t), tid, dtype=np.int64))
        self.v.append(seg.values)
        self.filled.append(seg.filled)
        self.failed[tid] = False
        self.filled_total += int(seg.filled.sum())
        self.trials.append({
            "trial": tid, "file": str(table.path), "first_row": a + seg.first_row,
            "episode": episode, "samples": len(seg.t), "filled_samples": int(seg.filled.sum()),
        })


def _grid_segments(table: LogTable, a: int, values: np.ndarray, imap: ImportMap, rate: float,
                   reports: list[ResampleReport]) -> list[GridSegment]:
    """The trial block of ``table`` starting at row ``a`` (``values (T, k)``, scaled) on its nominal grid
    at ``rate`` Hz: resampled, placed on the grid, or (no time column) taken as sampled at ``rate``.
    A ``time.resample: linear`` import appends its report to ``reports``."""
    tcol = imap.time.column
    if tcol is None:
        return [GridSegment(np.arange(len(values)) / rate, values, np.zeros(len(values), dtype=bool), 0)]
    t = table.columns[tcol][a:a + len(values)] * TIME_UNITS[imap.time.unit]
    where = lambda i: table.where(tcol, a + i)  # noqa: E731
    if imap.time.resample == "linear":
        segs, report = resample_linear(
            t, values, rate_hz=rate, max_fill=imap.time.max_fill, on_gap=imap.time.on_gap,
            tolerance=imap.time.max_jitter, where=where,
        )
        reports.append(report)
        return segs
    return place_on_grid(
        t, values, rate_hz=rate, max_jitter=imap.time.max_jitter, max_fill=imap.time.max_fill,
        on_gap=imap.time.on_gap, where=where,
    )


def _import_meta(imap: ImportMap, rate: float, failed: dict[int, bool], provenance: dict) -> TrajectoryMeta:
    """The imported trajectory's metadata; ``provenance`` goes to ``extra["import"]``."""
    kinds = tuple(j.kind_and_scale()[0] for j in imap.joints)
    u_units = [u.unit for u in imap.inputs]
    return TrajectoryMeta(
        robot=imap.robot,
        joint_names=tuple(j.name for j in imap.joints),
        unactuated=imap.unactuated,
        actuator_names=tuple(u.name for u in imap.inputs),
        sample_rate_hz=rate,
        trial_failed=failed,
        units={"t": "s", "q": q_unit_label(kinds), "u": u_units[0] if len(set(u_units)) == 1 else "|".join(u_units)},
        joint_kinds=kinds,
        channel_names=tuple(imap.keep),
        torque_joints=tuple(tq.joint for tq in imap.torques),
        extra={"import": provenance},
    )

def _resample_summary(reports: list[ResampleReport], rate: float, samples: int, tables: list[LogTable],
                      imap: ImportMap, steps: list[float | None]) -> dict:
    """``meta.extra["import"]["resample"]`` and the log lines of a ``time.resample: linear`` import."""
    assert imap.time.column is not None  # resampling needs the time column
    scale = TIME_UNITS[imap.time.unit]
    stamps = sum(r.stamps for r in reports)
    moved = sum(r.moved for r in reports)
    largest = max((r.largest_step_s for r in reports), default=0.0)
    duration = 0.0
    intervals = 0
    for table in tables:
        for a, b, _ in _trial_blocks(table, imap):
            if b - a > 1:
                t = table.columns[imap.time.column]
                duration += float(t[b - 1] - t[a]) * scale
                intervals += b - a - 1
    stamp_rate = intervals / duration if duration > 0 else rate
    info: dict[str, Any] = {
        "method": "linear", "rate_hz": rate, "stamps": stamps, "samples": samples, "moved": moved,
        "tolerance_steps": imap.time.max_jitter, "largest_step_s": largest,
        "largest_overrun_s": max(0.0, largest - 1.0 / rate), "stamp_rate_hz": stamp_rate,
    }
    logger.info("resampled (time.resample: linear) onto %g Hz: %d logged samples -> %d; %d (%.1f %%) had moved more than "
                "%g step off the grid; largest overrun %.4g ms (a step of %.4g ms); the stamps average %.6g Hz",
                rate, stamps, samples, moved, 100.0 * moved / max(stamps, 1), imap.time.max_jitter,
                info["largest_overrun_s"] * 1e3, largest * 1e3, stamp_rate)
    quantized = [f"{j.name} (step {_step_text(st)})" for j, st in zip(imap.joints, steps) if st is not None]
    if quantized and moved:
        warn(DataWarning, logger, "time.resample: linear: the interpolated angles of %s leave their encoder grid; the step detected "
                                  "before resampling is kept in meta.extra['import']['quantization_step']", ", ".join(quantized))
    return info


def _apply_window(table: LogTable, imap: ImportMap, min_samples: int, record: list[dict]) -> LogTable:
    """``table`` with its rows inside the file's time window marked (``LogTable.window``); the window and the
    rows it keeps are appended to ``record``.  Times as logged, in ``time.unit`` (no time column: s from the
    file's first row, at ``time.rate_hz``).

    Raises:
        TrajectoryFormatError: a bound outside the log's time, or a window holding fewer than
            ``min_samples`` rows; naming the file and the map key.
    """
    found = imap.window_for(table.path)
    if found is None:
        return table
    key, (t0, t1) = found
    if imap.time.column is not None:
        t, unit = table.columns[imap.time.column], imap.time.unit
    else:
        assert imap.time.rate_hz is not None  # the map gives a time column or the rate
        t, unit = np.arange(table.n_rows) / imap.time.rate_hz, "s"
    shown = f"[{'null' if t0 is None else f'{t0:g}'}, {'null' if t1 is None else f'{t1:g}'}] {unit}"
    lo, hi = float(np.min(t)), float(np.max(t))
    for bound, name in ((t0, "t0"), (t1, "t1")):
        if bound is not None and not lo <= bound <= hi:
            raise TrajectoryFormatError(f"{table.path}: {key} = {shown}: {name} = {bound:g} lies outside the log, whose time "
                                        f"runs {lo:g}–{hi:g} {unit} (null stands for the log's start or end)")
    inside = np.ones(table.n_rows, dtype=bool)
    if t0 is not None:
        inside &= t >= t0
    if t1 is not None:
        inside &= t <= t1
    kept = int(inside.sum())
    if kept < min_samples:
        raise TrajectoryFormatError(f"{table.path}: {key} = {shown} holds {kept} samples, fewer than the {min_samples} a "
                                    "trial needs")
    record.append({"file": str(table.path), "key": key, "window": [t0, t1], "unit": unit, "rows": table.n_rows, "kept": kept})
    logger.info("%s: %s = %s keeps %d of %d rows", table.path, key, shown, kept, table.n_rows)
    return dataclasses.replace(table, window=inside)


def _torque_summary(tau: np.ndarray, imap: ImportMap) -> dict[str, dict]:
    """Per logged torque (``tau (T, p)``, N·m or N, the imported samples): its unit, rms, mean and largest
    magnitude, and whether it acts on the unactuated joint (which the BEM assumes carries none, Γ_u = 0)."""
    out = {}
    for c, tq in enumerate(imap.torques):
        x = tau[:, c]
        unit = "N" if TORQUE_UNITS[tq.unit][0] == "slide" else "N·m"
        on_qu = tq.joint == imap.unactuated
        rms, mean, largest = float(np.sqrt(np.mean(x**2))), float(np.mean(x)), float(np.max(np.abs(x)))
        out[tq.joint] = {"unit": unit, "rms": rms, "mean": mean, "max_abs": largest, "unactuated": on_qu}
        if on_qu and largest > 0:
            warn(DataWarning, logger, "the unactuated joint %s carries a logged %s of %.4g %s rms (mean %.4g, largest %.4g): the BEM "
                                      "assumes it unactuated (Γ_u = 0, eq. 2), so the learned map mixes this torque in",
                                      tq.joint, "force" if unit == "N" else "torque", rms, unit, mean, largest)
    return out
