"""Robots by registry name or by MJCF path: :func:`load`, :func:`resolve_robot`.

The core registers no robot itself.  Names come from applications
(:mod:`bemlearn.applications`: bemlearn's own Furuta application registers ``furuta``,
``furuta-analytic`` and ``furuta-paper``, its biped application ``biped``) or from
:func:`register_robot`.  Any MJCF file of this class loads by path with no registration.

A run records the robot it used as a :class:`RobotRef` (the MJCF path, its sha256 and the
registry name if any), so that later commands load exactly that model.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bemlearn.errors import CheckpointError, ConfigError, MissingFileError
from bemlearn.files import file_sha256
from bemlearn.robots.mujoco_robot import MujocoRobot
from bemlearn.robots.robot import Robot

if TYPE_CHECKING:
    from bemlearn.robots.coordinates import CoordinatesConfig

__all__ = ["ROBOTS", "RobotRef", "load", "register_robot", "registered_robots", "resolve_robot"]

#: Directly registered robots (name → factory); see :func:`registered_robots` for all.
ROBOTS: dict[str, Callable[[], Robot]] = {}


def register_robot(name: str, factory: Callable[[], Robot]) -> None:
    """Register ``factory`` under ``name`` (an application or a user script)."""
    ROBOTS[name] = factory


def registered_robots() -> dict[str, Callable[[], Robot]]:
    """Every registered robot: :data:`ROBOTS` plus those of the installed applications."""
    from bemlearn.applications import applications

    out: dict[str, Callable[[], Robot]] = {}
    for app in applications().values():
        out.update(app.robots)
    out.update(ROBOTS)
    return out


@dataclass(frozen=True)
class RobotRef:
    """The robot a run used: MJCF path and sha256, and the registry name it was given by (if any).

    Attributes:
        name: the robot's name (registry name, or the model name of an MJCF given by path).
        mjcf: absolute path of the MJCF file, or ``None`` for a robot with no MJCF (analytic).
        sha256: sha256 of the MJCF file's bytes (``None`` without a file).
        registry: the registry name the config used, or ``None`` when the config gave a path.
        coordinates: the config's ``coordinates:`` block the model was loaded with (:mod:`bemlearn.robots.coordinates`),
            or ``None``.
    """

    name: str
    mjcf: str | None
    sha256: str | None
    registry: str | None
    coordinates: dict[str, Any] | None = None

    def to_dict(self) -> dict:
        out: dict[str, Any] = {"name": self.name, "mjcf": self.mjcf, "sha256": self.sha256, "registry": self.registry}
        if self.coordinates is not None:
            out["coordinates"] = dict(self.coordinates)
        return out

    @classmethod
    def from_dict(cls, data: dict, *, where: str = "robot") -> RobotRef:
        if not isinstance(data, dict) or "mjcf" not in data:
            raise CheckpointError(f"{where}: expected a mapping with keys name, mjcf, sha256, registry; got {data!r}")
        coords = data.get("coordinates")
        if coords is not None and not isinstance(coords, dict):
            raise CheckpointError(f"{where}: coordinates: expected a mapping (a config's coordinates block), got {coords!r}")
        return cls(str(data.get("name") or "robot"), data.get("mjcf"), data.get("sha256"), data.get("registry"), coords)

    def load(self, *, check: bool = True) -> Robot:
        """Load the recorded robot; with ``check`` the MJCF must still have the recorded sha256."""
        if self.mjcf is None:
            if self.registry is None:
                raise CheckpointError(f"robot {self.name!r}: the run recorded neither an MJCF file nor a registry name")
            return load(self.registry)
        path = Path(self.mjcf)
        if not path.is_file():
            raise MissingFileError(f"robot {self.name!r}: the run's MJCF {path} no longer exists")
        if check and self.sha256 and (actual := file_sha256(path)) != self.sha256:
            raise CheckpointError(
                f"robot {self.name!r}: {path} changed since the run (sha256 {actual[:12]}… ≠ recorded "
                f"{self.sha256[:12]}…); the run's results belong to the old file"
            )
        return MujocoRobot.from_xml(path, name=self.name, coordinates=self.coordinates)


def resolve_robot(name_or_path: str | Path, *, coordinates: CoordinatesConfig | Mapping[str, Any] | None = None
                  ) -> tuple[Robot, RobotRef]:
    """Load a robot by registry name or MJCF path and return it with its :class:`RobotRef`.

    A path always means that file, even when its stem equals a registry name (a user's own
    ``furuta.xml`` is never mistaken for the shipped Furuta).  A bare name is a path when it ends in
    ``.xml`` or names an existing file; a folder of that name (e.g. a run's ``--out furuta``) is not.
    ``coordinates`` (a config's ``coordinates:`` block) declares the coordinates of an MJCF given by path.
    """
    key = str(name_or_path)
    path = Path(key)
    if path.suffix.lower() == ".xml" or path.is_file() or "/" in key or (path.exists() and key not in registered_robots()):
        if not path.is_file():
            raise MissingFileError(f"robot: MJCF file {path} not found")
        mj = MujocoRobot.from_xml(path, coordinates=coordinates)
        return mj, RobotRef(mj.name, str(path.resolve()), file_sha256(path), None, mj.coordinates)
    if coordinates is not None:
        raise ConfigError(f"coordinates: declares the coordinates of an MJCF file given by path; {key!r} is a registered "
                          "robot (its application defines its coordinates)")
    known = registered_robots()
    if key not in known:
        raise ConfigError(f"unknown robot {key!r}; registered robots are {sorted(known)}, or give the path of an MJCF (.xml) file")
    robot = known[key]()
    src = getattr(robot, "source", None)
    mjcf = Path(src) if isinstance(robot, MujocoRobot) and src and Path(src).is_file() else None
    return robot, RobotRef(key, str(mjcf.resolve()) if mjcf else None, file_sha256(mjcf) if mjcf else None, key)


def load(name_or_path: str | Path, *, coordinates: CoordinatesConfig | Mapping[str, Any] | None = None) -> Robot:
    """A registered robot by name or any MJCF file of this class by path (``coordinates``: :func:`resolve_robot`).

    Raises:
        ConfigError: an unknown name (the message lists the registered names).
        RobotModelError: a model that is not an underactuated balance robot (exactly one
            unactuated hinge/slide).
        MissingFileError: (a FileNotFoundError) a path that does not exist.
    """
    return resolve_robot(name_or_path, coordinates=coordinates)[0]
