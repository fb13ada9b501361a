"""The biped application's benches: ``bemlearn bench biped-bem`` and ``bemlearn bench walks``.

* ``bench biped-bem [CONFIG] [--data D | --collect-seeds S …]`` — learned torso BEM error over training
  subsets and training walks;
* ``bench walks [CONFIG]`` — seeded biped walks per gait and torso BEM source.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bemlearn.errors import ArgumentError, MissingFileError
from bemlearn.examples import config_argument

__all__ = ["add_bench"]


def add_bench(sub) -> None:
    b = sub.add_parser("biped-bem", help="learned torso BEM vs model BEM on held-out walks, over training subsets",
                       description="Fit the biped's torso-BEM GP (as `bemlearn run configs/biped.yaml` does) on "
                       "several random training subsets of the same walks and score each on the held-out walks.")
    b.add_argument("config", type=config_argument, nargs="?", default="configs/biped.yaml",
                   help="biped YAML (default: configs/biped.yaml, or the shipped example of that name)")
    b.add_argument("--data", type=Path, default=None,
                   help="data.npz of a biped run (default: collect the walks of the config, about 30 s)")
    b.add_argument("--subsets", type=int, default=4, help="training subsets (dataset seeds seed … seed + k − 1)")
    b.add_argument("--collect-seeds", type=int, nargs="+", default=None, metavar="SEED",
                   help="collect the training walks once per seed (collect.seed) and fit the subsets on each: "
                   "the spread over training walks too (about 40 s of walks per seed)")
    b.add_argument("--no-progress", action="store_true", help="no progress bars (for logs and scripts)")
    b.set_defaults(func=_biped_bem)
    w = sub.add_parser("walks", help="seeded biped walks per gait and torso BEM source: steps reached, falls",
                       description="Repeat the walk of the config's 'walk' section over seeds (initial-angle and "
                       "encoder noise) on each gait, with the model-based torso BEM and/or an exported predictor "
                       "in the loop, and count the walks that reach --steps steps.")
    w.add_argument("config", type=config_argument, nargs="?", default="configs/biped.yaml",
                   help="biped YAML (default: configs/biped.yaml, or the shipped example of that name)")
    w.add_argument("--predictor", type=Path, default=None, help="exported bem_predictor.pt to walk with")
    w.add_argument("--no-model", action="store_true", help="only the predictor (needs --predictor)")
    w.add_argument("--seeds", type=int, default=20, help="walks per gait and source (default 20)")
    w.add_argument("--steps", type=int, default=30, help="steps asked of each walk (default 30)")
    w.add_argument("--gaits", nargs="+", default=["default", "human"], choices=["default", "human"],
                   help="gaits to walk (default: both)")
    w.add_argument("--initial-noise", type=float, default=0.02, help="initial joint-angle noise std, rad (default 0.02)")
    w.add_argument("--sensor-noise", type=float, default=0.001, help="encoder noise std, rad (default 0.001)")
    w.add_argument("--no-progress", action="store_true", help="no progress bars (for logs and scripts)")
    w.set_defaults(func=_walks)


def _biped_bem(args: argparse.Namespace) -> int:
    from bemlearn.apps.biped.bem_bench import format_biped_bem_bench, run_biped_bem_bench
    from bemlearn.apps.biped.pipeline import load_biped_config

    if args.subsets < 1:
        raise ArgumentError(f"--subsets: expected a positive integer, got {args.subsets}")
    result = run_biped_bem_bench(load_biped_config(args.config), data=args.data, subsets=args.subsets,
                                 collect_seeds=args.collect_seeds, progress=not args.no_progress)
    print(format_biped_bem_bench(result))
    return 0


def _walks(args: argparse.Namespace) -> int:
    from bemlearn.apps.biped.walk_bench import format_walk_bench, run_walk_bench
    from bemlearn.apps.biped.walker import load_walk_config

    if args.predictor is not None and not args.predictor.is_file():
        raise MissingFileError(f"--predictor: no such file {args.predictor} (expected an exported bem_predictor.pt)")
    if args.no_model and args.predictor is None:
        raise ArgumentError("--no-model: needs --predictor (nothing else to walk with)")
    rows = run_walk_bench(load_walk_config(args.config), seeds=args.seeds, steps=args.steps, gaits=tuple(args.gaits),
                          predictor=None if args.predictor is None else str(args.predictor), model=not args.no_model,
                          initial_noise=args.initial_noise, sensor_noise=args.sensor_noise,
                          progress=not args.no_progress)
    print(format_walk_bench(rows, steps=args.steps))
    return 0
