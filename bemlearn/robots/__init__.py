"""Robot models: dynamics, partition, model-based BEM and zero dynamics (eq. 1–10)."""

from typing import TYPE_CHECKING

from bemlearn._lazy import lazy_namespace

if TYPE_CHECKING:  # imported on first use: bemlearn._lazy
    from bemlearn.robots.bem import BEMResult, find_roots, solve_bem
    from bemlearn.robots.cyclic import cyclic_coordinates
    from bemlearn.robots.mujoco_robot import MujocoRobot, RobotModelError
    from bemlearn.robots.protocol import BalanceRobot, ControlRobot
    from bemlearn.robots.registry import ROBOTS, RobotRef, load, register_robot, registered_robots, resolve_robot
    from bemlearn.robots.robot import Robot
    from bemlearn.robots.rolling import RollingContact, RollingMap, find_rolling, kkt_acceleration

__all__ = [
    "BEMResult",
    "BalanceRobot",
    "ControlRobot",
    "MujocoRobot",
    "ROBOTS",
    "Robot",
    "RollingContact",
    "RollingMap",
    "find_rolling",
    "kkt_acceleration",
    "RobotModelError",
    "RobotRef",
    "load",
    "register_robot",
    "registered_robots",
    "resolve_robot",
    "solve_bem",
    "find_roots",
    "cyclic_coordinates",
]

__getattr__, __dir__ = lazy_namespace(__name__, __file__)
