"""Walking data of the biped pipeline: training walks → one trajectory → GP pairs of eq. (11).

Stages 1–2 of :mod:`bemlearn.apps.biped.pipeline`: :func:`collect_walks` simulates the training
walks of ``collect:``, :func:`concat_trajectories` joins the walks' trajectories (one trial
per step; :func:`walks_trajectories` for a list of walks) and :func:`walking_gp_data` draws the training pairs x ∈ R^14, y = q1 of eq. (11).
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
from tqdm.auto import tqdm

from bemlearn.apps.biped.config import BipedConfig, WalkDatasetConfig
from bemlearn.apps.biped.walker import WalkResult
from bemlearn.data.trajectory import Trajectory
from bemlearn.errors import ArgumentError, DataError

__all__ = ["collect_walks", "concat_trajectories", "walks_trajectories", "segmented_states", "walking_gp_data"]

log = logging.getLogger(__name__)


def collect_walks(config: BipedConfig, *, progress: bool = True) -> list[WalkResult]:
    """The training walks of ``config.collect`` (:mod:`bemlearn.apps.biped.pipeline`), as ``WalkResult`` s."""
    from bemlearn.apps.biped.walker import simulate_walk

    c = config.collect
    rng = np.random.default_rng(c.seed)
    jobs = [(g, c.seed + i) for i, g in enumerate(g for g in c.gaits for _ in range(c.walks_per_gait))]
    walks = []
    for gait, seed in tqdm(jobs, desc="training walks", disable=not progress):
        kp_u = float(rng.uniform(*c.kp_u))
        g = config.walk.gait
        g = dataclasses.replace(g, kind=gait, design=dataclasses.replace(g.design, step_length=float(rng.uniform(*c.step_length))))
        cfg = dataclasses.replace(
            config.walk, duration_s=c.duration_s, max_steps=0, gait=g, bem_source="model", predictor=None,
            gains=dataclasses.replace(config.walk.gains, kp_u=kp_u, kd_u=2.0 * kp_u**0.5),
            initial_noise=c.initial_noise, seed=seed, excitation=dataclasses.replace(c.excitation, seed=seed))
        walks.append(simulate_walk(cfg, progress=False))
    log.info("collected %d walks: %d steps, %d fell", len(walks), sum(len(w.steps) for w in walks),
             sum(w.fell for w in walks))
    return walks


def concat_trajectories(parts: list[Trajectory]) -> Trajectory:
    """One trajectory of several ``walk_trajectories`` outputs, trial ids renumbered consecutively.

    ``meta.extra["stance_leg"]`` is merged, ``meta.extra["walks"]`` lists each walk's first trial id.
    """
    parts = [p for p in parts if p.n_samples]
    if not parts:
        raise DataError("concat_trajectories: no samples in any walk")
    arrays: dict[str, list] = {k: [] for k in ("t", "trial", "q", "u", "qd", "qdd")}
    failed, legs, firsts, offset = {}, {}, [], 0
    for p in parts:
        ids = {int(i): offset + j for j, i in enumerate(p.trial_ids)}
        firsts.append(offset)
        for k in arrays:
            v = getattr(p, k)
            arrays[k].append(np.vectorize(ids.get)(v) if k == "trial" else v)
        failed.update({ids[i]: f for i, f in p.meta.trial_failed.items() if i in ids})
        legs.update({str(ids[int(i)]): s for i, s in p.meta.extra.get("stance_leg", {}).items() if int(i) in ids})
        offset += len(ids)
    extra = {"source": "bemlearn.apps.biped.pipeline", "stance_leg": legs, "walks": firsts,
             "coordinates": parts[0].meta.extra.get("coordinates")}
    meta = dataclasses.replace(parts[0].meta, trial_failed=failed, extra=extra)
    truth = parts[0].has_ground_truth
    cat = {k: np.concatenate(v) for k, v in arrays.items() if truth or k not in ("qd", "qdd")}
    return Trajectory(meta=meta, **cat)


def walks_trajectories(walks: list[WalkResult]) -> tuple[Trajectory, Trajectory]:
    """``(measured, truth)``: the ``walk_trajectories`` of each walk, each side joined by
    :func:`concat_trajectories`."""
    from bemlearn.apps.biped.walker import walk_trajectories

    measured, truth = zip(*(walk_trajectories(w) for w in walks))
    return concat_trajectories(list(measured)), concat_trajectories(list(truth))


def segmented_states(data: Trajectory, est, config: WalkDatasetConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
    """q, q̇, q̈ and their validity ``(T, ·)`` estimated within segments, and a report of what it cost.

    The steps (trials, ended by the walker's foot strikes) are cut again wherever the measured
    angles jump in velocity (:func:`~bemlearn.data.velocity_jumps.detect_velocity_jumps`, factor
    ``config.jump_factor``, the encoder step as noise floor); the estimator then never smooths
    across a jump (:func:`~bemlearn.data.segmented_derivatives.estimate_segmented`, edges
    ``config.segment_edges``).
    """
    import math

    from bemlearn.data.segmented_derivatives import estimate_segmented
    from bemlearn.data.velocity_jumps import detect_velocity_jumps

    assert config.jump_factor is not None
    steps = data.quantization_steps()
    noise = np.array([(steps.get(j) or 0.0) / math.sqrt(12.0) for j in data.meta.joint_names])
    jumps = detect_velocity_jumps(data.q, data.meta.sample_rate_hz, trial=data.trial, noise_std=noise,
                                  factor=config.jump_factor)
    q, qd, qdd, valid, seg = estimate_segmented(data, est, events=jumps.starts, edges=config.segment_edges)
    report = {"jumps": jumps.count, "jump_threshold_rad_s": [float(v) for v in jumps.threshold],
              "jump_factor": jumps.factor, **seg.to_dict()}
    log.info("walking_gp_data: %d velocity jumps inside the steps (threshold %s rad/s); %d segments, %d too short "
             "(%d samples), %d samples next to a jump dropped, %d kept one-sided", jumps.count,
             " / ".join(f"{v:.2g}" for v in jumps.threshold), seg.segments, seg.segments_too_short, seg.rows_too_short,
             seg.rows_event_dropped, seg.rows_one_sided)
    return q, qd, qdd, valid, report


def walking_gp_data(data: Trajectory, truth: Trajectory | None, config: WalkDatasetConfig) -> tuple[np.ndarray, np.ndarray, dict]:
    """Training pairs of eq. (11) from walk trajectories (:mod:`bemlearn.apps.biped.pipeline`, step 2).

    Args:
        data: the measured trajectory (quantized q), stance-relative q1..q5.
        truth: its ground truth (used only with ``derivatives: truth``), or ``None``.
        config: :class:`WalkDatasetConfig`.

    Returns:
        ``X (N, 14)`` [rad/s², rad/s, rad, rad/s², rad/s], ``y (N,)`` rad, and a report of counts.
    """
    from bemlearn.data import gp_inputs, make_estimator
    from bemlearn.data.derivative_choice import estimate_states, resolve_estimator

    if data.meta.joint_names != ("q1", "q2", "q3", "q4", "q5") or data.meta.unactuated != "q1":
        raise DataError(f"walking_gp_data: expected biped joints q1..q5, q1 unactuated; got {data.meta.joint_names}")
    est = make_estimator(config.derivative, config.derivative_options, where="dataset.derivative_options")
    est, choice = resolve_estimator(est, data, qu_window=config.qu_window)   # e.g. the Gaussian's σ, from the steps
    need = max(est.min_samples(data.meta.sample_rate_hz), config.skip_after_impact + config.skip_before_impact + 1)
    keep = [s.trial_id for s in data.trial_slices() if s.n_samples >= need]
    report = {"steps": len(data.trial_ids), "steps_too_short": len(data.trial_ids) - len(keep), "estimator": repr(est)}
    if choice is not None:
        report["derivative_choice"] = choice.to_dict()
    if report["steps_too_short"]:
        log.info("walking_gp_data: %d of %d steps shorter than %d samples left out", report["steps_too_short"],
                 report["steps"], need)
    data = data.select_trials(keep)
    if config.derivatives == "truth":
        if truth is None or not truth.has_ground_truth:
            raise ArgumentError("dataset.derivatives = truth needs the ground-truth trajectory")
        truth = truth.select_trials(keep)
        assert truth.qd is not None and truth.qdd is not None  # has_ground_truth
        q, qd, qdd = truth.q, truth.qd, truth.qdd
    elif config.jump_factor is None:   # an estimator that smooths gives the smoothed q too (eq. G2)
        q, qd, qdd, valid = estimate_states(data, est)
    else:   # within segments: each step, cut again at the velocity jumps of the measured angles
        q, qd, qdd, valid, report["segments"] = segmented_states(data, est, config)
    X = gp_inputs(q, qd, qdd, unactuated_index=0)
    rows = np.concatenate([np.arange(s.rows.start + config.skip_after_impact, s.rows.stop - config.skip_before_impact)
                           for s in data.trial_slices()])
    if config.derivatives != "truth":
        report["invalid_edge_samples"] = int((~valid[rows]).sum())
        rows = rows[valid[rows]]
    inside = np.abs(q[rows, 0]) <= config.qu_window
    report["outside_qu_window"] = int((~inside).sum())
    rows = rows[inside]
    report["pool"] = int(len(rows))
    log.info("walking_gp_data: %d samples in the pool (%d with |q1| > %g rad left out)", len(rows),
             report["outside_qu_window"], config.qu_window)
    if len(rows) == 0:
        raise DataError("walking_gp_data: no samples left (steps too short for the skips, or |q1| above qu_window)")
    rng = np.random.default_rng(config.seed)
    if len(rows) > config.n_points:
        rows = np.sort(rng.choice(rows, config.n_points, replace=False))
    report["n_train"] = int(len(rows))
    return X[rows], q[rows, 0].copy(), report
