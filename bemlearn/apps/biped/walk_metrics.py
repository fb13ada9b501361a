"""Walking metrics of a simulated biped run: steps, step length, speed, clearance, torso and BEM statistics.

The feet are located by batched forward kinematics of the logged states
(:func:`bemlearn.apps.biped.walk_kinematics.foot_positions`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np

from bemlearn.apps.biped.assets import planar_model
from bemlearn.apps.biped.walk_kinematics import foot_positions

if TYPE_CHECKING:
    from bemlearn.apps.biped.walk_result import WalkResult

__all__ = ["walk_metrics"]


def walk_metrics(result: WalkResult) -> dict:
    """Steps, step length (m), speed (m/s), step time (s), swing clearance (m), torso and BEM statistics (rad).

    Step lengths are the distances between successive stance feet at touchdown; the
    clearance of a step is the swing foot's highest point above its sphere radius.
    Torso statistics use the ticks after the first two steps (steady walking) when
    there are more than two steps.
    """
    r = result
    n = len(r.steps)
    out: dict = {"steps": n, "fell": r.fell, "duration_s": float(len(r.t) / r.config.rate_hz)}
    if len(r.t) == 0:
        return out
    model = planar_model()
    radius = float(model.geom_size[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "foot1"), 0])
    feet = foot_positions(r.qpos)
    touch = foot_positions(r.touchdown_qpos) if n else np.zeros((0, 2, 3))
    bounds = np.r_[0, r.steps + 1]
    lengths, clear = [], []
    for i, k in enumerate(r.steps):
        leg = r.stance[k]
        lengths.append(float(touch[i, 2 - leg, 0] - touch[i, leg - 1, 0]))
        clear.append(float(feet[bounds[i]:k + 1, 2 - leg, 2].max() - radius))
    steady = slice(r.steps[1] + 1, None) if n > 2 else slice(None)
    q1, que = r.qpos[steady, 2], r.qu_e[steady]
    out.update(
        step_length_mean=float(np.mean(lengths)) if lengths else float("nan"),
        step_length_std=float(np.std(lengths)) if lengths else float("nan"),
        step_time_mean=float(np.mean(np.diff(r.t[r.steps]))) if n > 1 else float("nan"),
        clearance_min=float(np.min(clear)) if clear else float("nan"),
        speed=float((r.qpos[-1, 0] - r.qpos[steady][0, 0]) / max(r.t[-1] - r.t[steady][0], 1e-9)),
        torso_mean=float(q1.mean()), torso_min=float(q1.min()), torso_max=float(q1.max()),
        torso_range=float(q1.max() - q1.min()),
        qu_e_mean=float(que.mean()), qu_e_min=float(que.min()), qu_e_max=float(que.max()),
        torque_max=float(np.abs(r.u).max()),
    )
    return out
