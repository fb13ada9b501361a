"""Atomic writes, the overwrite guard, new run folders and the exception family (issue 16)."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from bemlearn import BemlearnError, ConfigError, OutputExistsError, RobotModelError, TrajectoryFormatError
from bemlearn.errors import CheckpointError, EnvironmentProblem, PredictorInputError, StalePredictorError
from bemlearn.files import atomic_path, atomic_write_text, check_outputs, check_writable, created_dir, new_run_dir


def test_atomic_write_replaces_only_on_success(tmp_path):
    target = tmp_path / "metrics.json"
    atomic_write_text(target, "old")
    with pytest.raises(RuntimeError, match="boom"), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metrics.json"]  # no temporary left
    with atomic_path(target) as tmp:
        assert tmp.name == "metrics.json" and tmp.parent != tmp_path  # the writer sees the real name
        tmp.write_text("new")
    assert target.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["metrics.json"]


def test_a_killed_writer_leaves_the_old_file(tmp_path):
    target = tmp_path / "data.npz"
    target.write_bytes(b"old contents")
    code = textwrap.dedent(f"""
        import sys, time
        from bemlearn.files import atomic_path
        with atomic_path({str(target)!r}) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(b"x" * 100000)
                fh.flush()
                print("writing", flush=True)
                time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=os.getcwd())
    assert proc.stdout.readline().strip() == "writing"
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    assert target.read_bytes() == b"old contents"


def test_check_outputs_names_what_would_be_overwritten(tmp_path):
    (tmp_path / "a.pt").write_text("x")
    (tmp_path / "empty").mkdir()
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "f").write_text("x")
    paths = [tmp_path / "a.pt", tmp_path / "b.pt", tmp_path / "empty", tmp_path / "full"]
    with pytest.raises(OutputExistsError, match=r"export: would overwrite .*a\.pt, .*full; use --force") as info:
        check_outputs(paths, what="export")
    assert "b.pt" not in str(info.value) and "empty" not in str(info.value)
    assert isinstance(info.value, FileExistsError)
    assert check_outputs(paths, force=True) == [tmp_path / "a.pt", tmp_path / "full"]


def test_new_run_dir_is_never_an_existing_folder(tmp_path):
    now = time.mktime((2026, 11, 25, 1, 2, 3, 0, 0, -1))
    first = new_run_dir("furuta", root=tmp_path, now=now)
    assert first == tmp_path / "furuta-20261125-010203" and not first.exists()
    first.mkdir()
    second = new_run_dir("furuta", root=tmp_path, now=now)
    assert second == tmp_path / "furuta-20261125-010203-2"


def test_created_dir_removes_what_a_failed_command_created(tmp_path):
    with pytest.raises(ValueError), created_dir(tmp_path / "runs" / "x") as out:
        (out / "config.yaml").write_text("robot: furuta\n")
        raise ValueError("bad")
    assert not (tmp_path / "runs").exists()
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "keep.txt").write_text("x")
    with pytest.raises(ValueError), created_dir(tmp_path / "mine"):
        raise ValueError("bad")
    assert (tmp_path / "mine" / "keep.txt").is_file()
    with pytest.raises(KeyboardInterrupt):  # Ctrl-C keeps the best state written on purpose
        with created_dir(tmp_path / "run2") as out:
            (out / "checkpoint.pt").write_text("x")
            raise KeyboardInterrupt
    assert (tmp_path / "run2" / "checkpoint.pt").is_file()
    with pytest.raises(KeyboardInterrupt):  # nothing worth keeping yet: removed
        with created_dir(tmp_path / "run3", keep_on_interrupt=["checkpoint.pt"]) as out:
            (out / "config.yaml").write_text("x")
            raise KeyboardInterrupt
    assert not (tmp_path / "run3").exists()


def test_check_writable(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(EnvironmentProblem, match="is a file, expected a folder"):
        check_writable(tmp_path / "file" / "run")
    with pytest.raises(EnvironmentProblem, match="cannot write in /proc"):
        check_writable("/proc/bemlearn-run")
    check_writable(tmp_path / "new" / "deeper")
    assert not (tmp_path / "new").exists()


def test_one_exception_family_still_value_errors():
    for cls in (ConfigError, TrajectoryFormatError, RobotModelError, CheckpointError, PredictorInputError, StalePredictorError):
        assert issubclass(cls, BemlearnError) and issubclass(cls, ValueError), cls
    assert issubclass(OutputExistsError, FileExistsError) and issubclass(EnvironmentProblem, BemlearnError)
    from bemlearn.config import ConfigError as C1
    from bemlearn.data.trajectory import TrajectoryFormatError as T1
    from bemlearn.robots.mujoco_robot import RobotModelError as R1

    assert (ConfigError, TrajectoryFormatError, RobotModelError) == (C1, T1, R1)
