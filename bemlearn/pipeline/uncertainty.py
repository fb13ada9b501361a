"""The calibrated BEM band of a training run: c, s and δ of eq. (B1) from the data alone.

    σ_band(x)² = c² σ(x)² + max(Σ_{i ∈ inputs} (s_i ∂μ/∂x_i)², (1/J) Σ_j (y_std k_Z(x̃)ᵀ δ_j)²)   (B1)

* s (``PredictorState.input_std``): the derivative estimator's noise gains applied to the
  quantization step detected in each joint's recorded angles (eq. N3,
  :mod:`bemlearn.models.input_noise`); joints without a detectable grid get s = 0;
* c (``PredictorState.std_scale``): trial-split and residual-split (q̈_u, q̇_u given the actuated
  motion) replica calibration at held-out BEM queries (:mod:`bemlearn.fitting.calibration`);
* δ (``PredictorState.estimator_delta``, J = K + 1 columns): the mean weights' shift when the training
  rows' derivatives come from each of K neighbouring estimators (eq. E2,
  :mod:`bemlearn.fitting.estimator_sensitivity`), and μ's deviation from the average of R other draws
  of its N training rows from the training pool (eq. R2, :mod:`bemlearn.fitting.resample_sensitivity`),
  stacked so that the mean square over the J columns is σ_est² + σ_rs²
  (:func:`~bemlearn.fitting.resample_sensitivity.stack_shift_columns`).

None of them needs a robot model.  :func:`calibrate_band` is called by ``bemlearn train`` after
the fit; see docs/uncertainty.md for the measurements behind the choice.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import torch

from bemlearn.data import build_datasets
from bemlearn.errors import ArgumentError, DataError
from bemlearn.fitting.calibration import calibrate_replicas
from bemlearn.fitting.estimator_sensitivity import estimator_sensitivity
from bemlearn.fitting.resample_sensitivity import N_DRAWS, resample_sensitivity, stack_shift_columns
from bemlearn.models.input_noise import quantization_input_std
from bemlearn.models.predictor_state import PredictorState
from bemlearn.warnings import UncertaintyWarning, warn

__all__ = ["calibrate_band"]

log = logging.getLogger(__name__)


def calibrate_band(state: PredictorState, traj, dataset_config, *, train_rows: torch.Tensor | None = None,
                   n_queries: int = 2000, n_pairs: int = 4, n_draws: int = N_DRAWS, level: float = 0.95,
                   seed: int = 0) -> tuple[PredictorState, dict]:
    """``state`` with ``std_scale``, ``input_std`` and ``estimator_delta`` set, and a JSON-able summary.

    Args:
        state: the fitted posterior (input columns as built from ``traj`` by ``dataset_config``).
        traj: the training :class:`~bemlearn.data.trajectory.Trajectory`.
        dataset_config: the :class:`~bemlearn.data.DatasetConfig` the posterior was trained with
            (``GPDatasets.config``: with the options chosen from the data written out; an estimator
            that still leaves an option to the data is an :class:`~bemlearn.errors.ArgumentError`).
        train_rows: ``(N,)`` the rows of ``traj`` the posterior was trained on
            (``BEMDataset.row``); default: drawn again by ``build_datasets(traj, dataset_config)``.
        n_queries: held-out BEM queries x_0^e for the replica calibration.
        n_pairs: random trial splits (:func:`~bemlearn.fitting.calibration.calibrate_replicas`).
        n_draws: other draws of the training rows (R of eq. R2,
            :func:`~bemlearn.fitting.resample_sensitivity.resample_sensitivity`).
        level: nominal level the band is calibrated to.
        seed: seed of the splits and draws.
    """
    est = dataset_config.estimator()
    if not getattr(est, "resolved", True):   # the σ build_datasets chose is in GPDatasets.config: pass that
        raise ArgumentError(f"calibrate_band: dataset_config: its estimator {est!r} leaves an option to the data; pass the "
                            "config the datasets were built with (GPDatasets.config), which holds the value chosen")
    t0 = time.perf_counter()
    meta = traj.meta
    # the encoder steps (detected in the angles, or as an import recorded them before resampling)
    steps = {k: v for k, v in traj.quantization_steps().items() if v is not None}
    s = quantization_input_std(state.input_names, steps, estimator=est, sample_rate_hz=meta.sample_rate_hz)
    pool = build_datasets(traj, dataclasses.replace(dataset_config, n_points=None, n_val_points=None))
    source = pool.val if len(pool.val) else pool.train
    g = torch.Generator().manual_seed(seed)
    queries = source.x[torch.randperm(len(source), generator=g)[:n_queries]].clone()
    queries[:, -2:] = 0.0                                  # x_0^e: q̈_u = q̇_u = 0 (eq. 14)
    summary: dict = {"formula": "std² = std_scale² · latent_std² + max(Σ_i (input_std_i ∂mean/∂x_i)², mean_j (y_std k_Z(x)ᵀ estimator_delta_j)²); estimator_delta: K neighbouring estimators and μ's deviation from the mean of other draws of its training rows, mean square σ_est² + σ_rs²",
                     "quantization_step": steps, "input_std": dict(zip(state.input_names, s.tolist())),
                     "estimator": repr(est), "queries_from": "validation trials" if len(pool.val) else "training trials"}
    try:
        d = state.dim   # columns [q̈_a, q̇_a, q_a] (3m), then q̈_u, q̇_u: the two the BEM query sets to 0 (eq. 14)
        cal = calibrate_replicas(state, pool.train.x, pool.train.y, pool.train.trial, queries,
                                 n_points=state.n_train, n_pairs=n_pairs, level=level, seed=seed,
                                 lockstep_columns=(d - 2, d - 1), motion_columns=d - 2, column_names=tuple(state.input_names))
        scale = cal.scale
        summary["replicas"] = cal.to_dict()
    except DataError as exc:  # a single training trial: nothing to split
        warn(UncertaintyWarning, log, "band calibration: no replica calibration (%s); std_scale = 1", exc)
        scale = 1.0
        summary["replicas"] = None
    summary["std_scale"] = scale
    if train_rows is None:
        train_rows = build_datasets(traj, dataset_config).train.row
    sens = estimator_sensitivity(state, traj, est, train_rows, queries=queries, qu_window=dataset_config.qu_window)
    summary["estimator_term"] = sens.to_dict()
    rs = resample_sensitivity(state, pool.train.x, pool.train.y, pool.train.row, train_rows, n_draws=n_draws, queries=queries, seed=seed)
    summary["resample_term"] = rs.to_dict()
    summary["seconds"] = time.perf_counter() - t0
    new = dataclasses.replace(state, std_scale=torch.tensor(scale, dtype=torch.float64), input_std=s.to(torch.float64),
                              estimator_delta=stack_shift_columns(sens.delta, rs.delta))
    log.info("calibrated band: std_scale %.3f, input_std %s, %d neighbouring estimators, %d draws of the training rows (%.2f s)",
             scale, ", ".join(f"{n} {v:.3g}" for n, v in zip(state.input_names, s.tolist())), sens.delta.shape[1], rs.n_draws,
             summary["seconds"])
    return new, summary
