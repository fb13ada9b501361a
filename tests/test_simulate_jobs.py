"""Concurrent stages (bemlearn.pipeline.workers, bemlearn.pipeline.overlap): the closed loops and the export
run in forked workers with ``jobs > 1`` and give the same results as ``jobs = 1``; a worker's failure is the
failure of the stage that awaits it; ``--jobs`` is checked before anything runs."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from bemlearn.cli.main import main
from bemlearn.errors import ArgumentError, NumericalError

ROBOT = Path(__file__).parent / "robots" / "cartpole.xml"
#: Short loops of the cart-pole (2 s each): a few seconds per stage.
SIM = {"robot": str(ROBOT), "simulate": {"duration_s": 2.0, "warmup_s": 0.5}}
#: A whole run kept small: 3 excitation trials of 3 s, 30 fit iterations, 2 s loops.
SMALL = {"robot": str(ROBOT), "collect": {"n_trials": 3, "duration_s": 3.0, "workers": 1},
         "train": {"max_iter": 30}, "evaluate": {"duration_s": 2.0, "design_points": 40},
         "simulate": {"duration_s": 2.0, "warmup_s": 0.5}}
#: Wall-clock measurements of a loop: the only entries allowed to differ between two runs.
TIMING = ("real_time_factor", "tick_us")

needs_fork = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers are forked on Linux only (elsewhere jobs run serially)")


def _config(doc: dict):
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    return resolve_pipeline_config(doc).config


def _untimed(loop) -> dict:
    """A loop's entry of simulate/metrics.json without its wall-clock measurements."""
    doc = loop.as_dict()
    return {k: v for k, v in doc.items() if k not in TIMING}


@needs_fork
def test_loops_in_workers_equal_the_serial_loops(tmp_path):
    from bemlearn.pipeline.simulate import simulate_stage

    cfg = _config(SIM)
    serial = simulate_stage(cfg, tmp_path / "serial", sources=("model", "zero"), progress=False, jobs=1)
    forked = simulate_stage(cfg, tmp_path / "forked", sources=("model", "zero"), progress=False, jobs=2)
    assert list(forked.loops) == ["model", "zero"]           # reported in the order of the sources
    for src in ("model", "zero"):
        a, b = serial.loops[src], forked.loops[src]
        assert _untimed(a) == _untimed(b), src                  # every figure bit for bit, not to a tolerance
        assert a.metrics["duration_s"] > 1.0                   # the loops ran (a fall at once would compare nothing)
        png = f"simulate/fig2_{src}.png"
        assert (tmp_path / "serial" / png).read_bytes() == (tmp_path / "forked" / png).read_bytes()
    written = json.loads((tmp_path / "forked" / "simulate" / "metrics.json").read_text())
    assert {k: {e: v for e, v in d.items() if e not in TIMING} for k, d in written.items()} == \
        {src: _untimed(loop) for src, loop in serial.loops.items()}


@needs_fork
def test_a_failed_loop_in_a_worker_is_the_stage_error(tmp_path, monkeypatch):
    import bemlearn.pipeline.simulate as simulate_module
    from bemlearn.pipeline.simulate import simulate_stage

    real = simulate_module.simulate

    def failing(robot, config, **kwargs):
        if config.bem_source == "zero":
            raise NumericalError("injected: the zero loop diverged")
        return real(robot, config, **kwargs)

    monkeypatch.setattr(simulate_module, "simulate", failing)   # the forked workers inherit the patch
    with pytest.raises(NumericalError, match="injected: the zero loop diverged"):
        simulate_stage(_config(SIM), tmp_path, sources=("model", "zero"), progress=False, jobs=2)
    assert not (tmp_path / "simulate" / "metrics.json").exists()     # a failed stage writes no metrics


@pytest.mark.parametrize("jobs", [0, -1])
def test_jobs_must_be_positive(jobs, tmp_path, capsys):
    out = tmp_path / "run"
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"robot: {ROBOT}\n")
    assert main(["run", str(cfg), "--out", str(out), "--jobs", str(jobs), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"--jobs: expected a positive integer (1 runs the stages one after the other), got {jobs}" in err
    assert not out.exists()                                   # refused before any folder exists
    assert main(["simulate", str(cfg), "--out", str(out), "--jobs", str(jobs), "--no-progress"]) == 2
    assert "--jobs: expected a positive integer" in capsys.readouterr().err and not out.exists()


def test_jobs_is_checked_by_the_library_too(tmp_path):
    from bemlearn.pipeline.run import run_pipeline
    from bemlearn.pipeline.simulate import simulate_stage
    from bemlearn.pipeline.workers import check_jobs, default_jobs, usable_cpus

    for call in (lambda: simulate_stage(_config(SIM), tmp_path, jobs=0),
                 lambda: run_pipeline(_config(SIM), tmp_path / "run", jobs=0), lambda: check_jobs(True)):
        with pytest.raises(ArgumentError, match="expected a positive integer"):
            call()
    assert not (tmp_path / "run").exists()
    assert 1 <= default_jobs() <= min(usable_cpus(), 4)


def test_jobs_is_in_the_help(capsys):
    for command in ("run", "simulate"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert "--jobs N" in capsys.readouterr().out


def _untimed_metrics(path: Path) -> dict:
    """A run's metrics.json without wall-clock measurements and with its own folder replaced."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    try:
        from diff_metrics import TIMING as timing
        from diff_metrics import flatten
    finally:
        sys.path.pop(0)
    import re

    text = (path / "metrics.json").read_text().replace(str(path), "<run>")
    return {k: v for k, v in flatten(json.loads(text)) if not any(re.search(p, k) for p in timing)}


@needs_fork
@pytest.mark.slow
def test_a_run_with_workers_equals_the_serial_run(tmp_path):
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.pipeline.run import run_pipeline

    runs = {jobs: run_pipeline(resolve_pipeline_config(SMALL), tmp_path / f"jobs{jobs}", progress=False, jobs=jobs) for jobs in (1, 2)}
    assert _untimed_metrics(runs[1].out) == _untimed_metrics(runs[2].out)
    assert runs[1].simulate is not None and list(runs[2].simulate.loops) == ["predictor", "model", "zero"]
    names = lambda out: sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if "tb" not in p.parts)  # noqa: E731
    assert names(runs[1].out) == names(runs[2].out)       # the same files, nothing left over by the workers


@needs_fork
def test_a_failed_overlapped_export_is_the_export_stage(tmp_path, monkeypatch):
    """The .pt2 export fails in its worker: the run records it at the export stage, keeps the checkpoint and
    writes no predictor file (as the serial run: both files or none)."""
    import importlib

    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.pipeline.run import run_pipeline

    def failing(predictor):
        raise NumericalError("injected: torch.export failed")

    monkeypatch.setattr(importlib.import_module("bemlearn.export.export_run"), "pt2_bytes", failing)   # the workers inherit it
    small = {**SMALL, "collect": {"n_trials": 2, "duration_s": 2.0, "workers": 1}, "dataset": {"n_points": 80},
             "train": {"max_iter": 5}, "evaluate": {"duration_s": 1.0, "design_points": 16, "n_references": 1},
             "simulate": {"duration_s": 0.5, "warmup_s": 0.1}}
    out = tmp_path / "run"
    with pytest.raises(NumericalError, match="injected: torch.export failed"):
        run_pipeline(resolve_pipeline_config(small), out, progress=False, jobs=2)
    failed = json.loads((out / "metrics.json").read_text())["failed"]
    assert (failed["stage"], failed["error_type"], failed["error"]) == ("export", "NumericalError", "injected: torch.export failed")
    assert "checkpoint.pt" in failed["kept"] and (out / "checkpoint.pt").is_file()
    assert not (out / "bem_predictor.pt").exists() and not (out / "bem_predictor.pt2").exists()
    assert not (out / "simulate").exists()

