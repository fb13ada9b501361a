"""Shared builders for the data tests: sum-of-sines trajectories with known derivatives.

Each trial j of joint i follows q_i(t) = Σ_k A_ik sin(ω_ik t + φ_ijk), so q̇ and q̈ are
known in closed form; optional quantization rounds q to the grid 2π/4096 rad.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bemlearn.data import Trajectory, TrajectoryMeta

QSTEP = 2 * np.pi / 4096  # 4096-count encoder, rad


@dataclass
class SineSpec:
    amplitudes: np.ndarray  # (n, K) rad
    omegas: np.ndarray  # (n, K) rad/s


def sines(t: np.ndarray, spec: SineSpec, phases: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, q̇, q̈ (T, n) of Σ_k A sin(ω t + φ) for t (T,) s and phases (n, K)."""
    arg = spec.omegas[None] * t[:, None, None] + phases[None]
    A, w = spec.amplitudes[None], spec.omegas[None]
    return (A * np.sin(arg)).sum(-1), (A * w * np.cos(arg)).sum(-1), (-A * w**2 * np.sin(arg)).sum(-1)


def furuta_spec(n: int = 2) -> SineSpec:
    amps = np.array([[0.4, 0.2, 0.1], [0.15, 0.08, 0.04]] + [[0.2, 0.1, 0.05]] * (n - 2))
    freqs_hz = np.array([[0.4, 0.9, 1.7], [0.5, 1.1, 1.9]] + [[0.3, 0.8, 1.5]] * (n - 2))
    return SineSpec(amps, 2 * np.pi * freqs_hz)


def make_trajectory(
    lengths: tuple[int, ...] = (400, 300, 500, 250),
    *,
    rate: float = 400.0,
    quantize: bool = False,
    ground_truth: bool = False,
    seed: int = 0,
    joint_names: tuple[str, ...] = ("theta", "alpha"),
    unactuated: str = "alpha",
    failed: tuple[int, ...] = (1,),
    trial_ids: tuple[int, ...] | None = None,
    t0: float = 0.0,
) -> Trajectory:
    """A multi-trial trajectory; trial k has ``lengths[k]`` samples, time restarting at ``t0``."""
    rng = np.random.default_rng(seed)
    n = len(joint_names)
    spec = furuta_spec(n)
    ids = trial_ids if trial_ids is not None else tuple(range(len(lengths)))
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "trial", "q", "qd", "qdd", "u")}
    for tid, T in zip(ids, lengths):
        t = t0 + np.arange(T) / rate
        q, qd, qdd = sines(t, spec, rng.uniform(0, 2 * np.pi, size=spec.amplitudes.shape))
        if quantize:
            q = np.round(q / QSTEP) * QSTEP
        parts["t"].append(t)
        parts["trial"].append(np.full(T, tid, dtype=np.int64))
        parts["q"].append(q)
        parts["qd"].append(qd)
        parts["qdd"].append(qdd)
        parts["u"].append(rng.normal(size=(T, n - 1)))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    meta = TrajectoryMeta(
        robot="furuta" if n == 2 else "biped",
        joint_names=joint_names,
        unactuated=unactuated,
        actuator_names=tuple(f"m_{j}" for j in joint_names if j != unactuated),
        sample_rate_hz=rate,
        trial_failed={tid: tid in failed for tid in ids},
        extra={"seed": seed, "source": "tests"},
    )
    gt = {"qd": cat["qd"], "qdd": cat["qdd"]} if ground_truth else {}
    return Trajectory(t=cat["t"], trial=cat["trial"], q=cat["q"], u=cat["u"], meta=meta, **gt)


def true_derivatives(traj_lengths: tuple[int, ...], **kwargs) -> tuple[np.ndarray, np.ndarray]:
    """The closed-form q̇, q̈ of ``make_trajectory(traj_lengths, **kwargs)``."""
    traj = make_trajectory(traj_lengths, ground_truth=True, **kwargs)
    return traj.qd, traj.qdd
