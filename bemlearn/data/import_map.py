"""The map of a logger's CSV columns onto a trajectory (``bemlearn data import --map MAP.yaml``).

Example (format: ``docs/log-import.md``)::

    time: {column: t, unit: s}            # or ms, us; or {rate_hz: 500} without a time column
    joints:
      - {name: theta, column: theta, unit: rad}
      - {name: alpha, column: alpha, unit: deg, sign: -1, offset: 0.0, unactuated: true}
    inputs:
      - {name: voltage, column: plant_input, unit: V}
    trials: per_file                      # or {column: episode}
    keep: [target_theta, feedforward]

A joint's value is  q = sign · scale(unit) · raw + offset,  with scale(rad) = 1,
scale(deg) = π/180, scale(counts:N) = 2π/N (hinges, q in rad) and scale(m) = 1,
scale(mm) = 10⁻³ (slides, q in m); ``offset`` is in rad (hinge) or m (slide).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from bemlearn.config import ConfigError, from_dict, load_yaml

__all__ = ["TIME_UNITS", "ImportMap", "InputMap", "JointMap", "TimeMap", "TrialsByColumn", "load_import_map"]

#: Seconds per unit of the time column.
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
_JOINT_UNITS: dict[str, tuple[str, float]] = {"rad": ("hinge", 1.0), "deg": ("hinge", math.pi / 180.0),
                                              "m": ("slide", 1.0), "mm": ("slide", 1e-3)}


@dataclass(frozen=True)
class TimeMap:
    """Where time comes from and how samples are placed on the nominal grid (:mod:`bemlearn.data.resample`).

    Attributes:
        column: the time column (``None``: no time column, samples are 1/rate_hz apart).
        unit: ``"s"``, ``"ms"`` or ``"us"``.
        rate_hz: nominal sample rate, Hz (``None`` with a time column: 1 / median step, rounded
            to an integer Hz when within 0.1 %).
        max_jitter: largest accepted |t − grid time| of a sample, fraction of a step (< 0.5).
        max_fill: longest run of missing samples (dropped by the logger) filled by linear
            interpolation; longer gaps split the trial (or fail with ``on_gap: error``).
        on_gap: ``"split"`` or ``"error"`` for a gap longer than ``max_fill`` samples.
    """

    column: str | None = None
    unit: Literal["s", "ms", "us"] = "s"
    rate_hz: float | None = None
    max_jitter: float = 0.25
    max_fill: int = 2
    on_gap: Literal["split", "error"] = "split"

    def __post_init__(self) -> None:
        if self.column is None and self.rate_hz is None:
            raise ValueError("give a time column (time.column) or the sample rate (time.rate_hz)")
        if self.rate_hz is not None and not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"rate_hz: expected a positive number of Hz, got {self.rate_hz!r}")
        if not 0 < self.max_jitter < 0.5:
            raise ValueError(f"max_jitter: expected a fraction of a step in (0, 0.5), got {self.max_jitter!r}")
        if self.max_fill < 0:
            raise ValueError(f"max_fill: expected a number of samples >= 0, got {self.max_fill!r}")


@dataclass(frozen=True)
class JointMap:
    """One joint: q = sign · scale(unit) · raw + offset (module docstring).

    Attributes:
        name: joint name in the trajectory.
        column: the logger's column.
        unit: ``rad``, ``deg``, ``counts:<per_rev>`` (hinges) or ``m``, ``mm`` (slides).
        sign: +1 or −1 (a logger whose positive direction is opposite to the convention).
        offset: added after scaling, rad (hinge) or m (slide).
        unactuated: this is q_u (exactly one joint).
    """

    name: str
    column: str
    unit: str
    sign: int = 1
    offset: float = 0.0
    unactuated: bool = False

    def __post_init__(self) -> None:
        self.kind_and_scale()
        if self.sign not in (1, -1):
            raise ValueError(f"sign: expected 1 or -1, got {self.sign!r}")
        if not math.isfinite(self.offset):
            raise ValueError(f"offset: expected a finite number, got {self.offset!r}")

    def kind_and_scale(self) -> tuple[str, float]:
        """(``"hinge"`` or ``"slide"``, scale to rad or m)."""
        if self.unit in _JOINT_UNITS:
            return _JOINT_UNITS[self.unit]
        head, _, per_rev = self.unit.partition(":")
        if head == "counts":
            try:
                n = int(per_rev)
            except ValueError:
                n = 0
            if n > 0:
                return "hinge", 2.0 * math.pi / n
        raise ValueError(
            f"unit: expected one of {sorted(_JOINT_UNITS)} or counts:<per_rev> (e.g. counts:2048), got {self.unit!r}"
        )


@dataclass(frozen=True)
class InputMap:
    """One input (actuator): name, the logger's column, and its unit (V, N·m, N, A …; stored as given)."""

    name: str
    column: str
    unit: str = "V"


@dataclass(frozen=True)
class TrialsByColumn:
    """Trials given by an integer column (a new trial wherever its value changes)."""

    column: str


@dataclass(frozen=True)
class ImportMap:
    """A logger's column map (module docstring).

    Attributes:
        time: the time column or rate.
        joints: the n joints, in the robot's joint order; exactly one ``unactuated``.
        inputs: the n − 1 inputs.
        trials: ``"per_file"`` (each file one trial) or ``{column: <name>}``.
        keep: other columns carried along as extra channels (``Trajectory.channel(name)``).
        robot: the robot's name written to the file's metadata.
        delimiter: the field separator (``","``, ``";"``, ``"\\t"``).
        comment: lines starting with this before the header (and anywhere) are skipped.
    """

    time: TimeMap
    joints: tuple[JointMap, ...]
    inputs: tuple[InputMap, ...]
    trials: Literal["per_file"] | TrialsByColumn = "per_file"
    keep: tuple[str, ...] = ()
    robot: str = "rig"
    delimiter: str = ","
    comment: str = "#"

    def __post_init__(self) -> None:
        if len(self.joints) < 2:
            raise ValueError(f"joints: expected at least 2 joints, got {len(self.joints)}")
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise ValueError(f"joints: duplicate joint names {names}")
        unact = [j.name for j in self.joints if j.unactuated]
        if len(unact) != 1:
            raise ValueError(f"joints: expected exactly one joint with unactuated: true, got {unact or 'none'}")
        if len(self.inputs) != len(self.joints) - 1:
            raise ValueError(
                f"inputs: expected {len(self.joints) - 1} inputs (n − 1 for {len(self.joints)} joints), got {len(self.inputs)}"
            )
        if len(self.delimiter) != 1 or self.delimiter in "\n\r\"'":
            raise ValueError(f"delimiter: expected one character, got {self.delimiter!r}")
        if len(set(self.keep)) != len(self.keep):
            raise ValueError(f"keep: duplicate columns {list(self.keep)}")

    @property
    def unactuated(self) -> str:
        return next(j.name for j in self.joints if j.unactuated)

    @property
    def trial_column(self) -> str | None:
        return self.trials.column if isinstance(self.trials, TrialsByColumn) else None

    def columns(self) -> dict[str, str]:
        """Every column the map reads → the map key that names it (for error messages)."""
        cols: dict[str, str] = {}
        if self.time.column is not None:
            cols[self.time.column] = "time.column"
        for i, j in enumerate(self.joints):
            cols.setdefault(j.column, f"joints[{i}].column")
        for i, u in enumerate(self.inputs):
            cols.setdefault(u.column, f"inputs[{i}].column")
        if self.trial_column is not None:
            cols.setdefault(self.trial_column, "trials.column")
        for i, c in enumerate(self.keep):
            cols.setdefault(c, f"keep[{i}]")
        return cols


def load_import_map(path: str | Path) -> ImportMap:
    """Parse MAP.yaml strictly (unknown keys and bad values fail, naming the file and key)."""
    path = Path(path)
    data = load_yaml(path)
    try:
        return from_dict(ImportMap, data, where=f"{path}: map")
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:  # pragma: no cover - from_dict wraps these already
        raise ConfigError(f"{path}: {exc}") from exc
