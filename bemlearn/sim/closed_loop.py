"""Closed-loop MuJoCo simulation of the EIC controller with a BEM source in the loop.

The plant is the robot's MuJoCo model (the *true* system); the controller uses a nominal
model (optionally with mass/length errors) and sees only quantized angles and filtered
velocity estimates (:mod:`bemlearn.data.sensors`), at the control rate with the command
held between ticks.  A run stops early when |q_u − nominal| leaves ``fall_window``.

The commands come from the generic inverse of the model's actuators
(:class:`~bemlearn.control.actuator_inverse.MujocoActuatorInverse`); the metrics count the
ticks where the EIC rejected a non-finite or out-of-range BEM value (``bem_rejected``) or a
non-finite command (``command_rejected``).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, overload

import numpy as np
from tqdm.auto import tqdm

from bemlearn._lazy import lazy_module
from bemlearn.config import Limit, config_limits
from bemlearn.control.actuator_inverse import MujocoActuatorInverse
from bemlearn.control.bem_sources import BEMSource, make_bem_source
from bemlearn.control.eic import EICController, EICGains
from bemlearn.data.sensors import SensorConfig
from bemlearn.errors import ConfigError, RobotModelError
from bemlearn.robots.mujoco_robot import MujocoRobot
from bemlearn.robots.protocol import BalanceRobot
from bemlearn.robots.reference import CompositeSinusoid
from bemlearn.sim.plant import SensedPlant
from bemlearn.threads import torch_threads

if TYPE_CHECKING:
    import torch
else:
    torch = lazy_module("torch")

__all__ = ["ReferenceConfig", "NominalConfig", "SimulateConfig", "SimResult", "simulate", "nominal_robot"]


@dataclass(frozen=True)
class ReferenceConfig:
    """A composite sinusoid for each actuated joint (the same for all when m > 1).

    Attributes:
        amplitudes: per component, in the actuated joints' unit (rad or m) (``null``: derived from the model).
        frequencies_hz: per component, Hz (``null``: derived from the model).
        phases: per component, rad (``null``: derived from the model).
        offset: constant offset, in the actuated joints' unit (``null``: derived from the model).
    """

    amplitudes: tuple[float, ...] | None = None
    frequencies_hz: tuple[float, ...] | None = None
    phases: tuple[float, ...] | None = None
    offset: float | None = None

    def build(self, m: int) -> CompositeSinusoid:
        if self.amplitudes is None or self.frequencies_hz is None or self.phases is None or self.offset is None:
            raise ConfigError("simulate.reference: amplitudes, frequencies_hz, phases and offset must be set "
                             "(derive them from the model with bemlearn.pipeline.complete_section)")
        if not (len(self.amplitudes) == len(self.frequencies_hz) == len(self.phases)):
            raise ConfigError("reference: amplitudes, frequencies_hz and phases must have the same length")
        rows = lambda v: tuple(tuple(v) for _ in range(m))  # noqa: E731
        return CompositeSinusoid(rows(self.amplitudes), rows(self.frequencies_hz), rows(self.phases), (self.offset,) * m)

    def __post_init__(self) -> None:
        lengths = {k: len(v) for k, v in (("amplitudes", self.amplitudes), ("frequencies_hz", self.frequencies_hz),
                                          ("phases", self.phases)) if v is not None}
        if len(set(lengths.values())) > 1:
            raise ConfigError(f"amplitudes, frequencies_hz and phases need one entry per component, got lengths {lengths}")


@dataclass(frozen=True)
class NominalConfig:
    """The controller's model of the robot: relative parameter errors of the MJCF
    (:mod:`bemlearn.robots.variants`).

    Attributes:
        mass_scale: multiplies the masses (and inertias) of ``bodies``.
        length_scale: multiplies the lengths of ``bodies`` (inertias scale with length²).
        bodies: the scaled bodies (None: every body).
    """

    mass_scale: float = 1.0
    length_scale: float = 1.0
    bodies: tuple[str, ...] | None = None


config_limits(ReferenceConfig, amplitudes=Limit(min_len=1), frequencies_hz=Limit(ge=0, min_len=1, unit="Hz"), phases=Limit(min_len=1))
config_limits(NominalConfig, mass_scale=Limit(gt=0, le=1e3), length_scale=Limit(gt=0, le=1e3))


@dataclass(frozen=True)
class SimulateConfig:
    """Closed-loop simulation options (``simulate:`` section).

    Attributes:
        duration_s: simulated time, s.
        rate_hz: control rate, Hz (``null``: derived from the model): the collection's rate.
        bem_source: ``"predictor"``, ``"model"`` or ``"zero"`` (:data:`~bemlearn.control.bem_sources.BEM_SOURCES`).
        predictor: path of the exported ``bem_predictor.pt`` (for ``predictor``).
        reference: q_a^d(t).
        gains: EIC gains (:class:`~bemlearn.control.EICGains`) (``null``: derived from the model).
        nominal: model mismatch of the controller's nominal model.
        sensor: encoder and velocity filter.
        initial_qu: initial q_u − nominal, in q_u's unit.
        fall_window: |q_u − nominal| beyond this is a fall, in q_u's unit (``null``: derived from the model).
        warmup_s: samples before this time are excluded from the tracking RMSE, s.
        seed: sensor-noise seed.
        physics_timestep: physics step, s (``null``: the model file's; derived finer when the file's step is too coarse).
    """

    duration_s: float = 60.0
    rate_hz: float | None = None
    bem_source: Literal["predictor", "model", "zero"] = "predictor"
    predictor: str | None = None
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    gains: EICGains = field(default_factory=EICGains)
    nominal: NominalConfig = field(default_factory=NominalConfig)
    sensor: SensorConfig = field(default_factory=lambda: SensorConfig(velocity_cutoff=100.0))
    initial_qu: float = 0.0
    fall_window: float | None = None
    warmup_s: float = 1.0
    seed: int = 0
    physics_timestep: float | None = None


config_limits(SimulateConfig, duration_s=Limit(gt=0, le=1e6, unit="s"), rate_hz=Limit(gt=0, le=1e6, unit="Hz"),
              initial_qu=Limit(ge=-1e3, le=1e3), fall_window=Limit(gt=0), warmup_s=Limit(ge=0, unit="s"), seed=Limit(ge=0),
              physics_timestep=Limit(gt=0, le=1, unit="s"))


@dataclass(frozen=True)
class SimResult:
    """Logged signals (``(T, ·)`` arrays at the control rate) and summary metrics."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    q_meas: np.ndarray
    qd_est: np.ndarray
    u: np.ndarray
    qa_ref: np.ndarray
    qad_ref: np.ndarray
    qadd_ref: np.ndarray
    bem_x: np.ndarray
    qu_e: np.ndarray
    fell: bool
    metrics: dict


@overload
def nominal_robot(robot: MujocoRobot, nominal: NominalConfig) -> MujocoRobot: ...
@overload
def nominal_robot(robot: BalanceRobot, nominal: NominalConfig) -> BalanceRobot: ...


def nominal_robot(robot: BalanceRobot, nominal: NominalConfig) -> BalanceRobot:
    """The controller's model: ``robot`` itself, or its MJCF scaled by :func:`~bemlearn.robots.variants.
    scaled_robot` when ``nominal`` asks for a mismatch (any MJCF robot)."""
    from bemlearn.robots.variants import scaled_robot

    if (nominal.mass_scale, nominal.length_scale) == (1.0, 1.0):
        return robot
    if not isinstance(robot, MujocoRobot):
        raise ConfigError(f"simulate.nominal: parameter mismatch needs an MJCF robot, {robot.name!r} is {type(robot).__name__}")
    return scaled_robot(robot.source, name=robot.name, coordinates=robot.coordinates, mass_scale=nominal.mass_scale,
                        length_scale=nominal.length_scale, bodies=nominal.bodies)


class _Timed:
    def __init__(self, fn: BEMSource) -> None:
        self.fn, self.total, self.name = fn, 0.0, fn.name

    def __call__(self, x):
        t0 = time.perf_counter()
        out = self.fn(x)
        self.total += time.perf_counter() - t0
        return out

    def full(self, x):
        t0 = time.perf_counter()
        out = self.fn.full(x)
        self.total += time.perf_counter() - t0
        return out


def simulate(robot: BalanceRobot, config: SimulateConfig, *, progress: bool = True, reference=None) -> SimResult:
    """Run the closed loop (module docstring) and return logs and metrics.

    ``robot`` is the simulated (true) robot, a :class:`~bemlearn.robots.MujocoRobot` (e.g.
    ``bemlearn.robots.load(name_or_path)``; another robot is rejected with a ``ValueError``); the
    controller's nominal model is ``robot`` or its scaled copy (:func:`nominal_robot`).

    ``reference`` overrides ``config.reference`` with any object offering ``m``,
    ``evaluate(t)`` and ``derivative(t, order)`` (e.g. a
    :class:`~bemlearn.robots.reference.ConstantAcceleration`).

    The loop runs torch on one thread, as a controller would (intra-op threads only add
    synchronization to these tiny per-tick calls and thrash under load); the previous
    setting is restored afterwards.  The model and zero BEMs do not import torch for that
    (when it is not loaded yet).
    """
    if config.bem_source != "predictor" and "torch" not in sys.modules:
        # the model and zero BEMs run on NumPy: a model check stays torch-free (importing torch takes seconds)
        return _simulate(robot, config, progress=progress, reference=reference)
    with torch_threads(1):
        return _simulate(robot, config, progress=progress, reference=reference)


def _simulate(plant: BalanceRobot, config: SimulateConfig, *, progress: bool, reference) -> SimResult:
    unset = [n for n in ("rate_hz", "fall_window") if getattr(config, n) is None]
    unset += [f"gains.{n}" for n in ("kp_a", "kd_a", "kp_u", "kd_u") if getattr(config.gains, n) is None]
    if unset and reference is None:
        unset += [f"reference.{n}" for n in ("amplitudes", "frequencies_hz", "phases", "offset") if getattr(config.reference, n) is None]
    if unset:
        raise ConfigError(f"simulate: {unset} not set; derive them from the model with "
                         "bemlearn.pipeline.complete_section(robot, 'simulate', config) (as every pipeline command does) or give them")
    if not isinstance(plant, MujocoRobot):
        raise RobotModelError(f"simulate: robot {plant.name!r} has no MuJoCo model")
    nominal = nominal_robot(plant, config.nominal)
    bem = _Timed(make_bem_source(config.bem_source, robot=nominal, predictor=config.predictor))
    ref = reference if reference is not None else config.reference.build(plant.m)
    assert config.rate_hz is not None  # complete_section derives it
    actuator = MujocoActuatorInverse(plant, hold_s=1.0 / config.rate_hz)   # the command is held over the tick
    ctrl = EICController(nominal, bem, ref, actuator, config.gains, rate_hz=config.rate_hz)
    model = plant.model
    sensed = SensedPlant(plant, rate_hz=config.rate_hz, sensor=config.sensor, rng=np.random.default_rng(config.seed), where="simulate",
                         timestep=config.physics_timestep)
    dt = sensed.dt
    n, m, iu, ia = plant.n, plant.m, plant.unactuated_index, list(plant.actuated_index)
    q0, qd0 = np.zeros(n), np.zeros(n)
    qa_start, qad_start, _ = ref.evaluate(np.array([0.0]))   # NumPy (derivative() goes through torch)
    q0[ia] = np.asarray(qa_start)[0]
    q0[iu] = plant.qu_nominal + config.initial_qu
    qd0[ia] = np.asarray(qad_start)[0]
    sensed.reset(q0, qd0)
    steps = int(round(config.duration_s * config.rate_hz))
    log = {k: np.empty((steps, w)) for k, w in (("q", n), ("qd", n), ("qdd", n), ("q_meas", n), ("qd_est", n), ("u", model.nu), ("bem_x", 3 * m))}
    qu_e = np.empty(steps)
    t_phys = t_ctrl = 0.0
    fell = False
    k = steps
    bar = tqdm(total=steps, desc=f"simulate ({config.bem_source})", unit="tick", disable=not progress, mininterval=0.5)
    for tick in range(steps):
        q_true = sensed.true_q()
        if not abs(q_true[iu] - plant.qu_nominal) <= config.fall_window:  # also a NaN state
            fell, k = True, tick
            break
        y, v = sensed.measure(q_true)
        c0 = time.perf_counter()
        u, info = ctrl(tick * dt, y, v)
        c1 = time.perf_counter()
        qd, qdd = sensed.apply(u)
        t_phys += time.perf_counter() - c1
        t_ctrl += c1 - c0
        log["q"][tick], log["qd"][tick], log["qdd"][tick] = q_true, qd, qdd
        log["q_meas"][tick], log["qd_est"][tick], log["u"][tick] = y, v, u
        log["bem_x"][tick] = np.concatenate([info["v_ext"], v[ia], y[ia]])
        qu_e[tick] = info["qu_e"]
        if tick % 400 == 0:
            bar.update(400 if tick else 1)
    bar.close()
    K = k
    tt = np.arange(K) * dt
    qa_ref, qad_ref, qadd_ref = ref.evaluate(tt)
    logs = {name: arr[:K] for name, arr in log.items()}
    mask = tt >= config.warmup_s
    err = logs["q"][mask][:, ia] - qa_ref[mask]
    wall = t_phys + t_ctrl
    metrics = {
        "robot": plant.name,
        "bem_source": config.bem_source,
        "fell": fell,
        "duration_s": float(K * dt),
        "tracking_rmse": float(np.sqrt(np.mean(err**2))) if mask.any() else float("nan"),
        "tracking_max": float(np.abs(err).max()) if mask.any() else float("nan"),
        "qu_max": float(np.abs(logs["q"][:, iu]).max()) if K else float("nan"),
        "qu_dev_max": float(np.abs(logs["q"][:, iu] - plant.qu_nominal).max()) if K else float("nan"),
        "u_max": float(np.abs(logs["u"]).max()) if K else float("nan"),
        "bem_rejected": int(ctrl.bem_rejected),
        "command_rejected": int(ctrl.command_rejected),
        "real_time_factor": float(K * dt / wall) if wall > 0 else float("inf"),
        "tick_us": {
            "physics": 1e6 * t_phys / max(K, 1),
            "predictor": 1e6 * bem.total / max(K, 1),
            "controller": 1e6 * (t_ctrl - bem.total) / max(K, 1),
        },
    }
    return SimResult(tt, logs["q"], logs["qd"], logs["qdd"], logs["q_meas"], logs["qd_est"], logs["u"], qa_ref, qad_ref, qadd_ref, logs["bem_x"], qu_e[:K], fell, metrics)
