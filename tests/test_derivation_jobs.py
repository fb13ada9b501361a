"""The derivations' MuJoCo trials in forked workers (``pipeline.workers.using_jobs``): the same falls, trial by
trial, as in the calling process."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from bemlearn.errors import ArgumentError
from bemlearn.pipeline import derive
from bemlearn.pipeline.workers import derivation_jobs, fork_available, usable_cpus, using_jobs

ROBOTS = Path(__file__).parent / "robots"


def test_using_jobs_sets_the_count_for_the_block_only():
    assert derivation_jobs() == usable_cpus()
    with using_jobs(1):
        assert derivation_jobs() == 1
        with using_jobs(3):
            assert derivation_jobs() == 3
        assert derivation_jobs() == 1
    assert derivation_jobs() == usable_cpus()
    with pytest.raises(ArgumentError, match="--jobs: expected a positive integer"), using_jobs(0):
        pass


@pytest.mark.skipif(not fork_available(), reason="the workers are forked (Linux); elsewhere the trials run serially")
def test_trials_fell_in_workers_equal_the_serial_trials():
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.robots import load

    robot = load(str(ROBOTS / "cartpole.xml"))
    collect = resolve_pipeline_config({"robot": str(ROBOTS / "cartpole.xml")}).config.collect
    seqs = np.random.SeedSequence(11).spawn(4)
    for scale in (1.0, 12.0):   # ×12: most trials fall, so the lists hold both outcomes
        lo, hi = collect.amplitude
        cfg = dataclasses.replace(collect, amplitude=(lo * scale, hi * scale), duration_s=1.5, n_trials=1, workers=1)
        with using_jobs(1):
            serial = derive._trials_fell(robot, cfg, seqs)
        with using_jobs(2):
            forked = derive._trials_fell(robot, cfg, seqs)
        assert forked == serial and len(serial) == 4
        if scale > 1:
            assert any(serial)
