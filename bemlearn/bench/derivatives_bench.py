"""Derivative estimators on the shipped excitation data: accuracy and effect on the learned BEM.

For each estimator setting: the RMS error of q̇ and q̈ against the simulator's ground truth
(interior samples with |q_u| inside the dataset window), and — optionally — the held-out
learned-BEM accuracy of an exact GP trained on 500 points built with that estimator.

About the q̈ reference: the input is held between control ticks, so the true acceleration
jumps at every sample (the value logged at sample k is the right limit, with the new
input).  Errors are therefore reported against the mean of the left and right limits,
½(q̈_{k−1}⁺ + q̈_k⁺) ≈ ½(q̈(t_k⁻) + q̈(t_k⁺)), the value a symmetric estimator can recover;
the error against the right limit is reported too.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from bemlearn.data import build_datasets, estimate_derivatives, make_estimator

__all__ = ["ESTIMATOR_GRID", "derivative_errors", "run_derivatives_bench", "load_or_collect"]

#: (name, options) settings compared by the bench.
ESTIMATOR_GRID: tuple[tuple[str, dict], ...] = (
    ("central", {}),
    ("savgol", {"window_s": 0.05, "polyorder": 3}),
    ("savgol", {"window_s": 0.1, "polyorder": 3}),
    ("savgol", {"window_s": 0.1, "polyorder": 4}),
    ("savgol", {"window_s": 0.2, "polyorder": 3}),
    ("savgol", {"window_s": 0.2, "polyorder": 4}),
    ("savgol", {"window_s": 0.3, "polyorder": 4}),
    ("savgol", {"window_s": 0.4, "polyorder": 4}),
    ("savgol", {"window_s": 0.5, "polyorder": 4}),
)


def load_or_collect(config, data_path: str | Path):
    """The data file and its ground truth; the truth is re-simulated (bit-identical, seeded) if missing."""
    from bemlearn.data.trajectory_io import ground_truth_path, read_ground_truth, read_trajectory, write_trajectory

    data_path = Path(data_path)
    gt = ground_truth_path(data_path)
    if not gt.is_file():
        from bemlearn.data.collect import collect

        data, truth = collect(config.robot, config.collect, progress=False)
        old = read_trajectory(data_path)
        if not (np.array_equal(old.q, data.q) and np.array_equal(old.t, data.t)):
            raise ValueError(f"{data_path}: does not match what the config's collect section produces; cannot rebuild its ground truth")
        write_trajectory(truth, gt)
    return read_trajectory(data_path), read_ground_truth(gt)


def derivative_errors(data, truth, name: str, options: dict, *, qu_window: float | None) -> dict:
    """RMS q̇ / q̈ errors per joint against the ground truth (module docstring)."""
    est = make_estimator(name, options)
    rate = data.meta.sample_rate_hz
    long_enough = [s.trial_id for s in data.trial_slices() if s.n_samples >= est.min_samples(rate)]
    data, truth = data.select_trials(long_enough), truth.select_trials(long_enough)  # as the dataset's short_trials="drop"
    qd, qdd = estimate_derivatives(data, est)
    edge = est.edge_samples(rate)
    keep = np.zeros(data.n_samples, dtype=bool)
    qdd_mid = np.full_like(truth.qdd, np.nan)
    for s in data.trial_slices():
        lo, hi = s.rows.start, s.rows.stop
        keep[lo + max(edge, 1) : hi - edge] = True
        qdd_mid[lo + 1 : hi] = 0.5 * (truth.qdd[lo : hi - 1] + truth.qdd[lo + 1 : hi])
    if qu_window is not None:
        keep &= np.abs(truth.q[:, data.meta.unactuated_index]) <= qu_window
    rms = lambda e: np.sqrt(np.mean(e[keep] ** 2, axis=0))  # noqa: E731
    return {
        "qd_rms": rms(qd - truth.qd).tolist(),
        "qdd_rms": rms(qdd - qdd_mid).tolist(),
        "qdd_rms_right_limit": rms(qdd - truth.qdd).tolist(),
        "n_samples": int(keep.sum()),
    }


def run_derivatives_bench(config, data_path: str | Path, *, with_gp: bool = True, progress=print) -> list[dict]:
    """Run :data:`ESTIMATOR_GRID`; return one row per setting."""
    data, truth = load_or_collect(config, data_path)
    rows = []
    for name, options in ESTIMATOR_GRID:
        row = {"estimator": name, "options": options}
        row.update(derivative_errors(data, truth, name, options, qu_window=config.dataset.qu_window))
        if with_gp:
            from bemlearn.fitting import train_gp
            from bemlearn.models import predictor_state
            from bemlearn.pipeline.evaluation import evaluate_bem, held_out_references
            from bemlearn.robots import load

            dcfg = dataclasses.replace(config.dataset, derivative=name, derivative_options=options)
            ds = build_datasets(data, dcfg)
            tr = ds.train
            t0 = time.perf_counter()
            model, lik, _ = train_gp(tr.x_normalized, tr.y_normalized, config=config.train)
            st = predictor_state(model, lik, x_mean=tr.x_mean, x_std=tr.x_std, y_mean=tr.y_mean, y_std=tr.y_std, input_names=tr.input_names, n_train=len(tr))
            ecfg = config.evaluate
            robot = load(config.robot)
            ev = evaluate_bem(st, robot, held_out_references(ecfg, robot.m), duration_s=ecfg.duration_s, rate_hz=ecfg.rate_hz)
            row.update({
                "bem_rmse": ev["rmse"], "bem_max": ev["max_abs"], "bem_coverage_latent": ev["coverage_2sigma_latent"],
                "fit_seconds": time.perf_counter() - t0,
            })
        rows.append(row)
        progress(format_row(row, data.meta.joint_names))
    return rows


def format_row(row: dict, joints) -> str:
    opts = ", ".join(f"{k}={v}" for k, v in row["options"].items()) or "-"
    qd = " / ".join(f"{v:.4f}" for v in row["qd_rms"])
    qdd = " / ".join(f"{v:.2f}" for v in row["qdd_rms"])
    s = f"| {row['estimator']} | {opts} | {qd} | {qdd} |"
    if "bem_rmse" in row:
        s += f" {row['bem_rmse']:.4f} | {row['bem_max']:.4f} | {100 * row['bem_coverage_latent']:.0f}% |"
    return s
