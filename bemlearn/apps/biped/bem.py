"""The learned torso BEM of the biped: GP fit of eq. (11)–(12), export, held-out evaluation.

Stages 3–4 of :mod:`bemlearn.apps.biped.pipeline`: :func:`train_walking_gp` fits the GP and
exports its predictor; :func:`heldout_walks` simulates walks with other seeds (model BEM in
the loop), and :func:`bem_errors` / :func:`heldout_bem` score a learned μ(x_0^e) (eq. 14)
against the model-based BEM (eq. 9) at the controller's queries.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from bemlearn.apps.biped.config import BipedConfig
from bemlearn.apps.biped.controller import WalkExcitation
from bemlearn.apps.biped.walker import WalkResult
from bemlearn.fitting.gp_config import GPConfig

__all__ = ["train_walking_gp", "heldout_walks", "bem_errors", "heldout_bem"]


def train_walking_gp(X: np.ndarray, y: np.ndarray, out_dir: str | Path, *, config: GPConfig, data_path: str | Path,
                     extra: dict | None = None, progress: bool = True) -> dict:
    """Fit the GP of eq. (11) on ``X (N, 14)``, ``y (N,)`` rad with the core's shared stages
    (:func:`~bemlearn.pipeline.gp_stage.fit_bem_gp`, :func:`~bemlearn.export.export_run`).

    Writes ``out_dir/{checkpoint.pt, bem_predictor.pt, tb/, metrics.json}``; returns the metrics.
    """
    from torch.utils.tensorboard import SummaryWriter

    from bemlearn.data import Normalization, gp_input_names
    from bemlearn.export.export_run import export_run
    from bemlearn.pipeline.gp_stage import fit_bem_gp
    from bemlearn.pipeline.train import file_sha256
    from bemlearn.robots import resolve_robot
    from bemlearn.units import gp_input_units

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    robot, ref = resolve_robot("biped")
    joints, qu = robot.joint_names, robot.unactuated_name
    names = gp_input_names(joints, qu)
    x, yt = torch.from_numpy(X), torch.from_numpy(y)
    writer = SummaryWriter(str(out / "tb"))
    stage = fit_bem_gp(x, yt, out, normalization=Normalization.fit(x, yt, names=names), input_names=names,
                       units=gp_input_units(names, joints, robot.coordinate_kinds), config=config,
                       robot=ref.to_dict(), joint_names=joints, unactuated_name=qu, data_sha256=file_sha256(data_path),
                       extra={"data_file": str(data_path), **(extra or {})}, writer=writer, progress=progress)
    writer.close()
    if stage.interrupted:
        raise KeyboardInterrupt
    export_run(out, fmt="torchscript")
    state = stage.state
    metrics = {"fit": stage.fit, "n_train": len(y), "noise_std_rad": float(state.y_std * state.noise.sqrt()),
               "lengthscale_physical": stage.lengthscale_physical}
    from bemlearn.files import atomic_write_text

    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=2, default=float))
    return metrics


def _step_position(result) -> np.ndarray:
    """Ticks since the last touchdown, ``(T,)`` (the first step counts from the start)."""
    starts = np.r_[0, result.steps + 1]
    k = np.arange(len(result.t))
    return k - starts[np.searchsorted(starts, k, side="right") - 1]


def heldout_walks(config: BipedConfig, *, progress: bool = True) -> dict[str, WalkResult]:
    """The held-out walks of ``config.evaluate``: per gait, ``heldout_duration_s`` with the model
    BEM in the loop, seed ``evaluate.seed + i``, no excitation."""
    from bemlearn.apps.biped.walker import simulate_walk

    out = {}
    for i, gait in enumerate(tqdm(config.evaluate.gaits, desc="held-out walks", disable=not progress)):
        w = config.walk
        cfg = dataclasses.replace(w, duration_s=config.evaluate.heldout_duration_s, max_steps=0, bem_source="model",
                                  gait=dataclasses.replace(w.gait, kind=gait), seed=config.evaluate.seed + i,
                                  initial_noise=config.collect.initial_noise, excitation=WalkExcitation())
        out[gait] = simulate_walk(cfg, progress=False)
    return out


def bem_errors(bem, walks: dict[str, WalkResult], *, skip_after_impact: int) -> dict:
    """Learned BEM ``bem(x (B, 12)) -> (B,)`` against the model-based BEM (eq. 9) at each walk's
    controller queries x^d = [q̈_a^d, q̇_a^d, q_a^d]: per gait the RMSE and max error over all
    ticks and the RMSE over single support (``skip_after_impact`` ticks after each touchdown
    left out), rad."""
    out = {}
    for gait, r in walks.items():
        e = np.asarray(bem(r.bem_x)).reshape(-1) - r.qu_e
        ss = _step_position(r) >= skip_after_impact
        out[gait] = {"rmse": float(np.sqrt(np.mean(e**2))), "max_abs": float(np.abs(e).max()),
                     "rmse_single_support": float(np.sqrt(np.mean(e[ss] ** 2))), "ticks": int(len(e)),
                     "steps": len(r.steps), "fell": bool(r.fell), "model_bem_std": float(r.qu_e.std())}
    return out


def heldout_bem(predictor_path: str | Path, config: BipedConfig, *, walks: dict[str, WalkResult] | None = None,
                progress: bool = True) -> dict:
    """Learned μ(x_0^e) (eq. 14) of the exported predictor vs the model-based BEM (eq. 9), held-out walks.

    ``walks``: from :func:`heldout_walks` (simulated here if ``None``).  Returns
    :func:`bem_errors` of the predictor's ``bem_mean``.
    """
    from bemlearn.control.bem_sources import PredictorBEM
    from bemlearn.robots import load

    pred = PredictorBEM(predictor_path, robot=load("biped"))
    walks = heldout_walks(config, progress=progress) if walks is None else walks
    return bem_errors(pred, walks, skip_after_impact=config.evaluate.skip_after_impact)
