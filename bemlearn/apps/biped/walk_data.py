"""Walking data: a logged biped walk as trajectory files and GP training pairs (paper Section IV-B).

:func:`walk_trajectories` logs the run in the trajectory format (pinned-model coordinates
q1..q5 relative to the stance leg, one trial per step, stance leg per trial in
``meta.extra``), :func:`stance_per_sample` reads the stance leg back per sample, and
:func:`walking_data` turns the ground truth into GP inputs x ∈ R^14 (eq. 11, n = 5).
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING

import numpy as np

from bemlearn.apps.biped.gait import stance_frame
from bemlearn.config import to_dict
from bemlearn.data.features import gp_inputs
from bemlearn.data.trajectory import Trajectory, TrajectoryMeta
from bemlearn.data.validation import MIN_TRIAL_SAMPLES
from bemlearn.errors import DataError, TrajectoryFormatError
from bemlearn.warnings import DataWarning, warn

if TYPE_CHECKING:
    from bemlearn.apps.biped.walk_result import WalkResult

__all__ = ["walk_trajectories", "stance_per_sample", "walking_data"]

log = logging.getLogger(__name__)


def walk_trajectories(result: WalkResult) -> tuple[Trajectory, Trajectory]:
    """The run as a data trajectory (measured angles, torques) and its ground truth (true q, q̇, q̈).

    Coordinates are the pinned model's q1..q5 *relative to the stance leg* (legs swapped
    while the walker stands on leg 2); each step is one trial (continuous coordinates
    within it), ``meta.extra["stance_leg"][trial]`` is the walker's stance leg, the last
    trial failed iff the walk fell.  Steps shorter than the minimum trial length are
    dropped and listed in ``meta.extra["dropped_steps"]`` (and logged).
    """
    r = result
    trial = np.searchsorted(r.steps, np.arange(len(r.t)), side="left")  # tick k > steps[i] → trial i + 1
    frame = lambda a, width: np.stack([stance_frame(np.r_[np.zeros(5 - width), row], leg)[5 - width:]  # noqa: E731
                                       for row, leg in zip(a, r.stance)]) if len(a) else a
    ids, counts = np.unique(trial, return_counts=True)
    short = [int(i) for i, c in zip(ids, counts) if c < MIN_TRIAL_SAMPLES]
    if short:
        warn(DataWarning, log, "walk_trajectories: dropping step(s) %s shorter than %d samples", short, MIN_TRIAL_SAMPLES)
    keep = ~np.isin(trial, short)
    last = int(trial[-1]) if len(trial) else 0
    stance_of = {int(i): int(r.stance[np.flatnonzero(trial == i)[0]]) for i in ids if int(i) not in short}
    meta = TrajectoryMeta(
        robot="biped", joint_names=("q1", "q2", "q3", "q4", "q5"), unactuated="q1",
        actuator_names=("hip1", "knee1", "hip2", "knee2"), sample_rate_hz=r.config.rate_hz,
        trial_failed={i: (r.fell and i == last) for i in stance_of},
        units={"t": "s", "q": "rad", "u": "N*m"},
        extra={"source": "bemlearn.apps.biped.walker", "coordinates": "pinned biped q1..q5, leg 1 = stance leg",
               "stance_leg": {str(i): leg for i, leg in stance_of.items()}, "dropped_steps": short,
               "metrics": {k: (v if not isinstance(v, float) or math.isfinite(v) else None)
                           for k, v in r.metrics.items() if isinstance(v, (int, float, str, bool))},
               "config": to_dict(r.config)},
    )
    t, tr = r.t[keep], trial[keep]
    u = frame(r.u, 4)[keep]
    data = Trajectory(t=t, trial=tr, q=frame(r.q_meas, 5)[keep], u=u, meta=meta)
    truth = Trajectory(t=t, trial=tr, q=frame(r.qpos[:, 2:], 5)[keep], u=u, meta=meta,
                       qd=frame(r.qvel[:, 2:], 5)[keep], qdd=frame(r.qacc[:, 2:], 5)[keep])
    return data, truth


def stance_per_sample(traj: Trajectory) -> np.ndarray:
    """The walker's stance leg (1 or 2) of every sample ``(T,)`` of a :func:`walk_trajectories` file."""
    try:
        legs = {int(k): int(v) for k, v in traj.meta.extra["stance_leg"].items()}
        return np.array([legs[int(i)] for i in traj.trial], dtype=np.int64)
    except (KeyError, TypeError, ValueError) as exc:
        raise TrajectoryFormatError(
            f"stance_per_sample: meta.extra['stance_leg'] must map every trial id to 1 or 2 ({exc!r})"
        ) from None


def walking_data(truth: Trajectory, *, skip_after_impact: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """GP training pairs from walking ground truth: x = [q̈_a, q̇_a, q_a, q̈_1, q̇_1] ∈ R^14, y = q1 (eq. 11).

    Args:
        truth: a ground-truth trajectory of :func:`walk_trajectories` (stance-relative q).
        skip_after_impact: samples dropped at the start of every step (the double-support
            transient, where the pinned model does not hold).

    Returns:
        ``X (N, 14)`` [rad/s², rad/s, rad, rad/s², rad/s] and ``y (N,)`` rad.
    """
    if not truth.has_ground_truth:
        raise DataError("walking_data: the trajectory has no qd/qdd (pass the ground-truth file, *.truth.*)")
    if truth.meta.joint_names != ("q1", "q2", "q3", "q4", "q5") or truth.meta.unactuated != "q1":
        raise DataError(f"walking_data: expected biped joints q1..q5 with q1 unactuated, got {truth.meta.joint_names}")
    assert truth.qd is not None and truth.qdd is not None  # checked above
    rows = np.concatenate([np.arange(s.rows.start + skip_after_impact, s.rows.stop) for s in truth.trial_slices()])
    X = gp_inputs(truth.q[rows], truth.qd[rows], truth.qdd[rows], unactuated_index=0)
    return X, truth.q[rows, 0].copy()
