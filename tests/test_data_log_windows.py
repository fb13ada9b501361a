"""Import maps with a time window (global and per file) and logged torque columns (issue 28, part 4).

The logs are written here: a 500 Hz logger (ms stamps) of a hinge θ (counts), a pendulum α
(degrees) that swings up in its first second and then balances, a voltage, and the torques on
both joints (θ's in N·m, α's in mN·m).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from bemlearn.cli.main import main
from bemlearn.config import ConfigError
from bemlearn.data import TrajectoryFormatError, read_trajectory, write_trajectory
from bemlearn.data.import_map import load_import_map
from bemlearn.data.log_import import import_logs

RATE = 500.0
COUNTS = 2048


def write_log(path: Path, *, seconds: float = 4.0, t0_ms: float = 0.0, seed: int = 0, alpha_torque_mnm: float = 0.3) -> dict:
    """One logger file; returns its raw columns (as written)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE)
    t = t0_ms + np.arange(n) * 1000.0 / RATE
    s = (t - t0_ms) / 1000.0
    swing = s < 1.0
    alpha = np.where(swing, 180.0 * np.cos(math.pi * s), 2.0 * np.sin(2 * math.pi * 1.3 * s))   # deg
    theta = np.round(COUNTS / (2 * math.pi) * 0.4 * np.sin(2 * math.pi * 0.7 * s))             # counts
    cols = {"t": t, "theta": theta, "alpha": np.round(alpha, 4), "u": np.round(rng.normal(0, 1, n), 4),
            "tau_theta": np.round(0.05 * np.sin(2 * math.pi * 0.7 * s), 6),
            "tau_alpha": np.round(alpha_torque_mnm * rng.normal(0, 1, n), 6)}
    lines = [",".join(cols)] + [",".join(f"{cols[c][i]:.6f}" for c in cols) for i in range(n)]
    path.write_text("\n".join(lines) + "\n")
    return cols


def map_of(path: Path, **extra) -> Path:
    mapping = {
        "time": {"column": "t", "unit": "ms", **extra.pop("time", {})},
        "joints": [{"name": "theta", "column": "theta", "unit": f"counts:{COUNTS}"},
                   {"name": "alpha", "column": "alpha", "unit": "deg", "unactuated": True}],
        "inputs": [{"name": "voltage", "column": "u", "unit": "V"}],
        **extra,
    }
    path.write_text(yaml.safe_dump(mapping, sort_keys=False))
    return path


@pytest.fixture
def logs(tmp_path):
    raw = {name: write_log(tmp_path / name, seed=i) for i, name in enumerate(["swing_001.csv", "swing_002.csv", "calm_001.csv"])}
    return tmp_path, raw


# ---------------------------------------------------------------- windows


def test_a_global_window_keeps_the_logged_rows_inside_it(logs):
    root, raw = logs
    imap = load_import_map(map_of(root / "map.yaml", time={"window": [1000, 3000]}))
    traj = import_logs([root / "swing_001.csv"], imap)
    inside = (raw["swing_001.csv"]["t"] >= 1000) & (raw["swing_001.csv"]["t"] <= 3000)
    assert traj.n_samples == int(inside.sum()) == 1001
    # the logged values (scaled by π/180 in another order: equal to 1 ulp)
    np.testing.assert_allclose(traj.q[:, 1], raw["swing_001.csv"]["alpha"][inside] * math.pi / 180, rtol=4e-16, atol=0)
    assert traj.t[0] == pytest.approx(1.0, abs=1e-9) and traj.t[-1] == pytest.approx(3.0, abs=1e-9)
    assert np.abs(traj.q[:, 1]).max() < 0.04   # the swing-up (|α| up to π) is left out
    info = traj.meta.extra["import"]["windows"]
    assert info == [{"file": str(root / "swing_001.csv"), "key": "time.window", "window": [1000.0, 3000.0], "unit": "ms",
                     "rows": 2000, "kept": 1001}]


def test_per_file_windows_override_the_global_one(logs):
    root, _ = logs
    imap = load_import_map(map_of(root / "map.yaml", time={"window": [0, 2000]}, windows={"swing_*.csv": [1000, None]}))
    files = [root / "swing_001.csv", root / "calm_001.csv", root / "swing_002.csv"]
    traj = import_logs(files, imap)
    lengths = [s.n_samples for s in traj.trial_slices()]
    assert lengths == [1500, 1001, 1500]   # [1 s, end] of 2000 rows (4 s); [0, 2 s] inclusive; [1 s, end]
    starts = [traj.t[s.rows][0] for s in traj.trial_slices()]
    assert starts == pytest.approx([1.0, 0.0, 1.0], abs=1e-9)
    keys = [w["key"] for w in traj.meta.extra["import"]["windows"]]
    assert keys == ["windows['swing_*.csv']", "time.window", "windows['swing_*.csv']"]


def test_a_window_applies_before_resampling(logs):
    root, raw = logs
    imap = load_import_map(map_of(root / "map.yaml", time={"window": [1001.3, None], "resample": "linear"}))
    traj = import_logs([root / "swing_001.csv"], imap)
    first_stamp = raw["swing_001.csv"]["t"][raw["swing_001.csv"]["t"] >= 1001.3][0]   # 1002 ms: the grid starts there
    assert traj.t[0] == pytest.approx(first_stamp / 1000, abs=1e-9)
    assert traj.n_samples == int(np.sum(raw["swing_001.csv"]["t"] >= 1001.3))


def test_a_window_without_a_time_column_counts_seconds_from_the_first_row(tmp_path):
    write_log(tmp_path / "a.csv")
    imap = load_import_map(map_of(tmp_path / "map.yaml", time={"column": None, "rate_hz": RATE, "window": [1.0, 1.5]}))
    traj = import_logs([tmp_path / "a.csv"], imap)
    assert traj.n_samples == 251 and traj.meta.extra["import"]["windows"][0]["unit"] == "s"


@pytest.mark.parametrize("mapping, message", [
    ({"time": {"window": [3000, 1000]}}, r"map\.time: window: expected \[t0, t1\] with t0 < t1 .*got \[3000, 1000\]"),
    ({"time": {"window": [None, None]}}, r"window: expected \[t0, t1\] with at least one bound"),
    ({"windows": {"calm_*.csv": [2, 1]}}, r"windows\['calm_\*.csv'\]: expected \[t0, t1\] with t0 < t1"),
])
def test_bad_windows_in_the_map_name_the_key(tmp_path, mapping, message):
    with pytest.raises(ConfigError, match=message):
        load_import_map(map_of(tmp_path / "map.yaml", **mapping))


@pytest.mark.parametrize("mapping, message", [
    ({"time": {"window": [1000, 9000]}}, r"swing_001.csv: time.window = \[1000, 9000\] ms: t1 = 9000 lies outside the log, "
                                         r"whose time runs 0–3998 ms"),
    ({"windows": {"swing_001.csv": [-5, None]}}, r"swing_001.csv: windows\['swing_001.csv'\] = \[-5, null\] ms: t0 = -5 lies outside"),
    ({"time": {"window": [1000, 1010]}}, r"swing_001.csv: time.window = \[1000, 1010\] ms holds 6 samples, fewer than the 10"),
    ({"windows": {"swing_*": [1000, None], "*_001.csv": [0, 10]}}, r"swing_001.csv: matched by windows\['swing_\*', '\*_001.csv'\]"),
    ({"windows": {"swing_01.csv": [1000, None]}}, r"windows\['swing_01.csv'\]: matches none of the files \['swing_001.csv'\]"),
])
def test_bad_windows_for_a_file_name_the_file_and_the_key(logs, mapping, message):
    root, _ = logs
    imap = load_import_map(map_of(root / "map.yaml", **mapping))
    with pytest.raises((TrajectoryFormatError, ConfigError), match=message):
        import_logs([root / "swing_001.csv"], imap)


# ---------------------------------------------------------------- torques


def torque_map(root: Path, **extra) -> Path:
    return map_of(root / "map.yaml", time={"window": [1000, None]}, torques=[
        {"joint": "theta", "column": "tau_theta", "unit": "N*m", "scale": 2.0, "sign": -1},
        {"joint": "alpha", "column": "tau_alpha", "unit": "mN*m"}], **extra)


def test_torque_columns_are_carried_in_si_and_round_trip(logs):
    root, raw = logs
    traj = import_logs([root / "swing_001.csv", root / "calm_001.csv"], load_import_map(torque_map(root)))
    inside = raw["swing_001.csv"]["t"] >= 1000
    n = int(inside.sum())
    np.testing.assert_array_equal(traj.torque("theta")[:n], -2.0 * raw["swing_001.csv"]["tau_theta"][inside])
    np.testing.assert_array_equal(traj.torque("alpha")[:n], 1e-3 * raw["swing_001.csv"]["tau_alpha"][inside])
    assert traj.meta.torque_joints == ("theta", "alpha") and traj.summary()["torques"] == ["theta", "alpha"]
    for suffix in (".npz", ".csv"):
        back = read_trajectory(write_trajectory(traj, root / f"rig{suffix}"))
        assert back.meta.torque_joints == ("theta", "alpha")
        assert back.tau.tobytes() == traj.tau.tobytes() and back.q.tobytes() == traj.q.tobytes()
    header = (root / "rig.csv").read_text().splitlines()[2]
    assert header == "t,trial,q:theta,q:alpha,u:voltage,tau:theta,tau:alpha"
    summary = traj.meta.extra["import"]["torques"]
    both = np.concatenate([1e-3 * raw[f]["tau_alpha"][raw[f]["t"] >= 1000] for f in ("swing_001.csv", "calm_001.csv")])
    assert summary["alpha"]["rms"] == pytest.approx(math.sqrt(np.mean(both**2)), rel=1e-12)
    assert summary["alpha"]["unactuated"] and not summary["theta"]["unactuated"] and summary["alpha"]["unit"] == "N·m"


def test_a_file_without_torques_keeps_its_v1_form(logs):
    root, _ = logs
    traj = import_logs([root / "swing_001.csv"], load_import_map(map_of(root / "map.yaml")))
    path = write_trajectory(traj, root / "plain.npz")
    with np.load(path) as npz:
        assert "tau" not in npz.files and "torque_joints" not in json.loads(str(npz["meta"]))
    assert read_trajectory(path).tau.shape == (traj.n_samples, 0)


def test_a_torque_on_the_unactuated_joint_is_reported_by_the_import(logs, capsys):
    root, _ = logs
    assert main(["data", "import", str(root / "swing_001.csv"), "--map", str(torque_map(root)), "--out", str(root / "rig.npz")]) == 0
    out = capsys.readouterr().out
    assert "warning: the unactuated joint alpha carries a logged torque of 0.000" in out
    assert "the BEM assumes it unactuated (Γ_u = 0)" in out and "logged torque on theta:" in out
    assert "time.window = [1000, end] ms: 1500 of 2000 rows imported" in out
    assert main(["data", "check", str(root / "rig.npz")]) == 0
    assert "torques:      theta, alpha (on the unactuated joint: the BEM assumes none there)" in capsys.readouterr().out


@pytest.mark.parametrize("torque, message", [
    ({"joint": "phi", "column": "tau_alpha"}, r"torques\[0\].joint: 'phi' is not one of the joints \['theta', 'alpha'\]"),
    ({"joint": "alpha", "column": "tau_alpha", "unit": "N"}, r"torques\[0\].unit: 'alpha' is a hinge: expected one of \['N\*m'"),
    ({"joint": "alpha", "column": "tau_alpha", "unit": "Nm/A"}, r"unit: expected one of \['N\*m'"),
    ({"joint": "alpha", "column": "tau_alpha", "sign": 2}, r"sign: expected 1 or -1, got 2"),
])
def test_bad_torque_entries_name_the_key(tmp_path, torque, message):
    with pytest.raises(ConfigError, match=message):
        load_import_map(map_of(tmp_path / "map.yaml", torques=[torque]))


def test_a_missing_torque_column_names_the_map_key(logs):
    root, _ = logs
    imap = load_import_map(map_of(root / "map.yaml", torques=[{"joint": "alpha", "column": "tau_pend"}]))
    with pytest.raises(TrajectoryFormatError, match=r"swing_001.csv.*tau_pend"):
        import_logs([root / "swing_001.csv"], imap)
