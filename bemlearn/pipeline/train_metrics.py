"""What a trained BEM GP is judged by, computed once after the fit (eq. 11–15).

:func:`evaluate_trained` is the one entry: the validation split's RMSE, log likelihood and ±2σ coverages;
the data-only checks (held-out trials, resolution, joint support, slices:
:func:`~bemlearn.pipeline.data_evaluation.data_only_evaluation`); with a model, the learned BEM (eq. 14)
against the model-based BEM (eq. 9) along held-out references and over the design region; and a torque logged
on q_u.  It writes the figures (``bem_slices.png``, ``reliability.png``, ``bem_validation.png``,
``design_region.png``) and the TensorBoard scalars; the metrics come back as the dict that
:class:`~bemlearn.pipeline.run_metrics.RunMetrics` types.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from bemlearn.models import predict
from bemlearn.pipeline.model_comparison import compare_with_model

if TYPE_CHECKING:
    from bemlearn.data.dataset_types import BEMDataset
    from bemlearn.data.trajectory import Trajectory
    from bemlearn.fitting.gp_config import GPConfig
    from bemlearn.models.predictor_state import PredictorState
    from bemlearn.pipeline.evaluation import EvaluationConfig
    from bemlearn.pipeline.gp_stage import GPStageResult
    from bemlearn.robots.protocol import ControlRobot

__all__ = ["evaluate_trained"]


def evaluate_trained(stage: GPStageResult, train: BEMDataset, val: BEMDataset, traj: Trajectory,
                     truth_robot: ControlRobot | None, ecfg: EvaluationConfig, gp_cfg: GPConfig, units: dict[str, str],
                     out: Path, writer, metrics: dict[str, Any]) -> None:
    """Every evaluation of the fitted GP ``stage`` (module docstring), into ``metrics``.

    ``units``: each GP input's unit (:func:`~bemlearn.units.gp_input_units`); ``out`` the run folder for the
    figures, ``writer`` TensorBoard's.  ``metrics`` is filled as each evaluation finishes, so a failure part-way
    leaves the caller what was computed before it (the run records it with the failure).
    """
    unactuated = traj.meta.unactuated
    qu_unit = units[f"qd_{unactuated}"].removesuffix("/s")
    if len(val):
        metrics.update(_validation_metrics(stage, train, val, gp_cfg, writer))
    metrics["uncertainty"] = stage.calibration
    metrics.update(_data_only_metrics(stage.state, train, val, unactuated, units, qu_unit, out, writer))
    if truth_robot is not None:  # held-out learned BEM vs model-based BEM (eq. 14 vs 9)
        metrics.update(compare_with_model(stage.state, truth_robot, ecfg, unactuated, qu_unit, out, writer,
                                          excursion=traj.meta.collected_excursion))
    from bemlearn.pipeline.derive import design_region
    from bemlearn.pipeline.logged_torque import unactuated_torque_metrics

    # a torque logged on q_u, weighed against the model's gravity stiffness when there is a model
    tq = unactuated_torque_metrics(traj, truth_robot, bound=design_region(truth_robot).value if truth_robot is not None else None)
    if tq is not None:
        metrics["unactuated_torque"] = tq


def _validation_metrics(stage: GPStageResult, train: BEMDataset, val: BEMDataset, gp_cfg: GPConfig, writer) -> dict[str, float]:
    """The fitted GP on the validation split: RMSE (q_u's unit), mean log likelihood and ±2σ coverages."""
    state, model, lik = stage.state, stage.model, stage.likelihood
    dtype = gp_cfg.torch_dtype
    mean, var = predict(model, lik, val.x_normalized.to(device=gp_cfg.device, dtype=dtype), noisy=True)
    mean = mean.cpu().to(torch.float64) * train.y_std + train.y_mean + state.prior_mean(val.x.to(torch.float64))   # eq. (L1)
    var_pred = var.cpu().to(torch.float64) * train.y_std**2
    err = mean - val.y
    rmse = float(err.pow(2).mean().sqrt())
    mll = float((-0.5 * (err**2 / var_pred + var_pred.log() + math.log(2 * math.pi))).mean())
    metrics = {"val_rmse": rmse, "val_mean_log_likelihood": mll}
    writer.add_scalar("val/rmse", rmse, 0)
    writer.add_scalar("val/mean_log_likelihood", mll, 0)
    from bemlearn.models.band import band_reference

    band = band_reference(state, val.x)[1]  # model-free: held-out q_u inside ±2√(σ_band² + σ_0²)
    metrics["val_coverage_2sigma_band"] = float((err.abs() <= 2 * (band**2 + state.y_std**2 * state.noise).sqrt()).double().mean())
    metrics["val_coverage_2sigma_predictive"] = float((err.abs() <= 2 * var_pred.sqrt()).double().mean())
    return metrics


def _data_only_metrics(state: PredictorState, train: BEMDataset, val: BEMDataset, unactuated: str, units: dict[str, str],
                       qu_unit: str, out: Path, writer) -> dict:
    """Data-only evaluation (no model): held-out trials' q_u from f(x), resolution, joint support, and the BEM on
    slices with the region the data cover marked, so that extrapolation is visible (writes ``bem_slices.png``)."""
    from bemlearn.pipeline.data_evaluation import bem_slice_figure, data_only_evaluation

    ev = data_only_evaluation(state, train, val if len(val) else None, units, qu_unit)
    metrics: dict = {}
    if ev.heldout is not None:
        metrics["data_heldout"] = {**{k: v for k, v in ev.heldout.items() if k != "per_trial"},
                                   "per_trial": {str(k): v for k, v in ev.heldout["per_trial"].items()}}
    metrics["resolution"] = ev.resolution   # do the data resolve the BEM at all (model-free)?
    metrics["support"] = ev.support         # are its queries supported by the data jointly?
    metrics["bem_slices"] = {"summary": ev.slices["summary"],
                             "slices": [{k: v for k, v in sl.items() if not hasattr(v, "shape")} for sl in ev.slices["slices"]]}
    fig = bem_slice_figure(ev.slices, out / "bem_slices.png", unactuated=unactuated)
    writer.add_figure("bem/slices", fig, 0)
    return metrics
