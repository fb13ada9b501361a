"""A MuJoCo robot stepped at a control rate and observed like a real rig.

Both the excitation collector (:mod:`bemlearn.sim.collect`) and the closed-loop simulator
(:mod:`bemlearn.sim.closed_loop`) run the same plant: per control tick the true coordinates
are read, measured through the encoder and the velocity filter (:mod:`bemlearn.data.sensors`),
the controller's command is held over ``round(1 / (rate · timestep))`` physics steps, and the
true q̇, q̈ at the tick (with the new command) are returned for ground-truth logging.

``timestep`` (optional) runs the physics with a finer step than the model file's (public
models often use 20 ms, too coarse for a ≥ 100 Hz control loop); the robot's own model is
left unchanged (the plant uses a copy).
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from bemlearn.data.sensors import Encoder, FilteredDifferentiator, SensorConfig
from bemlearn.errors import ConfigError, NumericalError

if TYPE_CHECKING:
    from bemlearn.robots.mujoco_robot import MujocoRobot

__all__ = ["SensedPlant"]


class SensedPlant:
    """The robot's MuJoCo model with a zero-order-hold input and a sensor model.

    Args:
        robot: a :class:`~bemlearn.robots.MujocoRobot` (model, coordinate map, partition).
        rate_hz: control and sampling rate, Hz; must be a whole number of physics steps.
        sensor: encoder and velocity-filter options.
        rng: the generator of the sensor noise.
        where: a label for error messages (e.g. ``"collect"``).
        timestep: physics step override, s (default: the model's ``opt.timestep``).
    """

    def __init__(self, robot: MujocoRobot, *, rate_hz: float, sensor: SensorConfig, rng: np.random.Generator, where: str, timestep: float | None = None) -> None:
        self.robot = robot
        self.model = robot.model
        if timestep is not None and timestep != self.model.opt.timestep:
            if not timestep > 0:
                raise ConfigError(f"{where}: physics_timestep must be > 0 s, got {timestep}")
            self.model = copy.deepcopy(robot.model)
            self.model.opt.timestep = timestep
        self.data = mujoco.MjData(self.model)
        self.dt = 1.0 / rate_hz
        steps = self.dt / self.model.opt.timestep
        if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
            raise ConfigError(f"{where}: 1/rate_hz = {self.dt} s is not a whole number of physics steps ({self.model.opt.timestep} s)")
        self.substeps = int(round(steps))
        self.T, self.Tinv = robot.T_np, robot.Tinv_np
        self.encoder = Encoder(sensor, rng, kinds=_coordinate_kinds(robot))
        self.velocity = FilteredDifferentiator(robot.n, cutoff=sensor.velocity_cutoff, dt=self.dt)

    def reset(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> None:
        """Set the true state: ``q0``, ``qd0`` ``(n,)`` coordinates (rad / m) and rates (rad/s / m/s), by joint kind."""
        qpos, qvel = self.robot.state_to_mujoco(q0, qd0)
        self.data.qpos[:] = qpos
        if qd0 is not None:
            self.data.qvel[:] = qvel

    def true_q(self) -> np.ndarray:
        """The true coordinates now, ``(n,)`` rad / m by joint kind."""
        return self.robot.coordinates_of(self.data.qpos)

    def measure(self, q_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What the rig sees of ``q_true``: quantized angles and the filtered rate, each ``(n,)``."""
        y = self.encoder(q_true)
        return y, self.velocity(y)

    def apply(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hold command ``u (nu,)`` for one tick; returns the true ``(q̇, q̈)`` at the tick, ``(n,)`` each."""
        m, d = self.model, self.data
        if not np.all(np.isfinite(u)):
            raise NumericalError(f"SensedPlant.apply: non-finite command {u}; it must not reach MuJoCo's ctrl")
        d.ctrl[:] = u
        mujoco.mj_forward(m, d)
        qd, qdd = self.T @ d.qvel, self.T @ d.qacc
        for _ in range(self.substeps):
            mujoco.mj_step(m, d)
        return qd, qdd


def _coordinate_kinds(robot: MujocoRobot) -> tuple[str, ...] | None:
    """Joint kinds per coordinate when each coordinate is one joint (T = I, or joints a rolling freedom follows), else None."""
    if getattr(robot, "coordinate_joints", None) is None:
        return None
    return tuple(robot.coordinate_kinds)
