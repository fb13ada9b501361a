"""``bemlearn collect CONFIG --out FILE``: simulated excitation data (Section IV-A)."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

from bemlearn.errors import ArgumentError, ConfigError
from bemlearn.examples import config_argument

__all__ = ["add_parser"]

log = logging.getLogger(__name__)


def add_parser(sub) -> None:
    p = sub.add_parser(
        "collect",
        help="simulate excitation trials in MuJoCo and write a trajectory file",
        description="Run the paper's excitation controller (u = kᵀe around a random sum of sines) "
        "for many randomized trials and write what a rig logs (quantized angles, inputs, trial outcome) "
        "to FILE (.npz or .csv), plus the simulator's ground truth to <stem>.truth<suffix>.",
    )
    p.add_argument("config", type=config_argument, help="pipeline YAML (its 'robot' and 'collect' sections are used)")
    p.add_argument("--out", type=Path, help="output file, .npz or .csv (default: a new runs/collect-<timestamp>/data.npz)")
    p.add_argument("--force", action="store_true", help="replace FILE and its ground-truth file if they exist")
    p.add_argument("--trials", type=int, help="override collect.n_trials")
    p.add_argument("--seed", type=int, help="override collect.seed")
    p.add_argument("--workers", type=int, help="override collect.workers (0 = one per core)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    from bemlearn.data.trajectory_io import ground_truth_path, write_trajectory
    from bemlearn.outputs import claim_outputs
    from bemlearn.pipeline.preflight import preflight
    from bemlearn.sim.collect import collect

    target = args.out or Path("data.npz")   # without --out: data.npz in a new runs/collect-<timestamp>
    if target.suffix.lower() not in (".npz", ".csv"):
        raise ArgumentError(f"--out: expected a .npz or .csv file name, got {args.out}")
    names = (target.name, ground_truth_path(target).name)
    cfg = preflight(config=args.config, outputs=[args.out, ground_truth_path(args.out)] if args.out else [],
                    out_dir=args.out.parent if args.out else Path("runs"), force=args.force).pipeline_config()
    if cfg.robot is None:
        raise ConfigError(f"{args.config}: collect needs a robot (a model to simulate); the config names only data")
    overrides = {k: v for k, v in (("n_trials", args.trials), ("seed", args.seed), ("workers", args.workers)) if v is not None}
    ccfg = dataclasses.replace(cfg.collect, **overrides)
    with claim_outputs(args.out.parent if args.out else None, entries=names, default_name="collect", force=args.force,
                       what="collect") as folder:   # the data file and its ground truth: both or neither
        args.out = folder / target.name
        data, truth = collect(cfg.robot, ccfg, progress=not args.no_progress, coordinates=cfg.coordinates)
        write_trajectory(data, args.out)
        gt = write_trajectory(truth, ground_truth_path(args.out))
    n_failed = sum(data.meta.trial_failed.values())
    print(f"wrote {args.out}: {len(data.meta.trial_failed)} trials ({n_failed} fell), {data.n_samples} samples at {ccfg.rate_hz:g} Hz")
    print(f"wrote {gt}: ground truth (true q, q̇, q̈) for evaluation")
    return 0
