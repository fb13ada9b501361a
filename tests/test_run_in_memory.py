"""A run hands its stages' results over in memory (bemlearn.pipeline.results): the robot is loaded once,
the collected data go to training without being read back, metrics.json is written once and the verdict
judged once; the typed results agree with the files written from them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROBOT = Path(__file__).parent / "robots" / "cartpole.xml"
SMALL = {"robot": str(ROBOT), "collect": {"n_trials": 3, "duration_s": 3.0, "workers": 1},
         "train": {"max_iter": 30}, "evaluate": {"duration_s": 2.0, "design_points": 40},
         "simulate": {"duration_s": 2.0, "warmup_s": 0.5}}


@pytest.fixture(scope="module")
def counted_run(tmp_path_factory):
    import bemlearn.data.derivative_choice as derivative_choice
    import bemlearn.data.trajectory_io as trajectory_io
    import bemlearn.pipeline.run as run_module
    import bemlearn.pipeline.train as train_module
    import bemlearn.pipeline.verdict as verdict_module
    from bemlearn.files import atomic_write_text
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.pipeline.run import run_pipeline
    from bemlearn.robots import MujocoRobot

    counts = {"from_xml": 0, "read_trajectory": 0, "judge_run": 0, "metrics.json": 0, "estimates": []}
    mp = pytest.MonkeyPatch()
    real_estimate = derivative_choice._estimate_states

    def estimate(traj, est, within):
        counts["estimates"].append((id(traj), repr(est), None if within is None else within.tobytes()))
        return real_estimate(traj, est, within)

    real_from_xml = MujocoRobot.from_xml.__func__
    real_judge = verdict_module.judge_run

    def from_xml(cls, *a, **k):
        counts["from_xml"] += 1
        return real_from_xml(cls, *a, **k)

    def judge(metrics):
        counts["judge_run"] += 1
        return real_judge(metrics)

    def read(*a, **k):
        counts["read_trajectory"] += 1
        raise AssertionError("a run read its trajectory back from disk")

    def write(path, text, *a, **k):
        if Path(path).name == "metrics.json":
            counts["metrics.json"] += 1
        return atomic_write_text(path, text, *a, **k)

    resolved = resolve_pipeline_config(SMALL)
    mp.setattr(MujocoRobot, "from_xml", classmethod(from_xml))
    mp.setattr(derivative_choice, "_estimate_states", estimate)
    mp.setattr(run_module, "judge_run", judge)
    mp.setattr(trajectory_io, "read_trajectory", read)
    mp.setattr(train_module, "read_trajectory", read)
    mp.setattr(run_module, "atomic_write_text", write)
    mp.setattr(train_module, "atomic_write_text", write)
    mp.setattr("bemlearn.pipeline.results.atomic_write_text", write)
    try:
        result = run_pipeline(resolved, tmp_path_factory.mktemp("mem") / "run", progress=False)
    finally:
        mp.undo()
    return result, counts


def test_each_thing_is_done_once_per_run(counted_run):
    _, counts = counted_run
    assert counts["read_trajectory"] == 0
    assert counts["judge_run"] == 1
    assert counts["metrics.json"] == 1
    assert counts["from_xml"] <= 2      # the run's robot, and the collect stage's own (its workers load theirs)
    # derivatives: estimated once per trajectory, estimator and window (datasets, band calibration, estimator term)
    assert counts["estimates"] and len(set(counts["estimates"])) == len(counts["estimates"])


def test_the_typed_results_are_what_the_files_say(counted_run):
    result, _ = counted_run
    written = json.loads((result.out / "metrics.json").read_text())
    assert written["verdict"] == result.verdict.to_dict()
    assert written["verdict"]["status"] == result.verdict.status
    sim = json.loads((result.out / "simulate" / "metrics.json").read_text())
    assert result.simulate is not None and list(sim) == list(result.simulate.loops) == ["predictor", "model", "zero"]
    for src, loop in result.simulate.loops.items():
        assert sim[src]["fell"] == loop.fell and sim[src]["tracking_rmse"] == pytest.approx(loop.tracking_rmse, rel=1e-12)
        assert written["closed_loop"][src]["diverged"] == loop.diverged
    assert result.collect is not None and result.train is not None
    assert result.train.trajectory is result.collect.data
    assert written["data"]["samples"] == result.collect.data.n_samples == result.collect.summary.samples
    assert result.report == result.out / "report.md" and result.report.is_file()


def test_the_in_memory_predictor_is_the_checkpoints(counted_run):
    import torch

    from bemlearn.export.checkpoint import load_checkpoint

    result, _ = counted_run
    assert result.train is not None
    saved = load_checkpoint(result.out).predictor_state
    for name, tensor in result.train.state.tensors().items():     # the same posterior, bit for bit
        assert torch.equal(tensor, saved.tensors()[name]), name
    # predictions agree to round-off: the in-memory state caches factors computed under the fit's thread count
    x = torch.randn(7, saved.dim, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    x = saved.x_mean + saved.x_std * x
    mean_a, std_a = result.train.state.predict_reference(x)
    mean_b, std_b = saved.predict_reference(x)
    torch.testing.assert_close(mean_a, mean_b, rtol=1e-8, atol=1e-12)
    torch.testing.assert_close(std_a, std_b, rtol=1e-8, atol=1e-12)
