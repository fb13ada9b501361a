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


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    from bemlearn.data.trajectory_io import write_trajectory
    from bemlearn.pipeline.resolve import complete_section
    from bemlearn.sim.collect import CollectConfig, collect

    cfg = complete_section(str(ROBOT), "collect", CollectConfig(n_trials=4, duration_s=4.0, workers=1, seed=3))
    traj, _ = collect(str(ROBOT), cfg, progress=False)
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


def test_a_failure_after_training_keeps_the_trained_artifacts(data, tmp_path, monkeypatch, capsys, caplog):
    import importlib

    def fail(*args, **kwargs):
        raise CheckpointError("export: injected failure")

    monkeypatch.setattr(importlib.import_module("bemlearn.export.export_run"), "export_run", fail)
    out = tmp_path / "new" / "run"
    assert main(["run", str(_config(tmp_path, data)), "--out", str(out), "--no-progress"]) == 2
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


def test_a_bug_in_the_evaluation_after_the_fit_keeps_the_checkpoint(data, tmp_path, monkeypatch, capsys):
    def bug(*args, **kwargs):
        raise RuntimeError("injected bug in the data-only evaluation")

    monkeypatch.setattr("bemlearn.pipeline.train._data_only_metrics", bug)
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
