"""``bemlearn evaluate RUN_DIR``: learned vs model-based BEM on held-out composite sinusoids."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "evaluate",
        help="compare a trained run's learned BEM with the model-based BEM on held-out references",
        description="Evaluate μ(x₀ᵉ) (eq. 14) against the model-based BEM (eq. 9) of the true robot on random "
        "composite-sinusoid q_a^d(t): RMSE, max error, fraction inside ±2σ; writes RUN_DIR/evaluation.json and plots.",
    )
    p.add_argument("run_dir", type=Path)
    p.add_argument("--references", type=int, default=5, help="number of held-out references (default 5)")
    p.add_argument("--seed", type=int, default=12345, help="seed of the references")
    p.add_argument("--force", action="store_true", help="replace RUN_DIR/evaluation.{json,png} if they exist")
    p.set_defaults(func=run)


def run(args) -> int:
    import dataclasses

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bemlearn.export.checkpoint import load_checkpoint
    from bemlearn.pipeline.evaluation import EvaluationConfig, evaluate_bem, ground_truth_robot, held_out_references

    from bemlearn.export.staleness import check_run_predictors
    from bemlearn.files import atomic_path, atomic_write_text, check_outputs

    ck = load_checkpoint(args.run_dir)
    check_run_predictors(ck.path.parent)
    check_outputs([ck.path.parent / "evaluation.json", ck.path.parent / "evaluation.png"], args.force, what="evaluate")
    robot = ground_truth_robot(ck.metadata.robot)
    ecfg = dataclasses.replace(EvaluationConfig(), n_references=args.references, seed=args.seed)
    refs = held_out_references(ecfg, robot.m)
    ev = evaluate_bem(ck.predictor_state, robot, refs, duration_s=ecfg.duration_s, rate_hz=ecfg.rate_hz)
    c = ev.pop("curves")
    out = args.run_dir if args.run_dir.is_dir() else args.run_dir.parent
    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.plot(c["t"], c["model"], "k", lw=1.2, label="model-based BEM (eq. 9)")
    ax.plot(c["t"], c["mean"], "C1--", lw=1.2, label="learned BEM (eq. 14)")
    ax.fill_between(c["t"], c["mean"] - 2 * c["std"], c["mean"] + 2 * c["std"], color="C1", alpha=0.25, label="±2σ (latent)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel(f"{ck.metadata.unactuated_name} (rad)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(out / "evaluation.png") as tmp:
        fig.savefig(tmp, dpi=110)
    atomic_write_text(out / "evaluation.json", json.dumps(ev, indent=2))
    print(f"{'reference':<10}{'RMSE (rad)':>12}{'max (rad)':>12}")
    for i, r in enumerate(ev["per_reference"]):
        print(f"{i:<10}{r['rmse']:>12.5f}{r['max_abs']:>12.5f}")
    print(f"{'all':<10}{ev['rmse']:>12.5f}{ev['max_abs']:>12.5f}")
    print(f"inside ±2σ: {100 * ev['coverage_2sigma_latent']:.1f}% with the latent std, "
          f"{100 * ev['coverage_2sigma_predictive']:.1f}% with the predictive std (eq. 12 as printed: k* includes σ_0²)")
    print(f"wrote {out / 'evaluation.json'} and {out / 'evaluation.png'}")
    return 0
