"""scripts/family_refit.py: the derivative estimates' errors against exact ones, on a closed form, and its input errors.

A Gaussian of width σ smooths a sine of frequency ω by e^{−σ²ω²/2}; the Gaussian derivative estimate of q̈ is then
the exact q̈ times that factor, so (estimate − exact) has std (1 − e^{−σ²ω²/2}) × the exact column's and correlation
−1 with it.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from bemlearn.data import Trajectory, TrajectoryMeta
from bemlearn.data.trajectory_io import write_trajectory
from tests.file_module import load_file_module

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "family_refit.py"
SIGMA = 0.05      # s
RATE = 200.0      # Hz
OMEGA = {"theta": 2 * math.pi * 1.3, "alpha": 2 * math.pi * 0.7}   # rad/s
AMP = {"theta": 0.3, "alpha": 0.1}                                  # rad


def _run_folder(tmp_path: Path) -> Path:
    run = tmp_path / "run"
    run.mkdir()
    rng = np.random.default_rng(3)
    names = ("theta", "alpha")
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "trial", "q", "qd", "qdd")}
    for trial in range(5):
        t = np.arange(int(8 * RATE)) / RATE
        cols = [[], [], []]
        for name in names:
            w, a, phase = OMEGA[name], AMP[name], rng.uniform(0, 2 * math.pi)
            cols[0].append(a * np.sin(w * t + phase))
            cols[1].append(a * w * np.cos(w * t + phase))
            cols[2].append(-a * w * w * np.sin(w * t + phase))
        parts["t"].append(t)
        parts["trial"].append(np.full(len(t), trial, dtype=np.int64))
        for key, c in zip(("q", "qd", "qdd"), cols):
            parts[key].append(np.stack(c, axis=1))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    meta = TrajectoryMeta(robot="sines", joint_names=names, unactuated="alpha", actuator_names=("m_theta",),
                          sample_rate_hz=RATE, trial_failed={k: False for k in range(5)}, extra={"source": "tests"})
    traj = Trajectory(t=cat["t"], trial=cat["trial"], q=cat["q"], u=np.zeros((len(cat["t"]), 1)), meta=meta)
    write_trajectory(traj, run / "data.npz")
    np.savez(run / "data.truth.npz", q=cat["q"], qd=cat["qd"], qdd=cat["qdd"], trial=cat["trial"])
    cfg = {"robot": str(tmp_path / "robot.xml"), "dataset": {"derivative": "gaussian", "derivative_options": {"sigma_s": SIGMA},
                                                             "n_points": 300, "seed": 0}}
    (run / "config.yaml").write_text(yaml.safe_dump(cfg))
    return run


def test_errors_are_the_gaussian_shrink_of_each_sine(tmp_path):
    mod = load_file_module(SCRIPT)
    text = mod.estimate_errors(_run_folder(tmp_path))
    rows = {m.group(1): (float(m.group(2)), float(m.group(3)))
            for m in re.finditer(r"^\s+(\S+)\s+([0-9.]+)\s+corr ([+-][0-9.]+)$", text, flags=re.M)}
    assert set(rows) == {"qdd_theta", "qd_theta", "q_theta", "qdd_alpha", "qd_alpha"}, text
    for name, (rel, corr) in rows.items():
        joint = name.split("_", 1)[1]
        shrink = 1.0 - math.exp(-0.5 * (SIGMA * OMEGA[joint]) ** 2)
        assert rel == pytest.approx(shrink, abs=2e-3), (name, rel, shrink)
        assert corr < -0.99, (name, corr)


def test_bad_invocations_name_what_is_wrong(tmp_path, capsys):
    mod = load_file_module(SCRIPT)
    with pytest.raises(SystemExit):
        mod.main([str(tmp_path)])
    assert "give --out" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="config.yaml: no such file"):
        mod.main([str(tmp_path / "nowhere"), "--errors"])
    run = _run_folder(tmp_path)
    with pytest.raises(SystemExit, match="expected SECTION.KEY=VALUE"):
        mod.main([str(run), "--out", str(tmp_path / "out"), "--set", "n_points=3"])
    (run / "data.truth.npz").unlink()
    with pytest.raises(SystemExit, match="data.truth.npz: no such file"):
        mod.main([str(run), "--errors"])
