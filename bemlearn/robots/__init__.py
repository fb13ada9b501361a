"""Robot models: dynamics, partition, model-based BEM and zero dynamics (eq. 1–10)."""

from bemlearn.robots.bem import BEMResult, solve_bem
from bemlearn.robots.biped import BipedParameters, biped_pinned_mjcf, biped_planar_mjcf
from bemlearn.robots.furuta import (
    AnalyticFuruta,
    FurutaParameters,
    furuta_mjcf,
    torque_to_voltage,
    voltage_to_torque,
)
from bemlearn.robots.mujoco_robot import MujocoRobot, RobotModelError
from bemlearn.robots.registry import ROBOTS, asset_path, load
from bemlearn.robots.robot import Robot

__all__ = [
    "AnalyticFuruta",
    "BEMResult",
    "BipedParameters",
    "FurutaParameters",
    "MujocoRobot",
    "ROBOTS",
    "Robot",
    "RobotModelError",
    "asset_path",
    "biped_pinned_mjcf",
    "biped_planar_mjcf",
    "furuta_mjcf",
    "load",
    "solve_bem",
    "torque_to_voltage",
    "voltage_to_torque",
]
