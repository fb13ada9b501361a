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

:func:`rig_log_map` gives the :class:`~bemlearn.data.import_map.ImportMap` (as a plain
mapping, ready for YAML) that imports them back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bemlearn.data.trajectory import Trajectory

__all__ = ["RigLogStyle", "rig_log_map", "write_rig_logs"]


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
    """

    angle_unit: Literal["deg", "counts"] = "deg"
    deg_decimals: int = 4
    counts_per_rev: int = 4096
    flip: tuple[str, ...] = ("alpha",)
    jitter_s: float = 20e-6
    drop_prob: float = 0.002
    u_limit: float = 10.0
    seed: int = 0


def _columns(traj: Trajectory) -> list[str]:
    meta = traj.meta
    return ["t", *(f"target_{j}" for j in meta.actuated_names), f"target_{meta.unactuated}", *meta.joint_names,
            "control_output", "feedforward", "plant_input", "saturation"]


def write_rig_logs(traj: Trajectory, folder: str | Path, style: RigLogStyle = RigLogStyle()) -> list[Path]:
    """Write one logger CSV per trial of ``traj`` (an m = 1 robot: one input) into ``folder``.

    Args:
        traj: the trajectory (q (T, n) rad, u (T, 1)); hinges only.
        folder: created if missing.
        style: units, signs, jitter and drops.

    Returns:
        The files, in trial order.
    """
    meta = traj.meta
    if meta.n_joints - 1 != 1 or any(k != "hinge" for k in meta.joint_kinds):
        raise ValueError("write_rig_logs: expects one input and hinge joints (a rotary-pendulum-like rig)")
    unknown = sorted(set(style.flip) - set(meta.joint_names))
    if unknown:
        raise ValueError(f"write_rig_logs: flip names unknown joint(s) {unknown}; joints are {list(meta.joint_names)}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(style.seed)
    sign = np.array([-1.0 if j in style.flip else 1.0 for j in meta.joint_names])
    paths = []
    for s in traj.trial_slices():
        t, q, u = traj.t[s.rows], traj.q[s.rows], traj.u[s.rows, 0]
        T = len(t)
        keep = rng.random(T) >= style.drop_prob
        keep[0] = keep[-1] = True
        stamp_ms = (t - t[0] + rng.normal(0.0, style.jitter_s, T)) * 1e3
        qa = q[:, list(meta.actuated_indices)]
        targets = np.column_stack([qa + 0.05 * np.sin(2 * math.pi * 0.3 * t)[:, None], np.zeros(T)])
        if style.angle_unit == "deg":
            angles = np.degrees(q * sign)
            angle_fmt = f"%.{style.deg_decimals}f"
            targets = np.degrees(targets)
        else:
            angles = np.round(q * sign / (2 * math.pi / style.counts_per_rev))
            angle_fmt = "%d"
            targets = np.round(targets / (2 * math.pi / style.counts_per_rev))
        table = np.column_stack([
            stamp_ms, targets, angles, u, 0.1 * u, u, (np.abs(u) >= style.u_limit - 1e-9).astype(float),
        ])[keep]
        n_t = targets.shape[1]
        fmt = ["%.3f"] + [angle_fmt] * (n_t + meta.n_joints) + ["%.6f", "%.6f", "%.6f", "%d"]
        path = folder / f"episode_{s.trial_id:03d}.csv"
        with open(path, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(f"# rig logger v0.3, episode {s.trial_id}, nominal rate {meta.sample_rate_hz:g} Hz\n")
            fh.write(f"# angles in {style.angle_unit}; t in ms since episode start\n")
            fh.write(",".join(_columns(traj)) + "\n")
            np.savetxt(fh, table, fmt=fmt, delimiter=",")
        paths.append(path)
    return paths


def rig_log_map(traj: Trajectory, style: RigLogStyle = RigLogStyle()) -> dict[str, Any]:
    """The import map (a mapping for :func:`bemlearn.config.from_dict` / YAML) of :func:`write_rig_logs`' files."""
    meta = traj.meta
    unit = "deg" if style.angle_unit == "deg" else f"counts:{style.counts_per_rev}"
    return {
        "robot": meta.robot,
        "time": {"column": "t", "unit": "ms"},
        "joints": [
            {"name": j, "column": j, "unit": unit, "sign": -1 if j in style.flip else 1, "unactuated": j == meta.unactuated}
            for j in meta.joint_names
        ],
        "inputs": [{"name": meta.actuator_names[0], "column": "plant_input", "unit": meta.units.get("u", "V")}],
        "trials": "per_file",
        "keep": [*(f"target_{j}" for j in meta.actuated_names), "feedforward", "saturation"],
    }
