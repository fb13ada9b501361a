"""``bemlearn evaluate RUN_DIR``: learned vs model-based BEM on held-out composite sinusoids."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "evaluate",
        help="compare a trained run's learned BEM with the model-based BEM on held-out references",
        description="Evaluate μ(x₀ᵉ) (eq. 14) against the model-based BEM (eq. 9) of the robot the run recorded "
        "(its MJCF path and sha256; a changed file is an error) on the run's held-out references (the resolved "
        "config's 'evaluate' section): RMSE, max error, fraction inside ±2σ; and over the whole design region "
        "(|q_u^e| ≤ 0.2 rad on a Sobol set of actuated motions): RMSE, max and gain; writes RUN_DIR/evaluation.json and "
        "evaluation.png.",
    )
    p.add_argument("run_dir", type=Path, help="a run folder of `bemlearn run` or `bemlearn train`")
    p.add_argument("--references", type=int, help="number of held-out references (default: the run's evaluate.n_references)")
    p.add_argument("--seed", type=int, help="seed of the references (default: the run's evaluate.seed)")
    p.add_argument("--model", help="compare with this robot instead (registry name or MJCF path), e.g. for a model-free run")
    p.add_argument("--force", action="store_true", help="replace RUN_DIR/evaluation.{json,png} if they exist")
    p.set_defaults(func=run)


def run(args) -> int:
    from bemlearn.export.checkpoint import load_checkpoint
    from bemlearn.export.staleness import check_run_predictors
    from bemlearn.files import check_outputs
    from bemlearn.outputs import claim_outputs

    ck = load_checkpoint(args.run_dir)
    check_run_predictors(ck.path.parent)
    names = ("evaluation.json", "evaluation.png")
    check_outputs([ck.path.parent / n for n in names], args.force, what="evaluate")
    with claim_outputs(ck.path.parent, entries=names, force=args.force, what="evaluate"):  # both files or neither
        return _evaluate(args, ck)


def _evaluate(args, ck) -> int:
    """The evaluation of checkpoint ``ck`` (claimed by :func:`run`) into its run folder."""
    import dataclasses

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bemlearn.config import from_dict, load_yaml
    from bemlearn.files import atomic_path, atomic_write_text
    from bemlearn.pipeline.evaluation import EvaluationConfig, evaluate_bem, held_out_references, run_truth_robot
    from bemlearn.pipeline.resolve import complete_section

    out = ck.path.parent
    robot, ref = run_truth_robot(out, model=args.model)
    cfg_path = out / "config.yaml"
    ecfg = EvaluationConfig()
    if cfg_path.is_file():
        ecfg = from_dict(EvaluationConfig, load_yaml(cfg_path).get("evaluate"), where=f"{cfg_path}:evaluate")
    ecfg = complete_section(ref["mjcf"] or ref["registry"], "evaluate", ecfg)  # derived from the model where unset
    overrides = {k: v for k, v in (("n_references", args.references), ("seed", args.seed)) if v is not None}
    ecfg = dataclasses.replace(ecfg, **overrides)
    refs = held_out_references(ecfg, robot.m)
    result = evaluate_bem(ck.predictor_state, robot, refs, duration_s=ecfg.duration_s, rate_hz=ecfg.rate_hz)
    ev = result.as_dict()
    ev["robot"] = ref
    region = None
    if ecfg.design_points > 0:
        from bemlearn.pipeline.design_evaluation import design_grid, evaluate_design_region

        excursion, why = _collected_excursion(ck)
        if why:
            print(why)
        region = evaluate_design_region(ck.predictor_state, design_grid(robot, ecfg, n_points=ecfg.design_points, seed=ecfg.seed,
                                                                        excursion=excursion), robot)
        ev["bem_design_region"] = region.as_dict()   # over the whole design region (D1, D2); ev["design_region"] is along the references
    c = result.curves
    unit = ck.metadata.units.get(f"qd_{ck.metadata.unactuated_name}", "rad/s").removesuffix("/s")
    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.plot(c.t, c.model, "k", lw=1.2, label="model-based BEM (eq. 9)")
    ax.plot(c.t, c.mean, "C1--", lw=1.2, label="learned BEM (eq. 14)")
    ax.fill_between(c.t, c.mean - 2 * c.std, c.mean + 2 * c.std, color="C1", alpha=0.25, label="±2σ (latent)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel(f"{ck.metadata.unactuated_name} ({unit})")
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(out / "evaluation.png") as tmp:
        fig.savefig(tmp, dpi=110)
    atomic_write_text(out / "evaluation.json", json.dumps(ev, indent=2))
    print(f"robot: {ref['name']} ({ref['mjcf'] or ref['registry']})")
    print(f"{'reference':<10}{f'RMSE ({unit})':>12}{f'max ({unit})':>12}")
    for i, r in enumerate(result.per_reference):
        print(f"{i:<10}{r.rmse:>12.5f}{r.max_abs:>12.5f}")
    print(f"{'all':<10}{result.rmse:>12.5f}{result.max_abs:>12.5f}")
    print(f"inside ±2σ: {100 * result.coverage_2sigma_latent:.1f}% with the latent std, "
          f"{100 * result.coverage_2sigma_predictive:.1f}% with the predictive std (eq. 12 as printed: k* includes σ_0²)")
    v = result.bound_violation
    print(f"calibrated band (exported std): inside ±2σ {100 * result.coverage_2sigma_band:.1f}%, median σ / RMSE "
          f"{result.median_band_std_over_rmse:.2f}; eq. (13)/(15) bound at κ = 2 violated {100 * v.observed:.1f}% "
          f"(nominal {100 * v.nominal:.1f}%)")
    if region is not None:
        print(f"design region |q_u^e| ≤ {region.bound:g} {unit} ({region.n_points} actuated motions): RMSE {region.rmse:.5f}, "
              f"max {region.max_abs:.5f} {unit}, gain {region.gain:.3f} (least-squares slope of learned on model)")
    print(f"wrote {out / 'evaluation.json'} and {out / 'evaluation.png'}")
    return 0


def _collected_excursion(ck) -> tuple[tuple[float, ...] | None, str]:
    """The excitation's extents the run's training data were collected with (``collect.excursion``, m ≥ 2), read from
    the data file the checkpoint names, so that the design region's box is the one the run checked
    (:func:`~bemlearn.pipeline.design_evaluation.design_grid`); ``(None, why)`` where that file is not there."""
    from bemlearn.data.trajectory_io import read_trajectory

    data = ck.metadata.extra.get("data_file")
    if not data:
        return None, ""
    path = Path(data)
    if not path.is_file():
        return None, (f"note: {path}, the run's data file, is not there: the design region's box is the held-out "
                      "references' alone, not widened to the excitation's extents as the run's own check was")
    return read_trajectory(path).meta.collected_excursion, ""
