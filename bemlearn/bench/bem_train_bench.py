"""Training figures on the shipped Furuta config (``bemlearn bench train``).

* exact GP on the paper's 500 points: fit time (1 and 2 torch threads) and the held-out
  learned-BEM accuracy (RMSE, max, ±2σ coverage with latent and predictive std);
* sgpr with M inducing points on ≥ 50,000 points: fit time and the same accuracy;
* svgp on ~10⁶ points collected with the config's excitation (more trials): time per
  epoch, accuracy and the process's peak resident memory.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from bemlearn.bench.train_bench import peak_rss_mib
from bemlearn.data import build_datasets, read_trajectory
from bemlearn.fitting import train_gp
from bemlearn.models import predictor_state
from bemlearn.pipeline.evaluation import evaluate_bem, held_out_references
from bemlearn.robots import load
from bemlearn.threads import torch_threads

__all__ = ["bench_bem_training"]


def _fit_and_eval(ds, gp_cfg, config, *, threads: int) -> dict:
    tr = ds.train
    with torch_threads(threads):
        t0 = time.perf_counter()
        model, lik, res = train_gp(tr.x_normalized, tr.y_normalized, config=gp_cfg)
        seconds = time.perf_counter() - t0
    st = predictor_state(model, lik, x_mean=tr.x_mean, x_std=tr.x_std, y_mean=tr.y_mean, y_std=tr.y_std, input_names=tr.input_names, n_train=len(tr))
    robot = load(config.robot, coordinates=config.coordinates)
    ev = evaluate_bem(st, robot, held_out_references(config.evaluate, robot.m), duration_s=config.evaluate.duration_s, rate_hz=config.evaluate.rate_hz)
    return {"kind": gp_cfg.kind, "n_train": len(tr), "threads": threads, "seconds": seconds, "steps": res.steps,
            "stop_reason": res.stop_reason, "rmse": ev.rmse, "max_abs": ev.max_abs,
            "coverage_latent": ev.coverage_2sigma_latent, "coverage_predictive": ev.coverage_2sigma_predictive}


def bench_bem_training(config, data_path: str | Path, *, sgpr_points: int = 50_000, n_inducing: int = 512,
                       svgp: bool = True, svgp_trials: int = 100, svgp_duration_s: float = 45.0, svgp_epochs: int = 2,
                       progress=print) -> list[dict]:
    """Run the benchmark (module docstring); returns one row per measurement."""
    traj = read_trajectory(data_path, robot=config.robot)
    rows = []
    ds = build_datasets(traj, config.dataset)
    for threads in (1, 2):
        rows.append(_fit_and_eval(ds, config.train, config, threads=threads))
        progress(rows[-1])
    ds_big = build_datasets(traj, dataclasses.replace(config.dataset, n_points=sgpr_points, n_val_points=1000))
    # the sparse kinds use their own iteration defaults (max_iter=None), not the exact GP's
    rows.append(_fit_and_eval(ds_big, dataclasses.replace(config.train, kind="sgpr", n_inducing=n_inducing, max_iter=None), config, threads=2))
    progress(rows[-1])
    if svgp:
        from bemlearn.sim.collect import collect

        cc = dataclasses.replace(config.collect, n_trials=svgp_trials, duration_s=svgp_duration_s, seed=config.collect.seed + 1000)
        big, _ = collect(config.robot, cc, progress=False)
        del _
        ds_huge = build_datasets(big, dataclasses.replace(config.dataset, n_points=None, n_val_points=1000))
        del big
        gp_cfg = dataclasses.replace(config.train, kind="svgp", n_inducing=256, epochs=svgp_epochs, max_iter=None)
        row = _fit_and_eval(ds_huge, gp_cfg, config, threads=2)
        row["seconds_per_epoch"] = row["seconds"] / svgp_epochs
        row["peak_rss_gib"] = peak_rss_mib() / 1024
        rows.append(row)
        progress(row)
    return rows
