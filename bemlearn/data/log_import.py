"""Importing a logger's CSV files into a trajectory (``bemlearn data import``), by an :class:`ImportMap`.

Each file is read by :func:`~bemlearn.data.log_table.read_log_table`.  Joints are converted to rad / m
(:class:`~bemlearn.data.import_map.JointMap`), trials are cut (per file or by an episode
column), each trial is placed on its nominal time grid (:mod:`bemlearn.data.resample`), and
kept columns become the trajectory's extra channels.  Samples the logger dropped
(filled by interpolation) are rounded back onto a joint's encoder grid when its measured
samples lie on one (:func:`~bemlearn.data.quantization.detect_quantization_step`).  Every error names the file, the
column and the row (0-based data row and 1-based file line).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bemlearn._version import __version__
from bemlearn.config import to_dict
from bemlearn.data.import_map import TIME_UNITS, ImportMap
from bemlearn.units import q_unit_label
from bemlearn.data.log_table import LogTable, check_finite, read_log_table
from bemlearn.data.quantization import detect_quantization_step, snap_to_grid
from bemlearn.data.resample import GridSegment, place_on_grid
from bemlearn.data.trajectory import Trajectory, TrajectoryFormatError, TrajectoryMeta
from bemlearn.data.validation import MIN_TRIAL_SAMPLES

__all__ = ["import_logs"]

logger = logging.getLogger(__name__)


def _trial_blocks(table: LogTable, imap: ImportMap) -> list[tuple[int, int, int | None]]:
    """(first row, stop row, episode value or None) of each trial in one file."""
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
    blocks = []
    for a, b in zip(starts, stops):
        value = int(ep[a])
        if value in seen:
            raise TrajectoryFormatError(
                f"{table.where(col, int(a))}: episode {value} resumes after another episode (it began at row {seen[value]})"
            )
        seen[value] = int(a)
        blocks.append((int(a), int(b), value))
    return blocks


def _snap_filled_joints(v: np.ndarray, filled: np.ndarray, n: int) -> dict[int, float]:
    """Round interpolated joint samples onto the joint's encoder grid when the measured ones lie on one.

    Modifies ``v`` (T, ·) in place; returns joint column → detected step.
    """
    out = {}
    for c in range(n):
        step = detect_quantization_step(v[~filled, c])
        if step is not None:
            v[filled, c] = snap_to_grid(v[filled, c], step, v[~filled, c])
            out[c] = step
    return out


def _sample_rate(tables: list[LogTable], imap: ImportMap) -> float:
    if imap.time.rate_hz is not None:
        return float(imap.time.rate_hz)
    scale = TIME_UNITS[imap.time.unit]
    steps = []
    for table in tables:
        for a, b, _ in _trial_blocks(table, imap):
            d = np.diff(table.columns[imap.time.column][a:b]) * scale
            steps.append(d[d > 0])
    allsteps = np.concatenate(steps) if steps else np.zeros(0)
    if len(allsteps) == 0:
        raise TrajectoryFormatError(f"{tables[0].path}: cannot estimate the sample rate (no increasing time steps)")
    rate = 1.0 / float(np.median(allsteps))
    if abs(rate - round(rate)) <= 1e-3 * rate:
        rate = float(round(rate))
    logger.info("sample rate %g Hz (1 / median time step)", rate)
    return rate


def import_logs(paths: Sequence[str | Path], imap: ImportMap, *, min_trial_samples: int = MIN_TRIAL_SAMPLES) -> Trajectory:
    """One trajectory from a logger's files (module docstring; map format ``docs/log-import.md``).

    Args:
        paths: the CSV files, in trial order (``per_file``: file i is trial i).
        imap: the column map.
        min_trial_samples: segments shorter than this (after splitting at long gaps) are
            dropped, counted and logged.

    Returns:
        The trajectory: q (T, n) rad / m by joint kind, u (T, n − 1) in the inputs' units,
        the kept columns as channels, every trial on its nominal grid; provenance (files,
        per-trial source rows, filled samples, splits) in ``meta.extra["import"]``.

    Raises:
        TrajectoryFormatError: naming file, column and row (see :func:`read_log_table`,
            :func:`bemlearn.data.resample.place_on_grid`).
    """
    if not paths:
        raise ValueError("import_logs: no input files")
    tables = [read_log_table(p, imap) for p in paths]
    value_cols = [j.column for j in imap.joints] + [u.column for u in imap.inputs] + list(imap.keep)
    for table in tables:
        check_finite(table, value_cols + ([imap.time.column] if imap.time.column else []))
    rate = _sample_rate(tables, imap)
    scales = [j.sign * j.kind_and_scale()[1] for j in imap.joints]
    offsets = [j.offset for j in imap.joints] + [0.0] * (len(imap.inputs) + len(imap.keep))
    mult = np.asarray(scales + [1.0] * (len(imap.inputs) + len(imap.keep)))
    parts: dict[str, list[np.ndarray]] = {"t": [], "trial": [], "v": [], "filled": []}
    trials_info, failed = [], {}
    filled_total = splits = dropped = 0
    tcol = imap.time.column
    for table in tables:
        raw = np.stack([table.columns[c] for c in value_cols], axis=1)
        values = raw * mult + np.asarray(offsets)
        for a, b, episode in _trial_blocks(table, imap):
            if tcol is not None:
                t = table.columns[tcol][a:b] * TIME_UNITS[imap.time.unit]
                segs = place_on_grid(
                    t, values[a:b], rate_hz=rate, max_jitter=imap.time.max_jitter, max_fill=imap.time.max_fill,
                    on_gap=imap.time.on_gap, where=lambda i, a=a, table=table: table.where(tcol, a + i),
                )
            else:
                segs = [GridSegment(np.arange(b - a) / rate, values[a:b], np.zeros(b - a, dtype=bool), 0)]
            splits += len(segs) - 1
            for seg in segs:
                if len(seg.t) < min_trial_samples:
                    dropped += 1
                    logger.warning("%s: dropped a %d-sample piece at row %d (shorter than %d samples)",
                                   table.path, len(seg.t), a + seg.first_row, min_trial_samples)
                    continue
                tid = len(trials_info)
                parts["t"].append(seg.t)
                parts["trial"].append(np.full(len(seg.t), tid, dtype=np.int64))
                parts["v"].append(seg.values)
                parts["filled"].append(seg.filled)
                failed[tid] = False
                filled_total += int(seg.filled.sum())
                trials_info.append({
                    "trial": tid, "file": str(table.path), "first_row": a + seg.first_row,
                    "episode": episode, "samples": len(seg.t), "filled_samples": int(seg.filled.sum()),
                })
    if not trials_info:
        raise TrajectoryFormatError(f"{tables[0].path}: no trial with at least {min_trial_samples} samples")
    if filled_total or splits or dropped:
        logger.info("import: %d dropped samples interpolated, %d trials split at gaps, %d short pieces dropped",
                    filled_total, splits, dropped)
    v = np.concatenate(parts["v"])
    n, m = len(imap.joints), len(imap.inputs)
    snapped = _snap_filled_joints(v, np.concatenate(parts["filled"]), n) if filled_total else {}
    kinds = tuple(j.kind_and_scale()[0] for j in imap.joints)
    u_units = [u.unit for u in imap.inputs]
    meta = TrajectoryMeta(
        robot=imap.robot,
        joint_names=tuple(j.name for j in imap.joints),
        unactuated=imap.unactuated,
        actuator_names=tuple(u.name for u in imap.inputs),
        sample_rate_hz=rate,
        trial_failed=failed,
        units={"t": "s", "q": q_unit_label(kinds), "u": u_units[0] if len(set(u_units)) == 1 else "|".join(u_units)},
        joint_kinds=kinds,
        channel_names=tuple(imap.keep),
        extra={"import": {
            "generator": f"bemlearn {__version__} data import",
            "map": to_dict(imap),
            "files": [str(p) for p in paths],
            "filled_samples": filled_total, "split_gaps": splits, "dropped_pieces": dropped,
            "filled_snapped_to_grid": {imap.joints[c].name: step for c, step in snapped.items()},
            "trials": trials_info,
        }},
    )
    return Trajectory(
        t=np.concatenate(parts["t"]), trial=np.concatenate(parts["trial"]), q=v[:, :n], u=v[:, n:n + m],
        meta=meta, channels=v[:, n + m:],
    )
