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
    windows: {"episode_00[1-3].csv": [2.5, null]}   # per file (name or glob): overrides time.window
    delimiter: whitespace                 # optional: ",", ";", "\t", whitespace; default: detected
    header: false                         # optional: the file has no header line ...
    columns: [t, theta, alpha, plant_input, target_theta, feedforward]   # ... so name its columns

A joint's value is  q = sign · scale(unit) · raw + offset,  with scale(rad) = 1,
scale(deg) = π/180, scale(counts:N) = 2π/N (hinges, q in rad) and scale(m) = 1,
scale(mm) = 10⁻³ (slides, q in m); ``offset`` is in rad (hinge) or m (slide).
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from bemlearn.config import ConfigError, from_dict, load_yaml

__all__ = ["DELIMITERS", "TIME_UNITS", "WHITESPACE", "ImportMap", "delimiter_name", "InputMap", "JointMap", "TimeMap", "TrialsByColumn",
           "TORQUE_UNITS", "TorqueMap", "Window", "load_import_map"]

#: A time window [t₀, t₁] in the log's own time unit (``time.unit``; s from the file's first row without a
#: time column); ``None`` for either bound: the log's start or end.
Window = tuple[float | None, float | None]


def _check_window(window: Window | None, key: str) -> None:
    if window is None:
        return
    t0, t1 = window
    if t0 is None and t1 is None:
        raise ConfigError(f"{key}: expected [t0, t1] with at least one bound (null: the log's start or end), got [null, null]")
    if t0 is not None and t1 is not None and not t0 < t1:
        raise ConfigError(f"{key}: expected [t0, t1] with t0 < t1 (in the log's time unit), got [{t0:g}, {t1:g}]")

#: Seconds per unit of the time column.
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
#: ``delimiter: whitespace``: fields separated by any run of spaces and tabs.
WHITESPACE = "whitespace"
#: The delimiters tried, in this order, when the map gives none (:func:`bemlearn.data.log_table.detect_delimiter`).
DELIMITERS: tuple[str, ...] = (",", ";", "\t", WHITESPACE)
_DELIMITER_NAMES = {",": "comma", ";": "semicolon", "\t": "tab", WHITESPACE: "whitespace"}
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
            With ``resample: linear``: the distance beyond which a stamp counts as *moved*.
        max_fill: longest run of missing samples (dropped by the logger) filled by linear
            interpolation; longer gaps split the trial (or fail with ``on_gap: error``).
            With ``resample: linear``: a step between two stamps of more than
            ``max_fill + 1.5`` nominal steps is such a gap.
        on_gap: ``"split"`` or ``"error"`` for a gap longer than ``max_fill`` samples.
        resample: ``"none"`` (default: each sample keeps its logged value on its grid point,
            :func:`~bemlearn.data.resample.place_on_grid`) or ``"linear"``: every channel is
            linearly interpolated onto t₀ + k/f_s within each trial, for a logger whose loop
            overruns or whose clock drifts (:func:`~bemlearn.data.resample.resample_linear`).
        window: ``[t0, t1]``: only the samples with t0 ≤ t ≤ t1 are imported (e.g. to leave out a
            swing-up), t in the time column's own unit as logged (without a time column: s from
            the file's first row); ``null`` for either bound is the log's start or end.  Applied
            to every file (``ImportMap.windows`` overrides it per file), before the samples are
            placed on the grid or resampled.
    """

    column: str | None = None
    unit: Literal["s", "ms", "us"] = "s"
    rate_hz: float | None = None
    max_jitter: float = 0.25
    max_fill: int = 2
    on_gap: Literal["split", "error"] = "split"
    resample: Literal["none", "linear"] = "none"
    window: Window | None = None

    def __post_init__(self) -> None:
        _check_window(self.window, "window")
        if self.column is None and self.rate_hz is None:
            raise ConfigError("give a time column (time.column) or the sample rate (time.rate_hz)")
        if self.column is None and self.resample != "none":
            raise ConfigError("resample: linear needs the time stamps (time.column) to interpolate from")
        if self.rate_hz is not None and not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ConfigError(f"rate_hz: expected a positive number of Hz, got {self.rate_hz!r}")
        if not 0 < self.max_jitter < 0.5:
            raise ConfigError(f"max_jitter: expected a fraction of a step in (0, 0.5), got {self.max_jitter!r}")
        if self.max_fill < 0:
            raise ConfigError(f"max_fill: expected a number of samples >= 0, got {self.max_fill!r}")


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
            raise ConfigError(f"sign: expected 1 or -1, got {self.sign!r}")
        if not math.isfinite(self.offset):
            raise ConfigError(f"offset: expected a finite number, got {self.offset!r}")

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
        raise ConfigError(
            f"unit: expected one of {sorted(_JOINT_UNITS)} or counts:<per_rev> (e.g. counts:2048), got {self.unit!r}"
        )


@dataclass(frozen=True)
class InputMap:
    """One input (actuator): name, the logger's column, and its unit (V, N·m, N, A …; stored as given)."""

    name: str
    column: str
    unit: str = "V"


#: Units of a logged torque (hinge, stored in N·m) or force (slide, stored in N) → (joint kind, scale to SI).
TORQUE_UNITS: dict[str, tuple[str, float]] = {"N*m": ("hinge", 1.0), "Nm": ("hinge", 1.0), "N.m": ("hinge", 1.0),
                                              "N·m": ("hinge", 1.0), "mN*m": ("hinge", 1e-3), "mNm": ("hinge", 1e-3),
                                              "mN.m": ("hinge", 1e-3), "mN·m": ("hinge", 1e-3),
                                              "N": ("slide", 1.0), "mN": ("slide", 1e-3)}


@dataclass(frozen=True)
class TorqueMap:
    """A logged torque (hinge) or force (slide) on one joint: τ = sign · scale · scale(unit) · raw.

    The generalized force acting on the joint besides gravity and the coupling: for an actuated
    joint the motor's (measured or commanded) torque, for the unactuated joint whatever acts on
    it (a friction compensation, an applied perturbation) -- which the BEM assumes is zero.

    Attributes:
        joint: the joint's name (one of ``joints[].name``).
        column: the logger's column.
        unit: ``N*m`` (also ``Nm``, ``N.m``, ``N·m``), ``mN*m`` (…) for a hinge; ``N``, ``mN`` for a
            slide.  Stored in N·m or N.
        scale: a factor applied first (e.g. a torque constant, N·m/A, for a logged current); the
            unit is then the product's.
        sign: +1 or −1 (the joint's positive direction, as ``joints[].sign``).
    """

    joint: str
    column: str
    unit: str = "N*m"
    scale: float = 1.0
    sign: int = 1

    def __post_init__(self) -> None:
        if self.unit not in TORQUE_UNITS:
            raise ConfigError(f"unit: expected one of {list(TORQUE_UNITS)}, got {self.unit!r}")
        if not (math.isfinite(self.scale) and self.scale != 0):
            raise ConfigError(f"scale: expected a finite non-zero number, got {self.scale!r}")
        if self.sign not in (1, -1):
            raise ConfigError(f"sign: expected 1 or -1, got {self.sign!r}")

    @property
    def factor(self) -> float:
        """SI value per raw value: sign · scale · scale(unit)."""
        return self.sign * self.scale * TORQUE_UNITS[self.unit][1]


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
        delimiter: the field separator: ``","``, ``";"``, ``"\\t"`` (or ``tab``), another single
            character, or ``whitespace`` (any run of spaces and tabs); ``None`` (default):
            detected per file from its first lines (:func:`bemlearn.data.log_table.detect_delimiter`).
        comment: lines starting with this before the header (and anywhere) are skipped.
        header: the file's first line (after comments) names the columns.  ``False``: the
            file starts with data, and ``columns`` names its columns.
        columns: the file's columns in order, one name per field.  Required with
            ``header: false``; with ``header: true`` they replace the header's names (the
            header line is skipped, its field count must match).  Each file's lines must have
            exactly this many fields.
        windows: per-file time windows, file name (or glob, matched against the file's name and
            against the path as given) → ``[t0, t1]`` as ``time.window``, which they override.  A
            file matched by two keys, and a key that matches no file, are errors.
        torques: logged joint torques / forces (optional; :class:`TorqueMap`).
    """

    time: TimeMap
    joints: tuple[JointMap, ...]
    inputs: tuple[InputMap, ...]
    trials: Literal["per_file"] | TrialsByColumn = "per_file"
    keep: tuple[str, ...] = ()
    robot: str = "rig"
    delimiter: str | None = None
    comment: str = "#"
    header: bool = True
    columns: tuple[str, ...] | None = None
    windows: dict[str, Window] | None = None
    torques: tuple[TorqueMap, ...] = ()

    def __post_init__(self) -> None:
        for pattern, window in (self.windows or {}).items():
            if not pattern.strip():
                raise ConfigError("windows: expected file names or globs as keys, got an empty one")
            _check_window(window, f"windows[{pattern!r}]")
        joint_names = [j.name for j in self.joints]
        for i, tq in enumerate(self.torques):
            if tq.joint not in joint_names:
                raise ConfigError(f"torques[{i}].joint: {tq.joint!r} is not one of the joints {joint_names}")
            kind = next(j for j in self.joints if j.name == tq.joint).kind_and_scale()[0]
            if TORQUE_UNITS[tq.unit][0] != kind:
                want = [u for u, (k, _) in TORQUE_UNITS.items() if k == kind]
                raise ConfigError(f"torques[{i}].unit: {tq.joint!r} is a {kind}: expected one of {want}, got {tq.unit!r}")
        tq_joints = [tq.joint for tq in self.torques]
        if len(set(tq_joints)) != len(tq_joints):
            raise ConfigError(f"torques: a joint named twice in {tq_joints}")
        if len(self.joints) < 2:
            raise ConfigError(f"joints: expected at least 2 joints, got {len(self.joints)}")
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise ConfigError(f"joints: duplicate joint names {names}")
        unact = [j.name for j in self.joints if j.unactuated]
        if len(unact) != 1:
            raise ConfigError(f"joints: expected exactly one joint with unactuated: true, got {unact or 'none'}")
        if len(self.inputs) != len(self.joints) - 1:
            raise ConfigError(
                f"inputs: expected {len(self.joints) - 1} inputs (n − 1 for {len(self.joints)} joints), got {len(self.inputs)}"
            )
        if self.delimiter == "tab":
            object.__setattr__(self, "delimiter", "\t")
        if self.delimiter is not None and self.delimiter != WHITESPACE and (
            len(self.delimiter) != 1 or self.delimiter in "\n\r\"' " or self.delimiter == self.comment
        ):
            hint = (" (for fields separated by spaces write delimiter: whitespace)" if self.delimiter.strip() == "" else
                    ' (a tab is written "\\t" in double quotes, or tab)' if self.delimiter == "\\t" else "")
            raise ConfigError(f"delimiter: expected one character (',', ';', '\\t', …), tab or whitespace, got {self.delimiter!r}{hint}")
        if len(set(self.keep)) != len(self.keep):
            raise ConfigError(f"keep: duplicate columns {list(self.keep)}")
        if self.columns is None:
            if not self.header:
                raise ConfigError("header: false needs columns: [name, …] naming the file's columns in order")
            return
        if not self.columns or any(not c.strip() for c in self.columns):
            raise ConfigError(f"columns: expected a list of non-empty names, got {list(self.columns)}")
        dup = sorted({c for c in self.columns if self.columns.count(c) > 1})
        if dup:
            raise ConfigError(f"columns: duplicate names {dup}")
        for col, key in self.used_columns().items():
            if col not in self.columns:
                raise ConfigError(f"{key}: {col!r} is not one of columns: {list(self.columns)}")

    @property
    def unactuated(self) -> str:
        return next(j.name for j in self.joints if j.unactuated)

    @property
    def trial_column(self) -> str | None:
        return self.trials.column if isinstance(self.trials, TrialsByColumn) else None

    def used_columns(self) -> dict[str, str]:
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
        for i, tq in enumerate(self.torques):
            cols.setdefault(tq.column, f"torques[{i}].column")
        return cols

    def window_for(self, path: str | Path, files: list[str | Path] | None = None) -> tuple[str, Window] | None:
        """``(map key, window)`` of the file ``path``: the ``windows`` entry whose name or glob matches it
        (its name, or the path as given), else ``time.window``, else ``None``.

        Raises:
            ConfigError: two ``windows`` keys match the file.
        """
        hits = [k for k in (self.windows or {}) if _matches(k, path)]
        if len(hits) > 1:
            raise ConfigError(f"{path}: matched by windows{hits}: give one window per file")
        if hits:
            assert self.windows is not None
            return f"windows[{hits[0]!r}]", self.windows[hits[0]]
        return ("time.window", self.time.window) if self.time.window is not None else None

    def unmatched_windows(self, paths: list[str | Path]) -> list[str]:
        """The ``windows`` keys that match none of ``paths`` (a misspelt name)."""
        return [k for k in (self.windows or {}) if not any(_matches(k, p) for p in paths)]


def _matches(pattern: str, path: str | Path) -> bool:
    """Whether the file name or glob ``pattern`` names ``path`` (its name, or the path as given)."""
    return fnmatch.fnmatchcase(Path(path).name, pattern) or fnmatch.fnmatchcase(str(path), pattern)


def delimiter_name(delimiter: str) -> str:
    """``"comma"``, ``"semicolon"``, ``"tab"``, ``"whitespace"`` or the character itself (messages)."""
    return _DELIMITER_NAMES.get(delimiter, repr(delimiter))


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
