"""``bemlearn bench walks``: seeded walks per gait and BEM source, counted against the step target."""

from pathlib import Path

import pytest

from bemlearn.apps.biped.walk_bench import WalkBenchRow, format_walk_bench, run_walk_bench
from bemlearn.apps.biped.walker import WalkConfig, simulate_walk
from bemlearn.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_rows_match_independent_walks():
    import dataclasses

    walk = WalkConfig()
    rows = run_walk_bench(walk, seeds=2, steps=3, gaits=("default",), initial_noise=0.02, sensor_noise=0.001,
                          progress=False)
    assert [(r.source, r.gait, r.seed) for r in rows] == [("model", "default", 0), ("model", "default", 1)]
    for r in rows:   # the same walk simulated directly
        cfg = dataclasses.replace(walk, duration_s=6.0, max_steps=3, seed=r.seed, initial_noise=0.02,
                                  sensor=dataclasses.replace(walk.sensor, noise_std=0.001))
        ref = simulate_walk(cfg, progress=False)
        assert (r.steps, r.fell) == (len(ref.steps), ref.fell)


def test_table_counts_reached_and_fallen():
    rows = [WalkBenchRow("model", "human", 0, 30, False, 1.0), WalkBenchRow("model", "human", 1, 12, True, 2.0),
            WalkBenchRow("predictor", "human", 0, 30, False, 1.5)]
    text = format_walk_bench(rows, steps=30)
    assert "| model | human | 1/2 | 1 | 12 | 21 | 1.5 |" in text
    assert "| predictor | human | 1/1 | 0 | 30 | 30 | 1.5 |" in text


@pytest.mark.parametrize("argv, message", [
    (["--no-model"], "--no-model: needs --predictor"),
    (["--predictor", "nope.pt"], "--predictor: no such file nope.pt"),
    (["--seeds", "0"], "expected positive integers, got seeds=0"),
    (["--sensor-noise", "-1"], "expected >= 0 rad, got 0.02, -1.0"),
])
def test_cli_rejects_bad_arguments(argv, message, capsys):
    assert main(["bench", "walks", str(ROOT / "configs" / "biped.yaml"), "--no-progress", *argv]) == 2
    assert message in capsys.readouterr().err


def test_cli_prints_the_table(capsys):
    assert main(["bench", "walks", str(ROOT / "configs" / "biped.yaml"), "--seeds", "1", "--steps", "2",
                 "--gaits", "human", "--no-progress"]) == 0
    assert "| model | human | 1/1 | 0 | 2 | 2 |" in capsys.readouterr().out
