"""Commands never lose a user's work: --force, new run folders, preflight, stale predictors (issue 16)."""

import time
from pathlib import Path

import pytest
import yaml
from conftest import furuta_section

from bemlearn.cli.main import main
from bemlearn.data.trajectory_io import write_trajectory
from bemlearn.export.staleness import check_predictor_matches, file_sha256, predictor_checkpoint_sha256
from bemlearn.sim.collect import collect


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    data, _ = collect("furuta", furuta_section("collect", n_trials=6, duration_s=6.0, workers=1, seed=1), progress=False)
    path = write_trajectory(data, root / "data.npz")
    cfg = yaml.safe_load(Path("configs/furuta.yaml").read_text())
    cfg["dataset"]["n_points"] = 120
    cfg["train"]["max_iter"] = 15
    cfg["collect"].update(n_trials=2, duration_s=2.0, workers=1)
    cfg_path = root / "small.yaml"
    cfg_path.write_text(yaml.safe_dump(cfg))
    run = root / "run"
    assert main(["train", str(cfg_path), "--data", str(path), "--out", str(run), "--no-progress"]) == 0
    assert main(["export", str(run), "--format", "both"]) == 0
    return root, cfg_path, path, run


def _err(capsys):
    return capsys.readouterr().err


def test_collect_refuses_to_replace_a_data_file(small, capsys, tmp_path):
    _, cfg, _, _ = small
    target = tmp_path / "x.npz"
    target.write_bytes(b"user data")
    assert main(["collect", str(cfg), "--out", str(target), "--no-progress"]) == 2
    err = _err(capsys)
    assert f"would overwrite {target}" in err and "use --force" in err
    assert target.read_bytes() == b"user data"


def test_train_into_an_existing_run_refuses_then_force_removes_stale_predictors(small, capsys, tmp_path):
    _root, cfg, data, run = small
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    before = (copy / "checkpoint.pt").read_bytes()
    assert main(["train", str(cfg), "--data", str(data), "--out", str(copy), "--no-progress"]) == 2
    assert "use --force" in _err(capsys) and (copy / "checkpoint.pt").read_bytes() == before
    check_predictor_matches(copy / "bem_predictor.pt", copy / "checkpoint.pt")
    # a different fit (fewer iterations) with --force: the old predictors no longer match and are removed
    cfg2 = tmp_path / "c2.yaml"
    c = yaml.safe_load(cfg.read_text())
    c["train"]["max_iter"] = 3
    cfg2.write_text(yaml.safe_dump(c))
    assert main(["train", str(cfg2), "--data", str(data), "--out", str(copy), "--no-progress", "--force"]) == 0
    assert (copy / "checkpoint.pt").read_bytes() != before
    assert not (copy / "bem_predictor.pt").exists() and not (copy / "bem_predictor.pt2").exists()


def test_predictor_records_its_checkpoint_and_stale_ones_are_refused(small, capsys, tmp_path):
    root, cfg, data, run = small
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    assert predictor_checkpoint_sha256(copy / "bem_predictor.pt") == file_sha256(copy / "checkpoint.pt")
    assert predictor_checkpoint_sha256(copy / "bem_predictor.pt2") == file_sha256(copy / "checkpoint.pt")
    assert main(["export", str(copy)]) == 2  # exists: refuse
    assert "would overwrite" in _err(capsys)
    shutil.copy(root / "run" / "checkpoint.pt", copy / "other.pt")
    (copy / "checkpoint.pt").write_bytes((copy / "checkpoint.pt").read_bytes())  # same bytes: still fresh
    assert main(["evaluate", str(copy), "--references", "1"]) == 0
    # replace the checkpoint by another fit's: the predictors are now stale
    cfg2 = tmp_path / "c2.yaml"
    c = yaml.safe_load(cfg.read_text())
    c["train"]["max_iter"] = 2
    cfg2.write_text(yaml.safe_dump(c))
    other = tmp_path / "other"
    assert main(["train", str(cfg2), "--data", str(data), "--out", str(other), "--no-progress"]) == 0
    shutil.copy(other / "checkpoint.pt", copy / "checkpoint.pt")
    assert main(["evaluate", str(copy), "--references", "1", "--force"]) == 2
    err = _err(capsys)
    assert "stale predictor" in err and "bem_predictor.pt" in err
    assert main(["export", str(copy), "--format", "both", "--force"]) == 0
    assert main(["evaluate", str(copy), "--references", "1", "--force"]) == 0


def test_run_into_a_non_empty_folder_refuses(small, capsys, tmp_path):
    _, cfg, _, _ = small
    (tmp_path / "report.md").write_text("my notes")
    t0 = time.perf_counter()
    assert main(["run", str(cfg), "--out", str(tmp_path), "--no-progress"]) == 2
    assert time.perf_counter() - t0 < 2.0
    assert "use --force" in _err(capsys) and sorted(p.name for p in tmp_path.iterdir()) == ["report.md"]


@pytest.mark.parametrize(
    "text, args, message",
    [
        ("", [], "config is empty (or only comments)"),
        ("# robot: furuta\n# collect: {n_trials: 3}\n", [], "config is empty (or only comments)"),
        ("collect: {n_trials: 3}\n", [], "names neither robot: nor data:"),
        ("robot: nosuch\n", [], "robot: unknown robot 'nosuch'"),
        ("robot: no/such.xml\n", [], "/no/such.xml not found"),   # resolved against the config's folder
        ("robot: furuta\n", ["--device", "cuda"], "CUDA was requested but no CUDA device is available"),
    ],
)
@pytest.mark.parametrize("command", ["run", "train", "collect"])
def test_preflight_fails_fast_and_leaves_nothing(tmp_path, capsys, text, args, message, command):
    import torch

    if "cuda" in args and (torch.cuda.is_available() or command == "collect"):
        pytest.skip("CUDA present, or collect has no --device")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(text)
    out = tmp_path / "out" / ("data.npz" if command == "collect" else "run")
    t0 = time.perf_counter()
    assert main([command, str(cfg), "--out", str(out), "--no-progress", *args]) == 2
    assert time.perf_counter() - t0 < 2.0
    assert message in _err(capsys)
    assert not (tmp_path / "out").exists()


def test_unwritable_output_fails_before_any_work(small, capsys):
    _, cfg, data, _ = small
    assert main(["train", str(cfg), "--data", str(data), "--out", "/proc/bemlearn-run", "--no-progress"]) == 2
    assert "--out: cannot write in /proc" in _err(capsys)


def test_failed_train_leaves_no_folder(small, capsys, tmp_path):
    _, cfg, _, _ = small
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    out = tmp_path / "run"
    assert main(["train", str(cfg), "--data", str(bad), "--out", str(out), "--no-progress"]) == 2
    assert "bad.npz: not a readable NPZ file" in _err(capsys)
    assert not out.exists()


def test_default_output_is_a_new_timestamped_folder(small, tmp_path, monkeypatch, capsys):
    _, cfg, _data, _ = small
    monkeypatch.chdir(tmp_path)
    (tmp_path / "configs").mkdir()
    assert main(["collect", str(cfg), "--no-progress", "--trials", "1"]) == 0
    made = list((tmp_path / "runs").iterdir())
    assert len(made) == 1 and made[0].name.startswith("collect-") and (made[0] / "data.npz").is_file()


@pytest.mark.parametrize("argv", [["collect", "c"], ["train", "c"], ["export", "r"], ["simulate", "c"], ["run", "c"],
                                  ["walk", "c"], ["gpdm", "c"], ["evaluate", "r"], ["data", "convert", "a", "b"]])
def test_every_writing_command_takes_force(argv):
    from bemlearn.cli.main import build_parser

    assert build_parser().parse_args([*argv, "--force"]).force is True
