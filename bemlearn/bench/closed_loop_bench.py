"""``bemlearn bench closed-loop-data``: a rig's own balancing loop as the only source of data.

A robot balanced by a plain discrete LQR (``bemlearn.control.lqr.discrete_lqr`` at ``rate_hz``),
u = K e, e = [q − q_t, q̂̇ − q̇_t] (quantized encoders, the filtered velocity of
:mod:`bemlearn.data.sensors`), with small random torques d(t) on *every* joint (the unactuated
one included: bearing friction, a touch of the hand), each an Ornstein–Uhlenbeck process

    d_{k+1} = ρ d_k + σ √(1 − ρ²) ε_k,   ρ = exp(−Δt/τ_d),   ε_k ~ N(0, 1)                 (C1)

of stationary rms σ and correlation time τ_d, applied through ``qfrc_applied``.  Two cases:

* ``lockstep``: the reference is still (q_t = 0): nothing but the loop and the disturbances moves
  the robot, so the unactuated acceleration follows the actuated one (q̈_u ≈ b q̈_a);
* ``excited``: the same loop plays the reference schedule ``bemlearn excite`` writes for the
  lockstep data's config (sums of sines on the actuated reference).

Each case writes one CSV per trial (``t, <joints…>, u``, encoder-quantized angles), imports them
with ``bemlearn data import`` and a map, runs ``bemlearn run`` model-free on the file, and reads
the verdict and the learned BEM's slopes ∂q_u^e/∂q_a, ∂q_u^e/∂q̈_a (mean over the data's
actuated motions, eq. 14) against the model's (:func:`bemlearn.robots.scales.bem_slopes`).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bemlearn.errors import EnvironmentProblem
from bemlearn.pipeline.run_metrics import RunMetrics

__all__ = ["ClosedLoopCase", "simulate_logs", "bench_closed_loop_data", "learned_slopes"]


@dataclass(frozen=True)
class ClosedLoopCase:
    """One closed-loop data set (module docstring).

    Attributes:
        robot: MJCF path.
        trials, duration_s, rate_hz: the logs' shape.
        disturbance_rms: σ of (C1) per joint, N·m (N on a slide).
        disturbance_tau_s: τ_d of (C1), s.
        counts_per_rev: encoder resolution.
        seed: seed of the initial states, disturbances and encoder.
    """

    robot: str
    trials: int = 12
    duration_s: float = 20.0
    rate_hz: float = 500.0
    disturbance_rms: float = 3e-4
    disturbance_tau_s: float = 0.05
    counts_per_rev: int = 4096
    seed: int = 0


def _schedule_offsets(schedule: dict[str, Any] | None, names: tuple[str, ...], t: float, trial: int) -> tuple[np.ndarray, np.ndarray]:
    """q_t and q̇_t offsets of the actuated joints ``names`` at time ``t`` of ``trial`` from an excite schedule."""
    q, qd = np.zeros(len(names)), np.zeros(len(names))
    if schedule is None:
        return q, qd
    phases = schedule["phases"][trial % len(schedule["phases"])]
    for j, name in enumerate(names):
        for c, ph in zip(schedule["joints"][name]["sines"], phases[name]):
            w = 2 * math.pi * c["frequency_hz"]
            q[j] += c["amplitude"] * math.sin(w * t + ph)
            qd[j] += c["amplitude"] * w * math.cos(w * t + ph)
    return q, qd


def simulate_logs(case: ClosedLoopCase, out: Path, *, schedule: dict[str, Any] | None = None) -> tuple[list[Path], Path, dict]:
    """Run ``case`` (with ``schedule``'s reference when given) and write one CSV per trial and an import map.

    Returns:
        (CSV paths, map path, {"fell": trials that left |q_u − nominal| ≤ 0.5, "u_max": max |u| / ctrl limit}).
    """
    from bemlearn.control.lqr import discrete_lqr
    from bemlearn.data.sensors import SensorConfig
    from bemlearn.errors import RobotModelError
    from bemlearn.robots import MujocoRobot, load
    from bemlearn.sim.plant import SensedPlant

    robot = load(case.robot)
    if not isinstance(robot, MujocoRobot):
        raise RobotModelError(f"bench closed-loop-data: {case.robot!r} has no MuJoCo model to simulate")
    lqr = discrete_lqr(robot, rate_hz=case.rate_hz)
    n, iu, ia = robot.n, robot.unactuated_index, list(robot.actuated_index)
    act_names = tuple(robot.joint_names[j] for j in ia)
    lo, hi = robot.model.actuator_ctrlrange[:, 0], robot.model.actuator_ctrlrange[:, 1]
    out.mkdir(parents=True, exist_ok=True)
    seqs = np.random.SeedSequence(case.seed).spawn(case.trials)
    paths, fell, u_peak = [], 0, 0.0
    dofs = [int(robot.model.jnt_dofadr[robot.model.joint(name).id]) for name in robot.joint_names]
    for i, seq in enumerate(seqs):
        rng = np.random.default_rng(seq)
        plant = SensedPlant(robot, rate_hz=case.rate_hz, sensor=SensorConfig(counts_per_rev=case.counts_per_rev), rng=rng,
                            where="bench closed-loop-data")
        q0 = np.zeros(n)
        q0[ia] = rng.uniform(-0.05, 0.05, len(ia))
        q0[iu] = robot.qu_nominal + rng.uniform(-0.02, 0.02)
        plant.reset(q0)
        rho = math.exp(-1.0 / (case.rate_hz * case.disturbance_tau_s))
        d = rng.normal(0.0, case.disturbance_rms, n)
        ticks = int(round(case.duration_s * case.rate_hz))
        rows = np.empty((ticks, n + 2))
        k = ticks
        for tick in range(ticks):
            t = tick / case.rate_hz
            q_true = plant.true_q()
            if not abs(q_true[iu] - robot.qu_nominal) <= 0.5:
                fell, k = fell + 1, tick
                break
            y, v = plant.measure(q_true)
            q_ref, qd_ref = np.zeros(n), np.zeros(n)
            q_ref[iu] = robot.qu_nominal
            q_ref[ia], qd_ref[ia] = _schedule_offsets(schedule, act_names, t, i)
            if schedule is not None:            # the passive joint's rest position for those offsets (E1)
                sp = np.array([schedule["unactuated"]["static_slope"][nm] for nm in act_names])
                q_ref[iu] += float(sp @ q_ref[ia])
                qd_ref[iu] += float(sp @ qd_ref[ia])
            u = np.clip(lqr.K @ np.concatenate([y - q_ref, v - qd_ref]), lo, hi)
            u_peak = max(u_peak, float(np.max(np.abs(u) / np.maximum(hi, 1e-300))))
            d = rho * d + case.disturbance_rms * math.sqrt(1 - rho * rho) * rng.normal(size=n)
            plant.data.qfrc_applied[:] = 0.0
            plant.data.qfrc_applied[dofs] = d
            plant.apply(u)
            rows[tick, 0], rows[tick, 1:n + 1], rows[tick, n + 1:] = t, y, u
        path = out / f"trial_{i:02d}.csv"
        header = ",".join(["t", *robot.joint_names, "u"])
        np.savetxt(path, rows[:k], delimiter=",", header=header, comments="", fmt="%.9g")
        paths.append(path)
    map_path = out / "map.yaml"
    joints = "\n".join(f"  - {{name: {nm}, column: {nm}, unit: rad{', unactuated: true' if j == iu else ''}}}"
                       for j, nm in enumerate(robot.joint_names))
    map_path.write_text(f"robot: closed-loop-{Path(case.robot).stem}\ntime: {{column: t, unit: s, rate_hz: {case.rate_hz:g}}}\n"
                        f"joints:\n{joints}\ninputs:\n  - {{name: u, column: u, unit: ctrl}}\ntrials: per_file\n")
    return paths, map_path, {"fell": fell, "u_max": u_peak}


def _bemlearn(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run([sys.executable, "-m", "bemlearn", *args], capture_output=True, text=True, env=env, timeout=3600)


def learned_slopes(run_dir: Path) -> dict[str, float]:
    """Mean ∂μ/∂x_i of the run's learned BEM over its training data's actuated motions x_0^e (eq. 14), per actuated input."""
    import torch

    from bemlearn.export.checkpoint import load_checkpoint
    from bemlearn.models.input_noise import mean_gradient

    ck = load_checkpoint(run_dir)
    st = ck.predictor_state
    x = (st.Z * st.x_std + st.x_mean).to(torch.float64).clone()
    x[:, -2:] = 0.0
    g = mean_gradient(st, x).mean(0).numpy()
    return {name: float(v) for name, v in zip(st.input_names[:-2], g)}


def _run_case(label: str, case: ClosedLoopCase, work: Path, *, schedule: dict | None) -> dict[str, Any]:
    folder = work / label
    logs, map_path, sim = simulate_logs(case, folder / "logs", schedule=schedule)
    data = folder / "data.npz"
    p = _bemlearn("data", "import", *map(str, logs), "--map", str(map_path), "--out", str(data), "--force")
    if p.returncode:
        raise EnvironmentProblem(f"bemlearn data import failed ({p.returncode}): {p.stderr[-2000:]}")
    cfg = folder / "config.yaml"
    cfg.write_text(f"data: {data}\n")
    run = folder / "run"
    p = _bemlearn("run", str(cfg), "--out", str(run), "--no-progress", "--force")
    if p.returncode not in (0, 3):
        raise EnvironmentProblem(f"bemlearn run failed ({p.returncode}): {p.stderr[-3000:]}")
    metrics = RunMetrics.from_dict(json.loads((run / "metrics.json").read_text()))
    return {"label": label, "sim": sim, "verdict": metrics.verdict, "support": metrics.support,
            "slopes": learned_slopes(run), "config": cfg, "run": run}


def bench_closed_loop_data(case: ClosedLoopCase, work: Path) -> dict[str, Any]:
    """Both cases of the module docstring; returns their verdicts, supports and slopes vs the model's."""
    import yaml

    from bemlearn.robots import load
    from bemlearn.robots.scales import bem_slopes

    robot = load(case.robot)
    s = bem_slopes(robot)
    model = {}
    for j, nm in enumerate(robot.actuated_names):
        model[f"q_{nm}"], model[f"qd_{nm}"], model[f"qdd_{nm}"] = float(s[0, j]), float(s[1, j]), float(s[2, j])
    lock = _run_case("lockstep", case, work, schedule=None)
    sched_path = work / "excite.yaml"
    p = _bemlearn("excite", str(lock["config"]), "--out", str(sched_path), "--force")
    if p.returncode:
        raise EnvironmentProblem(f"bemlearn excite failed ({p.returncode}): {p.stderr[-2000:]}")
    schedule = yaml.safe_load(sched_path.read_text())
    dur = float(schedule.get("log_seconds_per_trial", case.duration_s))
    excited = _run_case("excited", ClosedLoopCase(**{**case.__dict__, "duration_s": max(case.duration_s, dur)}), work,
                        schedule=schedule)
    return {"model_slopes": model, "cases": [lock, excited], "excite_stdout": p.stdout, "schedule": schedule}
