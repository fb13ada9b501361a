"""The biped pipeline of Section IV-B: walking data → learned torso BEM → walks with it → GPDM.

``bemlearn run configs/biped.yaml`` (:func:`run_biped_pipeline`) fills a run folder:

1. **collect** — training walks in MuJoCo (:func:`collect_walks`): both gaits, seeded
   step lengths, torso gains and initial perturbations, the excitation of
   :class:`~bemlearn.apps.biped.controller.WalkExcitation` on; falls are kept.  The walker's
   sensor model gives quantized angles at the control rate (115 Hz) → ``data.npz``
   (stance-relative q1..q5, one trial per step) and its ground truth ``data.truth.npz``.
2. **dataset** (:func:`walking_gp_data`) — q̇, q̈ estimated per step from the quantized
   angles, each step cut again at the velocity jumps the angles show (the touchdown's tail,
   swing-foot scuffs; ``dataset.jump_factor``), so that no window spans one; samples ``skip_after_impact`` … ``len − skip_before_impact`` of each step
   (single support away from the impacts, where the pinned model of eq. 1 holds);
   x = [q̈_a, q̇_a, q_a, q̈_1, q̇_1] ∈ R^14, y = q1 (eq. 11); N drawn at random.
3. **train** (:func:`train_walking_gp`) — the GP of eq. (11)–(12) → ``gp/checkpoint.pt``
   (robot ``biped``, m = 4) → ``gp/bem_predictor.pt`` (TorchScript, ``bem_mean``).
4. **evaluate** (:func:`heldout_bem`) — walks with other seeds and no excitation (model
   BEM in the loop): the exported μ(x_0^e) (eq. 14) against the model-based BEM (eq. 9)
   at the controller's BEM queries.
5. **loop** — walks with the exported predictor's ``bem_mean`` in the loop, both gaits.
6. **GPDM** (eq. 16–17) on the robot's steps and on the human gait; χ = c·(q − q̄),
   χ̂ = c·([q_a, μ(x_0^e)] − q̄); Fig. 4 / Fig. 5 equivalents and ``report.md``
   (:mod:`bemlearn.apps.biped.report`).

Modules: :mod:`~bemlearn.apps.biped.config` (configs), :mod:`~bemlearn.apps.biped.data` (1–2),
:mod:`~bemlearn.apps.biped.bem` (3–4, on the core's shared train → export stage), here (5),
:mod:`~bemlearn.apps.biped.report` (6).  The measured findings on the learned torso BEM (why it
misses 0.02 rad, every lever tried) are in ``docs/biped.md``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from pathlib import Path
from typing import Literal, cast

from bemlearn.apps.biped.bem import bem_errors, heldout_bem, heldout_walks, train_walking_gp
from bemlearn.apps.biped.config import (
    BipedConfig,
    BipedEvaluateConfig,
    BipedGPDMConfig,
    WalkCollectConfig,
    WalkDatasetConfig,
    is_biped_config,
    load_biped_config,
)
from bemlearn.apps.biped.controller import WalkExcitation
from bemlearn.apps.biped.data import collect_walks, concat_trajectories, walking_gp_data, walks_trajectories
from bemlearn.config import save_yaml
from bemlearn.errors import DataError

__all__ = ["WalkCollectConfig", "WalkDatasetConfig", "BipedEvaluateConfig", "BipedGPDMConfig", "BipedConfig",
           "load_biped_config", "is_biped_config", "collect_walks", "concat_trajectories", "walks_trajectories",
           "walking_gp_data",
           "train_walking_gp", "heldout_walks", "bem_errors", "heldout_bem", "run_biped_pipeline"]

log = logging.getLogger(__name__)


def run_biped_pipeline(config: BipedConfig, out_dir: str | Path | None = None, *, progress: bool = True) -> Path:
    """Run every stage (module docstring) into ``out_dir`` (default ``runs/biped-<timestamp>``); returns it."""
    from bemlearn.apps.biped.gpdm_study import fit_gpdm_logged, human_gait_sequences, latent_study
    from bemlearn.apps.biped.report import biped_verdict, write_biped_report
    from bemlearn.apps.biped.walker import simulate_walk, walk_trajectories
    from bemlearn.data import ground_truth_path, write_trajectory
    from bemlearn.files import atomic_write_text

    out = Path(out_dir) if out_dir else Path("runs") / time.strftime("biped-%Y%m%d-%H%M%S")
    out.mkdir(parents=True, exist_ok=True)
    save_yaml(config, out / "config.yaml")
    t0 = time.perf_counter()
    log.info("[1/6] training walks")
    walks = collect_walks(config, progress=progress)
    data, truth = walks_trajectories(walks)
    data_path = write_trajectory(data, out / "data.npz")
    write_trajectory(truth, ground_truth_path(data_path))
    info = {"walks": len(walks), "fell": int(sum(w.fell for w in walks)), "steps": int(sum(len(w.steps) for w in walks)),
            "samples": data.n_samples, "rate_hz": data.meta.sample_rate_hz}
    log.info("[2/6] learned torso BEM (eq. 11–14)")
    runs = {"gp": config.dataset}
    if config.evaluate.oracle:
        runs["gp_oracle"] = dataclasses.replace(config.dataset, derivatives="truth")
    learned = {}
    walks_out = heldout_walks(config, progress=progress)
    for name, dcfg in runs.items():
        X, y, rep = walking_gp_data(data, truth, dcfg)
        fit = train_walking_gp(X, y, out / name, config=config.train, data_path=data_path, progress=progress,
                               extra={"dataset": rep, "derivatives": dcfg.derivatives})
        heldout = heldout_bem(out / name / "bem_predictor.pt", config, walks=walks_out)
        learned[name] = {"derivatives": dcfg.derivatives, "dataset": rep, "fit": fit, "heldout": heldout}
    log.info("[3/6] walks with the exported predictor in the loop")
    predictor = out / "gp" / "bem_predictor.pt"
    loop = {}
    for gait in config.evaluate.gaits:
        cfg = dataclasses.replace(config.walk, duration_s=config.evaluate.loop_duration_s, max_steps=0,
                                  bem_source="predictor", predictor=str(predictor),
                                  gait=dataclasses.replace(config.walk.gait, kind=cast(Literal["default", "human"], gait)), excitation=WalkExcitation())
        loop[gait] = simulate_walk(cfg, progress=progress)
        write_trajectory(walk_trajectories(loop[gait])[0], out / f"walk_{gait}.npz")
    log.info("[4/6] GPDM on the robot's steps and on the human gait (eq. 16–17)")
    g = config.gpdm
    r = loop["default"] if "default" in loop else next(iter(loop.values()))
    sel = range(g.first_step, min(g.first_step + g.steps, len(r.steps)))
    if len(sel) < 1:
        raise DataError(f"gpdm: the walk with the predictor has {len(r.steps)} steps; need more than first_step = {g.first_step}")
    q_steps = walk_trajectories(r)[0]
    Q_robot = [q_steps.q[(q_steps.trial == i)] for i in sel]
    robot_gpdm = fit_gpdm_logged(Q_robot, out / "gpdm" / "robot", config=g.fit, threads=g.threads, progress=progress)
    human_Q, human_phase = human_gait_sequences(g.human)
    human_gpdm = fit_gpdm_logged(human_Q, out / "gpdm" / "human", config=g.fit, threads=g.threads, progress=progress)
    log.info("[5/6] latent study and figures")
    study = latent_study(loop, robot_gpdm, human_gpdm, human_Q, human_phase, first_step=g.first_step,
                         bins=g.phase_bins, out=out)
    log.info("[6/6] report")
    metrics = {"data": info, "learned": learned, "study": study, "seconds": time.perf_counter() - t0,
               "loop": {k: {m: v for m, v in w.metrics.items()} for k, w in loop.items()}}
    metrics["verdict"] = biped_verdict(metrics)
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=2, default=float))
    write_biped_report(out, metrics, config)
    log.info("biped pipeline done in %.0f s: %s", metrics["seconds"], out / "report.md")
    return out
