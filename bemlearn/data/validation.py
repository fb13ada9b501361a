"""Value checks on a :class:`~bemlearn.data.trajectory.Trajectory` and its match with a robot.

Checked (an empty trajectory is an error too), each failing with a :class:`TrajectoryFormatError` that names the source, the
column (``t``, ``trial``, ``q:<joint>``, ``u:<actuator>``, ``qd:<joint>``, ``qdd:<joint>``)
and the row (0-based sample index; for CSV files also the file line):

- every value finite;
- each trial's rows contiguous, and its outcome listed in ``meta.trial_failed`` (and no
  outcome listed for a trial without samples);
- time strictly increasing within a trial; the *median* step of each trial equal to
  1/f_s within ``rate_rtol`` (1 %), and every step within ``jitter_rtol`` (10 %) of 1/f_s
  (timestamp jitter is accepted; a dropped sample — a step of 2/f_s — is not: resample
  such logs with ``bemlearn data import``);
- every trial at least ``min_trial_samples`` long;
- units: t in s, q in rad for hinges and m for slides (``meta.joint_kinds``; qd, qdd per
  second and per second² when present), as labelled by :func:`~bemlearn.units.q_unit_label`;
- optionally, joint names, unactuated joint and robot name equal to a robot's.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from bemlearn.data.limits import JITTER_RTOL, MIN_TRIAL_SAMPLES, RATE_RTOL
from bemlearn.data.trajectory import Trajectory, TrajectoryFormatError, TrajectoryMeta
from bemlearn.units import q_unit_label

__all__ = [
    "validate", "check_robot", "column_names", "RobotLike", "MIN_TRIAL_SAMPLES", "RATE_RTOL", "JITTER_RTOL",
]


class RobotLike(Protocol):
    """What :func:`check_robot` reads from a robot (``bemlearn.robots.load(name)`` objects)."""

    # read-only: a robot may give them as attributes or properties
    @property
    def name(self) -> str: ...
    @property
    def joint_names(self) -> tuple[str, ...]: ...
    @property
    def unactuated_name(self) -> str: ...
    @property
    def actuated_names(self) -> tuple[str, ...]: ...


def column_names(meta: TrajectoryMeta, *, ground_truth: bool = False) -> list[str]:
    """Column labels in file order: ``t, trial, q:<joint>..., u:<actuator>...[, qd:..., qdd:...][, tau:<joint>...][, x:<channel>...]``."""
    cols = ["t", "trial", *(f"q:{j}" for j in meta.joint_names), *(f"u:{a}" for a in meta.actuator_names)]
    if ground_truth:
        cols += [f"qd:{j}" for j in meta.joint_names] + [f"qdd:{j}" for j in meta.joint_names]
    return cols + [f"tau:{j}" for j in meta.torque_joints] + [f"x:{c}" for c in meta.channel_names]


def _row(i: int, first_line: int | None) -> str:
    return f"row {i}" if first_line is None else f"row {i} (line {first_line + i})"


def validate(
    traj: Trajectory,
    *,
    source: str = "<trajectory>",
    min_trial_samples: int = MIN_TRIAL_SAMPLES,
    rate_rtol: float = RATE_RTOL,
    robot: RobotLike | None = None,
    first_line: int | None = None,
    jitter_rtol: float = JITTER_RTOL,
) -> Trajectory:
    """Check ``traj`` (see module docstring) and return it unchanged.

    Args:
        traj: the trajectory.
        source: file name or label used in messages.
        min_trial_samples: shortest accepted trial, samples.
        rate_rtol: accepted |median(Δt) · f_s − 1| of each trial.
        jitter_rtol: accepted |Δt · f_s − 1| of every single step (timestamp jitter).
        robot: if given, joint names / unactuated joint / robot name must match it.
        first_line: for CSV sources, the 1-based file line of row 0 (added to messages).

    Raises:
        TrajectoryFormatError: naming ``source``, the column and the row.
    """
    meta = traj.meta
    if traj.n_samples == 0:
        raise TrajectoryFormatError(f"{source}: no samples")
    required = {"t": "s", **{k: q_unit_label(meta.joint_kinds, o) for o, k in enumerate(("q", "qd", "qdd"))}}
    for key, unit in required.items():
        if key in ("qd", "qdd") and not traj.has_ground_truth:
            continue
        if meta.units.get(key, unit) != unit:
            raise TrajectoryFormatError(f"{source}: meta.units[{key!r}] must be {unit!r}, got {meta.units[key]!r}")
    _check_finite(traj, source, first_line)
    slices = traj.trial_slices()
    seen: dict[int, int] = {}
    for s in slices:
        if s.trial_id in seen:
            raise TrajectoryFormatError(
                f"{source}: column 'trial', {_row(s.rows.start, first_line)}: trial {s.trial_id} resumes after "
                f"another trial (its rows must be contiguous; it first ended at row {seen[s.trial_id]})"
            )
        seen[s.trial_id] = s.rows.stop - 1
    present = set(seen)
    listed = set(meta.trial_failed)
    if present - listed:
        raise TrajectoryFormatError(
            f"{source}: meta.trial_failed has no outcome for trial(s) {sorted(present - listed)}"
        )
    if listed - present:
        raise TrajectoryFormatError(
            f"{source}: meta.trial_failed lists trial(s) {sorted(listed - present)} that have no samples"
        )
    dt = meta.dt
    for s in slices:
        if s.n_samples < min_trial_samples:
            raise TrajectoryFormatError(
                f"{source}: column 'trial', {_row(s.rows.start, first_line)}: trial {s.trial_id} has "
                f"{s.n_samples} samples, fewer than the minimum {min_trial_samples}"
            )
        t = traj.t[s.rows]
        steps = np.diff(t)
        bad = np.flatnonzero(steps <= 0)
        if len(bad):
            i = s.rows.start + int(bad[0]) + 1
            raise TrajectoryFormatError(
                f"{source}: column 't', {_row(i, first_line)}: time {float(t[bad[0] + 1])!r} s does not increase "
                f"(previous {float(t[bad[0]])!r} s) within trial {s.trial_id}"
            )
        if len(steps) and abs(float(np.median(steps)) / dt - 1.0) > rate_rtol:
            raise TrajectoryFormatError(
                f"{source}: column 't', {_row(s.rows.start, first_line)}: median time step "
                f"{float(np.median(steps))!r} s of trial {s.trial_id} is inconsistent with sample_rate_hz = "
                f"{meta.sample_rate_hz!r} (expected {dt!r} s ± {rate_rtol:.1e} relative)"
            )
        off = np.flatnonzero(np.abs(steps / dt - 1.0) > jitter_rtol)
        if len(off):
            i = s.rows.start + int(off[0]) + 1
            raise TrajectoryFormatError(
                f"{source}: column 't', {_row(i, first_line)}: time step {float(steps[off[0]])!r} s in trial "
                f"{s.trial_id} is inconsistent with sample_rate_hz = {meta.sample_rate_hz!r} "
                f"(expected {dt!r} s ± {jitter_rtol:.1e} relative jitter; a dropped sample or a gap? "
                "resample the logger's files with `bemlearn data import`)"
            )
    if robot is not None:
        check_robot(meta, robot, source=source)
    return traj


def _check_finite(traj: Trajectory, source: str, first_line: int | None) -> None:
    meta = traj.meta
    blocks: list[tuple[str, np.ndarray, list[str]]] = [
        ("t", traj.t[:, None], ["t"]),
        ("q", traj.q, [f"q:{j}" for j in meta.joint_names]),
        ("u", traj.u, [f"u:{a}" for a in meta.actuator_names]),
    ]
    assert traj.channels is not None  # Trajectory.__post_init__ fills it
    if traj.has_ground_truth:
        assert traj.qd is not None and traj.qdd is not None
        blocks += [
            ("qd", traj.qd, [f"qd:{j}" for j in meta.joint_names]),
            ("qdd", traj.qdd, [f"qdd:{j}" for j in meta.joint_names]),
        ]
    blocks.append(("channels", traj.channels, [f"x:{c}" for c in meta.channel_names]))
    assert traj.tau is not None  # Trajectory.__post_init__ fills it
    blocks.append(("tau", traj.tau, [f"tau:{j}" for j in meta.torque_joints]))
    for _, arr, names in blocks:
        finite = np.isfinite(arr)
        if not finite.all():
            row, col = (int(v[0]) for v in np.nonzero(~finite))
            raise TrajectoryFormatError(
                f"{source}: column {names[col]!r}, {_row(row, first_line)}: non-finite value {float(arr[row, col])!r}"
            )


def check_robot(meta: TrajectoryMeta, robot: RobotLike, *, source: str = "<trajectory>", match_name: bool = True) -> None:
    """Require the file's robot name, joint names (in order) and unactuated joint to be ``robot``'s.

    ``match_name=False`` leaves the robot's name out (an MJCF given by path is matched by its joints, not its label).

    Raises:
        TrajectoryFormatError: naming the first mismatch.
    """
    expected: dict[str, Any] = {
        "robot": robot.name,
        "joint_names": tuple(robot.joint_names),
        "unactuated": robot.unactuated_name,
    }
    found: dict[str, Any] = {"robot": meta.robot, "joint_names": meta.joint_names, "unactuated": meta.unactuated}
    if not match_name:
        del expected["robot"]
    for key, want in expected.items():
        if found[key] != want:
            has = "is" if key == "robot" else f"{robot.name!r} has"
            raise TrajectoryFormatError(f"{source}: meta.{key} is {_show(found[key])} but robot {has} {_show(want)}")


def _show(v: Any) -> str:
    return repr(list(v)) if isinstance(v, tuple) else repr(v)
