"""A training run: data file → GP datasets (eq. 11) → fitted GP → run folder.

The run folder holds::

    config.yaml      the resolved pipeline config
    checkpoint.pt    state dict + frozen posterior + metadata (torch.load(weights_only=True))
    metrics.json     fit summary, validation RMSE / mean predictive log-likelihood, held-out BEM accuracy
    tb/              TensorBoard: loss, noise, outputscale, lengthscale/<input>, lr, validation, BEM figure
    bem_validation.png

:func:`train_run` returns a :class:`~bemlearn.pipeline.results.TrainResult` (the metrics, the frozen
predictor, the trajectory).  Within ``bemlearn run`` (``part_of_run=True``) the run writes
``config.yaml`` and ``metrics.json`` and judges the verdict once, from the typed results of every
stage; training alone writes them itself.

Ctrl-C during the fit writes a checkpoint of the current hyperparameters (marked
``interrupted``) before exiting; ``resume=True`` loads the checkpoint's model state and
continues the fit.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from bemlearn.config import save_yaml
from bemlearn.data import build_datasets, read_trajectory
from bemlearn.data.validation import check_robot
from bemlearn.errors import ArgumentError, EnvironmentProblem
from bemlearn.files import atomic_path, atomic_write_text, file_sha256
from bemlearn.models import predict
from bemlearn.pipeline.config import PipelineConfig
from bemlearn.pipeline.evaluation import BEMCurves, EvaluationConfig, evaluate_bem, held_out_references
from bemlearn.pipeline.reliability import reliability_figure
from bemlearn.pipeline.results import TrainResult
from bemlearn.pipeline.run_metrics import RunMetrics
from bemlearn.pipeline.uncertainty import calibrate_band
from bemlearn.robots.protocol import BalanceRobot, ControlRobot
from bemlearn.units import gp_input_units

if TYPE_CHECKING:
    from bemlearn.data.dataset_types import BEMDataset
    from bemlearn.data.trajectory import Trajectory
    from bemlearn.fitting.gp_config import GPConfig
    from bemlearn.models.predictor_state import PredictorState
    from bemlearn.pipeline.gp_stage import GPStageResult
    from bemlearn.robots.registry import RobotRef

__all__ = ["train_run", "file_sha256"]

log = logging.getLogger(__name__)


def _resolve_device(device: str) -> str:
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise EnvironmentProblem(f"--device {device}: CUDA was requested but no CUDA device is available (use --device cpu)")
    return device


def train_run(
    config: PipelineConfig,
    data_path: str | Path,
    out_dir: str | Path,
    *,
    device: str | None = None,
    resume: bool = False,
    progress: bool = True,
    threads: int | None = 1,
    trajectory: Trajectory | None = None,
    loaded: tuple[BalanceRobot, RobotRef] | None = None,
    part_of_run: bool = False,
) -> TrainResult:
    """Train the BEM GP of ``config`` on ``data_path`` into ``out_dir``.

    ``threads`` sets torch's intra-op threads for the run (restored afterwards; ``None``
    keeps the current setting).  One thread is the default, because a second thread slows
    the fit down when other processes share the cores (``bemlearn bench train`` times both;
    figures in docs/furuta.md).

    Args:
        trajectory: the data of ``data_path`` when the caller holds them already (a run that
            collected them); ``data_path`` then only names them (provenance).
        loaded: ``(robot, ref)`` of ``config.robot`` when the caller has loaded it already.
        part_of_run: the caller (``bemlearn run``) writes ``config.yaml``, ``metrics.json`` and the
            verdict from every stage's results; on failure training still records what it kept.
    """
    previous = torch.get_num_threads()
    if threads is not None:
        if threads < 1:
            raise ArgumentError(f"threads: expected a positive integer, got {threads}")
        torch.set_num_threads(threads)
    try:
        return _train_run(config, data_path, out_dir, device=device, resume=resume, progress=progress, trajectory=trajectory,
                          loaded=loaded, part_of_run=part_of_run)
    finally:
        torch.set_num_threads(previous)


def _train_run(config: PipelineConfig, data_path, out_dir, *, device, resume, progress, trajectory, loaded,
               part_of_run) -> TrainResult:
    from torch.utils.tensorboard import SummaryWriter

    from bemlearn.pipeline.gp_stage import CheckpointProvenance, fit_bem_gp
    from bemlearn.pipeline.robot_source import run_robot

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    started_ns = time.time_ns()
    gp_cfg = config.train
    if device is not None:
        gp_cfg = dataclasses.replace(gp_cfg, device=_resolve_device(device))
    else:
        _resolve_device(gp_cfg.device)
    config = dataclasses.replace(config, train=gp_cfg)
    if not part_of_run:
        save_yaml(config, out / "config.yaml")
    robot, ref, truth_robot = run_robot(config, loaded)
    traj = trajectory if trajectory is not None else read_trajectory(data_path)
    if robot is not None:  # the file's joints must be the robot's (its robot label matters only for registry names)
        check_robot(traj.meta, robot if ref.registry else _Named(robot, traj.meta.robot), source=str(data_path))
    else:
        ref = dataclasses.replace(ref, name=traj.meta.robot or ref.name)
    ds = build_datasets(traj, config.dataset, progress=progress)
    train, val = ds.train, ds.val
    log.info("dataset: %d training points, %d validation points; %s", len(train), len(val), ds.report)
    names = train.input_names
    meta = traj.meta
    kinds = robot.coordinate_kinds if robot is not None else meta.joint_kinds  # model-free: as the file records them
    units = gp_input_units(names, meta.joint_names, kinds)
    writer = SummaryWriter(str(out / "tb"))
    stage = fit_bem_gp(
        train.x, train.y, out, normalization=train.normalization, input_names=names, units=units, config=gp_cfg,
        provenance=CheckpointProvenance(robot=ref.to_dict(), joint_names=meta.joint_names, unactuated_name=meta.unactuated,
                                        data_sha256=file_sha256(data_path),
                                        extra={"data_file": str(data_path), "dataset_report": ds.report}),
        writer=writer, resume=resume, progress=progress,
        calibrate=lambda st: calibrate_band(st, traj, ds.config, train_rows=train.row, seed=config.dataset.seed),  # std of eq. (B1)
    )
    state = stage.state
    interrupted = stage.interrupted
    metrics: dict = {"robot": ref.to_dict(), "fit": stage.fit, "hyperparameters": stage.hyperparameters,
                     "lengthscale_physical": stage.lengthscale_physical, "units": units,
                     "unactuated": meta.unactuated, "actuated": list(meta.actuated_names),
                     "output_unit": units[f"qd_{meta.unactuated}"].removesuffix("/s"), "n_train": len(train),
                     "n_val": len(val), "dataset": ds.report, "interrupted": interrupted}
    if interrupted:  # the best checkpoint is written; skip the slow evaluation so Ctrl-C ends within seconds
        writer.close()
        atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=2, default=float))
        raise KeyboardInterrupt
    try:   # the checkpoint exists: a failure from here on keeps it, and metrics.json says where the run stopped
        if len(val):
            metrics.update(_validation_metrics(stage, train, val, gp_cfg, writer))
        metrics["uncertainty"] = stage.calibration
        metrics.update(_data_only_metrics(state, train, val, meta.unactuated, out, writer))
        if truth_robot is not None:  # held-out learned BEM vs model-based BEM (eq. 14 vs 9)
            metrics.update(_model_metrics(state, truth_robot, config.evaluate, meta.unactuated,
                                          units[f"qd_{meta.unactuated}"].removesuffix("/s"), out, writer,
                                          excursion=_collected_excursion(meta)))
        tq = _torque_metrics(traj, truth_robot)
        if tq is not None:
            metrics["unactuated_torque"] = tq
    except Exception as exc:
        from bemlearn.pipeline.failure import record_failure

        writer.close()
        record_failure(out, "train: evaluation", exc, metrics, since_ns=started_ns)
        raise
    writer.close()
    typed = RunMetrics.from_dict(metrics)      # the sections as the verdict, the report and the run read them
    if not part_of_run:
        from bemlearn.pipeline.verdict import judge_run

        typed.verdict = judge_run(typed)        # what training alone can tell
        atomic_write_text(out / "metrics.json", json.dumps(typed.as_dict(), indent=2, default=float))
    return TrainResult(typed, state, traj, robot)


def _torque_metrics(traj, truth_robot) -> dict | None:
    """A torque logged on q_u, weighed against the model's gravity stiffness when there is a model
    (:mod:`bemlearn.pipeline.logged_torque`)."""
    from bemlearn.pipeline.derive import design_region
    from bemlearn.pipeline.logged_torque import unactuated_torque_metrics

    bound = design_region(truth_robot).value if truth_robot is not None else None
    return unactuated_torque_metrics(traj, truth_robot, bound=bound)


def _validation_metrics(stage: GPStageResult, train: BEMDataset, val: BEMDataset, gp_cfg: GPConfig, writer) -> dict[str, float]:
    """The fitted GP on the validation split: RMSE (q_u's unit), mean log likelihood and ±2σ coverages."""
    state, model, lik = stage.state, stage.model, stage.likelihood
    dtype = gp_cfg.torch_dtype
    mean, var = predict(model, lik, val.x_normalized.to(device=gp_cfg.device, dtype=dtype), noisy=True)
    mean = mean.cpu().to(torch.float64) * train.y_std + train.y_mean
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


def _data_only_metrics(state: PredictorState, train: BEMDataset, val: BEMDataset, unactuated: str, out: Path, writer) -> dict:
    """Data-only evaluation (no model): held-out trials' q_u from f(x), and the BEM on slices with the
    region the data cover marked, so that extrapolation is visible (writes ``bem_slices.png``)."""
    from bemlearn.pipeline.data_evaluation import bem_resolution, bem_slice_figure, bem_slices, design_support, heldout_prediction

    metrics: dict = {}
    if len(val):
        held = heldout_prediction(state, val, train=train)
        metrics["data_heldout"] = {**{k: v for k, v in held.items() if k != "per_trial"},
                                   "per_trial": {str(k): v for k, v in held["per_trial"].items()}}
    metrics["resolution"] = bem_resolution(state, train)   # do the data resolve the BEM at all (model-free)?
    metrics["support"] = design_support(train, model=state)           # are its queries supported by the data jointly?
    slices = bem_slices(state, train)
    metrics["bem_slices"] = {"summary": slices["summary"],
                             "slices": [{k: v for k, v in sl.items() if not hasattr(v, "shape")} for sl in slices["slices"]]}
    fig = bem_slice_figure(slices, out / "bem_slices.png", unactuated=unactuated)
    writer.add_figure("bem/slices", fig, 0)
    return metrics


def _collected_excursion(meta) -> tuple[float, ...] | None:
    """The per-direction extents the data were collected with (``collect.excursion`` in the trajectory's provenance,
    written by :func:`~bemlearn.sim.collect.collect`); ``None`` for data from elsewhere or without them."""
    cc = (meta.extra or {}).get("collect_config") or {}
    ext = cc.get("excursion") if isinstance(cc, dict) else None
    return tuple(float(x) for x in ext) if ext else None


def _model_metrics(state: PredictorState, truth_robot: ControlRobot, ecfg: EvaluationConfig, unactuated: str, unit: str,
                   out: Path, writer, *, excursion: tuple[float, ...] | None = None) -> dict:
    """Learned vs model-based BEM along held-out references and over the design region (writes
    ``reliability.png``, ``bem_validation.png``, ``design_region.png``); ``excursion``: the data's collection extents,
    which the design region's box then covers (:func:`~bemlearn.pipeline.design_evaluation.design_grid`)."""
    ev = evaluate_bem(state, truth_robot, held_out_references(ecfg, truth_robot.m), duration_s=ecfg.duration_s, rate_hz=ecfg.rate_hz)
    metrics: dict = {"bem_heldout": ev.as_dict()}
    for k in ("rmse", "max_abs", "coverage_2sigma_latent", "coverage_2sigma_predictive", "coverage_2sigma_band"):
        writer.add_scalar(f"bem/{k}", getattr(ev, k), 0)
    writer.add_figure("bem/reliability", reliability_figure(ev.reliability), 0)
    with atomic_path(out / "reliability.png") as tmp:
        reliability_figure(ev.reliability).savefig(tmp, dpi=110)
    fig = _bem_figure(ev.curves, unactuated, unit)
    writer.add_figure("bem/learned_vs_model", fig, 0)
    with atomic_path(out / "bem_validation.png") as tmp:
        fig.savefig(tmp, dpi=110)
    if ecfg.design_points > 0:   # over the whole design region (D1, D2), not only along the references
        from bemlearn.pipeline.design_evaluation import design_grid, design_region_figure, evaluate_design_region

        dr = evaluate_design_region(state, design_grid(truth_robot, ecfg, n_points=ecfg.design_points, seed=ecfg.seed, excursion=excursion))
        metrics["bem_design_region"] = dr.as_dict()
        for k in ("rmse", "max_abs", "gain"):
            writer.add_scalar(f"bem/design_region_{k}", getattr(dr, k), 0)
        fig = design_region_figure(dr, unactuated, unit)
        writer.add_figure("bem/design_region", fig, 0)
        with atomic_path(out / "design_region.png") as tmp:
            fig.savefig(tmp, dpi=110)
    return metrics


class _Named:
    """``robot`` under another name (an MJCF given by path is matched by its joints, not its label)."""

    def __init__(self, robot: BalanceRobot, name: str) -> None:
        self.name, self.joint_names, self.unactuated_name = name, robot.joint_names, robot.unactuated_name
        self.actuated_names = robot.actuated_names


def _bem_figure(curves: BEMCurves, qu_name: str, unit: str = "rad"):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, model, mean, std = curves.t, curves.model, curves.mean, curves.band_std
    fig, ax = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    ax[0].plot(t, model, "k", lw=1.2, label="model-based BEM (eq. 9)")
    ax[0].plot(t, mean, "C1--", lw=1.2, label="learned BEM μ(x₀ᵉ) (eq. 14)")
    ax[0].fill_between(t, mean - 2 * std, mean + 2 * std, color="C1", alpha=0.25, label="±2σ (calibrated band, eq. B1)")
    ax[0].set_ylabel(f"{qu_name} ({unit})")
    ax[0].legend(fontsize=8)
    ax[0].set_title("held-out composite-sinusoid reference")
    ax[1].plot(t, mean - model, "C3", lw=1)
    ax[1].fill_between(t, -2 * std, 2 * std, color="C1", alpha=0.2)
    ax[1].set_ylabel(f"error ({unit})")
    ax[1].set_xlabel("t (s)")
    fig.tight_layout()
    return fig
