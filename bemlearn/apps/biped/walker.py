"""Walking simulation of the planar 5-link biped in MuJoCo (paper Section IV-B).

The plant is the floating planar walker (``assets/biped_planar.xml``: torso slides in x, z
and pitches q1, point feet with contact).  The controller
(:class:`~bemlearn.apps.biped.controller.WalkingController`) runs at ``rate_hz`` (115 Hz) with
the torque held over ``1/(rate · timestep)`` physics steps, and sees quantized angles and
a filtered velocity estimate (:mod:`bemlearn.data.sensors`), never the base position.

A step ends when the swing foot touches the ground (foot site at most ``contact_height``
above its sphere radius, like a foot switch) after phase ``min_step_phase``; the legs then
swap roles.  A run ends at ``duration_s``, after ``max_steps`` steps, or with a fall (hip
below ``fall_hip_height``, |q1| above ``fall_torso``, or no step for ``max_step_time``).

Afterwards the feet are located by batched pytorch-kinematics forward kinematics of the
logged states (:func:`foot_positions`, :mod:`bemlearn.apps.biped.walk_kinematics`), giving step
lengths and swing-foot clearance (:func:`walk_metrics`, :mod:`bemlearn.apps.biped.walk_metrics`).
:func:`walk_trajectories`, :func:`stance_per_sample` and :func:`walking_data`
(:mod:`bemlearn.apps.biped.walk_data`) turn the logged run into trajectory files and GP inputs
x ∈ R^14 (eq. 11, n = 5); all are re-exported here, as are the options (:class:`WalkConfig`,
:mod:`~bemlearn.apps.biped.walk_config`) and the log (:class:`WalkResult`, :mod:`~bemlearn.apps.biped.walk_result`).
"""

from __future__ import annotations

import logging
import time

import mujoco
import numpy as np
from tqdm.auto import tqdm

from bemlearn.apps.biped.assets import planar_model
from bemlearn.apps.biped.controller import WalkingController
from bemlearn.apps.biped.gait import build_gait
from bemlearn.apps.biped.walk_config import WalkConfig, load_walk_config
from bemlearn.apps.biped.walk_data import stance_per_sample, walk_trajectories, walking_data
from bemlearn.apps.biped.walk_kinematics import FOOT_SITES, foot_positions
from bemlearn.apps.biped.walk_metrics import walk_metrics
from bemlearn.apps.biped.walk_result import WalkResult
from bemlearn.control.bem_sources import make_bem_source
from bemlearn.data.sensors import Encoder, FilteredDifferentiator
from bemlearn.errors import ConfigError

__all__ = ["WalkConfig", "WalkResult", "load_walk_config", "simulate_walk", "foot_positions", "walk_metrics",
           "walk_trajectories", "stance_per_sample", "walking_data"]

log = logging.getLogger(__name__)


def _initial_state(model, data, gait, config: WalkConfig, rng: np.random.Generator) -> None:
    """Put the walker on the gait at ``initial_phase`` with leg 1 pinned (at rest) on the ground."""
    s0, span = config.initial_phase, gait.theta_end - gait.theta_start
    q = gait.posture(s0)
    if config.initial_noise > 0:  # off the gait at the same phase: q1 absorbs the change of cᵀq
        dq = rng.normal(0.0, config.initial_noise, 4)
        q[1:] += dq
        q[0] -= gait.c[1:] @ dq / gait.c[0]
    sd = config.initial_phase_rate / span
    qd = np.r_[0.0, gait.evaluate(s0)[1] * sd]
    qd[0] = (config.initial_phase_rate - gait.c[1:] @ qd[1:]) / gait.c[0]
    data.qpos[:] = np.r_[0.0, 0.0, q]
    data.qvel[:] = np.r_[0.0, 0.0, qd]
    mujoco.mj_kinematics(model, data)
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "foot1")
    radius = float(model.geom_size[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "foot1"), 0])
    data.qpos[0] -= data.site_xpos[sid, 0]
    data.qpos[1] += radius - data.site_xpos[sid, 2]
    mujoco.mj_forward(model, data)
    jac = np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jac, None, sid)
    J = jac[[0, 2]]
    data.qvel[:2] = np.linalg.solve(J[:, :2], -J[:, 2:] @ qd)
    mujoco.mj_forward(model, data)


def simulate_walk(config: WalkConfig | None = None, *, bem=None, progress: bool = True) -> WalkResult:
    """Walk the planar biped (module docstring) and return logs and metrics.

    Args:
        config: :class:`WalkConfig` (default: ``WalkConfig()``).
        bem: a BEM source object overriding ``config.bem_source`` (``x (B, 12) -> (B,)``).
        progress: show a tqdm bar.
    """
    from bemlearn.robots import load
    from bemlearn.robots.protocol import ControlRobot

    config = WalkConfig() if config is None else config
    nominal = load("biped")
    assert isinstance(nominal, ControlRobot)
    gait = build_gait(config.gait)
    if bem is None:
        bem = make_bem_source(config.bem_source, robot=nominal, predictor=config.predictor)
    ctrl = WalkingController(nominal, bem, gait, gains=config.gains, excitation=config.excitation)
    model = planar_model()
    data = mujoco.MjData(model)
    dt = 1.0 / config.rate_hz
    substeps = int(round(dt / model.opt.timestep))
    if abs(substeps * model.opt.timestep - dt) > 1e-9:
        raise ConfigError(f"walk: 1/rate_hz = {dt} s is not a whole number of physics steps ({model.opt.timestep} s)")
    rng = np.random.default_rng(config.seed)
    _initial_state(model, data, gait, config, rng)
    enc = Encoder(config.sensor, rng)
    vf = FilteredDifferentiator(5, cutoff=config.sensor.velocity_cutoff, dt=dt)
    vf.v = data.qvel[2:].copy()
    sites = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, n) for n in FOOT_SITES]
    hip = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "hip")
    radius = float(model.geom_size[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "foot1"), 0])
    T = int(round(config.duration_s * config.rate_hz))
    buf = {k: np.empty((T, w)) for k, w in (("qpos", 7), ("qvel", 7), ("qacc", 7), ("q_meas", 5), ("qd_est", 5),
                                           ("u", 4), ("bem_x", 12))}
    stance_log, phase, qu_e = np.empty(T, dtype=np.int64), np.empty(T), np.empty(T)
    stance, steps, touch, last_step, fell, k = 1, [], [], 0.0, False, 0
    wall = 0.0
    bar = tqdm(total=T, desc="walk", unit="tick", disable=not progress, mininterval=0.5)
    for k in range(T):
        t = k * dt
        if (data.site_xpos[hip, 2] < config.fall_hip_height or abs(data.qpos[2]) > config.fall_torso
                or t - last_step > config.max_step_time):
            fell = True
            break
        y = enc(data.qpos[2:].copy())
        v = vf(y)
        c0 = time.perf_counter()
        u, info = ctrl(y, v, stance, t)
        wall += time.perf_counter() - c0
        data.ctrl[:] = u
        mujoco.mj_forward(model, data)
        buf["qpos"][k], buf["qvel"][k], buf["qacc"][k] = data.qpos, data.qvel, data.qacc
        buf["q_meas"][k], buf["qd_est"][k], buf["u"][k], buf["bem_x"][k] = y, v, u, info["bem_x"]
        stance_log[k], phase[k], qu_e[k] = stance, info["s"], info["qu_e"]
        for _ in range(substeps):
            mujoco.mj_step(model, data)
        sw, st = sites[2 - stance], sites[stance - 1]
        if (data.site_xpos[sw, 2] <= radius + config.contact_height and info["s"] >= config.min_step_phase
                and data.site_xpos[sw, 0] > data.site_xpos[st, 0]):
            steps.append(k)
            touch.append(data.qpos.copy())
            stance, last_step = 3 - stance, t + dt
            if config.max_steps and len(steps) >= config.max_steps:
                k += 1
                break
        if k % 115 == 0:
            bar.update(115 if k else 1)
    else:
        k = T
    bar.close()
    logs = {name: arr[:k] for name, arr in buf.items()}
    result = WalkResult(
        np.arange(k) * dt, logs["qpos"], logs["qvel"], logs["qacc"], logs["q_meas"], logs["qd_est"], logs["u"],
        stance_log[:k], phase[:k], qu_e[:k], logs["bem_x"], np.asarray(steps, dtype=np.int64),
        np.reshape(touch, (-1, 7)), fell, {}, config,
    )
    result.metrics.update(walk_metrics(result))
    result.metrics.update(gait=gait.name, bem_source=getattr(bem, "name", type(bem).__name__),
                          bem_invalid=ctrl.bem_invalid, controller_us_per_tick=1e6 * wall / max(k, 1))
    log.info("walked %d steps in %.2f s (fell: %s)", len(steps), k * dt, fell)
    return result
