"""``bemlearn gpdm``, ``bemlearn walk`` and the biped dispatch of ``bemlearn run``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from bemlearn.apps.biped.human_gait import HUMAN_GAIT_CSV
from bemlearn.apps.biped.walker import WalkConfig, simulate_walk, walk_trajectories
from bemlearn.cli.main import main
from bemlearn.data import read_ground_truth, read_trajectory, write_trajectory

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "biped.yaml"


def _printed_c(out: str) -> np.ndarray:
    line = next(ln for ln in out.splitlines() if ln.startswith("c = ["))
    return np.array([float(v) for v in line[5:line.index("]")].split(",")])


def test_gpdm_on_human_csv_writes_c_latents_metrics(tmp_path, capsys):
    out = tmp_path / "gpdm"
    assert main(["gpdm", str(CONFIG), "--data", str(HUMAN_GAIT_CSV), "--out", str(out), "--max-iter", "5", "--no-progress"]) == 0
    text = capsys.readouterr().out
    m = json.loads((out / "metrics.json").read_text())
    np.testing.assert_allclose(_printed_c(text), m["c"], atol=5e-4)  # printed to 3 decimals
    assert "human gait" in text and len(m["c"]) == 5 and sum(m["sequences"]) == len(np.load(out / "latents.npz")["chi"])
    assert any(p.name.startswith("events.out.tfevents") for p in (out / "tb").iterdir())


def test_gpdm_on_walk_trajectory_uses_trials_as_sequences(tmp_path, capsys):
    data, _ = walk_trajectories(simulate_walk(WalkConfig(duration_s=2.5, seed=5), progress=False))
    path = write_trajectory(data, tmp_path / "walk.npz")
    out = tmp_path / "gpdm"
    assert main(["gpdm", str(CONFIG), "--data", str(path), "--out", str(out), "--max-iter", "3", "--no-progress"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    ids = list(read_trajectory(path).trial_ids)[2:8]  # gpdm.first_step = 2, gpdm.steps = 6 in configs/biped.yaml
    assert m["sequences"] == [int((data.trial == i).sum()) for i in ids]
    z = np.load(out / "latents.npz")
    np.testing.assert_allclose(z["q"], np.concatenate([data.q[data.trial == i] for i in ids]), atol=0)
    assert "trials 2…" in capsys.readouterr().out


def test_gpdm_missing_data_is_a_named_error(tmp_path, capsys):
    assert main(["gpdm", str(CONFIG), "--data", str(tmp_path / "nope.npz"), "--out", str(tmp_path / "o")]) == 2
    assert "nope.npz not found" in capsys.readouterr().err


def test_walk_writes_files_and_metrics(tmp_path, capsys):
    out = tmp_path / "walk"
    assert main(["walk", str(CONFIG), "--duration", "2", "--steps", "3", "--out", str(out), "--no-progress"]) == 0
    m = json.loads((out / "walk.json").read_text())
    assert m["steps"] == 3 and not m["fell"] and m["bem_source"] == "model"
    truth = read_ground_truth(out / "walk.truth.npz")
    assert truth.has_ground_truth and truth.meta.robot == "biped" and (out / "walk.png").is_file()
    assert "default gait, BEM source model: 3 steps" in capsys.readouterr().out


def test_walk_bad_options_exit_2(tmp_path, capsys):
    assert main(["walk", str(CONFIG), "--source", "model", "--predictor", str(tmp_path / "p.pt"), "--out", str(tmp_path)]) == 2
    assert "--predictor is only used with --source predictor" in capsys.readouterr().err
    assert main(["walk", str(CONFIG), "--predictor", str(tmp_path / "p.pt"), "--out", str(tmp_path)]) == 2
    assert "p.pt not found" in capsys.readouterr().err


def test_run_dispatches_biped_configs(tmp_path, capsys):
    import torch

    assert main(["run", str(CONFIG), "--device", "cuda", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err  # no CUDA here: preflight says so first; with CUDA the biped refuses it
    assert ("CUDA was requested but no CUDA device" in err) if not torch.cuda.is_available() else ("the biped pipeline trains on the CPU" in err)
    bad = tmp_path / "bad.yaml"
    bad.write_text("application: biped\nrobot: biped\nwalk: {duration: 3}\n")
    assert main(["run", str(bad), "--out", str(tmp_path / "run")]) == 2
    assert "unknown key(s) ['duration']" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
