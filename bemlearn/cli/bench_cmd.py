"""``bemlearn bench``: the measurements the issues name, kept out of the timed test suite.

* ``bench train [CONFIG]`` — exact / sgpr / svgp fit times and learned-BEM accuracy (issue 4);
* ``bench predict [CHECKPOINT]`` — predictor latency, throughput and GPyTorch parity (issue 5);
* ``bench sim PREDICTOR`` — the learned BEM in the EIC loop, mismatch study, Lemma 1, speed (issue 6);
* ``bench derivatives [CONFIG]`` — derivative estimators and their effect on the learned BEM (issue 3);
* ``bench gpdm`` — GPDM fit time and recovery on synthetic gait data (issue 7);
* ``bench biped-bem [CONFIG] [--data D | --collect-seeds S …]`` — learned torso BEM error over training
  subsets and training walks (issue 7);
* ``bench walks [CONFIG]`` — seeded biped walks per gait and torso BEM source (issue 7);
* ``bench sigint [CONFIG]`` — Ctrl-C latency of ``train`` on the 3,000-point exact GP (issue 16);
* ``bench fuzz`` — bad-input classes fed to every reader and how many end in a named error (issue 16).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bemlearn.bench.predict_bench import format_predict_bench, run_predict_bench

__all__ = ["add_parser", "run_predict"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("bench", help="benchmarks", description="Benchmarks of bemlearn components.")
    sub = parser.add_subparsers(dest="bench", metavar="BENCH", required=True)
    p = sub.add_parser(
        "predict",
        help="latency, throughput and GPyTorch parity of the exported BEM predictor",
        description="Time the exported BEM predictor (TorchScript and torch.export) against NumPy and "
        "GPyTorch, single queries (B = 1) and a 1e5 batch.  Without CHECKPOINT a synthetic 500-point "
        "exact GP (d = 5, m = 1) is used.  Other load on the machine changes the numbers; the "
        "load average is printed.",
    )
    p.add_argument("checkpoint", metavar="CHECKPOINT", type=Path, nargs="?", default=None, help="run directory or checkpoint.pt")
    p.add_argument("--n-train", type=int, default=500, help="points of the synthetic model (default 500)")
    p.add_argument("--repeats", type=int, default=20000, help="timed calls per single-query case (default 20000)")
    p.add_argument("--gpytorch-repeats", type=int, default=200, help="timed GPyTorch calls (default 200)")
    p.add_argument("--batch", type=int, default=100_000, help="queries in the throughput case (default 1e5)")
    p.add_argument("--threads", type=int, default=1, help="torch/BLAS threads of the single-query cases (default 1)")
    p.add_argument("--batch-threads", type=int, default=None,
                   help="torch/BLAS threads of the batch case (default: every core)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-pt2", action="store_true", help="skip the torch.export artifact")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_predict)
    t = sub.add_parser("train", help="GP fit times and learned-BEM accuracy on the shipped Furuta config")
    t.add_argument("config", type=Path, nargs="?", default=Path("configs/furuta.yaml"))
    t.add_argument("--data", type=Path, default=Path("data/furuta_excitation.npz"))
    t.add_argument("--no-svgp", action="store_true", help="skip the 10⁶-point svgp run (minutes)")
    t.set_defaults(func=_train)
    s = sub.add_parser("sim", help="learned BEM in the EIC loop: 5 references × 5 seeds, mismatch, Lemma 1, speed")
    s.add_argument("predictor", type=Path, help="exported bem_predictor.pt (or a run folder holding one)")
    s.add_argument("--config", type=Path, default=Path("configs/furuta.yaml"))
    s.add_argument("--refs", type=int, default=5)
    s.add_argument("--seeds", type=int, default=5)
    s.add_argument("--duration", type=float, default=60.0, help="simulated seconds per run")
    s.add_argument("--no-mismatch", action="store_true")
    s.set_defaults(func=_sim)
    d = sub.add_parser("derivatives", help="derivative estimators vs ground truth and their effect on the learned BEM")
    d.add_argument("config", type=Path, nargs="?", default=Path("configs/furuta.yaml"))
    d.add_argument("--data", type=Path, default=Path("data/furuta_excitation.npz"))
    d.add_argument("--no-gp", action="store_true", help="only the derivative errors")
    d.set_defaults(func=_derivatives)
    g = sub.add_parser("gpdm", help="GPDM fit time and recovery of c and χ on synthetic gait data")
    g.add_argument("--max-iter", type=int, default=500)
    g.set_defaults(func=_gpdm)
    b = sub.add_parser("biped-bem", help="learned torso BEM vs model BEM on held-out walks, over training subsets",
                       description="Fit the biped's torso-BEM GP (as `bemlearn run configs/biped.yaml` does) on "
                       "several random training subsets of the same walks and score each on the held-out walks.")
    b.add_argument("config", type=Path, nargs="?", default=Path("configs/biped.yaml"))
    b.add_argument("--data", type=Path, default=None,
                   help="data.npz of a biped run (default: collect the walks of the config, about 30 s)")
    b.add_argument("--subsets", type=int, default=4, help="training subsets (dataset seeds seed … seed + k − 1)")
    b.add_argument("--collect-seeds", type=int, nargs="+", default=None, metavar="SEED",
                   help="collect the training walks once per seed (collect.seed) and fit the subsets on each: "
                   "the spread over training walks too (about 40 s of walks per seed)")
    b.add_argument("--no-progress", action="store_true")
    b.set_defaults(func=_biped_bem)
    w = sub.add_parser("walks", help="seeded biped walks per gait and torso BEM source: steps reached, falls",
                       description="Repeat the walk of the config's 'walk' section over seeds (initial-angle and "
                       "encoder noise) on each gait, with the model-based torso BEM and/or an exported predictor "
                       "in the loop, and count the walks that reach --steps steps.")
    w.add_argument("config", type=Path, nargs="?", default=Path("configs/biped.yaml"))
    w.add_argument("--predictor", type=Path, default=None, help="exported bem_predictor.pt to walk with")
    w.add_argument("--no-model", action="store_true", help="only the predictor (needs --predictor)")
    w.add_argument("--seeds", type=int, default=20, help="walks per gait and source (default 20)")
    w.add_argument("--steps", type=int, default=30, help="steps asked of each walk (default 30)")
    w.add_argument("--gaits", nargs="+", default=["default", "human"], choices=["default", "human"])
    w.add_argument("--initial-noise", type=float, default=0.02, help="initial joint-angle noise std, rad (default 0.02)")
    w.add_argument("--sensor-noise", type=float, default=0.001, help="encoder noise std, rad (default 0.001)")
    w.add_argument("--no-progress", action="store_true")
    w.set_defaults(func=_walks)
    g = sub.add_parser("sigint", help="Ctrl-C latency of `bemlearn train` (SIGINT → exit, checkpoint left)",
                       description="Start `bemlearn train` in a child process, send SIGINT a few seconds into the fit and "
                       "time until it exits; checks the interrupted checkpoint it leaves.")
    g.add_argument("config", type=Path, nargs="?", default=Path("configs/furuta.yaml"))
    g.add_argument("--data", type=Path, default=Path("data/furuta_excitation.npz"))
    g.add_argument("--n-points", type=int, default=3000, help="training points (default 3000: the largest exact fit)")
    g.add_argument("--kind", choices=["exact", "sgpr"], default="exact")
    g.add_argument("--delays", type=float, nargs="+", default=[3.0, 5.0, 7.0, 9.0, 11.0],
                   help="seconds after the fit starts at which SIGINT is sent, one run each")
    g.add_argument("--twice", action="store_true", help="also a run with a second SIGINT 0.2 s after the first")
    g.set_defaults(func=_sigint)
    z = sub.add_parser("fuzz", help="generated bad inputs for every reader: classes tried, named errors",
                       description="Feed generated bad trajectory files, configs, MJCF paths and checkpoint/predictor "
                       "files to bemlearn's readers and count the bad-input classes that end in a named error.")
    z.add_argument("--examples", type=int, default=20, help="generated examples per class (default 20)")
    z.set_defaults(func=_fuzz)


def run_predict(args: argparse.Namespace) -> int:
    for name in ("n_train", "repeats", "gpytorch_repeats", "batch", "threads", "batch_threads"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')}: expected a positive integer, got {getattr(args, name)}")
    result = run_predict_bench(
        checkpoint=args.checkpoint,
        n_train=args.n_train,
        seed=args.seed,
        repeats=args.repeats,
        warmup=min(2000, args.repeats),
        gpytorch_repeats=args.gpytorch_repeats,
        batch=args.batch,
        threads=args.threads,
        batch_threads=args.batch_threads,
        pt2=not args.no_pt2,
        progress=not args.no_progress,
    )
    print(format_predict_bench(result))
    return 0


def _train(args: argparse.Namespace) -> int:
    from bemlearn.bench.bem_train_bench import bench_bem_training
    from bemlearn.pipeline.config import load_pipeline_config

    cfg = load_pipeline_config(args.config)
    rows = bench_bem_training(cfg, args.data, svgp=not args.no_svgp, progress=lambda r: None)
    print("| model | N | threads | fit (s) | BEM RMSE (rad) | BEM max (rad) | inside ±2σ latent / predictive | notes |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        note = f"{r['seconds_per_epoch']:.0f} s/epoch, peak RSS {r['peak_rss_gib']:.2f} GiB" if "peak_rss_gib" in r else r["stop_reason"]
        print(f"| {r['kind']} | {r['n_train']} | {r['threads']} | {r['seconds']:.1f} | {r['rmse']:.5f} | {r['max_abs']:.5f} | "
              f"{100 * r['coverage_latent']:.0f}% / {100 * r['coverage_predictive']:.0f}% | {note} |")
    return 0


def _sim(args: argparse.Namespace) -> int:
    from bemlearn.bench.sim_bench import format_sim_bench, run_sim_bench
    from bemlearn.pipeline.config import load_pipeline_config

    pred = args.predictor / "bem_predictor.pt" if args.predictor.is_dir() else args.predictor
    cfg = load_pipeline_config(args.config)
    r = run_sim_bench(pred, base=cfg.simulate, n_refs=args.refs, n_seeds=args.seeds, duration_s=args.duration, mismatch=not args.no_mismatch)
    print(format_sim_bench(r))
    return 0


def _derivatives(args: argparse.Namespace) -> int:
    from bemlearn.bench.derivatives_bench import run_derivatives_bench
    from bemlearn.pipeline.config import load_pipeline_config

    cfg = load_pipeline_config(args.config)
    head = "| estimator | options | q̇ RMS θ / α (rad/s) | q̈ RMS θ / α (rad/s²) |"
    if not args.no_gp:
        head += " BEM RMSE (rad) | BEM max (rad) | inside ±2σ (latent) |"
    print(head)
    print("|" + " --- |" * (head.count("|") - 1))
    run_derivatives_bench(cfg, args.data, with_gp=not args.no_gp, progress=print)
    return 0


def _gpdm(args: argparse.Namespace) -> int:
    import dataclasses
    import json

    from bemlearn.bench.gpdm_bench import run_gpdm_bench
    from bemlearn.fitting.gpdm_fit import GPDMConfig

    result = run_gpdm_bench(config=dataclasses.replace(GPDMConfig(), max_iter=args.max_iter))
    print(json.dumps(result, indent=2, default=float))
    return 0


def _biped_bem(args: argparse.Namespace) -> int:
    from bemlearn.bench.biped_bem_bench import format_biped_bem_bench, run_biped_bem_bench
    from bemlearn.pipeline.biped import load_biped_config

    if args.subsets < 1:
        raise ValueError(f"--subsets: expected a positive integer, got {args.subsets}")
    result = run_biped_bem_bench(load_biped_config(args.config), data=args.data, subsets=args.subsets,
                                 collect_seeds=args.collect_seeds, progress=not args.no_progress)
    print(format_biped_bem_bench(result))
    return 0


def _walks(args: argparse.Namespace) -> int:
    from bemlearn.bench.walk_bench import format_walk_bench, run_walk_bench
    from bemlearn.sim.walking import load_walk_config

    if args.predictor is not None and not args.predictor.is_file():
        raise FileNotFoundError(f"--predictor: no such file {args.predictor} (expected an exported bem_predictor.pt)")
    if args.no_model and args.predictor is None:
        raise ValueError("--no-model: needs --predictor (nothing else to walk with)")
    rows = run_walk_bench(load_walk_config(args.config), seeds=args.seeds, steps=args.steps, gaits=tuple(args.gaits),
                          predictor=None if args.predictor is None else str(args.predictor), model=not args.no_model,
                          initial_noise=args.initial_noise, sensor_noise=args.sensor_noise,
                          progress=not args.no_progress)
    print(format_walk_bench(rows, steps=args.steps))
    return 0


def _sigint(args: argparse.Namespace) -> int:
    import os

    from bemlearn.bench.sigint_bench import format_sigint, measure_sigint

    rows = [measure_sigint(args.config, args.data, n_points=args.n_points, kind=args.kind, delay_s=d) for d in args.delays]
    if args.twice:
        rows.append(measure_sigint(args.config, args.data, n_points=args.n_points, kind=args.kind, delay_s=args.delays[0], twice=True))
    print(format_sigint(rows))
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f} on {os.cpu_count()} cores")
    return 0


def _fuzz(args: argparse.Namespace) -> int:
    from bemlearn.bench.fuzz_bench import format_fuzz, run_fuzz

    print(format_fuzz(run_fuzz(examples=args.examples)))
    return 0
