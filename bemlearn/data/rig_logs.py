"""Test logs written the way a real rig's logger writes them, from a (simulated) trajectory.

One CSV per trial (``episode_000.csv`` …), with a logger's comment preamble and header
``t,target_<a>…,target_<u>,<joint>…,control_output,feedforward,plant_input,saturation``:

- time in ms with µs digits, each stamp off by N(0, ``jitter_s``²) and a fraction
  ``drop_prob`` of samples missing (never the first or last);
- angles in degrees printed with ``deg_decimals`` decimals, or as encoder counts;
- the joints in ``flip`` written with the opposite sign (the logger's own convention);
- extra channels: targets, a feed-forward term, the input and a saturation flag
  (``target_<a>`` = q_a + 0.05 sin(2π·0.3 t), ``target_<u>`` = 0, ``feedforward`` = 0.1 u,
  ``saturation`` = 1 where |u| ≥ ``u_limit``).

Other loggers' habits, each off by default:

- ``header=False``: no header line (and no preamble): the map names the columns;
  ``delimiter``: ``","``, ``";"``, ``"\t"`` or ``" "`` (``aligned``: fields padded to a fixed
  width, so runs of spaces separate them); ``minimal``: only ``t``, the joints and
  ``plant_input`` (a home-built rig's ``t theta alpha voltage``);
- a real-time loop that *overruns*: each sample is late by U(0, ``overrun_max_s``] with
  probability ``overrun_prob`` and the loop never catches up (every later sample shifts); a
  clock that drifts: stamps = true time · (1 + ``clock_drift``).  The values are the
  trajectory linearly interpolated at the true sample times (angles rounded back onto the
  encoder grid, as an encoder reads them);
- ``cut_tail_chars``: the file ends that many characters early (1: just no final line end;
  more: the last line is cut mid-write).

:func:`rig_log_map` gives the :class:`~bemlearn.data.import_map.ImportMap` (as a plain
mapping, ready for YAML) that imports them back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bemlearn.data.quantization import detect_quantization_step, snap_to_grid
from bemlearn.data.trajectory import Trajectory
from bemlearn.errors import ArgumentError

__all__ = ["RigLogStyle", "log_columns", "rig_log_map", "write_rig_logs"]


@dataclass(frozen=True)
class RigLogStyle:
    """How the simulated logger writes (module docstring).

    Attributes:
        angle_unit: ``"deg"`` or ``"counts"``.
        deg_decimals: decimals of printed degrees.
        counts_per_rev: encoder resolution for ``"counts"``.
        flip: joints written with the opposite sign.
        jitter_s: std of the timestamp jitter, s.
        drop_prob: probability that a sample is missing.
        u_limit: the input's saturation level (``saturation`` flag), input units.
        seed: seed of jitter and drops.
        header: write the comment preamble and the header line.
        delimiter: the field separator (``","``, ``";"``, ``"\t"`` or ``" "``).
        aligned: pad every field to a fixed width (runs of spaces between fields).
        minimal: write only ``t``, the joints and ``plant_input``.
        overrun_prob: probability that the loop overruns at a sample.
        overrun_max_s: largest overrun, s (each one uniform in (0, overrun_max_s]).
        clock_drift: relative drift of the stamping clock (stamps = true time · (1 + drift)).
        cut_tail_chars: characters cut from the end of each file (the last line's line end first).
    """

    angle_unit: Literal["deg", "counts"] = "deg"
    deg_decimals: int = 4
    counts_per_rev: int = 4096
    flip: tuple[str, ...] = ("alpha",)
    jitter_s: float = 20e-6
    drop_prob: float = 0.002
    u_limit: float = 10.0
    seed: int = 0
    header: bool = True
    delimiter: str = ","
    aligned: bool = False
    minimal: bool = False
    overrun_prob: float = 0.0
    overrun_max_s: float = 0.0
    clock_drift: float = 0.0
    cut_tail_chars: int = 0


def log_columns(traj: Trajectory, style: RigLogStyle = RigLogStyle()) -> list[str]:
    """The column names of :func:`write_rig_logs`' files, in order (the header, or the map's ``columns``)."""
    meta = traj.meta
    if style.minimal:
        return ["t", *meta.joint_names, "plant_input"]
    return _columns(traj)


def _columns(traj: Trajectory) -> list[str]:
    meta = traj.meta
    return ["t", *(f"target_{j}" for j in meta.actuated_names), f"target_{meta.unactuated}", *meta.joint_names,
            "control_output", "feedforward", "plant_input", "saturation"]


def _late_times(t: np.ndarray, rate: float, style: RigLogStyle, rng: np.random.Generator) -> np.ndarray:
    """True sample times of a loop at ``rate`` that overruns (module docstring), within [t[0], t[-1]]."""
    n = len(t)
    late = np.where(rng.random(n) < style.overrun_prob, rng.uniform(0.0, style.overrun_max_s, n), 0.0)
    late[0] = 0.0
    tau = t[0] + np.arange(n) / rate + np.cumsum(late)
    return tau[tau <= t[-1]]


def write_rig_logs(traj: Trajectory, folder: str | Path, style: RigLogStyle = RigLogStyle()) -> list[Path]:
    """Write one logger CSV per trial of ``traj`` (an m = 1 robot: one input) into ``folder``.

    Args:
        traj: the trajectory (q (T, n) rad, u (T, 1)); hinges only.
        folder: created if missing.
        style: units, signs, jitter and drops, separators, header, clock (module docstring).

    Returns:
        The files, in trial order.
    """
    meta = traj.meta
    if meta.n_joints - 1 != 1 or any(k != "hinge" for k in meta.joint_kinds):
        raise ArgumentError("write_rig_logs: expects one input and hinge joints (a rotary-pendulum-like rig)")
    unknown = sorted(set(style.flip) - set(meta.joint_names))
    if unknown:
        raise ArgumentError(f"write_rig_logs: flip names unknown joint(s) {unknown}; joints are {list(meta.joint_names)}")
    if style.delimiter not in (",", ";", "\t", " "):
        raise ArgumentError(f"write_rig_logs: delimiter must be ',', ';', '\\t' or ' ', got {style.delimiter!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(style.seed)
    sign = np.array([-1.0 if j in style.flip else 1.0 for j in meta.joint_names])
    step = 2 * math.pi / style.counts_per_rev
    paths = []
    for s in traj.trial_slices():
        t, q, u = traj.t[s.rows], traj.q[s.rows], traj.u[s.rows, 0]
        if style.overrun_prob > 0:
            tau = _late_times(t, meta.sample_rate_hz, style, rng)
            q = np.column_stack([_encoder(np.interp(tau, t, q[:, j]), q[:, j], style) for j in range(meta.n_joints)])
            u = np.interp(tau, t, u)
            t = tau
        T = len(t)
        keep = rng.random(T) >= style.drop_prob
        keep[0] = keep[-1] = True
        stamp_ms = ((t - t[0]) * (1.0 + style.clock_drift) + rng.normal(0.0, style.jitter_s, T)) * 1e3
        qa = q[:, list(meta.actuated_indices)]
        targets = np.column_stack([qa + 0.05 * np.sin(2 * math.pi * 0.3 * t)[:, None], np.zeros(T)])
        if style.angle_unit == "deg":
            angles = np.degrees(q * sign)
            angle_fmt = f"%.{style.deg_decimals}f"
            targets = np.degrees(targets)
        else:
            angles = np.round(q * sign / step)
            angle_fmt = "%d"
            targets = np.round(targets / step)
        if style.minimal:
            table = np.column_stack([stamp_ms, angles, u])[keep]
            fmt = ["%.3f"] + [angle_fmt] * meta.n_joints + ["%.6f"]
        else:
            table = np.column_stack([
                stamp_ms, targets, angles, u, 0.1 * u, u, (np.abs(u) >= style.u_limit - 1e-9).astype(float),
            ])[keep]
            n_t = targets.shape[1]
            fmt = ["%.3f"] + [angle_fmt] * (n_t + meta.n_joints) + ["%.6f", "%.6f", "%.6f", "%d"]
        if style.aligned:
            fmt = [f"%14{f[1:]}" for f in fmt]
        path = folder / f"episode_{s.trial_id:03d}.csv"
        with open(path, "w", encoding="utf-8", newline="\n") as fh:
            if style.header:
                fh.write(f"# rig logger v0.3, episode {s.trial_id}, nominal rate {meta.sample_rate_hz:g} Hz\n")
                fh.write(f"# angles in {style.angle_unit}; t in ms since episode start\n")
                fh.write(style.delimiter.join(log_columns(traj, style)) + "\n")
            np.savetxt(fh, table, fmt=fmt, delimiter=style.delimiter)
        if style.cut_tail_chars:
            data = path.read_bytes()
            path.write_bytes(data[:-style.cut_tail_chars])
        paths.append(path)
    return paths


def _encoder(values: np.ndarray, logged: np.ndarray, style: RigLogStyle) -> np.ndarray:
    """Interpolated angles back on the encoder grid of ``logged`` (counts: rounded when written)."""
    if style.angle_unit == "counts":
        return values
    step = detect_quantization_step(logged)
    return values if step is None else snap_to_grid(values, step, logged)


def rig_log_map(traj: Trajectory, style: RigLogStyle = RigLogStyle()) -> dict[str, Any]:
    """The import map (a mapping for :func:`bemlearn.config.from_dict` / YAML) of :func:`write_rig_logs`' files.

    The delimiter is left to detection.  Header-less files get ``header: false`` and
    ``columns:``; an overrunning loop or a drifting clock gets ``time.resample: linear`` at
    the trajectory's rate.
    """
    meta = traj.meta
    unit = "deg" if style.angle_unit == "deg" else f"counts:{style.counts_per_rev}"
    time: dict[str, Any] = {"column": "t", "unit": "ms"}
    if style.overrun_prob > 0 or style.clock_drift != 0:
        time.update(rate_hz=meta.sample_rate_hz, resample="linear")
    mapping: dict[str, Any] = {
        "robot": meta.robot,
        "time": time,
        "joints": [
            {"name": j, "column": j, "unit": unit, "sign": -1 if j in style.flip else 1, "unactuated": j == meta.unactuated}
            for j in meta.joint_names
        ],
        "inputs": [{"name": meta.actuator_names[0], "column": "plant_input", "unit": meta.units.get("u", "V")}],
        "trials": "per_file",
        "keep": [] if style.minimal else [*(f"target_{j}" for j in meta.actuated_names), "feedforward", "saturation"],
    }
    if not style.header:
        mapping.update(header=False, columns=log_columns(traj, style))
    return mapping
