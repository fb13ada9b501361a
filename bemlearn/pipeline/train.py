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
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from bemlearn.config import save_yaml
from bemlearn.data import build_datasets, read_trajectory
from bemlearn.data.validation import check_robot
from bemlearn.errors import ConfigError, EnvironmentProblem
from bemlearn.files import atomic_write_text, file_sha256
from bemlearn.pipeline.config import PipelineConfig
from bemlearn.pipeline.results import TrainResult
from bemlearn.pipeline.run_metrics import RunMetrics
from bemlearn.pipeline.train_metrics import evaluate_trained
from bemlearn.pipeline.uncertainty import calibrate_band
from bemlearn.robots.protocol import BalanceRobot
from bemlearn.threads import torch_threads
from bemlearn.units import gp_input_units

if TYPE_CHECKING:
    from bemlearn.data.trajectory import Trajectory
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
    on_checkpoint: Callable[[Path], None] | None = None,
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
        on_checkpoint: called with the path of ``checkpoint.pt`` once it is written (not after Ctrl-C),
            before the evaluation of the trained GP: a run starts its export and learned closed loop
            there, beside the evaluation.  An exception it raises fails training; a caller that wants
            the failure reported as its own stage catches it (:func:`~bemlearn.pipeline.run.run_pipeline`).
    """
    with torch_threads(threads):
        return _train_run(config, data_path, out_dir, device=device, resume=resume, progress=progress, trajectory=trajectory,
                          loaded=loaded, part_of_run=part_of_run, on_checkpoint=on_checkpoint)


def _train_run(config: PipelineConfig, data_path, out_dir, *, device, resume, progress, trajectory, loaded,
               part_of_run, on_checkpoint) -> TrainResult:
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
        check_robot(traj.meta, robot, source=str(data_path), match_name=ref.registry)
    else:
        ref = dataclasses.replace(ref, name=traj.meta.robot or ref.name)
    ds = build_datasets(traj, config.dataset, progress=progress)
    train, val = ds.train, ds.val
    log.info("dataset: %d training points, %d validation points; %s", len(train), len(val), ds.report)
    names = train.input_names
    meta = traj.meta
    kinds = robot.coordinate_kinds if robot is not None else meta.joint_kinds  # model-free: as the file records them
    units = gp_input_units(names, meta.joint_names, kinds)
    left_out = _left_out_columns(config.dataset.cyclic, meta.actuated_names)
    writer = SummaryWriter(str(out / "tb"))
    stage = fit_bem_gp(
        train.x, train.y, out, normalization=train.normalization, input_names=names, units=units, config=gp_cfg,
        provenance=CheckpointProvenance(robot=ref.to_dict(), joint_names=meta.joint_names, unactuated_name=meta.unactuated,
                                        data_sha256=file_sha256(data_path),
                                        extra={"data_file": str(data_path), "dataset_report": ds.report}),
        writer=writer, resume=resume, progress=progress,
        calibrate=lambda st: calibrate_band(st, traj, ds.config, train_rows=train.row, seed=config.dataset.seed),  # std of eq. (B1)
        left_out=left_out,
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
    if on_checkpoint is not None:
        on_checkpoint(stage.checkpoint)
    try:   # the checkpoint exists: a failure from here on keeps it, and metrics.json says where the run stopped
        evaluate_trained(stage, train, val, traj, truth_robot, config.evaluate, gp_cfg, units, out, writer, metrics)
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


def _left_out_columns(cyclic: tuple[str, ...] | None, actuated: tuple[str, ...]) -> tuple[str, ...]:
    """The GP input columns ``q_<joint>`` of ``dataset.cyclic`` (``None``: none).

    Raises:
        ConfigError: a name that is not an actuated joint of the data, naming the key and the joints.
    """
    if not cyclic:
        return ()
    bad = [j for j in cyclic if j not in actuated]
    if bad:
        raise ConfigError(f"dataset.cyclic: {bad} are not actuated joints of the data; expected names among {list(actuated)}")
    return tuple(f"q_{j}" for j in cyclic)   # gp_input_names: one q_<joint> column per actuated joint
