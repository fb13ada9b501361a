"""`bemlearn excite`: the reference schedule (bemlearn.pipeline.excite, (E1)) from a data-only config and
from a robot config, checked against closed forms of the data's and the model's scales."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from bemlearn.data import Trajectory, TrajectoryMeta, write_trajectory

ROBOTS = Path(__file__).resolve().parent / "robots"


def _data_file(tmp_path: Path) -> Path:
    """Four 20 s trials at 100 Hz of an actuated joint moving as a 0.5 Hz sine (plus a slower 0.1 Hz one,
    1 % of the power) and an unactuated one on the BEM q_u = −0.1 q̈_a/g-like line (no lockstep needed here)."""
    rate, n = 100.0, 2000
    t = np.arange(n) / rate
    rows_q, rows_u, trial = [], [], []
    rng = np.random.default_rng(0)
    for i in range(4):
        ph = rng.uniform(0, 2 * np.pi)
        qa = 0.1 * np.sin(2 * np.pi * 0.5 * t + ph) + 0.01 * np.sin(2 * np.pi * 0.1 * t)
        qdd = -0.1 * (2 * np.pi * 0.5) ** 2 * np.sin(2 * np.pi * 0.5 * t + ph)
        qu = -0.01 * qdd + rng.normal(0, 2e-4, n)
        rows_q.append(np.c_[qa, qu])
        rows_u.append(0.5 * qdd[:, None])
        trial.append(np.full(n, i))
    meta = TrajectoryMeta(robot="rig", joint_names=("arm", "pole"), unactuated="pole", actuator_names=("motor",),
                          sample_rate_hz=rate, trial_failed={i: False for i in range(4)})
    traj = Trajectory(t=np.tile(t, 4), trial=np.concatenate(trial), q=np.concatenate(rows_q), u=np.concatenate(rows_u), meta=meta)
    return write_trajectory(traj, tmp_path / "rig.npz")


def test_schedule_from_data_follows_the_data_scales(tmp_path):
    from bemlearn.pipeline.excite import N_SINES, excitation_schedule, schedule_table
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    cfg = resolve_pipeline_config({"data": str(_data_file(tmp_path))}).config
    s = excitation_schedule(cfg)
    sines = s["joints"]["arm"]["sines"]
    f = np.array([c["frequency_hz"] for c in sines])
    # 75 % of the arm's motion power lies at 0.5 Hz (Welch bin 0.1 Hz at 10 s segments): f_hi = 2 × 0.5 Hz
    assert len(f) == N_SINES and f[-1] == pytest.approx(1.0, rel=0.11) and f[0] == pytest.approx(f[-1] / 10, rel=1e-9)
    assert np.allclose(np.diff(np.log(f)), np.log(10) / (N_SINES - 1))
    # lowest frequency 0.1 Hz → 10 periods = 100 s per trial; at least 12 trials
    assert s["log_seconds_per_trial"] == math.ceil(10 / f[0]) and s["trials"] == 12 and len(s["phases"]) == 12
    # the CSV table is the sum of the sines, and its rate column their derivative
    tab = schedule_table(s)
    first = tab[tab[:, 0] == 0]
    t = first[:, 1]
    ph = s["phases"][0]["arm"]
    ref = sum(c["amplitude"] * np.sin(2 * np.pi * c["frequency_hz"] * t + p) for c, p in zip(sines, ph))
    np.testing.assert_allclose(first[:, 2], ref, atol=1e-12)
    assert s["joints"]["arm"]["peak"] == pytest.approx(sum(c["amplitude"] for c in sines))


def test_cli_writes_yaml_and_csv_and_refuses_to_overwrite(tmp_path, capsys):
    from bemlearn.cli.main import main
    from bemlearn.pipeline.excite import write_schedule

    cfg = tmp_path / "data.yaml"
    cfg.write_text(f"data: {_data_file(tmp_path)}\n")
    out = tmp_path / "excite.yaml"
    assert main(["excite", str(cfg), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "log 12 trials ×" in printed and "arm:" in printed
    sched = yaml.safe_load(out.read_text())
    assert set(sched["joints"]) == {"arm"} and sched["rate_hz"] == 100.0
    assert main(["excite", str(cfg), "--out", str(out)]) == 2          # exists: needs --force
    assert "--force" in capsys.readouterr().err
    csv = write_schedule(sched, tmp_path / "excite.csv")
    assert csv.read_text().splitlines()[0] == "trial,t,arm,pole,arm_rate,pole_rate"


def test_schedule_from_a_robot_uses_its_instability_rate_and_limits():
    from bemlearn.pipeline.excite import excitation_schedule
    from bemlearn.pipeline.feasibility import equilibrium_stiffness
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.robots import load
    from bemlearn.robots.scales import bem_slopes, qa_half_ranges

    path = str(ROBOTS / "pendubot.xml")
    s = excitation_schedule(resolve_pipeline_config({"robot": path}).config)
    robot = load(path)
    eq = equilibrium_stiffness(robot)
    lam = math.sqrt(eq["gravity_stiffness"] / eq["d_uu"])
    f = [c["frequency_hz"] for c in s["joints"]["shoulder"]["sines"]]
    assert f[-1] == pytest.approx(1.5 * lam / (2 * math.pi), rel=1e-9)
    # the shoulder's position offsets stay within d / |s_p| (the lower link's BEM moves with q_a) and half its range
    cap = min(0.2 / abs(bem_slopes(robot)[0, 0]), 0.5 * qa_half_ranges(robot)[0])
    assert s["joints"]["shoulder"]["peak"] <= cap * (1 + 1e-9)
