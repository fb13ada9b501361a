"""Derivative estimators on a run's excitation data: accuracy and effect on the learned BEM.

For each estimator setting: the RMS error of q̇ and q̈ against the simulator's ground truth
(interior samples with |q_u| inside the dataset window; for an estimator that smooths, against
the truth through the same kernel, the quantity it estimates, eq. G1), and — optionally — the
learned BEM of an exact GP trained on the dataset built with that estimator, scored against
the model BEM over the whole design region (RMSE, max, gain: eq. D2 of
:mod:`bemlearn.pipeline.design_evaluation`) and along the held-out references.  The first row
is the exact-derivative oracle: the same GP on the simulator's own q, q̇, q̈, so the gap left by
estimating derivatives stays visible.  The Gaussian rows are the default (σ by rule C1 of
:mod:`bemlearn.data.derivative_choice`), the rule at ρ = 0.9 and 0.95, and σ × 2/3, × 3/2.

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
from typing import Any

import numpy as np
import torch

from bemlearn.data import build_datasets, make_estimator
from bemlearn.errors import DataError

__all__ = ["ESTIMATOR_GRID", "TABLE_HEAD", "derivative_errors", "format_row", "resolve_setting", "run_derivatives_bench",
           "load_or_collect"]

#: (name, options) settings compared by the bench; ``"truth"`` is the exact-derivative oracle, and
#: the Gaussian's ``kept_motion`` / ``sigma_scale`` are resolved against the data (module docstring).
ESTIMATOR_GRID: tuple[tuple[str, dict], ...] = (
    ("truth", {}),
    ("central", {}),
    ("savgol", {"window_s": 0.1, "polyorder": 3}),
    ("savgol", {"window_s": 0.2, "polyorder": 3}),
    ("savgol", {"window_s": 0.3, "polyorder": 4}),
    ("savgol", {"window_s": 0.45, "polyorder": 4}),
    ("gaussian", {}),
    ("gaussian", {"kept_motion": 0.9}),
    ("gaussian", {"kept_motion": 0.95}),
    ("gaussian", {"sigma_scale": 2 / 3}),
    ("gaussian", {"sigma_scale": 1.5}),
)


def resolve_setting(data, name: str, options: dict, *, qu_window: float | None) -> dict:
    """The estimator options a bench setting stands for: ``kept_motion`` (ρ of rule C1) and
    ``sigma_scale`` (× the rule's σ) become an explicit Gaussian ``sigma_s``."""
    if name != "gaussian" or not ({"kept_motion", "sigma_scale"} & set(options)):
        return dict(options)
    from bemlearn.data.derivative_choice import KEPT_MOTION, choose_sigma

    rho = options.get("kept_motion", KEPT_MOTION)
    sigma = choose_sigma(data, qu_window=qu_window, kept_motion=rho).sigma_s * options.get("sigma_scale", 1.0)
    return {"sigma_s": float(f"{sigma:.5g}")}


def load_or_collect(config, data_path: str | Path):
    """The data file and its ground truth; the truth is re-simulated (bit-identical, seeded) if missing."""
    from bemlearn.data.trajectory_io import ground_truth_path, read_ground_truth, read_trajectory, write_trajectory

    data_path = Path(data_path)
    gt = ground_truth_path(data_path)
    if not gt.is_file():
        from bemlearn.sim.collect import collect

        data, truth = collect(config.robot, config.collect, progress=False)
        old = read_trajectory(data_path)
        if not (np.array_equal(old.q, data.q) and np.array_equal(old.t, data.t)):
            raise DataError(f"{data_path}: does not match what the config's collect section produces; cannot rebuild its ground truth")
        write_trajectory(truth, gt)
    return read_trajectory(data_path), read_ground_truth(gt)


def derivative_errors(data, truth, name: str, options: dict, *, qu_window: float | None) -> dict:
    """RMS q̇ / q̈ errors per joint against the ground truth (module docstring)."""
    from bemlearn.data.derivative_choice import estimate_states, resolve_estimator

    if name == "truth":
        z = [0.0] * data.q.shape[1]
        return {"qd_rms": z, "qdd_rms": z, "qdd_rms_right_limit": z, "n_samples": int(truth.n_samples)}
    est, _ = resolve_estimator(make_estimator(name, options), data, qu_window=qu_window)
    rate = data.meta.sample_rate_hz
    long_enough = [s.trial_id for s in data.trial_slices() if s.n_samples >= est.min_samples(rate)]
    data, truth = data.select_trials(long_enough), truth.select_trials(long_enough)  # as the dataset's short_trials="drop"
    within = data.qu_window_mask(qu_window)
    _, qd, qdd, valid = estimate_states(data, est, within=within)
    ref_qd, ref_qdd = truth.qd, truth.qdd
    if getattr(est, "smooths", False):      # against the truth through the same kernel: S[q̇], S[q̈] (eq. G1)
        from bemlearn.data.gaussian_derivative import apply_kernel, gaussian_kernels

        w0 = gaussian_kernels(est.sigma_s, rate, est.truncate)[0]
        ref_qd, ref_qdd = np.empty_like(truth.qd), np.empty_like(truth.qdd)
        for s in data.trial_slices():
            ref_qd[s.rows], ref_qdd[s.rows] = apply_kernel(truth.qd[s.rows], w0), apply_kernel(truth.qdd[s.rows], w0)
    edge = est.edge_samples(rate)
    keep = np.zeros(data.n_samples, dtype=bool)
    qdd_mid = np.full_like(truth.qdd, np.nan)
    for s in data.trial_slices():
        lo, hi = s.rows.start, s.rows.stop
        keep[lo + max(edge, 1) : hi - edge] = True
        qdd_mid[lo + 1 : hi] = 0.5 * (ref_qdd[lo : hi - 1] + ref_qdd[lo + 1 : hi])
    keep &= valid
    if qu_window is not None:
        keep &= np.abs(truth.q[:, data.meta.unactuated_index] - data.meta.qu_upright) <= qu_window
    rms = lambda e: np.sqrt(np.mean(e[keep] ** 2, axis=0))  # noqa: E731
    return {
        "qd_rms": rms(qd - ref_qd).tolist(),
        "qdd_rms": rms(qdd - qdd_mid).tolist(),
        "qdd_rms_right_limit": rms(qdd - ref_qdd).tolist(),
        "n_samples": int(keep.sum()),
    }


def run_derivatives_bench(config, data_path: str | Path, *, with_gp: bool = True, progress=print,
                          grid: tuple[tuple[str, dict], ...] = ESTIMATOR_GRID) -> list[dict]:
    """Run ``grid`` (default :data:`ESTIMATOR_GRID`) on ``data_path``; return one row per setting."""
    data, truth = load_or_collect(config, data_path)
    qu_window = config.dataset.qu_window
    robot = grid_points = None
    if with_gp:
        from bemlearn.pipeline.design_evaluation import design_grid
        from bemlearn.robots import load

        robot = load(config.robot, coordinates=config.coordinates)
        grid_points = design_grid(robot, config.evaluate, n_points=config.evaluate.design_points or 4096, seed=config.evaluate.seed)
    rows = []
    base_rows = None
    for name, setting in grid:
        options = resolve_setting(data, name, setting, qu_window=qu_window)
        row: dict[str, Any] = {"estimator": name, "options": options, "setting": setting}
        row.update(derivative_errors(data, truth, name, options, qu_window=qu_window))
        if with_gp:
            assert robot is not None and grid_points is not None  # loaded above
            from bemlearn.data.features import gp_inputs
            from bemlearn.data.normalization import Normalization
            from bemlearn.fitting import train_gp
            from bemlearn.models import predictor_state
            from bemlearn.pipeline.design_evaluation import evaluate_design_region
            from bemlearn.pipeline.evaluation import evaluate_bem, held_out_references

            if name == "truth":   # the oracle: the simulator's q, q̇, q̈ at the rows a Savitzky–Golay dataset draws
                ref = base_rows if base_rows is not None else build_datasets(
                    data, dataclasses.replace(config.dataset, derivative="savgol", derivative_options={"window_s": 0.3, "polyorder": 4})).train
                x = torch.as_tensor(gp_inputs(truth.q, truth.qd, truth.qdd, unactuated_index=data.meta.unactuated_index)[ref.row.numpy()])
                y = torch.as_tensor(truth.q[ref.row.numpy(), data.meta.unactuated_index])
                norm = Normalization.fit(x, y, names=ref.input_names)
                xn, yn, names = norm.normalize_x(x), norm.normalize_y(y), ref.input_names
            else:
                tr = build_datasets(data, dataclasses.replace(config.dataset, derivative=name, derivative_options=options)).train
                if name == "savgol" and base_rows is None:
                    base_rows = tr
                norm, xn, yn, names = tr.normalization, tr.x_normalized, tr.y_normalized, tr.input_names
                y = tr.y
            t0 = time.perf_counter()
            model, lik, _ = train_gp(xn, yn, config=config.train)
            st = predictor_state(model, lik, x_mean=norm.x_mean, x_std=norm.x_std, y_mean=norm.y_mean, y_std=norm.y_std,
                                 input_names=names, n_train=len(y))
            ecfg = config.evaluate
            ev = evaluate_bem(st, robot, held_out_references(ecfg, robot.m), duration_s=ecfg.duration_s, rate_hz=ecfg.rate_hz)
            dr = evaluate_design_region(st, grid_points)
            row.update({
                "bem_rmse": ev.rmse, "bem_max": ev.max_abs, "bem_coverage_latent": ev.coverage_2sigma_latent,
                "design_rmse": dr.rmse, "design_max": dr.max_abs, "design_gain": dr.gain,
                "fit_seconds": time.perf_counter() - t0,
            })
        rows.append(row)
        progress(format_row(row, data.meta.joint_names))
    return rows


def format_row(row: dict, joints) -> str:
    """One Markdown row of :func:`run_derivatives_bench`'s table (:data:`TABLE_HEAD`)."""
    opts = ", ".join(f"{k}={v}" for k, v in {**row.get("setting", {}), **row["options"]}.items()) or "-"
    name = "exact derivatives (oracle)" if row["estimator"] == "truth" else row["estimator"]
    qd = " / ".join(f"{v:.4f}" for v in row["qd_rms"])
    qdd = " / ".join(f"{v:.2f}" for v in row["qdd_rms"])
    s = f"| {name} | {opts} | {qd} | {qdd} |"
    if "bem_rmse" in row:
        s += (f" {row['design_rmse']:.4f} | {row['design_max']:.4f} | {row['design_gain']:.3f} | {row['bem_rmse']:.4f} | "
              f"{row['bem_max']:.4f} |")
    return s


#: Header of :func:`format_row`'s table (``with_gp`` adds the last five columns).
TABLE_HEAD = ("| estimator | options | q̇ RMS per joint | q̈ RMS per joint |",
              " design-region BEM RMSE | max | gain | held-out refs RMSE | max |")
