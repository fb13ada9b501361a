"""``bemlearn bench import``: log import speed (10⁶ rows) and the model-free path's accuracy.

* speed: logger CSVs with ``rows`` rows in total (degrees, flipped pendulum, ms stamps with
  20 µs jitter, dropped samples, extra columns; :mod:`bemlearn.data.rig_logs`) are written
  once, then imported ``repeats`` times; the median wall time is reported.
* accuracy: the shipped Furuta data are written as such logs and imported; the GP is fitted
  on the imported file and on the simulator's own file (``read_trajectory`` →
  ``build_datasets`` → ``build_gp``/``fit_gp`` → ``predictor_state``), and both learned BEMs
  are scored against the model BEM on held-out references (as ``bemlearn train`` does) and
  on the data alone (:mod:`bemlearn.pipeline.data_evaluation`).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bemlearn.config import from_dict
from bemlearn.data.import_map import ImportMap
from bemlearn.data.log_import import import_logs
from bemlearn.data.rig_logs import RigLogStyle, rig_log_map, write_rig_logs
from bemlearn.data.trajectory import Trajectory

__all__ = ["bench_import_speed", "bench_model_free_accuracy", "fit_predictor"]


def _long_trajectory(rows: int, trials: int, source: Trajectory) -> Trajectory:
    """``trials`` trials of ``rows // trials`` samples, tiled from ``source``'s first trial."""
    import dataclasses

    first = source.trial_slices()[0]
    per = rows // trials
    reps = -(-per // first.n_samples)
    q = np.tile(source.q[first.rows], (reps, 1))[:per]
    u = np.tile(source.u[first.rows], (reps, 1))[:per]
    rate = source.meta.sample_rate_hz
    meta = dataclasses.replace(source.meta, trial_failed={i: False for i in range(trials)})
    return Trajectory(
        t=np.tile(np.arange(per) / rate, trials), trial=np.repeat(np.arange(trials), per),
        q=np.tile(q, (trials, 1)), u=np.tile(u, (trials, 1)), meta=meta,
    )


def bench_import_speed(source: Trajectory, *, rows: int = 1_000_000, trials: int = 10, repeats: int = 5) -> dict[str, Any]:
    """Median seconds to import ``rows`` logger rows in ``trials`` files (module docstring)."""
    traj = _long_trajectory(rows, trials, source)
    style = RigLogStyle()
    imap = from_dict(ImportMap, rig_log_map(traj, style))
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_rig_logs(traj, Path(tmp), style)
        size = sum(p.stat().st_size for p in paths)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            out = import_logs(paths, imap)
            times.append(time.perf_counter() - t0)
    return {
        "rows_written": int(traj.n_samples), "rows_imported": int(out.n_samples), "files": trials,
        "megabytes": size / 1e6, "seconds_median": statistics.median(times), "seconds_all": times,
        "filled_samples": out.meta.extra["import"]["filled_samples"],
    }


def fit_predictor(traj: Trajectory, dataset_config, gp_config):
    """The documented model-free path: trajectory → GP datasets → fitted GP → frozen predictor.

    Returns:
        (PredictorState, GPDatasets).
    """
    from bemlearn.data import build_datasets
    from bemlearn.fitting import build_gp, fit_gp
    from bemlearn.models import predictor_state

    ds = build_datasets(traj, dataset_config)
    x, y = ds.train.x_normalized, ds.train.y_normalized
    model, lik = build_gp(x, y, config=gp_config)
    fit_gp(model, lik, x, y, config=gp_config)
    model.eval()
    lik.eval()
    state = predictor_state(
        model, lik, x_mean=ds.train.x_mean, x_std=ds.train.x_std, y_mean=ds.train.y_mean, y_std=ds.train.y_std,
        input_names=ds.train.input_names, n_train=len(ds.train),
    )
    return state, ds


def bench_model_free_accuracy(
    source: Trajectory, config, *, style: RigLogStyle | None = None, figure_dir: Path | None = None
) -> dict[str, Any]:
    """Fit on the simulator's file and on its logger-written, re-imported copy; score both (module docstring).

    Args:
        source: the simulator's data file (e.g. ``data/furuta_excitation.npz``).
        config: a :class:`~bemlearn.pipeline.config.PipelineConfig` (its ``dataset`` and ``train``).
        style: how the logs are written (default :class:`RigLogStyle`).
        figure_dir: where to write the slice figures (``bem_slices_<which>.png``).
    """
    from bemlearn.pipeline.data_evaluation import (
        bem_slice_figure,
        bem_slices,
        heldout_prediction,
    )
    from bemlearn.pipeline.evaluation import evaluate_bem, held_out_references
    from bemlearn.robots import load

    style = style or RigLogStyle()
    robot = load(config.robot, coordinates=config.coordinates)  # the model the simulator data came from: the reference of the comparison
    ecfg = config.evaluate
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_rig_logs(source, Path(tmp), style)
        imported = import_logs(paths, from_dict(ImportMap, rig_log_map(source, style)))
    out: dict[str, Any] = {"filled_samples": imported.meta.extra["import"]["filled_samples"],
                           "max_abs_q_difference": float(np.abs(imported.q - source.q).max())}
    for which, traj in (("simulator_file", source), ("imported_logs", imported)):
        t0 = time.perf_counter()
        state, ds = fit_predictor(traj, config.dataset, config.train)
        ev = evaluate_bem(state, robot, held_out_references(ecfg, robot.m), duration_s=ecfg.duration_s, rate_hz=ecfg.rate_hz)
        held = heldout_prediction(state, ds.val)
        sl = bem_slices(state, ds.train)
        if figure_dir is not None:
            Path(figure_dir).mkdir(parents=True, exist_ok=True)
            bem_slice_figure(sl, Path(figure_dir) / f"bem_slices_{which}.png", unactuated=traj.meta.unactuated)
        out[which] = {
            "seconds": time.perf_counter() - t0, "bem_rmse_vs_model": ev.rmse, "bem_max_abs_vs_model": ev.max_abs,
            "heldout_rmse": held["rmse"], "heldout_coverage_2sigma": held["coverage"], "heldout_points": held["n_points"],
            "slices": sl["summary"],
        }
    return out
