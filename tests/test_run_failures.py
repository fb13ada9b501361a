"""A data-only run that names ``model:`` completes, and no failure after training deletes what a run produced (issue 28).

The data are the project's own: a short excitation of ``tests/robots/cartpole.xml`` collected here.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from bemlearn.cli.main import main
from bemlearn.errors import CheckpointError

ROBOT = Path(__file__).resolve().parent / "robots" / "cartpole.xml"
#: The cart-pole's gravity stiffness at upright, k_g = m g l_c: pole 0.2 kg, centre of mass 0.3 m up (N·m/rad).
K_G = 0.2 * 9.81 * 0.3
#: The logged torque on the hinge: its equilibrium shift τ_rms / k_g = 0.02 rad, twice the target 0.05 d (d = 0.2 rad).
TAU_RMS = 0.02 * K_G


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    import dataclasses

    import numpy as np

    from bemlearn.data import Trajectory
    from bemlearn.data.trajectory_io import write_trajectory
    from bemlearn.pipeline.resolve import complete_section
    from bemlearn.sim.collect import CollectConfig, collect

    cfg = complete_section(str(ROBOT), "collect", CollectConfig(n_trials=4, duration_s=4.0, workers=1, seed=3))
    traj, _ = collect(str(ROBOT), cfg, progress=False)
    # a torque "logged" on the pole's hinge (a label only: the simulation did not apply it), of rms TAU_RMS
    tau = np.random.default_rng(5).normal(0.0, 1.0, (traj.n_samples, 1))
    tau *= TAU_RMS / np.sqrt(np.mean(tau**2))
    traj = Trajectory(t=traj.t, trial=traj.trial, q=traj.q, u=traj.u, meta=dataclasses.replace(traj.meta, torque_joints=("hinge",)),
                      tau=tau)
    return write_trajectory(traj, tmp_path_factory.mktemp("cartpole") / "cartpole.npz")


def _config(tmp_path: Path, data: Path, **extra) -> Path:
    cfg = {"data": str(data), "model": str(ROBOT), "dataset": {"n_points": 80}, "train": {"max_iter": 8},
           "evaluate": {"design_points": 64, "n_references": 1, "duration_s": 1.0}, **extra}
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def test_the_model_of_a_data_only_run_derives_its_references(data, tmp_path):
    """``evaluate``'s references come from the model, as ``run`` with ``robot:`` derives them."""
    from bemlearn.pipeline.derive import control_rate, evaluation, excitation_signals
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.robots import load

    resolved = resolve_pipeline_config(_config(tmp_path, data))
    model = load(str(ROBOT))
    want = evaluation(model, excitation_signals(model, control_rate(model).value).value).value
    ev = resolved.config.evaluate
    assert ev.n_sines == tuple(want["n_sines"]) and ev.frequency_hz == pytest.approx(want["frequency_hz"], rel=1e-12)
    assert ev.amplitude_max == pytest.approx(want["amplitude_max"], rel=1e-12)
    assert ev.amplitude_min == pytest.approx(want["amplitude_min"], rel=1e-12)
    assert resolved.origins["evaluate.amplitude_max"] == "derived" and resolved.notes["evaluate.amplitude_max"].startswith("from model:")
    assert resolved.origins["evaluate.n_references"] == "given" and resolved.config.collect.rate_hz is None  # nothing else derived


def test_a_data_only_run_with_a_model_completes(data, tmp_path, capsys):
    out = tmp_path / "run"
    status = main(["run", str(_config(tmp_path, data)), "--out", str(out), "--no-progress"])
    assert status in (0, 3), capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert "failed" not in metrics and metrics["verdict"]["checked"][:1] != ["failed"]
    assert metrics["bem_design_region"]["n_points"] > 0 and metrics["bem_heldout"]["rmse"] >= 0
    for name in ("checkpoint.pt", "bem_predictor.pt", "report.md", "bem_validation.png"):
        assert (out / name).is_file(), name
    tq = metrics["unactuated_torque"]   # the logged torque on q_u, weighed against the model's gravity
    assert tq["stiffness"] == pytest.approx(K_G, rel=1e-6) and tq["rms"] == pytest.approx(TAU_RMS, rel=1e-12)
    assert tq["shift_rms"] == pytest.approx(0.02, rel=1e-6) and tq["target"] == pytest.approx(0.01, rel=1e-12)
    finding = next(f for f in metrics["verdict"]["findings"] if f["check"] == "unactuated_torque")
    assert finding["severity"] == "degraded" and metrics["verdict"]["status"] != "ok"
    assert finding["reason"].startswith("the unactuated joint hinge carries a logged torque of 0.0118 N·m rms")
    assert "moves the equilibrium by 0.02 rad rms, more than the accuracy target 0.01 rad" in finding["reason"]
    assert finding["reason"] in (out / "report.md").read_text()


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_a_failure_after_training_keeps_the_trained_artifacts(jobs, data, tmp_path, monkeypatch, capsys, caplog):
    """The export fails: in the export stage (``--jobs 1``) or beside the evaluation, where it is recorded as
    the export stage's failure all the same (``--jobs 2``: bemlearn.pipeline.overlap)."""
    import importlib

    def fail(*args, **kwargs):
        raise CheckpointError("export: injected failure")

    module = importlib.import_module("bemlearn.export.export_run")
    monkeypatch.setattr(module, "export_run", fail)     # the export stage of a serial run
    monkeypatch.setattr(module, "export_files", fail)   # the export checked beside the evaluation
    out = tmp_path / "new" / "run"
    assert main(["run", str(_config(tmp_path, data)), "--out", str(out), "--no-progress", "--jobs", jobs]) == 2
    assert "injected failure" in capsys.readouterr().err
    assert f"failed at stage 'export' (CheckpointError: export: injected failure); {out} keeps what it produced" in caplog.text
    for name in ("checkpoint.pt", "config.yaml", "config_resolved.json", "metrics.json"):
        assert (out / name).is_file(), name
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["failed"]["stage"] == "export" and metrics["failed"]["error_type"] == "CheckpointError"
    assert "checkpoint.pt" in metrics["failed"]["kept"] and metrics["data"]["samples"] > 0
    assert metrics["verdict"]["status"] == "unusable" and metrics["verdict"]["findings"][0]["check"] == "failed"
    assert "fit" in metrics and "bem_design_region" in metrics   # the partial metrics of the stages that ran
    from bemlearn.export.checkpoint import load_checkpoint

    load_checkpoint(out)   # the trained checkpoint is whole
    assert not [p for p in out.iterdir() if p.name.startswith(".bemlearn-")]
    assert not (out / "bem_predictor.pt").exists() and not (out / "bem_predictor.pt2").exists()


def test_a_bug_in_the_evaluation_after_the_fit_keeps_the_checkpoint(data, tmp_path, monkeypatch, capsys):
    def bug(*args, **kwargs):
        raise RuntimeError("injected bug in the data-only evaluation")

    monkeypatch.setattr("bemlearn.pipeline.train_metrics._data_only_metrics", bug)
    out = tmp_path / "run"
    assert main(["run", str(_config(tmp_path, data)), "--out", str(out), "--no-progress"]) == 1   # a bug: traceback, exit 1
    assert "injected bug" in capsys.readouterr().err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["failed"]["stage"] == "train: evaluation" and metrics["failed"]["error_type"] == "RuntimeError"
    assert metrics["verdict"]["status"] == "unusable" and "fit" in metrics and metrics["data"]["samples"] > 0
    assert (out / "checkpoint.pt").is_file() and not (out / "bem_predictor.pt").exists()


def test_a_failure_before_anything_worth_keeping_leaves_no_folder(data, tmp_path, monkeypatch, capsys):
    from bemlearn.errors import DataError

    def fail(*args, **kwargs):
        raise DataError("dataset: injected failure before the fit")

    monkeypatch.setattr("bemlearn.pipeline.train.build_datasets", fail)
    out = tmp_path / "new" / "run"
    assert main(["run", str(_config(tmp_path, data)), "--out", str(out), "--no-progress"]) == 2
    assert "injected failure" in capsys.readouterr().err and not (tmp_path / "new").exists()


def test_the_gravity_stiffness_is_m_g_l_for_the_cartpole():
    from bemlearn.pipeline.logged_torque import gravity_stiffness
    from bemlearn.robots import load

    assert gravity_stiffness(load(str(ROBOT))) == pytest.approx(K_G, rel=1e-6)


@pytest.mark.parametrize("extra, severity, status, text", [
    ({"stiffness": 0.5, "stiffness_unit": "N·m/rad", "bound": 0.2, "target": 0.01, "gravity_scale": 0.1, "shift_rms": 0.012},
     "degraded", "degraded", "moves the equilibrium by 0.012 rad rms, more than the accuracy target 0.01 rad (0.05 d; 6 % of"),
    ({"stiffness": 0.5, "stiffness_unit": "N·m/rad", "bound": 0.2, "target": 0.01, "gravity_scale": 0.1, "shift_rms": 0.008},
     "note", "ok", "less than the accuracy target"),
    ({}, "note", "ok", "with no model it cannot be weighed against gravity"),
])
def test_the_verdict_weighs_a_torque_on_the_unactuated_joint(extra, severity, status, text):
    from bemlearn.pipeline.verdict import judge_run

    rms = extra.get("shift_rms", 0.01) * extra.get("stiffness", 0.5)
    v = judge_run({"unactuated_torque": {"joint": "alpha", "unit": "N·m", "rms": rms, "mean": 0.0, "max_abs": 3 * rms, **extra}})
    assert v.status == status and "unactuated_torque" in v.checked
    (f,) = v.findings
    assert f.severity == severity and text in f.reason and f.reason.startswith("the unactuated joint alpha carries a logged torque of")
    assert judge_run({"unactuated_torque": {"joint": "alpha", "unit": "N·m", "rms": 0.0, "mean": 0.0, "max_abs": 0.0}}).findings == ()
