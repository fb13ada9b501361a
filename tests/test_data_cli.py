"""``bemlearn data check`` / ``bemlearn data convert``."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from test_data_helpers import make_trajectory

from bemlearn.cli.main import main
from bemlearn.data import read_trajectory, write_trajectory


@pytest.fixture
def npz(tmp_path):
    return write_trajectory(make_trajectory((120, 80, 100), quantize=True, failed=(1,)), tmp_path / "run.npz")


def test_check_prints_summary(npz, capsys):
    assert main(["data", "check", str(npz)]) == 0
    out = capsys.readouterr().out
    assert "robot:        furuta" in out
    assert "joints:       theta, alpha (unactuated: alpha)" in out
    assert "trials:       3 (1 failed: 1)" in out
    assert "samples:      300 (0.75 s; per trial min/median/max 80/100/120)" in out
    assert "sample rate:  400 Hz" in out
    assert "(= 2π/4096, 4096 counts/rev)" in out
    traj = read_trajectory(npz)
    assert f"alpha        [{traj.q[:, 1].min():+.6g}, {traj.q[:, 1].max():+.6g}]" in out


def test_check_json(npz, capsys):
    assert main(["data", "check", str(npz), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["samples"] == 300 and s["failed_trial_ids"] == [1] and s["joints"] == ["theta", "alpha"]


def test_check_bad_file_exits_nonzero_with_named_error(tmp_path, capsys):
    traj = make_trajectory((30, 30))
    path = write_trajectory(traj, tmp_path / "bad.csv")
    lines = path.read_text().splitlines()
    cells = lines[3 + 17].split(",")
    cells[2] = "nan"
    lines[3 + 17] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    assert main(["data", "check", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"bemlearn data: error: {path}: column 'q:theta', row 17 (line 21): non-finite value nan" in err
    assert main(["data", "check", str(tmp_path / "missing.npz")]) == 2
    assert "trajectory file not found" in capsys.readouterr().err
    assert main(["data", "check", str(path), "--min-trial-samples", "50"]) == 2


def test_check_robot_option(npz, capsys, monkeypatch):
    import bemlearn.robots

    stand_ins = {
        "furuta": SimpleNamespace(name="furuta", joint_names=("theta", "alpha"), unactuated_name="alpha", actuated_names=("theta",)),
        "biped": SimpleNamespace(name="biped", joint_names=("q1", "q2", "q3", "q4", "q5"), unactuated_name="q1",
                                 actuated_names=("q2", "q3", "q4", "q5")),
    }
    monkeypatch.setattr(bemlearn.robots, "load", stand_ins.__getitem__, raising=False)
    assert main(["data", "check", str(npz), "--robot", "furuta"]) == 0
    capsys.readouterr()
    assert main(["data", "check", str(npz), "--robot", "biped"]) == 2
    assert "meta.robot is 'furuta' but robot is 'biped'" in capsys.readouterr().err


def test_convert_round_trip_bit_identical(npz, tmp_path, capsys):
    csv, back = tmp_path / "run.csv", tmp_path / "back.npz"
    assert main(["data", "convert", str(npz), str(csv)]) == 0
    assert main(["data", "convert", str(csv), str(back)]) == 0
    a, b = np.load(npz), np.load(back)
    assert set(a.files) == set(b.files)
    for key in a.files:
        assert a[key].dtype == b[key].dtype and a[key].tobytes() == b[key].tobytes(), key
    capsys.readouterr()
    assert main(["data", "convert", str(npz), str(csv)]) == 2
    assert f"would overwrite {csv}; use --force" in capsys.readouterr().err
    assert main(["data", "convert", str(npz), str(csv), "--force"]) == 0
    assert main(["data", "convert", str(npz), str(tmp_path / "x.h5")]) == 2
    assert "unsupported output suffix '.h5'" in capsys.readouterr().err
