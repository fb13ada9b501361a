"""Robots by name or by MJCF path: :func:`load`.

Shipped robots (``ROBOTS``):

* ``furuta`` — the Quanser rotary pendulum, MuJoCo model (``assets/furuta.xml``).
* ``furuta-analytic`` — its exact closed-form rigid-body model (:class:`AnalyticFuruta`).
* ``furuta-paper`` — the rows printed in the paper's Section IV-A (Quanser approximation).
* ``biped`` — the 5-link planar biped, stance foot pinned (``assets/biped_pinned.xml``).

The floating planar walker (``assets/biped_planar.xml``) is a simulation model, not a
:class:`Robot` (its torso has three unactuated coordinates); see :func:`asset_path`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from bemlearn.robots.furuta import AnalyticFuruta
from bemlearn.robots.mujoco_robot import MujocoRobot
from bemlearn.robots.robot import Robot

__all__ = ["ROBOTS", "load", "asset_path", "ASSETS"]

ASSETS = Path(__file__).parent / "assets"


def asset_path(filename: str) -> Path:
    """Path of a shipped MJCF asset, e.g. ``asset_path("biped_planar.xml")``."""
    path = ASSETS / filename
    if not path.is_file():
        known = sorted(p.name for p in ASSETS.glob("*.xml"))
        raise FileNotFoundError(f"asset {filename!r} not found; shipped assets: {known}")
    return path


ROBOTS: dict[str, Callable[[], Robot]] = {
    "furuta": lambda: MujocoRobot.from_xml(asset_path("furuta.xml"), name="furuta"),
    "furuta-analytic": lambda: AnalyticFuruta(variant="rigid"),
    "furuta-paper": lambda: AnalyticFuruta(variant="paper"),
    "biped": lambda: MujocoRobot.from_xml(asset_path("biped_pinned.xml"), name="biped"),
}


def load(name_or_path: str | Path) -> Robot:
    """A shipped robot by name (see ``ROBOTS``) or any MJCF file of this class by path.

    Raises:
        ValueError: an unknown name (the message lists the valid names) or a model that is
            not an underactuated balance robot (exactly one unactuated hinge/slide).
        FileNotFoundError: a path that does not exist.
    """
    key = str(name_or_path)
    if key in ROBOTS:
        return ROBOTS[key]()
    path = Path(key)
    if path.suffix.lower() == ".xml" or path.exists():
        return MujocoRobot.from_xml(path)
    raise ValueError(f"unknown robot {key!r}; shipped robots are {sorted(ROBOTS)}, or give the path of an MJCF (.xml) file")
