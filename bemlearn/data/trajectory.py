"""Recorded (or simulated) robot trajectories: samples of time, trial id, joints and inputs.

A trajectory holds T samples of an n-joint robot with one unactuated joint q_u and
m = n − 1 actuated joints q_a (eq. 1, 2):

    t (T,) s,  trial (T,) int64,  q (T, n) rad (robot joint order),  u (T, n − 1) inputs,

optionally with the simulator's true q̇ (T, n) rad/s and q̈ (T, n) rad/s² (a ground-truth
file), extra logged channels (T, k) carried along (``meta.channel_names``) and logged joint
torques τ (T, p) N·m (N for slides) on the joints ``meta.torque_joints`` (a torque on q_u is
one the BEM assumes absent, eq. 2: Γ_u = 0).  Units
follow the joint (``meta.joint_kinds``): a hinge in rad, a slide in m
(:mod:`bemlearn.units`).  Samples of one trial are contiguous and time increases within a trial at the
nominal sample rate.  The on-disk format (NPZ and CSV) is described in
``docs/trajectory-format.md`` and implemented in :mod:`bemlearn.data.trajectory_io`;
the checks in :mod:`bemlearn.data.validation`.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bemlearn.data.quantization import detect_quantization_step
from bemlearn.errors import ArgumentError, TrajectoryFormatError
from bemlearn.units import JOINT_KINDS

__all__ = ["TrajectoryMeta", "Trajectory", "TrialSlice", "TrajectoryFormatError", "DEFAULT_UNITS"]

#: Units assumed when none are given; ``q`` must be rad, ``t`` must be s.
DEFAULT_UNITS: dict[str, str] = {"t": "s", "q": "rad", "u": "V"}


def check_names(present: Iterable[str], required: Sequence[str], optional: Sequence[str] = (), *, where: str, what: str,
                valid: str) -> None:
    """Refuse missing and unknown names of a stored trajectory (metadata keys, NPZ arrays, CSV columns).

    Raises:
        TrajectoryFormatError: ``"{where}: missing {what}(s) [...]; {valid}"`` or ``"{where}: unknown {what}(s) [...]; {valid}"``.
    """
    names = list(present)
    missing = [k for k in required if k not in names]
    unknown = [k for k in names if k not in required and k not in optional]
    if missing:
        raise TrajectoryFormatError(f"{where}: missing {what}(s) {missing}; {valid}")
    if unknown:
        raise TrajectoryFormatError(f"{where}: unknown {what}(s) {sorted(unknown)}; {valid}")


@dataclass(frozen=True)
class TrajectoryMeta:
    """What a trajectory's columns mean.

    Attributes:
        robot: robot name, e.g. ``"furuta"`` (compared with ``bemlearn.robots.load(name).name``).
        joint_names: the n joint (coordinate) names in the robot's joint order; the columns of q.
        unactuated: the name of the unactuated joint q_u (one of ``joint_names``).
        actuator_names: the n − 1 input names; the columns of u.
        sample_rate_hz: nominal sample rate, Hz (samples within a trial are 1/rate apart).
        units: unit of each array, e.g. ``{"t": "s", "q": "rad", "u": "V"}``.
        trial_failed: per trial id, whether the trial fell / failed (every trial id present).
        extra: free-form JSON-serializable provenance (seed, config, ...).
        joint_kinds: ``"hinge"`` or ``"slide"`` per joint (default: all hinges); q of a
            hinge is in rad, of a slide in m.
        channel_names: names of the extra logged channels (columns of ``Trajectory.channels``).
        qu_upright: the reading of q_u at the upright (the pose balanced), in its unit (default 0:
            the convention of imported logs; a simulated robot whose upright reads π by its geometry or
            its joint ``ref`` records π). Windows on q_u are taken relative to it.
        torque_joints: the joints with a logged torque (N·m) or force (N) (columns of
            ``Trajectory.tau``, a subset of ``joint_names``).
    """

    robot: str
    joint_names: tuple[str, ...]
    unactuated: str
    actuator_names: tuple[str, ...]
    sample_rate_hz: float
    trial_failed: dict[int, bool]
    units: dict[str, str] = field(default_factory=lambda: dict(DEFAULT_UNITS))
    extra: dict[str, Any] = field(default_factory=dict)
    joint_kinds: tuple[str, ...] = ()
    channel_names: tuple[str, ...] = ()
    qu_upright: float = 0.0
    torque_joints: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        object.__setattr__(self, "actuator_names", tuple(self.actuator_names))
        object.__setattr__(self, "trial_failed", {int(k): bool(v) for k, v in self.trial_failed.items()})
        object.__setattr__(self, "units", dict(self.units))
        object.__setattr__(self, "extra", dict(self.extra))
        kinds = tuple(self.joint_kinds) or ("hinge",) * len(self.joint_names)
        object.__setattr__(self, "joint_kinds", kinds)
        object.__setattr__(self, "channel_names", tuple(self.channel_names))
        object.__setattr__(self, "torque_joints", tuple(self.torque_joints))
        n = len(self.joint_names)
        if n < 2:
            raise TrajectoryFormatError(f"meta.joint_names: expected at least 2 joints, got {list(self.joint_names)}")
        if len(set(self.joint_names)) != n:
            raise TrajectoryFormatError(f"meta.joint_names: duplicate names in {list(self.joint_names)}")
        if self.unactuated not in self.joint_names:
            raise TrajectoryFormatError(
                f"meta.unactuated: {self.unactuated!r} is not one of the joints {list(self.joint_names)}"
            )
        if len(self.actuator_names) != n - 1 or len(set(self.actuator_names)) != n - 1:
            raise TrajectoryFormatError(
                f"meta.actuator_names: expected {n - 1} distinct names (n − 1 for {n} joints), "
                f"got {list(self.actuator_names)}"
            )
        for name in (*self.joint_names, *self.actuator_names):
            if not name or "," in name or ":" in name or name != name.strip():
                raise TrajectoryFormatError(
                    f"meta: joint/actuator name {name!r} must be non-empty, without ',' ':' or surrounding spaces"
                )
        if len(kinds) != n or any(k not in JOINT_KINDS for k in kinds):
            raise TrajectoryFormatError(
                f"meta.joint_kinds: expected {n} entries from {sorted(JOINT_KINDS)}, got {list(kinds)}"
            )
        for name in self.channel_names:
            if not isinstance(name, str) or not name or "," in name or name != name.strip():
                raise TrajectoryFormatError(
                    f"meta.channel_names: channel name {name!r} must be a non-empty string without ',' or surrounding spaces"
                )
        if len(set(self.channel_names)) != len(self.channel_names):
            raise TrajectoryFormatError(f"meta.channel_names: duplicate names in {list(self.channel_names)}")
        stray = [j for j in self.torque_joints if j not in self.joint_names]
        if stray or len(set(self.torque_joints)) != len(self.torque_joints):
            raise TrajectoryFormatError(f"meta.torque_joints: expected distinct joints of {list(self.joint_names)}, "
                                        f"got {list(self.torque_joints)}")
        rate = self.sample_rate_hz
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0:
            raise TrajectoryFormatError(f"meta.sample_rate_hz: expected a positive number, got {rate!r}")
        object.__setattr__(self, "sample_rate_hz", float(rate))
        up = self.qu_upright
        if isinstance(up, bool) or not isinstance(up, (int, float)) or not math.isfinite(up):
            raise TrajectoryFormatError(f"meta.qu_upright: expected a finite number (q_u's reading at upright), got {up!r}")
        object.__setattr__(self, "qu_upright", float(up))

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def unactuated_index(self) -> int:
        """Column of q_u in q."""
        return self.joint_names.index(self.unactuated)

    @property
    def actuated_names(self) -> tuple[str, ...]:
        """The m = n − 1 actuated joint names q_a, in the robot's joint order."""
        return tuple(j for j in self.joint_names if j != self.unactuated)

    @property
    def actuated_indices(self) -> tuple[int, ...]:
        """Columns of q_a in q, in the robot's joint order."""
        return tuple(i for i, j in enumerate(self.joint_names) if j != self.unactuated)

    @property
    def qu_from_upright(self) -> str:
        """``"alpha"`` or ``"alpha − 3.14159"``: how q_u's distance from the upright reads in messages."""
        return self.unactuated if self.qu_upright == 0.0 else f"{self.unactuated} − {self.qu_upright:g}"

    @property
    def dt(self) -> float:
        """Nominal sample period, s."""
        return 1.0 / self.sample_rate_hz

    @property
    def collected_excursion(self) -> tuple[float, ...] | None:
        """The per-direction extents the data were collected with (``collect.excursion`` in the provenance that
        :func:`~bemlearn.sim.collect.collect` writes under ``extra["collect_config"]``); ``None`` for data from
        elsewhere or without them."""
        cc = (self.extra or {}).get("collect_config") or {}
        ext = cc.get("excursion") if isinstance(cc, dict) else None
        return tuple(float(x) for x in ext) if ext else None

    def kind_of(self, joint: str) -> str:
        """``"hinge"`` or ``"slide"``."""
        return self.joint_kinds[self.joint_names.index(joint)]

    def to_json_dict(self) -> dict[str, Any]:
        """The JSON form stored in files (trial ids become string keys).

        ``joint_kinds`` is written only when some joint is a slide, ``channel_names`` only
        when there are channels, ``torque_joints`` only when torques were logged, so files
        without them keep their v1 form.
        """
        optional: dict[str, Any] = {}
        if any(k != "hinge" for k in self.joint_kinds):
            optional["joint_kinds"] = list(self.joint_kinds)
        if self.channel_names:
            optional["channel_names"] = list(self.channel_names)
        if self.qu_upright != 0.0:
            optional["qu_upright"] = self.qu_upright
        if self.torque_joints:
            optional["torque_joints"] = list(self.torque_joints)
        return {
            "robot": self.robot,
            "joint_names": list(self.joint_names),
            "unactuated": self.unactuated,
            "actuator_names": list(self.actuator_names),
            "sample_rate_hz": self.sample_rate_hz,
            "units": dict(self.units),
            "trial_failed": {str(k): v for k, v in sorted(self.trial_failed.items())},
            "extra": dict(self.extra),
            **optional,
        }

    def to_json(self) -> str:
        try:
            return json.dumps(self.to_json_dict(), sort_keys=False, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise ArgumentError(
                f"TrajectoryMeta.extra must be JSON-serializable (finite numbers, str, lists, dicts): {exc}"
            ) from exc

    @classmethod
    def from_json_dict(cls, data: Mapping[str, Any], *, source: str = "meta") -> TrajectoryMeta:
        """Parse the stored JSON form; errors name ``source`` and the offending key."""
        if not isinstance(data, Mapping):
            raise TrajectoryFormatError(f"{source}: metadata must be a JSON object, got {type(data).__name__}")
        required = ("robot", "joint_names", "unactuated", "actuator_names", "sample_rate_hz", "trial_failed")
        optional = ("units", "extra", "joint_kinds", "channel_names", "qu_upright", "torque_joints")
        check_names(data, required, optional, where=source, what="metadata key",
                    valid=f"valid keys are {sorted(required + optional)}")
        expect = {
            "robot": str, "joint_names": list, "unactuated": str, "actuator_names": list,
            "trial_failed": dict, "units": dict, "extra": dict, "joint_kinds": list, "channel_names": list,
            "torque_joints": list,
        }
        for key, typ in expect.items():
            if key in data and not isinstance(data[key], typ):
                raise TrajectoryFormatError(
                    f"{source}: metadata key {key!r} must be a JSON {typ.__name__}, got {data[key]!r}"
                )
        bad_units = {k: v for k, v in data.get("units", {}).items() if not isinstance(v, str)}
        if bad_units:
            raise TrajectoryFormatError(f"{source}: metadata key 'units' must map names to unit strings, got {bad_units!r}")
        for key in ("joint_names", "actuator_names", "joint_kinds", "channel_names", "torque_joints"):
            if key in data and not all(isinstance(s, str) for s in data[key]):
                raise TrajectoryFormatError(f"{source}: metadata key {key!r} must list strings, got {data[key]!r}")
        failed: dict[int, bool] = {}
        for k, v in data["trial_failed"].items():
            try:
                tid = int(k)
            except ValueError:
                raise TrajectoryFormatError(
                    f"{source}: meta.trial_failed key {k!r} is not an integer trial id"
                ) from None
            if not isinstance(v, bool):
                raise TrajectoryFormatError(f"{source}: meta.trial_failed[{k!r}] must be true or false, got {v!r}")
            failed[tid] = v
        try:
            return cls(
                robot=data["robot"],
                joint_names=tuple(data["joint_names"]),
                unactuated=data["unactuated"],
                actuator_names=tuple(data["actuator_names"]),
                sample_rate_hz=data["sample_rate_hz"],
                trial_failed=failed,
                units=dict(data.get("units", DEFAULT_UNITS)),
                extra=dict(data.get("extra", {})),
                joint_kinds=tuple(data.get("joint_kinds", ())),
                channel_names=tuple(data.get("channel_names", ())),
                qu_upright=data.get("qu_upright", 0.0),
                torque_joints=tuple(data.get("torque_joints", ())),
            )
        except TrajectoryFormatError as exc:
            raise TrajectoryFormatError(f"{source}: {exc}") from None


@dataclass(frozen=True)
class TrialSlice:
    """The contiguous rows ``rows`` of trial ``trial_id`` (``failed``: it fell)."""

    trial_id: int
    failed: bool
    rows: slice

    @property
    def n_samples(self) -> int:
        return self.rows.stop - self.rows.start


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Samples of one or more trials (see module docstring).

    Attributes:
        t: (T,) float64 time, s.
        trial: (T,) int64 trial id; each trial's rows are contiguous.
        q: (T, n) float64 joint coordinates, rad (m for slides), columns ``meta.joint_names``.
        u: (T, n − 1) float64 inputs, ``meta.units["u"]``, columns ``meta.actuator_names``.
        meta: what the columns mean, sample rate, per-trial outcome.
        qd: optional (T, n) float64 true joint velocities, rad/s (m/s for slides) (ground-truth files).
        qdd: optional (T, n) float64 true joint accelerations, rad/s² (m/s² for slides) (ground-truth files).
        channels: (T, k) float64 extra logged channels, columns ``meta.channel_names``
            (``None`` → an empty (T, 0) block when there are no channels).
        tau: (T, p) float64 logged torques, N·m (N for slides), columns ``meta.torque_joints``
            (``None`` → an empty (T, 0) block when none were logged).

    Construction checks only shapes and dtypes; :func:`bemlearn.data.validate` checks values.
    """

    t: np.ndarray
    trial: np.ndarray
    q: np.ndarray
    u: np.ndarray
    meta: TrajectoryMeta
    qd: np.ndarray | None = None
    qdd: np.ndarray | None = None
    channels: np.ndarray | None = None
    tau: np.ndarray | None = None

    def __post_init__(self) -> None:
        trial = np.asarray(self.trial)
        if trial.dtype.kind not in "iu":
            raise TrajectoryFormatError(f"Trajectory.trial: expected an integer array, got dtype {trial.dtype}")
        if trial.ndim != 1:
            raise TrajectoryFormatError(f"Trajectory.trial: expected shape (T,), got {trial.shape}")
        object.__setattr__(self, "trial", trial.astype(np.int64, copy=False))
        n = self.meta.n_joints
        no_channels = not self.meta.channel_names and (self.channels is None or np.shape(self.channels)[-1:] == (0,))
        if self.channels is None or no_channels:  # an empty block follows T (dataclasses.replace with new rows)
            object.__setattr__(self, "channels", np.zeros((len(trial), len(self.meta.channel_names))))
        if not self.meta.torque_joints and (self.tau is None or np.shape(self.tau)[-1:] == (0,)):
            object.__setattr__(self, "tau", np.zeros((len(trial), 0)))
        shapes = {"t": None, "q": n, "u": n - 1, "qd": n, "qdd": n, "channels": len(self.meta.channel_names),
                  "tau": len(self.meta.torque_joints)}
        for name, width in shapes.items():
            arr = getattr(self, name)
            if arr is None:
                if name in ("qd", "qdd"):
                    continue
                raise TrajectoryFormatError(f"Trajectory.{name}: required")
            arr = np.asarray(arr)
            if arr.dtype.kind not in "fiu":
                raise TrajectoryFormatError(f"Trajectory.{name}: expected a real numeric array, got dtype {arr.dtype}")
            arr = arr.astype(np.float64, copy=False)
            expected = (len(trial),) if width is None else (len(trial), width)
            if arr.shape != expected:
                k, p = len(self.meta.channel_names), len(self.meta.torque_joints)
                raise TrajectoryFormatError(
                    f"Trajectory.{name}: expected shape {expected} (T = len(trial), n = {n} joints, "
                    f"k = {k} channels, p = {p} torques), got {arr.shape}"
                )
            object.__setattr__(self, name, arr)
        if (self.qd is None) != (self.qdd is None):
            raise TrajectoryFormatError("Trajectory: ground truth needs both qd and qdd, or neither")

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def n_joints(self) -> int:
        return self.meta.n_joints

    @property
    def has_ground_truth(self) -> bool:
        return self.qd is not None

    def channel(self, name: str) -> np.ndarray:
        """(T,) float64 samples of the extra channel ``name`` (``meta.channel_names``)."""
        if name not in self.meta.channel_names:
            raise ArgumentError(f"no channel {name!r}; the trajectory has {list(self.meta.channel_names)}")
        assert self.channels is not None  # __post_init__ fills it
        return self.channels[:, self.meta.channel_names.index(name)]

    def qu_window_mask(self, window: float | None) -> np.ndarray | None:
        """``(T,)`` rows with |q_u − meta.qu_upright| ≤ ``window`` (q_u's unit), or ``None`` for no window."""
        if window is None:
            return None
        return np.abs(self.q[:, self.meta.unactuated_index] - self.meta.qu_upright) <= window
    def torque(self, joint: str) -> np.ndarray:
        """(T,) float64 logged torque (N·m) or force (N) on ``joint`` (``meta.torque_joints``)."""
        if joint not in self.meta.torque_joints:
            raise ArgumentError(f"no logged torque on {joint!r}; the trajectory has torques on {list(self.meta.torque_joints)}")
        assert self.tau is not None  # __post_init__ fills it
        return self.tau[:, self.meta.torque_joints.index(joint)]

    def trial_slices(self) -> list[TrialSlice]:
        """Contiguous row blocks, one per trial, in file order (a trial split in two blocks gives two entries)."""
        if self.n_samples == 0:
            return []
        starts = np.flatnonzero(np.diff(self.trial)) + 1
        bounds = np.concatenate([[0], starts, [self.n_samples]])
        return [
            TrialSlice(int(self.trial[a]), self.meta.trial_failed.get(int(self.trial[a]), False), slice(int(a), int(b)))
            for a, b in itertools.pairwise(bounds)
        ]

    def iter_trials(self) -> Iterator[TrialSlice]:
        """Yield each trial's :class:`TrialSlice` (use ``traj.q[s.rows]`` for its samples)."""
        yield from self.trial_slices()

    @property
    def trial_ids(self) -> tuple[int, ...]:
        """Trial ids in file order."""
        return tuple(s.trial_id for s in self.trial_slices())

    def select_rows(self, rows: np.ndarray) -> Trajectory:
        """A new trajectory with rows ``rows`` (bool mask or index array); ``trial_failed`` keeps present trials."""
        keys = ("t", "trial", "q", "u", "qd", "qdd", "channels", "tau")
        pick: dict[str, Any] = {k: (None if getattr(self, k) is None else getattr(self, k)[rows]) for k in keys}
        present = set(np.unique(pick["trial"]).tolist())
        failed = {k: v for k, v in self.meta.trial_failed.items() if k in present}
        meta = dataclasses.replace(self.meta, trial_failed=failed)
        return Trajectory(meta=meta, **pick)

    def select_trials(self, trial_ids: set[int] | list[int] | tuple[int, ...]) -> Trajectory:
        """A new trajectory holding only the given trials (rows keep their order)."""
        return self.select_rows(np.isin(self.trial, np.fromiter(trial_ids, dtype=np.int64)))

    def quantization_steps(self) -> dict[str, float | None]:
        """Each joint's encoder step δ (rad, m for slides), ``None`` where the angles lie on no grid.

        A file written by ``bemlearn data import`` carries the step detected in the *logged*
        values (``meta.extra["import"]["quantization_step"]``); it is used as stored, since
        after ``time.resample: linear`` the interpolated angles no longer lie on their
        encoder's grid.  Otherwise the step is detected in ``q``
        (:func:`~bemlearn.data.quantization.detect_quantization_step`).
        """
        imported = self.meta.extra.get("import")
        stored = imported.get("quantization_step") if isinstance(imported, dict) else None
        stored = stored if isinstance(stored, dict) else {}
        out: dict[str, float | None] = {}
        for i, name in enumerate(self.meta.joint_names):
            step = stored.get(name, "detect")
            if step is None or (isinstance(step, (int, float)) and not isinstance(step, bool) and math.isfinite(step) and step > 0):
                out[name] = None if step is None else float(step)
            else:
                out[name] = detect_quantization_step(self.q[:, i])
        return out

    def summary(self) -> dict[str, Any]:
        """A JSON-serializable overview: robot, joints, trials, samples, rate, failures, ranges, quantization."""
        slices = self.trial_slices()
        lengths = np.array([s.n_samples for s in slices]) if slices else np.zeros(0, dtype=int)
        failed = sorted(k for k, v in self.meta.trial_failed.items() if v)
        ranges = {
            name: [float(self.q[:, i].min()), float(self.q[:, i].max())] if self.n_samples else None
            for i, name in enumerate(self.meta.joint_names)
        }
        steps = self.quantization_steps()
        imported = self.meta.extra.get("import")
        resampled = isinstance(imported, dict) and isinstance(imported.get("resample"), dict)
        return {
            "robot": self.meta.robot,
            "joints": list(self.meta.joint_names),
            "unactuated": self.meta.unactuated,
            "actuators": list(self.meta.actuator_names),
            "units": dict(self.meta.units),
            "trials": int(len(np.unique(self.trial))),
            "failed_trials": len(failed),
            "failed_trial_ids": failed,
            "samples": self.n_samples,
            "sample_rate_hz": self.meta.sample_rate_hz,
            "duration_s": float(lengths.sum() / self.meta.sample_rate_hz),
            "trial_samples_min_median_max": (
                [int(lengths.min()), float(np.median(lengths)), int(lengths.max())] if len(lengths) else None
            ),
            "angle_ranges_rad": ranges,
            "quantization_step_rad": steps,
            "resampled": resampled,
            "ground_truth": self.has_ground_truth,
            "joint_kinds": dict(zip(self.meta.joint_names, self.meta.joint_kinds)),
            "channels": list(self.meta.channel_names),
            "torques": list(self.meta.torque_joints),
        }
