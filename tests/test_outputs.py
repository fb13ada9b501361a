"""Output folders are claimed atomically and a failed command leaves them as they were (issue 22).

bemlearn.outputs.claim_outputs: exclusive creation of default folders, one lock per folder (a
second command writing it fails at once, naming the first), a hard-link snapshot of what a
``--force`` / ``--resume`` replaces, restored when the command fails or is killed.
"""

import json
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import yaml

from bemlearn.cli.main import main
from bemlearn.errors import CheckpointError, DataError, OutputBusyError, OutputExistsError
from bemlearn.files import atomic_write_text
from bemlearn.outputs import LOCK_NAME, claim_outputs

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data" / "furuta_excitation.npz"


def _tree(folder: Path) -> dict[str, bytes]:
    """Every file below ``folder`` (relative path → bytes), bemlearn's own lock and backups left out."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and not any(part.startswith(".bemlearn-") for part in p.relative_to(folder).parts)}


def _small_config(root: Path, name: str = "small.yaml", **data) -> Path:
    cfg = yaml.safe_load((ROOT / "configs/furuta.yaml").read_text())
    cfg["dataset"]["n_points"] = 120
    cfg["train"]["max_iter"] = 10
    cfg["collect"].update(n_trials=2, duration_s=2.0, workers=1)
    cfg.update(data)
    path = root / name
    path.write_text(yaml.safe_dump(cfg))
    return path


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A small trained and exported run (config, data, run folder)."""
    root = tmp_path_factory.mktemp("claims")
    cfg = _small_config(root)
    run = root / "run"
    assert main(["train", str(cfg), "--data", str(DATA), "--out", str(run), "--no-progress"]) == 0
    assert main(["export", str(run)]) == 0
    return cfg, run


def _copy(run: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(run, dst)
    return dst


# ---------------------------------------------------------------- concurrency

_HOLD = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from bemlearn.outputs import claim_outputs
    go = Path(sys.argv[1])
    while not go.exists():
        time.sleep(0.001)
    with claim_outputs(None, default_name="train", root=sys.argv[2]) as out:
        print(out, flush=True)
        time.sleep(1.0)
""")


def test_two_commands_started_in_the_same_second_get_two_folders(tmp_path):
    go = tmp_path / "go"
    procs = [subprocess.Popen([sys.executable, "-c", _HOLD, str(go), str(tmp_path / "runs")], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, cwd=ROOT) for _ in range(3)]
    time.sleep(3.0)   # all three are waiting for the start signal
    go.touch()
    outs = [p.communicate(timeout=60) for p in procs]
    assert all(p.returncode == 0 for p in procs), outs
    folders = [o[0].strip() for o in outs]
    assert len(set(folders)) == 3, folders
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == sorted(Path(f).name for f in folders)


def test_two_train_into_the_same_folder_one_wins(tmp_path):
    import shutil

    copies = [shutil.copy(DATA, tmp_path / f"data_{k}.npz") for k in "ab"]
    cfgs = [_small_config(tmp_path, f"{k}.yaml", data=str(c)) for k, c in zip("ab", copies)]
    out = tmp_path / "same"
    procs = [subprocess.Popen([sys.executable, "-m", "bemlearn", "train", str(c), "--out", str(out), "--no-progress"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT) for c in cfgs]
    results = [p.communicate(timeout=300) for p in procs]
    codes = sorted(p.returncode for p in procs)
    assert codes == [0, 2], results
    loser = results[[p.returncode for p in procs].index(2)][1]
    assert "is writing there right now" in loser or "would overwrite" in loser, loser
    from bemlearn.export.checkpoint import load_checkpoint

    # one run's files only: the data the config names is the one the checkpoint was trained on
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert load_checkpoint(out).metadata.extra["data_file"] == config["data"]


def test_a_folder_being_written_is_busy_for_other_commands(tmp_path):
    folder = tmp_path / "run"
    code = textwrap.dedent(f"""
        import time
        from bemlearn.outputs import claim_outputs
        with claim_outputs({str(folder)!r}, what="train") as out:
            print("claimed", flush=True)
            time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert proc.stdout.readline().strip() == "claimed"
        with pytest.raises(OutputBusyError, match=rf"{folder}: .* \(pid {proc.pid}, started .*\) is writing there right now"):
            with claim_outputs(folder, force=True):
                pass
        with pytest.raises(OutputBusyError):   # writing a single file of it waits for the whole-folder claim too
            with claim_outputs(folder, entries=["evaluation.json"], force=True):
                pass
    finally:
        proc.kill()
        proc.wait()


def test_different_files_of_one_folder_are_written_side_by_side(tmp_path):
    code = textwrap.dedent(f"""
        import time
        from bemlearn.outputs import claim_outputs
        with claim_outputs({str(tmp_path)!r}, entries=["a.npz", "a.truth.npz"]) as out:
            print("claimed", flush=True)
            time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert proc.stdout.readline().strip() == "claimed"
        with claim_outputs(tmp_path, entries=["b.npz"]) as out:   # another file: fine
            atomic_write_text(out / "b.npz", "b")
        with pytest.raises(OutputBusyError, match="is writing there right now"):
            with claim_outputs(tmp_path, entries=["a.truth.npz"], force=True):
                pass
    finally:
        proc.kill()
        proc.wait()


# ---------------------------------------------------------------- failed --force / --resume

def test_a_failed_train_force_leaves_the_run_as_it_was(trained, tmp_path, monkeypatch, capsys):
    _cfg, run = trained
    copy = _copy(run, tmp_path / "run")
    before = _tree(copy)

    def fail(*args, **kwargs):
        raise DataError("dataset: injected failure after config.yaml was written")  # a user error: exit 2

    monkeypatch.setattr("bemlearn.pipeline.train.build_datasets", fail)
    cfg2 = _small_config(tmp_path, "other.yaml")
    c = yaml.safe_load(cfg2.read_text())
    c["train"]["max_iter"] = 3
    cfg2.write_text(yaml.safe_dump(c))
    for extra in (["--force"], ["--resume"]):
        assert main(["train", str(cfg2), "--data", str(DATA), "--out", str(copy), "--no-progress", *extra]) == 2
        assert "injected failure" in capsys.readouterr().err
        assert _tree(copy) == before, extra   # the old config beside the old checkpoint, predictors kept
        assert sorted(p.name for p in copy.iterdir() if p.name.startswith(".bemlearn-")) == []


def test_a_failed_run_force_keeps_the_new_checkpoint_without_the_old_report(trained, tmp_path, monkeypatch, capsys, caplog):
    """A failure after training keeps what the run produced (never a mix: the old run's files it had not
    rewritten are gone), and metrics.json says at which stage it failed."""
    cfg, run = trained
    copy = _copy(run, tmp_path / "run")
    (copy / "report.md").write_text("# the old run's report\n")
    before = _tree(copy)

    def fail(*args, **kwargs):
        raise CheckpointError("export: injected failure after the new checkpoint was written")  # a user error: exit 2

    import importlib

    module = importlib.import_module("bemlearn.export.export_run")
    monkeypatch.setattr(module, "export_run", fail)      # the export stage of a serial run (--jobs 1)
    monkeypatch.setattr(module, "export_files", fail)    # the export checked beside the evaluation (bemlearn.pipeline.overlap)
    cfg = _small_config(tmp_path, "run.yaml", data=str(DATA))   # train on the shipped data: no collection
    assert main(["run", str(cfg), "--out", str(copy), "--force", "--no-progress"]) == 2
    assert "injected failure" in capsys.readouterr().err and f"{copy} keeps what it produced" in caplog.text
    after = _tree(copy)
    assert after["checkpoint.pt"] != before["checkpoint.pt"]            # the new fit, kept
    assert "report.md" not in after and "bem_predictor.pt" not in after  # the old run's report and predictor: gone
    metrics = json.loads(after["metrics.json"])
    assert metrics["failed"]["stage"] == "export" and metrics["verdict"]["status"] == "unusable"
    assert "checkpoint.pt" in metrics["failed"]["kept"] and "report.md" not in metrics["failed"]["kept"]
    assert not [p for p in copy.iterdir() if p.name.startswith(".bemlearn-")]


def test_an_interrupted_train_force_keeps_its_resumable_checkpoint(trained, tmp_path, monkeypatch, capsys):
    cfg, run = trained
    copy = _copy(run, tmp_path / "run")
    old_checkpoint = (copy / "checkpoint.pt").read_bytes()

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("bemlearn.pipeline.gp_stage.fit_gp", interrupted)
    assert main(["train", str(cfg), "--data", str(DATA), "--out", str(copy), "--force", "--no-progress"]) == 130
    from bemlearn.export.checkpoint import load_checkpoint

    ck = load_checkpoint(copy)
    assert ck.metadata.extra["interrupted"] is True and (copy / "checkpoint.pt").read_bytes() != old_checkpoint
    assert not (copy / "bem_predictor.pt").exists()   # exported from the replaced checkpoint
    assert not [p for p in copy.iterdir() if p.name.startswith(".bemlearn-")]


def test_an_interrupted_train_force_before_its_checkpoint_restores_the_run(trained, tmp_path, monkeypatch):
    _cfg, run = trained
    copy = _copy(run, tmp_path / "run")
    before = _tree(copy)

    def interrupted(*args, **kwargs):   # Ctrl-C while the datasets are built: no new checkpoint yet
        raise KeyboardInterrupt

    monkeypatch.setattr("bemlearn.pipeline.train.build_datasets", interrupted)
    other = _small_config(tmp_path, "other.yaml")
    other.write_text(other.read_text().replace("max_iter: 10", "max_iter: 3"))   # a config.yaml that differs
    assert main(["train", str(other), "--data", str(DATA), "--out", str(copy), "--force", "--no-progress"]) == 130
    assert _tree(copy) == before   # not the new config.yaml beside the old checkpoint


_KILLED = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from bemlearn.files import atomic_write_text
    from bemlearn.outputs import claim_outputs
    with claim_outputs(Path(sys.argv[1]), force=True, what="train") as out:
        atomic_write_text(out / "config.yaml", "new config")
        (out / "checkpoint.pt").unlink()
        atomic_write_text(out / "new.txt", "new")
        print("written", flush=True)
        time.sleep(60)
""")


def test_a_killed_force_is_marked_and_the_next_command_restores_the_folder(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text("old config")
    (run / "checkpoint.pt").write_bytes(b"old checkpoint")
    (run / "tb").mkdir()
    (run / "tb" / "events").write_bytes(b"old events")
    before = _tree(run)
    proc = subprocess.Popen([sys.executable, "-c", _KILLED, str(run)], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    assert proc.stdout.readline().strip() == "written"
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    record = json.loads((run / LOCK_NAME).read_text())   # marked: who left it half-done, and the snapshot
    assert record["pid"] == proc.pid and record["backup"].startswith(".bemlearn-backup-")
    assert _tree(run) != before
    with claim_outputs(run, entries=["evaluation.json"]) as out:   # any later command on the folder
        assert _tree(out) == before
    assert _tree(run) == before and not [p for p in run.iterdir() if p.name.startswith(".bemlearn-")]


def test_a_killed_new_run_is_reported_as_incomplete(tmp_path):
    run = tmp_path / "run"
    code = textwrap.dedent(f"""
        import time
        from bemlearn.outputs import claim_outputs
        with claim_outputs({str(run)!r}, what="run") as out:
            (out / "config.yaml").write_text("half")
            print("written", flush=True)
            time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    assert proc.stdout.readline().strip() == "written"
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    with pytest.raises(OutputExistsError, match=rf"would overwrite .*config.yaml \(an incomplete run left by .*pid {proc.pid}.*\); use --force"):
        with claim_outputs(run, what="run"):
            pass
    with claim_outputs(run, force=True) as out:
        atomic_write_text(out / "config.yaml", "complete")
    assert _tree(run) == {"config.yaml": b"complete"} and not (run / LOCK_NAME).exists()


def test_a_failed_command_removes_the_folder_it_created_and_keeps_a_users_folder(tmp_path):
    with pytest.raises(ValueError), claim_outputs(tmp_path / "a" / "b", what="run") as out:
        atomic_write_text(out / "x", "x")
        raise ValueError("boom")
    assert not (tmp_path / "a").exists()
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(ValueError), claim_outputs(mine, entries=["data.npz"]) as out:
        atomic_write_text(out / "data.npz", "x")
        raise ValueError("boom")
    assert _tree(mine) == {"notes.txt": b"keep"}
