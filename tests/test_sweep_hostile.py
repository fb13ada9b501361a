"""Sweeps against hostile settings (issue 29, items 3–5): an unreachable cluster, an unwritable or
full --out, a sweep Ray refuses, a grid too large; none leaves a folder it created."""

import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bemlearn.errors import ConfigError, EnvironmentProblem, SweepError
from bemlearn.sweep import run_sweep
from bemlearn.sweep.cells import expand_cells
from bemlearn.sweep.config import MAX_CELLS, load_sweep

REPO = Path(__file__).resolve().parents[1]
BASE = {"robot": str(REPO / "tests" / "robots" / "cartpole.xml"), "collect": {"n_trials": 2, "duration_s": 2.0},
        "simulate": {"bem_source": "model", "duration_s": 2.0, "warmup_s": 0.5}}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_unreachable_address_fails_at_once_with_one_line(tmp_path):
    """Item 3: Ray retried an address with nothing listening for 5+ minutes and left the folder."""
    pytest.importorskip("ray")
    sweep = tmp_path / "s.yaml"
    sweep.write_text(f"base: {{robot: {BASE['robot']}, simulate: {{bem_source: model}}}}\nstage: simulate\n")
    port = _free_port()
    t0 = time.monotonic()
    res = subprocess.run([sys.executable, "-m", "bemlearn", "sweep", str(sweep), "--address", f"127.0.0.1:{port}",
                          "--out", str(tmp_path / "out"), "--no-progress"], cwd=tmp_path, capture_output=True, text=True,
                         timeout=120, env={**os.environ, "PYTHONPATH": str(REPO)})
    elapsed = time.monotonic() - t0
    assert res.returncode == 2, res.stderr[-2000:]
    lines = [ln for ln in res.stderr.strip().splitlines() if not ln.startswith("INFO")]
    assert len(lines) == 1 and f"--address 127.0.0.1:{port}: cannot connect" in lines[0], res.stderr
    assert elapsed < 30, elapsed
    assert not (tmp_path / "out").exists()


@pytest.fixture
def tmpfs(tmp_path):
    """A 1 MiB tmpfs at ``tmp_path/disk`` (needs root; skipped with the reason otherwise)."""
    if shutil.which("mount") is None or os.geteuid() != 0:
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


def test_a_read_only_out_is_one_error_and_leaves_nothing(tmpfs):
    """Item 4: a read-only --out ended in an internal OSError and left .sweep.lock and cells/."""
    subprocess.run(["mount", "-o", "remount,ro", str(tmpfs)], check=True, capture_output=True)
    with pytest.raises(EnvironmentProblem, match=r"--out: cannot write in .*disk"):
        run_sweep({"base": BASE, "stage": "simulate"}, tmpfs / "sweep", backend="serial", progress=False)
    assert list(tmpfs.iterdir()) == []


def test_a_full_out_is_one_error_and_leaves_nothing(tmpfs):
    free = shutil.disk_usage(tmpfs).free
    with open(tmpfs / "filler", "wb") as fh:   # leave room for the folders but not for sweep.yaml
        fh.write(b"\0" * max(0, free - 8192))
    with pytest.raises(EnvironmentProblem, match=r"no space left on device"):
        run_sweep({"base": BASE, "stage": "simulate"}, tmpfs / "sweep", backend="serial", progress=False)
    assert sorted(p.name for p in tmpfs.iterdir()) == ["filler"]


def test_an_unwritable_out_is_refused_in_process(tmp_path, monkeypatch):
    """The same without a tmpfs: creating the folder fails with EROFS."""
    import errno

    real_mkdir = Path.mkdir

    def read_only(self, *a, **k):
        if self == tmp_path / "sweep" / "cells":
            raise OSError(errno.EROFS, "Read-only file system", str(self))
        return real_mkdir(self, *a, **k)

    monkeypatch.setattr(Path, "mkdir", read_only)
    with pytest.raises(EnvironmentProblem, match=r"read-only"):
        run_sweep({"base": BASE, "stage": "simulate"}, tmp_path / "sweep", backend="serial", progress=False)
    assert not (tmp_path / "sweep").exists()


def test_a_sweep_ray_refuses_leaves_no_folder(tmp_path, monkeypatch):
    """Item 4: a sweep asking for more CPUs than the cluster has left its --out, so the rerun said 'would overwrite'."""
    import bemlearn.sweep.driver as driver

    def refuse(*a, **k):  # what RayBackend raises for `cpus: 1000` (tested with Ray in test_sweep_run.py)
        raise SweepError("resources: a cell asks for 1000 CPU(s) and 0 GPU(s); the Ray cluster has 2 CPU(s)")

    monkeypatch.setattr(driver, "make_backend", refuse)
    spec = {"base": BASE, "stage": "simulate", "resources": {"cpus": 1000}}
    with pytest.raises(SweepError, match="1000 CPU"):
        run_sweep(spec, tmp_path / "sweep", progress=False)
    assert not (tmp_path / "sweep").exists()


def test_a_grid_over_the_limit_is_refused_before_any_cell_is_resolved(tmp_path):
    """Item 5: a grid of 10⁴ cells took 342 s to validate; 10⁶ was still validating after 300 s."""
    spec = {"base": BASE, "stage": "simulate", "grid": {"collect.seed": list(range(1000)), "dataset.seed": list(range(1000))}}
    t0 = time.monotonic()
    with pytest.raises(ConfigError, match=rf"grid: 1000 × 1000 = 1000000 cells; a sweep holds at most {MAX_CELLS}"):
        run_sweep(spec, tmp_path / "sweep", backend="serial", progress=False)
    assert time.monotonic() - t0 < 2.0
    assert not (tmp_path / "sweep").exists()


def test_memoized_validation_gives_the_cells_of_a_full_resolution():
    """The sweep's validation loads each robot and derives its values once (bemlearn.pipeline.resolve.memoized_derivation);
    every cell must still be the config a lone resolution gives."""
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.sweep.cells import cell_id
    from bemlearn.sweep.stage import get_stage

    grid = {"collect.seed": [0, 1, 2], "simulate.rate_hz": [100.0, 200.0], "simulate.duration_s": [3.0, 4.0]}
    loaded = load_sweep({"base": BASE, "stage": "run", "grid": grid})
    t0 = time.perf_counter()
    cells = expand_cells(loaded)
    assert len(cells) == 12
    stage = get_stage("run", None, where="test")
    for cell in cells[::5]:
        raw = {**BASE, "collect": {**BASE["collect"], "seed": cell.grid["collect.seed"]},
               "simulate": {**BASE["simulate"], "rate_hz": cell.grid["simulate.rate_hz"],
                            "duration_s": cell.grid["simulate.duration_s"]}}
        alone = resolve_pipeline_config(raw, source="config")
        assert alone.config == cell.config.config
        assert cell_id(stage, None, alone) == cell.cell_id
    assert time.perf_counter() - t0 < 30


def _count_full_resolutions(monkeypatch):
    import bemlearn.sweep.stage as stage_mod

    calls = []
    real = stage_mod._resolve_pipeline

    def counting(raw, where):
        calls.append(where)
        return real(raw, where)

    monkeypatch.setattr(stage_mod, "_resolve_pipeline", counting)
    return calls


def test_a_seed_grid_is_resolved_in_full_once_per_value_and_patched_cells_equal_full_ones(monkeypatch):
    """Item 5's speed: a 10⁴-cell grid took 10–15 s because every cell was resolved in full.  Cells that differ
    from a resolved one only in leaf values are patched (bemlearn.sweep.cells._expand); each must equal its full
    resolution, with the same cell id."""
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.sweep.cells import cell_id
    from bemlearn.sweep.stage import get_stage

    calls = _count_full_resolutions(monkeypatch)
    grid = {"collect.seed": list(range(12)), "dataset.seed": list(range(10))}
    cells = expand_cells(load_sweep({"base": BASE, "stage": "run", "grid": grid}))
    assert len(cells) == 120
    assert len(calls) == 1 + 11 + 9          # the template, then each other value of each key once
    stage = get_stage("run", None, where="test")
    for cell in cells:
        raw = {**BASE, "collect": {**BASE["collect"], "seed": cell.grid["collect.seed"]},
               "dataset": {"seed": cell.grid["dataset.seed"]}}
        alone = resolve_pipeline_config(raw, source="config")
        assert cell.config == alone
        assert cell_id(stage, None, alone) == cell.cell_id


def test_a_grid_value_that_changes_derived_values_is_resolved_in_full(monkeypatch):
    """simulate.rate_hz changes the derived EIC gains and references: patching it would give another config
    than a full resolution, so the comparison of the first full resolution stops patching that key."""
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    calls = _count_full_resolutions(monkeypatch)
    grid = {"simulate.rate_hz": [100.0, 250.0], "collect.seed": [0, 1, 2]}
    cells = expand_cells(load_sweep({"base": BASE, "stage": "run", "grid": grid}))
    for cell in cells:
        raw = {**BASE, "collect": {**BASE["collect"], "seed": cell.grid["collect.seed"]},
               "simulate": {**BASE["simulate"], "rate_hz": cell.grid["simulate.rate_hz"]}}
        assert cell.config == resolve_pipeline_config(raw, source="config")
    assert cells[0].config.config.simulate.rate_hz == 100.0 and cells[3].config.config.simulate.rate_hz == 250.0
    assert len(calls) < 2 * 3 + 6   # not every cell twice


def test_a_bad_value_in_a_patched_cell_is_named_with_its_cell():
    """A value a patched cell sets is checked as the strict parse checks it (type and limits)."""
    grid = {"collect.seed": [0, 1], "collect.n_trials": [2, -3]}
    with pytest.raises(ConfigError, match=r"cell 1 \(collect.seed=0, collect.n_trials=-3\).*n_trials"):
        expand_cells(load_sweep({"base": BASE, "stage": "run", "grid": grid}))
    grid = {"collect.seed": [0, 1], "dataset.seed": [0, "one"]}
    with pytest.raises(ConfigError, match=r"cell 1 \(collect.seed=0, dataset.seed=one\).*dataset.seed: expected an integer"):
        expand_cells(load_sweep({"base": BASE, "stage": "run", "grid": grid}))
