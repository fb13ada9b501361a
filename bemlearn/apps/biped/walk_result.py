"""The log of a walking simulation of the planar biped (:func:`~bemlearn.apps.biped.walker.simulate_walk`).

:class:`WalkResult` is re-exported by :mod:`bemlearn.apps.biped.walker`; the trajectory files
(:mod:`~bemlearn.apps.biped.walk_data`) and metrics (:mod:`~bemlearn.apps.biped.walk_metrics`)
are computed from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bemlearn.apps.biped.walk_config import WalkConfig

__all__ = ["WalkResult"]


@dataclass(frozen=True)
class WalkResult:
    """Logged signals at the control rate (``(T, ·)``) and summary metrics.

    Attributes:
        t: (T,) s.  qpos, qvel, qacc: (T, 7) true [x m, z m, q1..q5 rad] and rates.
        q_meas, qd_est: (T, 5) what the controller saw, rad, rad/s.
        u: (T, 4) torques on [q2, q3, q4, q5], N·m.  stance: (T,) stance leg (1 or 2).
        phase: (T,) s.  qu_e: (T,) the BEM q1^e, rad.  bem_x: (T, 12) BEM queries.
        steps: (K,) tick index at which each step ended (its touchdown).
        touchdown_qpos: (K, 7) true state right after each touchdown.
        fell: whether the run ended in a fall.  metrics: :func:`~bemlearn.apps.biped.walk_metrics.walk_metrics`.
        config: the configuration of the run.
    """

    t: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    qacc: np.ndarray
    q_meas: np.ndarray
    qd_est: np.ndarray
    u: np.ndarray
    stance: np.ndarray
    phase: np.ndarray
    qu_e: np.ndarray
    bem_x: np.ndarray
    steps: np.ndarray
    touchdown_qpos: np.ndarray
    fell: bool
    metrics: dict
    config: WalkConfig
