"""``bemlearn run CONFIG``: the whole pipeline, and ``bemlearn simulate CONFIG``: the closed loop."""

from __future__ import annotations

from pathlib import Path

from bemlearn.errors import ConfigError
from bemlearn.examples import config_argument

__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "run",
        help="the main job: collect → train → export → simulate → report",
        description="Collect excitation data in MuJoCo, train the BEM GP, export the TorchScript predictor, run the EIC "
        "closed loop with the learned, model-based and zero BEM, and write RUN_DIR/report.md. Every run ends with a "
        "verdict (ok, degraded or unusable, with its reasons), printed last and in metrics.json; the exit status is 0 "
        "for ok and degraded, 3 for unusable (4 for degraded with --strict). A robot its model says cannot be balanced "
        "over the design region stops after the model checks, with the verdict written.",
    )
    p.add_argument("config", type=config_argument, help="pipeline YAML; `robot: path/to/robot.xml` alone is enough")
    p.add_argument("--out", type=Path, help="run folder (default: a new runs/<robot>-<timestamp>)")
    p.add_argument("--force", action="store_true", help="write into a non-empty --out folder, replacing its files")
    p.add_argument("--device", choices=["cpu", "cuda"], help="GP training device (default: the config's train.device)")
    p.add_argument("--strict", action="store_true",
                   help="exit non-zero (4) for a degraded verdict too (default: 0 for ok and degraded, 3 for unusable)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars (for logs and scripts)")
    _add_jobs(p, "the derivation's excitation trials run side by side, the model and zero closed loops beside collection "
                 "and training, the learned loop and the .pt2 export beside the evaluation of the trained GP")
    p.set_defaults(func=_run)
    s = sub.add_parser(
        "simulate",
        help="closed-loop EIC simulation with a BEM source in the loop",
        description="Simulate the EIC controller (eq. 3, 8) in MuJoCo with the configured BEM source; writes "
        "OUT/simulate/{metrics.json,fig2_<source>.png} and TensorBoard logs.",
    )
    s.add_argument("config", type=config_argument, help="pipeline YAML naming the robot, or the name of a shipped example")
    s.add_argument("--predictor", type=Path, help="exported bem_predictor.pt (overrides simulate.predictor)")
    s.add_argument("--source", action="append", choices=["predictor", "model", "zero"], help="BEM source(s); default: simulate.bem_source")
    s.add_argument("--out", type=Path, help="output folder (default: a new runs/simulate-<timestamp>)")
    s.add_argument("--force", action="store_true", help="replace an existing OUT/simulate folder's files")
    s.add_argument("--gif", action="store_true", help="also render OUT/simulate/<source>.gif (offscreen: picks a working OpenGL backend by itself, EGL first)")
    s.add_argument("--no-progress", action="store_true", help="no progress bars (for logs and scripts)")
    _add_jobs(s, "the closed loops of the sources run at once (not with --gif)")
    s.set_defaults(func=_simulate)


def _add_jobs(parser, what: str) -> None:
    parser.add_argument("--jobs", type=int, metavar="N",
                        help=f"worker processes: {what}; 1 runs everything in order in one process; the results are the "
                        "same (default: the usable CPUs, at most 4)")


def _jobs(args) -> int:
    """``--jobs``, checked (a positive integer), or its default."""
    from bemlearn.pipeline.workers import check_jobs, default_jobs

    return default_jobs() if args.jobs is None else check_jobs(args.jobs, where="--jobs")


def _run(args) -> int:
    from bemlearn.applications import get_application
    from bemlearn.outputs import claim_outputs
    from bemlearn.pipeline.preflight import preflight
    from bemlearn.pipeline.workers import using_jobs

    jobs = _jobs(args)
    with using_jobs(jobs):   # the derivations' MuJoCo trials use as many workers as the run
        checked = preflight(config=args.config, device=args.device)  # strict parse and model-derived values, before any folder exists
    raw, resolved = checked.raw, checked.resolved
    app = None
    if raw.get("application") is not None:  # a config of an application (e.g. the biped's): it runs its own stages
        app = get_application(str(raw["application"]))
        if app.run is None:
            raise ConfigError(f"{args.config}: application {raw['application']!r} has no pipeline of its own; remove the 'application' key")
    stem = Path(str(raw["robot"])).stem if "robot" in raw else Path(str(raw.get("data", "run"))).stem
    preflight(out_dir=args.out or Path("runs"), outputs=[args.out] if args.out else [], force=args.force)
    # claimed: created exclusively and locked; a failed --force puts the folder back as it was
    with claim_outputs(args.out, default_name=stem, force=args.force, keep=["data.npz", "checkpoint.pt"],
                       what="run") as claimed:
        verdict = None
        if app is not None:
            assert app.run is not None  # checked above
            out = app.run(args.config, claimed, device=args.device, progress=not args.no_progress)
        else:
            from bemlearn.pipeline.run import run_pipeline

            assert resolved is not None  # resolved above when no application runs
            result = run_pipeline(resolved, claimed, device=args.device, progress=not args.no_progress, jobs=jobs)
            out, verdict = result.out, result.verdict
    print((out / "report.md").read_text())
    print(f"\nrun folder: {out}")
    if verdict is None:   # an application's run: its verdict is in the metrics.json it wrote
        verdict = _written_verdict(out)
    if verdict is None:
        return 0
    print(verdict.summary())
    return verdict.exit_status(strict=args.strict)


def _written_verdict(out: Path):
    """The verdict an application's run wrote to ``out/metrics.json`` (``None`` when it wrote none)."""
    from bemlearn.pipeline.failure import read_metrics
    from bemlearn.pipeline.run_metrics import RunMetrics

    try:
        return RunMetrics.from_dict(read_metrics(out)).verdict
    except KeyError:    # a verdict without a status: none
        return None


def _simulate(args) -> int:
    from bemlearn.export.staleness import check_predictor_matches
    from bemlearn.outputs import claim_outputs
    from bemlearn.pipeline.preflight import preflight
    from bemlearn.pipeline.simulate import simulate_stage

    args.jobs = _jobs(args)
    cfg = preflight(config=args.config, out_dir=args.out or Path("runs"), outputs=[args.out / "simulate"] if args.out else [],
                    force=args.force).pipeline_config()
    if cfg.robot is None:
        raise ConfigError(f"{args.config}: simulate needs a robot (a model to simulate); the config names only data")
    pred = args.predictor or (Path(cfg.simulate.predictor) if cfg.simulate.predictor else None)
    if pred is not None and pred.is_file() and (pred.parent / "checkpoint.pt").is_file():
        check_predictor_matches(pred, pred.parent / "checkpoint.pt")
    if pred is not None and "predictor" in (args.source or [cfg.simulate.bem_source]):
        from bemlearn.control.bem_sources import PredictorBEM

        PredictorBEM(pred)  # a foreign or tampered file is refused before any folder exists
    if args.gif:
        from bemlearn.sim.render import require_offscreen_backend

        require_offscreen_backend()
    with claim_outputs(args.out, entries=["simulate", "tb/simulate"], default_name="simulate", force=args.force,
                       what="simulate") as args.out:
        return _simulate_into(args, cfg, simulate_stage)


def _simulate_into(args, cfg, simulate_stage) -> int:
    """The closed loop of ``cfg`` into ``args.out`` (checked by :func:`_simulate`)."""
    sources = tuple(args.source or [cfg.simulate.bem_source])
    res = simulate_stage(cfg, args.out, predictor=args.predictor, sources=sources, progress=not args.no_progress, gif=args.gif,
                         jobs=args.jobs)
    print(f"{'source':<10}{'fell':>6}{'duration s':>12}{'RMSE q_a':>10}{'max|u|':>8}{'×real time':>12}")
    from bemlearn.pipeline.report import ZERO_BASELINE_NOTE, ZERO_SOURCE

    for src, loop in res.loops.items():
        note = ZERO_BASELINE_NOTE if src == ZERO_SOURCE else ""
        print(f"{src:<10}{loop.fell!s:>6}{loop.duration_s:>12.1f}{loop.tracking_rmse:>10.4f}{loop.u_max:>8.2f}"
              f"{loop.real_time_factor:>12.1f}{note}")
    print(f"wrote {args.out / 'simulate'}")
    return 1 if any(loop.fell for loop in res.loops.values() if loop.source != ZERO_SOURCE) else 0
