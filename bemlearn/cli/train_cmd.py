"""``bemlearn train CONFIG``: learn the BEM GP (eq. 11–14) from a trajectory file."""

from __future__ import annotations

from pathlib import Path

from bemlearn.errors import ArgumentError, MissingFileError
from bemlearn.examples import config_argument

__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "train",
        help="train the BEM GP on excitation data into a run folder",
        description="Build the GP dataset (eq. 11) from a trajectory file, fit the GP by maximizing the marginal "
        "likelihood, and write RUN_DIR/{config.yaml,checkpoint.pt,metrics.json,tb/}. Ctrl-C leaves a usable checkpoint.",
    )
    p.add_argument("config", type=config_argument, help="pipeline YAML ('robot', 'dataset' and 'train' sections)")
    p.add_argument("--data", type=Path, help="trajectory file (.npz/.csv); default: the config's 'data:'")
    p.add_argument("--out", type=Path, help="run folder (default: runs/train-<timestamp>)")
    p.add_argument("--device", choices=["cpu", "cuda"], help="override train.device")
    p.add_argument("--resume", action="store_true", help="continue from the run folder's checkpoint")
    p.add_argument("--force", action="store_true",
                   help="train into an existing run folder, replacing its checkpoint and metrics (stale predictors are removed)")
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads of the GP fit (default 1). More threads can be faster on an idle machine, but "
                   "on a loaded 2-core machine the 500-point exact fit took 28 s with 2 threads against 4.5 s with 1 "
                   "(docs/design.md)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars (for logs and scripts)")
    p.set_defaults(func=run)


def run(args) -> int:
    # torch loads its compiler (torch._dynamo, ~1 s) when the first optimizer is built, i.e. at the
    # start of the fit; load it with the rest of the training stack instead, so that the fit, once
    # the dataset is logged, starts at once (and a Ctrl-C soon after lands inside it: checkpoint kept)
    import torch._dynamo  # noqa: F401

    from bemlearn.outputs import claim_outputs
    from bemlearn.pipeline.preflight import preflight
    from bemlearn.pipeline.train import train_run

    cfg = preflight(config=args.config, device=args.device).pipeline_config()
    data = args.data or (Path(cfg.data) if cfg.data else None)
    if data is None:
        raise ArgumentError(f"--data: no trajectory file given and {args.config} has no 'data:' key "
                         f"(collect one with `bemlearn collect {args.config} --out FILE`)")
    if not data.is_file():
        raise MissingFileError(f"--data: trajectory file {data} not found (collect one with `bemlearn collect {args.config} --out {data}`)")
    if args.resume and args.out is None:
        raise ArgumentError("--resume: give the run folder to continue with --out RUN")
    if args.resume and not (args.out / "checkpoint.pt").is_file():
        raise MissingFileError(f"--resume: no checkpoint in {args.out}")
    preflight(data=data, out_dir=args.out or Path("runs"), outputs=[] if args.resume or args.out is None else [args.out], force=args.force)
    # the run folder is claimed (created exclusively, locked); a failed --force / --resume puts it back as it was
    with claim_outputs(args.out, default_name="train", force=args.force, resume=args.resume,
                       keep=["checkpoint.pt"], what="train") as out:
        try:
            m = train_run(cfg, data, out, device=args.device, resume=args.resume, progress=not args.no_progress,
                          threads=args.threads).metrics
        except BaseException:  # an interrupted or failed run keeps its new checkpoint: the old predictors no longer match it
            _remove_stale(out, args)
            raise
        _remove_stale(out, args)
    unit = m.unit()
    fit = m.fit
    seconds = fit.seconds if fit and fit.seconds is not None else float("nan")
    print(f"run folder: {out}")
    print(f"fit: {fit.stop_reason if fit else None} in {seconds:.1f} s on {m.n_train} points")
    if m.val_rmse is not None:
        print(f"validation: RMSE {m.val_rmse:.5f} {unit}, mean predictive log-likelihood {m.val_mean_log_likelihood:.3f}")
    b = m.bem_heldout
    if b is None:
        print("no model to compare with (a model-free run): see the data-only evaluation in metrics.json")
    else:
        print(f"held-out BEM vs model ({m.robot.name if m.robot else None}): RMSE {b.rmse:.5f} {unit}, max {b.max_abs:.5f} {unit}, "
              f"inside ±2σ: {100 * b.coverage_2sigma_latent:.1f}% (latent), {100 * b.coverage_2sigma_predictive:.1f}% (predictive)")  # type: ignore[operator]
    if b is not None and b.coverage_2sigma_band is not None and b.bound_violation is not None:
        v = b.bound_violation
        print(f"calibrated band (exported std): inside ±2σ {100 * b.coverage_2sigma_band:.1f}%, median σ / RMSE "
              f"{b.median_band_std_over_rmse:.2f}; eq. (13)/(15) bound at κ = 2 violated {100 * v.observed:.1f}% "  # type: ignore[operator]
              f"(nominal {100 * v.nominal:.1f}%)")  # type: ignore[operator]
    return 0


def _remove_stale(out: Path, args) -> None:
    """``--force`` / ``--resume``: remove the predictors exported from the checkpoint this run replaced."""
    from bemlearn.export.staleness import remove_stale_predictors

    if (args.force or args.resume) and (out / "checkpoint.pt").is_file():
        for p in remove_stale_predictors(out):
            print(f"removed {p}: exported from the previous checkpoint (re-export with `bemlearn export {out}`)")
