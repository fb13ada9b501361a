"""``bemlearn run CONFIG``: the whole pipeline, and ``bemlearn simulate CONFIG``: the closed loop."""

from __future__ import annotations

from pathlib import Path

__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "run",
        help="the main job: collect → train → export → simulate → report",
        description="Collect excitation data in MuJoCo, train the BEM GP, export the TorchScript predictor, run the EIC "
        "closed loop with the learned, model-based and zero BEM, and write RUN_DIR/report.md.",
    )
    p.add_argument("config", type=Path, help="pipeline YAML; `robot: path/to/robot.xml` alone is enough")
    p.add_argument("--out", type=Path, help="run folder (default runs/<robot>-<timestamp>)")
    p.add_argument("--device", choices=["cpu", "cuda"], help="GP training device (default: the config's train.device)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_run)
    s = sub.add_parser(
        "simulate",
        help="closed-loop EIC simulation with a BEM source in the loop",
        description="Simulate the EIC controller (eq. 3, 8) in MuJoCo with the configured BEM source; writes "
        "OUT/simulate/{metrics.json,fig2_<source>.png} and TensorBoard logs.",
    )
    s.add_argument("config", type=Path)
    s.add_argument("--predictor", type=Path, help="exported bem_predictor.pt (overrides simulate.predictor)")
    s.add_argument("--source", action="append", choices=["predictor", "model", "zero"], help="BEM source(s); default: simulate.bem_source")
    s.add_argument("--out", type=Path, default=Path("runs") / "simulate")
    s.add_argument("--gif", action="store_true", help="also render OUT/simulate/<source>.gif (needs MUJOCO_GL=egl or osmesa without a display)")
    s.add_argument("--no-progress", action="store_true")
    s.set_defaults(func=_simulate)


def _run(args) -> int:
    from bemlearn.applications import get_application
    from bemlearn.config import load_yaml
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.pipeline.run import run_pipeline

    app_name = load_yaml(args.config).get("application")
    if app_name is not None:  # a config of an application (e.g. the biped's): it runs its own stages
        app = get_application(str(app_name))
        if app.run is None:
            raise ValueError(f"{args.config}: application {app_name!r} has no pipeline of its own; remove the 'application' key")
        out = app.run(args.config, args.out, device=args.device, progress=not args.no_progress)
        print((out / "report.md").read_text())
        print(f"\nrun folder: {out}")
        return 0
    resolved = resolve_pipeline_config(args.config)
    out = run_pipeline(resolved, args.out, device=args.device, progress=not args.no_progress)
    print((out / "report.md").read_text())
    print(f"\nrun folder: {out}")
    return 0


def _simulate(args) -> int:
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.pipeline.simulate import simulate_stage

    cfg = resolve_pipeline_config(args.config).config
    sources = tuple(args.source or [cfg.simulate.bem_source])
    res = simulate_stage(cfg, args.out, predictor=args.predictor, sources=sources, progress=not args.no_progress, gif=args.gif)
    print(f"{'source':<10}{'fell':>6}{'duration s':>12}{'RMSE rad':>10}{'max|V|':>8}{'×real time':>12}")
    for src, m in res.items():
        print(f"{src:<10}{str(m['fell']):>6}{m['duration_s']:>12.1f}{m['tracking_rmse']:>10.4f}{m['u_max']:>8.2f}{m['real_time_factor']:>12.1f}")
    print(f"wrote {args.out / 'simulate'}")
    return 1 if any(m["fell"] for m in res.values() if m["bem_source"] != "zero") else 0
