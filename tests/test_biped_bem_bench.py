"""``bemlearn bench biped-bem``: subsets, scores and errors (small walks, a few GP steps)."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from bemlearn.apps.biped.bem_bench import format_biped_bem_bench, run_biped_bem_bench
from bemlearn.apps.biped.pipeline import (
    BipedConfig,
    BipedEvaluateConfig,
    WalkCollectConfig,
    WalkDatasetConfig,
    heldout_bem,
    heldout_walks,
)
from bemlearn.cli import main
from bemlearn.fitting import GPConfig

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def small():
    return BipedConfig(
        collect=WalkCollectConfig(gaits=("default",), walks_per_gait=2, duration_s=1.5),
        dataset=WalkDatasetConfig(derivatives="truth", n_points=60, skip_after_impact=5, skip_before_impact=3),
        train=GPConfig(max_iter=5),
        evaluate=BipedEvaluateConfig(gaits=("default",), heldout_duration_s=1.5),
    )


def _pipeline_rmse(config, tmp_path, *, collect_seed: int, dataset_seed: int) -> float:
    """The held-out RMSE of one draw through the pipeline's own stages (collect → GP data → fit and
    export → held-out walks), independently of the bench's loop and bookkeeping."""
    from bemlearn.apps.biped.pipeline import collect_walks, train_walking_gp, walking_gp_data, walks_trajectories
    from bemlearn.data import write_trajectory

    cfg = dataclasses.replace(config, collect=dataclasses.replace(config.collect, seed=collect_seed),
                              dataset=dataclasses.replace(config.dataset, seed=dataset_seed))
    data, truth = walks_trajectories(collect_walks(cfg, progress=False))
    out = tmp_path / f"walks{collect_seed}-subset{dataset_seed}"
    out.mkdir()
    path = write_trajectory(data, out / "data.npz")
    X, y, _ = walking_gp_data(data, truth, cfg.dataset)
    train_walking_gp(X, y, out / "gp", config=cfg.train, data_path=path, progress=False)
    return heldout_bem(out / "gp" / "bem_predictor.pt", cfg, progress=False)["default"]["rmse"]


def test_subsets_are_scored_like_the_pipeline(small, tmp_path):
    result = run_biped_bem_bench(small, subsets=2, progress=False)
    assert [r.seed for r in result.subsets] == [0, 1] and result.derivatives == "truth"
    assert all(r.n_train == 60 and np.isfinite(r.loss) and set(r.rmse) == {"default"} for r in result.subsets)
    # subset i is the pipeline's draw with dataset.seed + i, scored as the pipeline scores it
    for r in result.subsets:
        assert r.rmse["default"] == _pipeline_rmse(small, tmp_path, collect_seed=small.collect.seed, dataset_seed=r.seed)
    text = format_biped_bem_bench(result)
    assert "| 0 | 60 |" in text and "default: RMSE min" in text and "target: median <= 0.02 rad" in text
    assert "every fit <= 0.02 rad" in text


def test_collect_seeds_refit_on_each_set_of_walks(small, tmp_path):
    one = run_biped_bem_bench(small, subsets=1, progress=False)  # config.collect.seed = 0
    both = run_biped_bem_bench(small, subsets=1, collect_seeds=[0, 7], progress=False)
    assert [r.collect_seed for r in both.subsets] == [0, 7] and len(both.pool) == 2
    # the seed-0 walks are the config's own: the same fit, bit for bit
    assert both.subsets[0].rmse == one.subsets[0].rmse and both.pool[0] == one.pool[0]
    # the seed-7 walks are collected as the pipeline collects them with collect.seed = 7
    assert both.subsets[1].rmse["default"] == _pipeline_rmse(small, tmp_path, collect_seed=7, dataset_seed=small.dataset.seed)
    assert "seed 0" in both.source and "seed 7" in both.source
    text = format_biped_bem_bench(both)
    assert "| walks seed | dataset seed |" in text and "| 7 | 0 | 60 |" in text
    assert "over 2 fits (2 sets of walks × 1 subsets)" in text and "median per walks seed: 0: " in text
    assert "walks seed" not in format_biped_bem_bench(one)


def test_heldout_walks_are_shared_bit_identically(small, tmp_path):
    # heldout_bem with precomputed walks equals heldout_bem simulating them itself
    from bemlearn.apps.biped.pipeline import collect_walks, train_walking_gp, walking_gp_data, walks_trajectories
    from bemlearn.data import write_trajectory

    walks = collect_walks(small, progress=False)
    data, truth = walks_trajectories(walks)
    path = write_trajectory(data, tmp_path / "data.npz")
    X, y, _ = walking_gp_data(data, truth, small.dataset)
    train_walking_gp(X, y, tmp_path / "gp", config=small.train, data_path=path, progress=False)
    a = heldout_bem(tmp_path / "gp" / "bem_predictor.pt", small, progress=False)
    b = heldout_bem(tmp_path / "gp" / "bem_predictor.pt", small, walks=heldout_walks(small, progress=False))
    assert a == b


def test_cli_errors(tmp_path, capsys):
    assert main(["bench", "biped-bem", str(ROOT / "configs" / "biped.yaml"), "--subsets", "0"]) == 2
    assert "--subsets: expected a positive integer, got 0" in capsys.readouterr().err
    missing = tmp_path / "nope.npz"
    assert main(["bench", "biped-bem", str(ROOT / "configs" / "biped.yaml"), "--data", str(missing), "--subsets", "1",
                 "--no-progress"]) == 2
    assert f"--data: no such file {missing}" in capsys.readouterr().err
    assert main(["bench", "biped-bem", str(ROOT / "configs" / "biped.yaml"), "--data", str(missing),
                 "--collect-seeds", "0", "1", "--no-progress"]) == 2
    assert "--collect-seeds and --data: give one" in capsys.readouterr().err
    assert main(["bench", "biped-bem", str(ROOT / "configs" / "biped.yaml"), "--collect-seeds", "3", "3",
                 "--no-progress"]) == 2
    assert "--collect-seeds: expected distinct non-negative integers, got [3, 3]" in capsys.readouterr().err
    assert main(["bench", "biped-bem", str(ROOT / "configs" / "biped.yaml"), "--collect-seeds", "0", "-1",
                 "--no-progress"]) == 2
    assert "--collect-seeds: expected distinct non-negative integers, got [0, -1]" in capsys.readouterr().err


def test_config_dataclass_defaults_match_the_shipped_yaml():
    from bemlearn.apps.biped.pipeline import load_biped_config

    shipped = load_biped_config(ROOT / "configs" / "biped.yaml")
    assert dataclasses.asdict(BipedConfig().collect) == dataclasses.asdict(shipped.collect)
    assert dataclasses.asdict(BipedConfig().dataset) == dataclasses.asdict(shipped.dataset)


def test_the_sweep_stage_scores_each_draw_exactly_as_the_bench(small, tmp_path):
    # configs/sweeps/biped-bem.yaml's cells (collect.seed × dataset.seed) are the bench's --collect-seeds × --subsets
    import torch

    from bemlearn.config import to_dict
    from bemlearn.sweep import run_sweep

    torch.set_num_threads(1)  # a cell runs with resources.cpus = 1 thread; the last bits of a fit depend on it
    bench = run_biped_bem_bench(small, subsets=2, collect_seeds=[7], progress=False)
    sweep = {"base": to_dict(small), "stage": "biped-bem", "grid": {"collect.seed": [7], "dataset.seed": [0, 1]}}
    result = run_sweep(sweep, tmp_path / "sweep", backend="serial", progress=False)
    got = {(r["collect.seed"], r["dataset.seed"]): (r["heldout.default.rmse"], r["n_train"]) for r in result.rows}
    assert got == {(s.collect_seed, s.seed): (s.rmse["default"], s.n_train) for s in bench.subsets}
    assert all(r["status"] == "ok" for r in result.rows) and len(set(got.values())) == 2
