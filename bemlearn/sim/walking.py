"""Walking simulation of the planar 5-link biped in MuJoCo (paper Section IV-B).

The plant is the floating planar walker (``assets/biped_planar.xml``: torso slides in x, z
and pitches q1, point feet with contact).  The controller
(:class:`~bemlearn.control.walking.WalkingController`) runs at ``rate_hz`` (115 Hz) with
the torque held over ``1/(rate · timestep)`` physics steps, and sees quantized angles and
a filtered velocity estimate (:mod:`bemlearn.data.sensors`), never the base position.

A step ends when the swing foot touches the ground (foot site at most ``contact_height``
above its sphere radius, like a foot switch) after phase ``min_step_phase``; the legs then
swap roles.  A run ends at ``duration_s``, after ``max_steps`` steps, or with a fall (hip
below ``fall_hip_height``, |q1| above ``fall_torso``, or no step for ``max_step_time``).

Afterwards the feet are located by batched pytorch-kinematics forward kinematics of the
logged states (:func:`foot_positions`), giving step lengths and swing-foot clearance
(:func:`walk_metrics`).  :func:`walk_trajectories` logs the run in the trajectory format
(pinned-model coordinates q1..q5 relative to the stance leg, one trial per step, stance
leg per trial in ``meta.extra``) and :func:`walking_data` turns the ground truth into GP
inputs x ∈ R^14 (eq. 11, n = 5).
"""

from __future__ import annotations

import functools
import logging
import math
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import mujoco
import numpy as np
import torch
from tqdm.auto import tqdm

from bemlearn.config import ConfigError, from_dict, load_yaml, to_dict
from bemlearn.control.bem_sources import make_bem_source
from bemlearn.control.gait import GaitConfig, build_gait, stance_frame
from bemlearn.control.walking import WalkExcitation, WalkingController, WalkingGains
from bemlearn.data.features import gp_inputs
from bemlearn.data.sensors import Encoder, FilteredDifferentiator, SensorConfig
from bemlearn.data.trajectory import Trajectory, TrajectoryMeta
from bemlearn.data.validation import MIN_TRIAL_SAMPLES

__all__ = ["WalkConfig", "WalkResult", "load_walk_config", "simulate_walk", "foot_positions", "walk_metrics",
           "walk_trajectories", "stance_per_sample", "walking_data"]

log = logging.getLogger(__name__)

_FOOT_SITES = ("foot1", "foot2")


@dataclass(frozen=True)
class WalkConfig:
    """Walking simulation options (``walk:`` section of ``configs/biped.yaml``).

    Attributes:
        duration_s: simulated time limit, s.  rate_hz: control rate, Hz.
        max_steps: stop after this many steps (0: no limit).
        gait: which gait.  gains: controller gains.
        bem_source: ``"model"``, ``"zero"`` or ``"predictor"`` (torso BEM in the loop).
        predictor: exported predictor file for ``"predictor"``.
        sensor: encoder and velocity filter (set ``counts_per_rev: 0`` for exact angles).
        initial_phase: s at the start.  initial_phase_rate: ϑ̇ at the start, rad/s.
        initial_noise: std of a seeded perturbation of the initial actuated angles (at the same phase), rad.
        contact_height: foot-switch threshold above the foot sphere, m.
        min_step_phase: earliest phase at which a touchdown counts as a step.
        fall_hip_height: m.  fall_torso: rad.  max_step_time: s.
        seed: seeds the initial perturbation and the sensor noise.
        excitation: sum-of-sines excitation of the references (data collection; off by default).
    """

    duration_s: float = 10.0
    rate_hz: float = 115.0
    max_steps: int = 0
    gait: GaitConfig = field(default_factory=GaitConfig)
    gains: WalkingGains = field(default_factory=WalkingGains)
    bem_source: str = "model"
    predictor: str | None = None
    sensor: SensorConfig = field(default_factory=SensorConfig)
    initial_phase: float = 0.02
    initial_phase_rate: float = 1.0
    initial_noise: float = 0.0
    contact_height: float = 0.0005
    min_step_phase: float = 0.5
    fall_hip_height: float = 0.25
    fall_torso: float = 1.0
    max_step_time: float = 2.0
    seed: int = 0
    excitation: WalkExcitation = field(default_factory=WalkExcitation)

    def __post_init__(self) -> None:
        if self.duration_s <= 0 or self.rate_hz <= 0:
            raise ValueError(f"walk: duration_s and rate_hz must be > 0, got {self.duration_s}, {self.rate_hz}")
        if self.max_steps < 0:
            raise ValueError(f"walk.max_steps must be >= 0, got {self.max_steps}")


def load_walk_config(path) -> WalkConfig:
    """The ``walk:`` section of a biped config file (e.g. ``configs/biped.yaml``), parsed strictly.

    Other top-level sections are left to their own parsers; ``robot``, when present, must be ``biped``.
    """
    data = load_yaml(path)
    if data.get("robot", "biped") != "biped":
        raise ConfigError(f"{path}: robot: the walking simulation needs 'biped', got {data['robot']!r}")
    return from_dict(WalkConfig, data.get("walk"), where=f"{path}:walk")


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
        fell: whether the run ended in a fall.  metrics: :func:`walk_metrics`.
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


def _planar_model() -> mujoco.MjModel:
    from bemlearn.robots import asset_path

    return mujoco.MjModel.from_xml_path(str(asset_path("biped_planar.xml")))


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


def simulate_walk(config: WalkConfig = WalkConfig(), *, bem=None, progress: bool = True) -> WalkResult:
    """Walk the planar biped (module docstring) and return logs and metrics.

    Args:
        config: :class:`WalkConfig`.
        bem: a BEM source object overriding ``config.bem_source`` (``x (B, 12) -> (B,)``).
        progress: show a tqdm bar.
    """
    from bemlearn.robots import load

    nominal = load("biped")
    gait = build_gait(config.gait)
    if bem is None:
        bem = make_bem_source(config.bem_source, robot=nominal, predictor=config.predictor)
    ctrl = WalkingController(nominal, bem, gait, gains=config.gains, excitation=config.excitation)
    model = _planar_model()
    data = mujoco.MjData(model)
    dt = 1.0 / config.rate_hz
    substeps = int(round(dt / model.opt.timestep))
    if abs(substeps * model.opt.timestep - dt) > 1e-9:
        raise ValueError(f"walk: 1/rate_hz = {dt} s is not a whole number of physics steps ({model.opt.timestep} s)")
    rng = np.random.default_rng(config.seed)
    _initial_state(model, data, gait, config, rng)
    enc = Encoder(config.sensor, rng)
    vf = FilteredDifferentiator(5, cutoff=config.sensor.velocity_cutoff, dt=dt)
    vf.v = data.qvel[2:].copy()
    sites = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, n) for n in _FOOT_SITES]
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


@functools.lru_cache(maxsize=1)
def _kinematic_chain():
    """The planar walker re-rooted as a one-joint-per-body tree (x slide → z slide → torso), and its chain.

    :func:`bemlearn.robots.kinematics.chain_from_model` needs at most one joint per body;
    the walker's torso carries three (x, z, q1), so they are split into nested bodies with
    the same joint order and a negligible inertia (kinematics only).
    """
    from bemlearn.robots import asset_path
    from bemlearn.robots.kinematics import chain_from_model

    root = ET.fromstring(asset_path("biped_planar.xml").read_text())
    world = root.find("worldbody")
    torso = world.find("body[@name='torso']")
    joints = {j.get("name"): j for j in torso.findall("joint")}
    inertial = dict(pos="0 0 0", mass="1e-6", diaginertia="1e-9 1e-9 1e-9")
    base_x = ET.Element("body", name="base_x", pos=torso.get("pos", "0 0 0"))
    base_z = ET.SubElement(base_x, "body", name="base_z")
    for body, name in ((base_x, "x"), (base_z, "z")):
        torso.remove(joints[name])
        body.insert(0, joints[name])
        ET.SubElement(body, "inertial", **inertial)
    torso.set("pos", "0 0 0")
    world.remove(torso)
    base_z.append(torso)
    world.append(base_x)
    model = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
    return model, chain_from_model(model)


def foot_positions(qpos: np.ndarray) -> np.ndarray:
    """World positions of both foot sites, ``qpos (T, 7)`` [x, z, q1..q5] → ``(T, 2, 3)`` m.

    Batched forward kinematics with pytorch-kinematics (float64) on the re-rooted tree of
    :func:`_kinematic_chain`.
    """
    from bemlearn.robots.kinematics import frame_positions

    model, chain = _kinematic_chain()
    qpos = np.asarray(qpos, dtype=np.float64)
    if qpos.ndim != 2 or qpos.shape[1] != model.nq:
        raise ValueError(f"foot_positions: qpos must have shape (T, {model.nq}), got {qpos.shape}")
    fk = frame_positions(chain, model, torch.from_numpy(qpos), _FOOT_SITES)
    return np.stack([fk[n].numpy() for n in _FOOT_SITES], 1)


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
    model = _planar_model()
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
        log.warning("walk_trajectories: dropping step(s) %s shorter than %d samples", short, MIN_TRIAL_SAMPLES)
    keep = ~np.isin(trial, short)
    last = int(trial[-1]) if len(trial) else 0
    stance_of = {int(i): int(r.stance[np.flatnonzero(trial == i)[0]]) for i in ids if int(i) not in short}
    meta = TrajectoryMeta(
        robot="biped", joint_names=("q1", "q2", "q3", "q4", "q5"), unactuated="q1",
        actuator_names=("hip1", "knee1", "hip2", "knee2"), sample_rate_hz=r.config.rate_hz,
        trial_failed={i: (r.fell and i == last) for i in stance_of},
        units={"t": "s", "q": "rad", "u": "N*m"},
        extra={"source": "bemlearn.sim.walking", "coordinates": "pinned biped q1..q5, leg 1 = stance leg",
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
        raise ValueError(
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
        raise ValueError("walking_data: the trajectory has no qd/qdd (pass the ground-truth file, *.truth.*)")
    if truth.meta.joint_names != ("q1", "q2", "q3", "q4", "q5") or truth.meta.unactuated != "q1":
        raise ValueError(f"walking_data: expected biped joints q1..q5 with q1 unactuated, got {truth.meta.joint_names}")
    rows = np.concatenate([np.arange(s.rows.start + skip_after_impact, s.rows.stop) for s in truth.trial_slices()])
    X = gp_inputs(truth.q[rows], truth.qd[rows], truth.qdd[rows], unactuated_index=0)
    return X, truth.q[rows, 0].copy()
