"""``bemlearn bench``: measurements kept out of the timed test suite.

* ``bench train [CONFIG]`` — exact / sgpr / svgp fit times and learned-BEM accuracy;
* ``bench predict [CHECKPOINT]`` — predictor latency, throughput and GPyTorch parity;
* ``bench sim PREDICTOR`` — the learned BEM in the EIC loop, mismatch study, Lemma 1, speed;
* ``bench derivatives [CONFIG]`` — derivative estimators and their effect on the learned BEM;
* ``bench gpdm`` — GPDM fit time and recovery on synthetic gait data;
* the installed applications' benches (e.g. the biped's ``bench biped-bem`` and ``bench walks``).
* ``bench import [--rows N] [--accuracy]`` — logger CSV import speed and the model-free path's accuracy.
* ``bench robots [MJCF …]`` — collect → train → export → held-out BEM → closed loop on MJCF
  robots with model-derived values only.
* ``bench sweep SWEEP`` — the Ray backend of ``bemlearn sweep`` against the serial one: speed-up,
  per-cell overhead, identical results.
* ``bench uncertainty`` — candidate BEM bands: coverage, sharpness, bound violations, cost.
* ``bench band RUN…`` — the exported band's terms on trained runs (coverage and sharpness of each).
* ``bench c-footprint`` — flash/RAM footprint of the C export per model size and kind.
* ``bench sigint CONFIG --data FILE`` — Ctrl-C latency of ``train`` on the 3,000-point exact GP;
* ``bench fuzz`` — bad-input classes fed to every reader and how many end in a named error.
* ``bench hostile`` — predictor peak memory on 10⁶ rows (TorchScript vs ``.pt2``), 10⁴-cell grid validation.
* ``bench family generate|run|score`` — a seeded family of in-class robots with an oracle; zero-config runs
  scored against it, per feature (docs/family.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bemlearn.errors import ArgumentError
from bemlearn.examples import config_argument

__all__ = ["add_parser", "run_predict"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("bench", help="benchmarks", description="Benchmarks of bemlearn components.")
    sub = parser.add_subparsers(dest="bench", metavar="BENCH", required=True)
    p = sub.add_parser(
        "predict",
        help="latency, throughput and GPyTorch parity of the exported BEM predictor",
        description="Time the exported BEM predictor (TorchScript, torch.export, AOTInductor; from Python and "
        "from C++) against NumPy and "
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
    p.add_argument("--seed", type=int, default=0, help="seed of the synthetic posterior and of the query points (default 0)")
    p.add_argument("--no-pt2", action="store_true", help="skip the torch.export artifact")
    p.add_argument("--no-c", action="store_true", help="skip the C export (compiled with the system cc)")
    p.add_argument("--no-aoti", action="store_true",
                   help="skip the AOTInductor package (compiling it takes 1-2 min) and the C++ timings")
    p.add_argument("--no-cpp", action="store_true",
                   help="skip timing TorchScript and AOTInductor from C++ (builds a libtorch program, 30-60 s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_predict)
    cf = sub.add_parser("c-footprint", help="flash/RAM footprint of the C export per model size and kind",
                        description="Compile the C export (bemlearn export --format c) of synthetic exact (N = 100..1000) "
                        "and sgpr/svgp (M = 64..512) posteriors, float64 and float32, and print a Markdown table of "
                        "code, constants and stack (needs cc and binutils size).")
    cf.set_defaults(func=_c_footprint)
    t = sub.add_parser("train", help="GP fit times (exact / sgpr / svgp) and learned-BEM accuracy of a config on a data file")
    t.add_argument("config", type=config_argument, help="pipeline YAML naming the robot (its model BEM is the reference)")
    t.add_argument("--data", type=Path, required=True, help="trajectory file to train on")
    t.add_argument("--no-svgp", action="store_true", help="skip the 10⁶-point svgp run (minutes)")
    t.set_defaults(func=_train)
    s = sub.add_parser("sim", help="learned BEM in the EIC loop of a run's robot: references × seeds, mismatch, Lemma 1, speed")
    s.add_argument("run_dir", type=Path, help="a run folder (its robot, closed-loop config and bem_predictor.pt are used)")
    s.add_argument("--mismatch-bodies", nargs="+", default=None, metavar="BODY",
                   help="bodies whose mass and lengths the mismatch study scales (default: all)")
    s.add_argument("--refs", type=int, default=5, help="random composite-sinusoid references (default 5)")
    s.add_argument("--seeds", type=int, default=5, help="seeds (sensor noise, initial state) per reference (default 5)")
    s.add_argument("--duration", type=float, default=60.0, help="simulated seconds per run")
    s.add_argument("--no-mismatch", action="store_true", help="skip the model-mismatch study")
    s.set_defaults(func=_sim)
    d = sub.add_parser("derivatives", help="derivative estimators vs ground truth and their effect on the learned BEM "
                       "(design region and held-out references; first row: the exact-derivative oracle)")
    d.add_argument("config", type=config_argument, help="pipeline YAML naming the robot (a run folder's config.yaml works)")
    d.add_argument("--data", type=Path, required=True, help="trajectory file with its <stem>.truth file beside it")
    d.add_argument("--no-gp", action="store_true", help="only the derivative errors")
    d.set_defaults(func=_derivatives)
    g = sub.add_parser("gpdm", help="GPDM fit time and recovery of c and χ on synthetic gait data")
    g.add_argument("--max-iter", type=int, default=500, help="GPDM optimizer iterations (default 500)")
    g.set_defaults(func=_gpdm)
    from bemlearn.applications import applications

    for app in applications().values():
        if app.add_bench is not None:
            app.add_bench(sub)
    cl = sub.add_parser("closed-loop-data", help="a rig's own LQR loop as the only data: verdict on lockstep data, and on "
                        "the same loop playing `bemlearn excite`'s schedule (slopes vs the model's)",
                        description="Balance ROBOT by a plain discrete LQR with small random torques on every joint, log "
                        "CSVs, import them with `bemlearn data import`, run model-free; then play the schedule `bemlearn "
                        "excite` writes for those data and run again (bemlearn/bench/closed_loop_bench.py).")
    cl.add_argument("--robot", default="tests/robots/pendubot.xml", help="MJCF file (default tests/robots/pendubot.xml)")
    cl.add_argument("--out", type=Path, required=True, help="work folder (logs, data, runs)")
    cl.add_argument("--trials", type=int, default=12, help="trials per data set (default 12)")
    cl.add_argument("--duration", type=float, default=20.0, help="seconds per lockstep trial (default 20)")
    cl.add_argument("--rate", type=float, default=500.0, help="control and log rate, Hz (default 500)")
    cl.add_argument("--disturbance", type=float, default=3e-4, help="rms torque on every joint, N·m (default 3e-4)")
    cl.add_argument("--seed", type=int, default=0, help="seed of the disturbances, encoders and schedule (default 0)")
    cl.set_defaults(func=_closed_loop_data)
    im = sub.add_parser("import", help="logger CSV import speed (10⁶ rows) and, with --accuracy, the model-free "
                        "path's learned BEM vs the simulator file's")
    im.add_argument("--data", type=Path, required=True,
                    help="a simulator trajectory file, written out as logger CSVs (e.g. the shipped data/*.npz)")
    im.add_argument("--rows", type=int, default=1_000_000, help="rows imported in the speed case (default 10⁶)")
    im.add_argument("--files", type=int, default=10, help="files the rows are spread over (default 10)")
    im.add_argument("--repeats", type=int, default=5, help="timed imports; the median is reported (default 5)")
    im.add_argument("--accuracy", action="store_true", help="also fit the GP on the imported and the original file")
    im.add_argument("--config", type=config_argument, default=None, help="pipeline YAML (robot, dataset and train sections); needed with --accuracy")
    im.add_argument("--figures", type=Path, default=None, help="folder for the BEM slice figures")
    im.set_defaults(func=_import)
    rb = sub.add_parser("robots", help="the whole chain on MJCF robots with derived values only")
    rb.add_argument("robots", nargs="+", help="MJCF files or registry names, e.g. tests/robots/*.xml")
    rb.add_argument("--out", type=Path, default=Path("runs/bench-robots"), help="folder of the per-robot runs")
    rb.add_argument("--trials", type=int, default=24, help="excitation trials per robot (default 24)")
    rb.add_argument("--duration", type=float, default=20.0, help="seconds per excitation trial (default 20)")
    rb.add_argument("--sim-duration", type=float, default=30.0, help="closed-loop seconds per BEM source (default 30)")
    rb.add_argument("--workers", type=int, default=1, help="collect processes (default 1)")
    rb.add_argument("--seed", type=int, default=0, help="collect seed (default 0)")
    rb.set_defaults(func=_robots)
    sw = sub.add_parser("sweep", help="the Ray backend of `bemlearn sweep` against the serial one: speed-up, per-cell "
                        "overhead, same results",
                        description="Run SWEEP with --backend serial into OUT/serial and with --backend ray into OUT/ray "
                        "(a local Ray instance with this machine's cores), resume the finished one, and report wall "
                        "times, Ray's overhead per cell and whether the results agree (see bemlearn/bench/sweep_bench.py).")
    sw.add_argument("sweep", type=config_argument, help="a sweep file, e.g. configs/sweeps/robots-quick.yaml")
    sw.add_argument("--out", type=Path, required=True, help="folder of the two sweeps (OUT/serial, OUT/ray)")
    sw.add_argument("--max-parallel", type=int, default=None, help="cells at once on Ray (default: the cores)")
    sw.add_argument("--force", action="store_true", help="run every cell again in existing OUT/serial and OUT/ray")
    sw.add_argument("--no-progress", action="store_true", help="no progress bars (for logs and scripts)")
    sw.set_defaults(func=_sweep)
    u = sub.add_parser("uncertainty", help="candidate BEM bands: coverage of the model BEM, sharpness, bound violations, cost",
                       description="Fit the config's robot (and a generated cart-pole) BEM GP and score each candidate band "
                       "on held-out references against the model-based BEM (see bemlearn/bench/uncertainty_bench.py).")
    u.add_argument("--config", type=config_argument, required=True, help="pipeline YAML of the robot (e.g. the shipped configs/*.yaml)")
    u.add_argument("--data", type=Path, required=True, help="its excitation data (e.g. the shipped data/*.npz)")
    u.add_argument("--no-cartpole", action="store_true", help="only the config's robot (the cart-pole collects ~10 s of trials)")
    u.add_argument("--workdir", type=Path, default=None, help="keep the cart-pole MJCF and data here (default: a temp dir)")
    u.add_argument("--seeds", type=int, default=0, help="also refit the chosen band with dataset seeds 1..K (robustness)")
    u.add_argument("--json", type=Path, default=None, help="also write the full results (reliability tables) as JSON")
    u.add_argument("--force", action="store_true", help="replace an existing --json file")
    u.set_defaults(func=_uncertainty)

    bb = sub.add_parser("band", help="the calibrated band's terms on trained runs: coverage of the model BEM and sharpness",
                        description="Score the exported band (eq. B1) term by term on each run's held-out references "
                        "against the model-based BEM; nothing is refitted (see bemlearn/bench/band_bench.py).")
    bb.add_argument("runs", nargs="+", type=Path, help="run folders of `bemlearn run` / `bemlearn train` (with a robot model)")
    bb.set_defaults(func=_band)

    g = sub.add_parser("sigint", help="Ctrl-C latency of `bemlearn train` (SIGINT → exit, checkpoint left)",
                       description="Start `bemlearn train` in a child process, send SIGINT a few seconds into the fit and "
                       "time until it exits; checks the interrupted checkpoint it leaves.")
    g.add_argument("config", type=config_argument, help="pipeline YAML (e.g. the shipped configs/*.yaml)")
    g.add_argument("--data", type=Path, required=True, help="trajectory file to train on (e.g. the shipped data/*.npz)")
    g.add_argument("--n-points", type=int, default=3000, help="training points (default 3000: the largest exact fit)")
    g.add_argument("--kind", choices=["exact", "sgpr"], default="exact", help="GP kind to fit (default exact)")
    g.add_argument("--delays", type=float, nargs="+", default=[3.0, 5.0, 7.0, 9.0, 11.0],
                   help="seconds after the fit starts at which SIGINT is sent, one run each")
    g.add_argument("--twice", action="store_true", help="also a run with a second SIGINT 0.2 s after the first")
    g.set_defaults(func=_sigint)
    z = sub.add_parser("fuzz", help="generated bad inputs for every reader: classes tried, named errors",
                       description="Feed generated bad trajectory files, configs, MJCF paths and checkpoint/predictor "
                       "files to bemlearn's readers and count the bad-input classes that end in a named error.")
    z.add_argument("--examples", type=int, default=20, help="generated examples per class (default 20)")
    z.set_defaults(func=_fuzz)
    h = sub.add_parser("hostile", help="issue 29's figures: predictor peak memory on large batches, large-grid validation",
                       description="Peak RSS growth of the TorchScript and .pt2 predictors on --rows rows (child processes) "
                       "and the wall time of validating a --cells-cell sweep grid.")
    h.add_argument("--rows", type=int, default=10**6, help="batch rows (default 10⁶)")
    h.add_argument("--n-train", type=int, default=500, help="support points of the synthetic exact GP (default 500)")
    h.add_argument("--cells", type=int, default=10**4, help="sweep grid cells to validate (default 10⁴; 0: skip)")
    h.set_defaults(func=_hostile)
    _add_family(sub)


def _add_family(sub: argparse._SubParsersAction) -> None:
    fam = sub.add_parser("family", help="a seeded family of in-class robots with an oracle; the pipeline scored on it",
                         description="Generate MJCF robots of bemlearn's class from a seed, each with its oracle "
                         "(true upright, model BEM from mj_inverse, whether its actuators can hold it), and score "
                         "zero-config runs against the oracle (docs/family.md).")
    fsub = fam.add_subparsers(dest="family_cmd", metavar="ACTION", required=True)
    g = fsub.add_parser("generate", help="write the family: one MJCF + one oracle JSON per robot, and index.json")
    g.add_argument("--seed", type=int, default=0, help="family seed (default 0)")
    g.add_argument("--count", type=int, default=64, help="robots (default 64)")
    g.add_argument("--out", type=Path, required=True, help="folder of the family")
    g.add_argument("--force", action="store_true", help="replace existing family files")
    g.set_defaults(func=_family_generate)
    r = fsub.add_parser("run", help="run each robot zero-config (`robot: FILE`) with `bemlearn run` and score it against "
                        "its oracle: results.csv/json and the per-feature table",
                        description="Generate (or reuse) the family in OUT/robots, run `bemlearn run` on a config naming only "
                        "each robot file (OUT/runs/NAME), compare each exported predictor with the oracle BEM on "
                        "design-region queries and print the per-feature table (also OUT/table.md).  Finished runs "
                        "(OUT/runs/NAME/family_run.json) are scored again, not rerun, unless --rerun.")
    r.add_argument("--seed", type=int, default=0, help="family seed (default 0)")
    r.add_argument("--count", type=int, default=64, help="robots in the family (default 64)")
    r.add_argument("--out", type=Path, required=True, help="bench folder (robots/, configs/, runs/, logs/, results)")
    r.add_argument("--only", type=int, nargs="+", default=None, metavar="IDX", help="run only these robot indices")
    r.add_argument("--backend", choices=["serial", "ray"], default="serial", help="serial (default) or ray")
    r.add_argument("--jobs", type=int, default=2, help="runs at once with --backend ray (default 2)")
    r.add_argument("--timeout", type=float, default=3600.0, help="seconds per run before it is stopped (default 3600)")
    r.add_argument("--rerun", action="store_true", help="run robots again that have a finished run")
    r.add_argument("--force", action="store_true", help="replace a family of another seed/count in OUT/robots")
    r.add_argument("--checkout", type=Path, default=None,
                   help="run the pipeline of another bemlearn source tree (a worktree with a fix); default this one")
    r.set_defaults(func=_family_run)
    sc = fsub.add_parser("score", help="score a `bemlearn sweep` over the family (configs/sweeps/family.yaml) against the oracles",
                         description="Score each complete cell of SWEEP whose robot is a file of FAMILY against its oracle "
                         "and write results.csv/json and table.md into SWEEP.")
    sc.add_argument("--sweep", type=Path, required=True, help="the sweep folder (`bemlearn sweep ... --out SWEEP`)")
    sc.add_argument("--family", type=Path, required=True, help="the family folder (`bench family generate --out FAMILY`)")
    sc.set_defaults(func=_family_score)

def _c_footprint(args: argparse.Namespace) -> int:
    from bemlearn.bench.c_footprint import format_footprints, measure_footprints

    print(format_footprints(measure_footprints()))
    return 0


def run_predict(args: argparse.Namespace) -> int:
    from bemlearn.bench.predict_bench import format_predict_bench, run_predict_bench

    for name in ("n_train", "repeats", "gpytorch_repeats", "batch", "threads", "batch_threads"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise ArgumentError(f"--{name.replace('_', '-')}: expected a positive integer, got {getattr(args, name)}")
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
        c=not args.no_c,
        aoti=not args.no_aoti,
        cpp=not args.no_cpp,
    )
    print(format_predict_bench(result))
    return 0


def _train(args: argparse.Namespace) -> int:
    from bemlearn.bench.bem_train_bench import bench_bem_training
    from bemlearn.pipeline.resolve import load_pipeline_config

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

    bodies = tuple(args.mismatch_bodies) if args.mismatch_bodies else None
    r = run_sim_bench(args.run_dir, n_refs=args.refs, n_seeds=args.seeds, duration_s=args.duration,
                      mismatch=not args.no_mismatch, bodies=bodies)
    print(format_sim_bench(r))
    return 0


def _derivatives(args: argparse.Namespace) -> int:
    from bemlearn.bench.derivatives_bench import TABLE_HEAD, run_derivatives_bench
    from bemlearn.pipeline.resolve import load_pipeline_config

    cfg = load_pipeline_config(args.config)
    head = TABLE_HEAD[0] + ("" if args.no_gp else TABLE_HEAD[1])
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


def _import(args: argparse.Namespace) -> int:
    import json
    import os

    from bemlearn.bench.import_bench import bench_import_speed, bench_model_free_accuracy
    from bemlearn.data import read_trajectory

    for name in ("rows", "files", "repeats"):
        if getattr(args, name) < 1:
            raise ArgumentError(f"--{name}: expected a positive integer, got {getattr(args, name)}")
    source = read_trajectory(args.data)
    result = {"load_average_1min": os.getloadavg()[0],
              "speed": bench_import_speed(source, rows=args.rows, trials=args.files, repeats=args.repeats)}
    if args.accuracy:
        from bemlearn.pipeline.resolve import load_pipeline_config

        if args.config is None:
            raise ArgumentError("--accuracy: needs --config (the robot whose model BEM is the reference, and the dataset/train sections)")

        result["accuracy"] = bench_model_free_accuracy(source, load_pipeline_config(args.config), figure_dir=args.figures)
    print(json.dumps(result, indent=2, default=float))
    return 0


def _robots(args: argparse.Namespace) -> int:
    import os

    from bemlearn.bench.robots_bench import format_robots_bench, robot_chain

    rows = []
    for path in args.robots:
        out = args.out / Path(path).stem
        rows.append(robot_chain(path, out, n_trials=args.trials, duration_s=args.duration, sim_duration_s=args.sim_duration,
                                workers=args.workers, seed=args.seed, progress=print))
    print(f"load average {os.getloadavg()[0]:.2f}")
    print(format_robots_bench(rows))
    return 0


def _sweep(args: argparse.Namespace) -> int:
    from bemlearn.bench.sweep_bench import format_sweep_bench, run_sweep_bench

    print(format_sweep_bench(run_sweep_bench(args.sweep, args.out, max_parallel=args.max_parallel, force=args.force,
                                             progress=not args.no_progress)))
    return 0


def _uncertainty(args: argparse.Namespace) -> int:
    import json

    from bemlearn.bench.uncertainty_bench import format_seed_sweep, format_uncertainty_bench, run_uncertainty_bench
    from bemlearn.files import atomic_write_text, check_outputs

    if args.seeds < 0:
        raise ArgumentError(f"--seeds: expected a non-negative integer, got {args.seeds}")
    if args.json is not None:   # refused before minutes of fitting, not after
        check_outputs([args.json], args.force, what="bench uncertainty --json")
    results, sweep = run_uncertainty_bench(config=args.config, data=args.data, cartpole=not args.no_cartpole,
                                           workdir=args.workdir, seeds=args.seeds, progress=print)
    print(format_uncertainty_bench(results))
    if sweep:
        print("\nchosen band over dataset seeds (training draw and trial split):")
        print(format_seed_sweep(sweep))
    if args.json is not None:
        atomic_write_text(args.json, json.dumps({"candidates": results, "seeds": sweep}, indent=1, default=float))
    return 0


def _band(args: argparse.Namespace) -> int:
    from bemlearn.bench.band_bench import format_band_bench, run_band_bench

    print(format_band_bench(run_band_bench(args.runs, progress=print)))
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


def _hostile(args: argparse.Namespace) -> int:
    from bemlearn.bench.hostile_bench import format_hostile, predictor_memory, sweep_validation_s

    memory = predictor_memory(rows=args.rows, n_train=args.n_train)
    validation = sweep_validation_s(cells=args.cells) if args.cells else None
    print(format_hostile(memory, validation, args.cells))
    return 0


def _family_generate(args: argparse.Namespace) -> int:
    import sys

    from bemlearn.bench.family.family_bench import write_family

    index = write_family(args.seed, args.count, args.out, force=args.force,
                         progress=lambda s: print(s, file=sys.stderr, flush=True))
    n_hold = sum(bool(r["holdable"]) for r in index["robots"])
    print(f"{args.out}: {len(index['robots'])} robots of family seed {args.seed} ({n_hold} holdable by the oracle)")
    return 0


def _family_run(args: argparse.Namespace) -> int:
    import sys

    from bemlearn.bench.family.family_bench import run_family

    if args.jobs < 1:
        raise ArgumentError(f"--jobs: expected a positive integer, got {args.jobs}")
    res = run_family(args.seed, args.count, args.out, only=args.only, backend=args.backend, jobs=args.jobs,
                     timeout_s=args.timeout, force=args.force, rerun=args.rerun, checkout=args.checkout,
                     progress=lambda s: print(s, file=sys.stderr, flush=True))
    print(f"family seed {args.seed}: {len(res['rows'])} robots scored ({args.out}/results.csv)")
    print(res["markdown"])
    return 0


def _family_score(args: argparse.Namespace) -> int:
    from bemlearn.bench.family.family_bench import score_sweep

    res = score_sweep(args.sweep, args.family)
    print(f"{len(res['rows'])} family runs scored ({args.sweep}/results.csv)")
    print(res["markdown"])
    return 0


def _fuzz(args: argparse.Namespace) -> int:
    from bemlearn.bench.fuzz_bench import format_fuzz, run_fuzz

    print(format_fuzz(run_fuzz(examples=args.examples)))
    return 0


def _closed_loop_data(args) -> int:
    from bemlearn.bench.closed_loop_bench import ClosedLoopCase, bench_closed_loop_data

    case = ClosedLoopCase(robot=args.robot, trials=args.trials, duration_s=args.duration, rate_hz=args.rate,
                          disturbance_rms=args.disturbance, seed=args.seed)
    res = bench_closed_loop_data(case, args.out)
    model = res["model_slopes"]
    print(f"robot {args.robot}: {args.trials} trials, LQR at {args.rate:g} Hz, {1e3 * args.disturbance:g} mN·m rms on every joint")
    print("| data | trials fell | verdict | support share | t of q̈_u slope (S2) | corr(q̈_u, q̈_a) | slope ∂q_u^e/∂q_a (model) "
          "| error | slope ∂q_u^e/∂q̈_a (model) | error |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for c in res["cases"]:
        sup = c["support"]   # a Support (bemlearn.pipeline.run_metrics) or None
        pair = next((p for p in (sup.pairs if sup else None) or () if (p.input or "").startswith("qdd_")), None)
        share = sup.share if sup and sup.share is not None else float("nan")
        t = sup.t if sup and sup.t is not None else float("nan")
        cells = []
        for key in [k for k in model if k.startswith("q_")] + [k for k in model if k.startswith("qdd_")]:
            got, ref = c["slopes"][key], model[key]
            cells += [f"{got:.4g} ({ref:.4g})", f"{100 * (got - ref) / ref:+.1f} %" if ref else "—"]
        print(f"| {c['label']} | {c['sim']['fell']} | {c['verdict'].status} | {share:.2f} | "
              f"{t:.1f} | {pair.corr if pair else float('nan'):+.3f} | " + " | ".join(cells) + " |")
    for c in res["cases"]:
        print(f"{c['label']}: {c['verdict'].summary()}")
    print(res["excite_stdout"].rstrip())
    return 0
