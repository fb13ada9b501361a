"""The ``coordinates:`` block of a config: a robot's balance coordinates declared beside its MJCF file.

A file this class's zero-config reading cannot settle on its own (docs/wheeled.md, docs/config.md) gets its
coordinates from a few lines of the run's config instead of edits to the file::

    robot: robots/my_wheel_pendulum.xml
    coordinates:
      rolling_dependent: [chassis_x]   # the freedoms that move only by rolling
      qu_nominal: 3.14159              # the upright, in q_u's unit
      qu_range: [2.6, 3.7]             # where the BEM is searched

Each key is the same declaration as a ``<custom>`` element of the MJCF (:mod:`bemlearn.robots.mujoco_robot`):

============================  ==========================================  ======================================
key                           MJCF ``<custom>`` element                    meaning
============================  ==========================================  ======================================
``map``                       ``<numeric name="bemlearn_coordinates">``     T of q = T q_joint, ``n × n`` (rows)
``names``                     ``<text name="bemlearn_coordinate_names">``   the coordinates' names (with ``map``)
``qu_nominal``                ``<numeric name="bemlearn_qu_nominal">``      the upright of q_u (q_u's unit)
``qu_range``                  ``<numeric name="bemlearn_qu_range">``        the BEM search bracket of q_u
``rolling_dependent``         ``<text name="bemlearn_rolling_dependent">``  joints that only roll with a wheel
============================  ==========================================  ======================================

The block is applied to the model as it compiles (:func:`custom_entries`, :func:`apply_custom`): where the file
declares the same element, the config's value replaces it, and the robot reads one set of declarations whatever
their origin.  A run records the block with its robot (:class:`~bemlearn.robots.registry.RobotRef`), so every later
load of the run's robot (the closed loop, ``evaluate``, a predictor's robot) has the same coordinates.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bemlearn.errors import ConfigError

if TYPE_CHECKING:
    import mujoco
    import numpy as np

__all__ = ["CoordinatesConfig", "apply_custom", "coordinates_mapping", "custom_entries", "declared_numeric", "declared_text"]


@dataclass(frozen=True)
class CoordinatesConfig:
    """A robot's balance coordinates declared in the config, beside its MJCF file (the same declarations as its `<custom>` elements).

    Attributes:
        map: T of the constant change of coordinates q = T q_joint, as ``n`` rows of ``n`` numbers (the MJCF's
            joints in model order); ``None`` keeps the joints (or the rolling/free-body reading) as coordinates.
        names: the coordinates' names, one per row of ``map`` (only with ``map``).
        qu_nominal: the upright of q_u in q_u's unit (rad or m): the reference of every window, bracket and fall
            test; ``None`` finds it from the physics (the unstable equilibrium of highest potential energy).
        qu_range: ``[low, high]`` where the BEM is searched (q_u's unit); ``None`` takes q_u's joint range or
            ±π/2 (±1 m) about the upright.
        rolling_dependent: the joints without an actuator that move only because a wheel rolls (a chassis slide),
            when more than one choice fits the rolling contacts; ``None`` lets the model decide when it can.
    """

    map: list[list[float]] | None = None
    names: list[str] | None = None
    qu_nominal: float | None = None
    qu_range: list[float] | None = None
    rolling_dependent: list[str] | None = None

    def __post_init__(self) -> None:
        where = "coordinates"
        if self.map is not None:
            n = len(self.map)
            if n == 0 or any(len(row) != n for row in self.map):
                raise ConfigError(f"{where}.map: expected n rows of n numbers (a square matrix), got rows of lengths "
                                  f"{[len(row) for row in self.map]}")
            if any(not math.isfinite(float(v)) for row in self.map for v in row):
                raise ConfigError(f"{where}.map: expected finite numbers")
        if self.names is not None:
            if self.map is None:
                raise ConfigError(f"{where}.names: names the rows of coordinates.map; give the map too (without it the "
                                  "coordinates are the MJCF joints and keep their names)")
            if len(self.names) != len(self.map) or any(not n or " " in n for n in self.names):
                raise ConfigError(f"{where}.names: expected {len(self.map)} names without spaces (one per row of the map), "
                                  f"got {self.names!r}")
        if self.qu_nominal is not None and not math.isfinite(self.qu_nominal):
            raise ConfigError(f"{where}.qu_nominal: expected a finite number, got {self.qu_nominal!r}")
        if self.qu_range is not None and (len(self.qu_range) != 2 or not all(math.isfinite(v) for v in self.qu_range)
                                          or not self.qu_range[0] < self.qu_range[1]):
            raise ConfigError(f"{where}.qu_range: expected [low, high] with finite low < high, got {self.qu_range!r}")
        if self.rolling_dependent is not None and (not self.rolling_dependent
                                                   or any(not n or " " in n for n in self.rolling_dependent)):
            raise ConfigError(f"{where}.rolling_dependent: expected a list of joint names (no spaces), got "
                              f"{self.rolling_dependent!r}")


def _as_config(coordinates: CoordinatesConfig | Mapping[str, Any]) -> CoordinatesConfig:
    if isinstance(coordinates, CoordinatesConfig):
        return coordinates
    from bemlearn.config import from_dict

    return from_dict(CoordinatesConfig, dict(coordinates), where="coordinates")


def coordinates_mapping(coordinates: CoordinatesConfig | Mapping[str, Any] | None) -> dict[str, Any] | None:
    """The block as a plain mapping of its given keys (what a run records), ``None`` without one."""
    if coordinates is None:
        return None
    c = _as_config(coordinates)
    return {k: v for k, v in vars(c).items() if v is not None} or None


def custom_entries(coordinates: CoordinatesConfig | Mapping[str, Any] | None) -> dict[str, list[float] | str]:
    """The MJCF ``<custom>`` elements the block declares: ``{name: numbers}`` (numeric) or ``{name: text}``."""
    if coordinates is None:
        return {}
    c = _as_config(coordinates)
    out: dict[str, list[float] | str] = {}
    if c.map is not None:
        out["bemlearn_coordinates"] = [float(v) for row in c.map for v in row]
    if c.names is not None:
        out["bemlearn_coordinate_names"] = " ".join(c.names)
    if c.qu_nominal is not None:
        out["bemlearn_qu_nominal"] = [float(c.qu_nominal)]
    if c.qu_range is not None:
        out["bemlearn_qu_range"] = [float(v) for v in c.qu_range]
    if c.rolling_dependent is not None:
        out["bemlearn_rolling_dependent"] = " ".join(c.rolling_dependent)
    return out


def declared_numeric(model: mujoco.MjModel, name: str) -> np.ndarray | None:
    """The numbers of the model's ``<numeric name=...>`` (from its file or a ``coordinates:`` block), or ``None``."""
    import mujoco
    import numpy as np

    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, name)
    if i < 0:
        return None
    start, size = int(model.numeric_adr[i]), int(model.numeric_size[i])
    return np.array(model.numeric_data[start : start + size], dtype=np.float64)


def declared_text(model: mujoco.MjModel, name: str) -> str | None:
    """The text of the model's ``<text name=...>`` (from its file or a ``coordinates:`` block), or ``None``."""
    import mujoco

    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, name)
    if i < 0:
        return None
    start, size = int(model.text_adr[i]), int(model.text_size[i])
    return bytes(model.text_data[start : start + size]).split(b"\0")[0].decode()


def apply_custom(spec: mujoco.MjSpec, entries: Mapping[str, list[float] | str]) -> None:
    """Declare ``entries`` (:func:`custom_entries`) in ``spec``, replacing elements of the same name."""
    numerics = {el.name: el for el in spec.numerics}
    texts = {el.name: el for el in spec.texts}
    for name, value in entries.items():
        if isinstance(value, str):
            el = texts.get(name) or spec.add_text()
            el.name, el.data = name, value
        else:
            el = numerics.get(name) or spec.add_numeric()
            el.name, el.data = name, list(value)
