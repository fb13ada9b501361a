"""A full or read-only disk is one clear error, with no temporary file left (issue 22).

The real cases run on a tiny tmpfs (mounting needs root and CAP_SYS_ADMIN; skipped with the
reason otherwise): filled, or remounted read-only, which stops root too (``chmod`` does not).
The write primitive is also made to fail with ``ENOSPC`` in-process, which runs everywhere.
Before issue 22 ``export`` aborted with exit status 134 (``terminate called … c10::Error``,
torch's C++ archive writer) and left ``.p.pt.tmp-*`` behind; ``data convert`` and others
ended in an ``OSError`` traceback.
"""

import errno
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.cli.main import main
from bemlearn.errors import EnvironmentProblem
from bemlearn.export import write_checkpoint
from bemlearn.files import atomic_write_files

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data" / "furuta_excitation.npz"


def _leftovers(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if ".tmp-" in p.name or p.name.startswith(".bemlearn-"))


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    state, meta = synthetic_posterior(n_train=120, m=1, seed=4)
    return write_checkpoint(tmp_path_factory.mktemp("ck") / "run", model_state={"w": torch.ones(2)}, predictor_state=state, metadata=meta)


@pytest.fixture
def tmpfs(tmp_path):
    """A 1 MiB tmpfs at ``tmp_path/disk``; skipped with the reason when it cannot be mounted."""
    if shutil.which("mount") is None or not hasattr(os, "geteuid") or os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root (and the mount command)")
    disk = tmp_path / "disk"
    disk.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(disk)], capture_output=True, text=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


def _fill(disk: Path, leave: int) -> None:
    """Fill ``disk`` up to ``leave`` free bytes."""
    free = shutil.disk_usage(disk).free
    with open(disk / "filler", "wb") as fh:
        fh.write(b"\0" * max(0, free - leave))


def _read_only(disk: Path) -> None:
    subprocess.run(["mount", "-o", "remount,ro", str(disk)], check=True, capture_output=True)


def test_export_on_a_full_disk_exits_cleanly(tmpfs, checkpoint):
    run = tmpfs / "run"
    run.mkdir()
    shutil.copy(checkpoint, run / "checkpoint.pt")
    _fill(tmpfs, 60_000)   # less than the predictor needs
    res = subprocess.run([sys.executable, "-m", "bemlearn", "export", str(run)],
                         capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 2, res.stderr[-3000:]
    assert "no space left on device" in res.stderr and "Traceback" not in res.stderr and "terminate" not in res.stderr
    assert sorted(p.name for p in run.iterdir()) == ["checkpoint.pt"] and not _leftovers(tmpfs)


@pytest.mark.parametrize("command", ["export-c", "convert", "train"])
def test_writes_that_run_out_of_space_midway_exit_cleanly(tmpfs, checkpoint, command, monkeypatch, capsys):
    """With the up-front space check out of the way, the disk fills up during the write itself."""
    monkeypatch.setattr("bemlearn.files.check_free_space", lambda *a, **k: None)
    _fill(tmpfs, 40_000)
    out = tmpfs / "out"
    if command == "export-c":
        argv = ["export", str(checkpoint.parent), "--format", "c", "--out", str(out)]
    elif command == "convert":
        argv = ["data", "convert", str(DATA), str(out / "data.csv")]
    else:
        import yaml

        cfg = yaml.safe_load((ROOT / "configs/furuta.yaml").read_text())
        cfg["dataset"]["n_points"], cfg["train"]["max_iter"] = 400, 2
        path = tmpfs.parent / "c.yaml"
        path.write_text(yaml.safe_dump(cfg))
        argv = ["train", str(path), "--data", str(DATA), "--out", str(out), "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "no space left on device (ENOSPC)" in err, err
    assert not out.exists() and not _leftovers(tmpfs)   # the folder the command created is gone with its temporaries


@pytest.mark.parametrize("command", ["export", "export-c", "convert", "import"])
def test_a_read_only_output_fails_before_any_work(tmpfs, checkpoint, command, capsys, tmp_path):
    (tmpfs / "sub").mkdir()
    _read_only(tmpfs)
    out = tmpfs / "sub"
    argv = {"export": ["export", str(checkpoint.parent), "--out", str(out / "p.pt")],
            "export-c": ["export", str(checkpoint.parent), "--format", "c", "--out", str(out / "c")],
            "convert": ["data", "convert", str(DATA), str(out / "d.csv")],
            "import": ["data", "import", str(tmp_path / "missing.csv"), "--map", str(tmp_path / "missing.yaml"), "--out", str(out / "d.npz")],
            }[command]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"cannot write in {out}" in err and "Read-only file system" in err, err   # not the missing input


def test_a_failing_write_keeps_the_old_predictor(checkpoint, tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(checkpoint, run / "checkpoint.pt")
    assert main(["export", str(run)]) == 0
    before = (run / "bem_predictor.pt").read_bytes()

    def full(path, data):
        with open(path, "wb") as fh:
            fh.write(data[: len(data) // 2])
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr("bemlearn.files._write_data", full)
    assert main(["export", str(run), "--force"]) == 2
    err = capsys.readouterr().err
    assert f"cannot write {run / 'bem_predictor.pt'}: no space left on device (ENOSPC)" in err, err
    assert (run / "bem_predictor.pt").read_bytes() == before
    assert not _leftovers(run)


def test_a_file_set_is_written_all_or_none(tmp_path, monkeypatch):
    (tmp_path / "a.h").write_text("old a")
    (tmp_path / "a.c").write_text("old c")
    calls = []

    def second_fails(path, data):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(errno.EROFS, "Read-only file system", str(path))
        Path(path).write_bytes(data)

    monkeypatch.setattr("bemlearn.files._write_data", second_fails)
    with pytest.raises(EnvironmentProblem, match=r"cannot write .*a.c: read-only file system \(EROFS\)"):
        atomic_write_files({tmp_path / "a.h": b"new a", tmp_path / "a.c": b"new c"})
    assert (tmp_path / "a.h").read_text() == "old a" and (tmp_path / "a.c").read_text() == "old c"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.c", "a.h"]


def test_room_is_checked_before_anything_is_written(tmp_path, monkeypatch):
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr("shutil.disk_usage", lambda p: usage(10**6, 10**6 - 1000, 1000))
    with pytest.raises(EnvironmentProblem, match=r"cannot write .*big.bin: 0.1 MiB needed, 0.0 MiB free .*nothing was written"):
        atomic_write_files({tmp_path / "big.bin": b"x" * 100_000})
    assert list(tmp_path.iterdir()) == []
