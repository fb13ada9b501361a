"""The learned BEM against the model-based BEM (eq. 14 vs eq. 9), as a run with a model evaluates it.

Along held-out composite-sinusoid references (:func:`~bemlearn.pipeline.evaluation.evaluate_bem`) and over the
design region (:func:`~bemlearn.pipeline.design_evaluation.evaluate_design_region`); writes ``reliability.png``,
``bem_validation.png`` and ``design_region.png`` into the run folder and the scalars to TensorBoard.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from bemlearn.files import atomic_path
from bemlearn.pipeline.evaluation import BEMCurves, EvaluationConfig, evaluate_bem, held_out_references
from bemlearn.pipeline.reliability import reliability_figure

if TYPE_CHECKING:
    from bemlearn.models.predictor_state import PredictorState
    from bemlearn.robots.protocol import ControlRobot

__all__ = ["compare_with_model", "bem_figure"]


def compare_with_model(state: PredictorState, truth_robot: ControlRobot, ecfg: EvaluationConfig, unactuated: str, unit: str,
                   out: Path, writer, *, excursion: tuple[float, ...] | None = None) -> dict:
    """Learned vs model-based BEM along held-out references and over the design region (writes
    ``reliability.png``, ``bem_validation.png``, ``design_region.png``); ``excursion``: the data's collection extents,
    which the design region's box then covers (:func:`~bemlearn.pipeline.design_evaluation.design_grid`)."""
    ev = evaluate_bem(state, truth_robot, held_out_references(ecfg, truth_robot.m), duration_s=ecfg.duration_s, rate_hz=ecfg.rate_hz)
    metrics: dict = {"bem_heldout": ev.as_dict()}
    for k in ("rmse", "max_abs", "coverage_2sigma_latent", "coverage_2sigma_predictive", "coverage_2sigma_band"):
        writer.add_scalar(f"bem/{k}", getattr(ev, k), 0)
    writer.add_figure("bem/reliability", reliability_figure(ev.reliability), 0)
    with atomic_path(out / "reliability.png") as tmp:
        reliability_figure(ev.reliability).savefig(tmp, dpi=110)
    fig = bem_figure(ev.curves, unactuated, unit)
    writer.add_figure("bem/learned_vs_model", fig, 0)
    with atomic_path(out / "bem_validation.png") as tmp:
        fig.savefig(tmp, dpi=110)
    if ecfg.design_points > 0:   # over the whole design region (D1, D2), not only along the references
        from bemlearn.pipeline.design_evaluation import design_grid, design_region_figure, evaluate_design_region

        dr = evaluate_design_region(state, design_grid(truth_robot, ecfg, n_points=ecfg.design_points, seed=ecfg.seed, excursion=excursion),
                                    truth_robot)
        metrics["bem_design_region"] = dr.as_dict()
        for k in ("rmse", "max_abs", "gain"):
            writer.add_scalar(f"bem/design_region_{k}", getattr(dr, k), 0)
        fig = design_region_figure(dr, unactuated, unit)
        writer.add_figure("bem/design_region", fig, 0)
        with atomic_path(out / "design_region.png") as tmp:
            fig.savefig(tmp, dpi=110)
    return metrics


def bem_figure(curves: BEMCurves, qu_name: str, unit: str = "rad"):
    """The learned BEM with its ±2σ band against the model's along one held-out reference, and their difference."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, model, mean, std = curves.t, curves.model, curves.mean, curves.band_std
    fig, ax = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    ax[0].plot(t, model, "k", lw=1.2, label="model-based BEM (eq. 9)")
    ax[0].plot(t, mean, "C1--", lw=1.2, label="learned BEM μ(x₀ᵉ) (eq. 14)")
    ax[0].fill_between(t, mean - 2 * std, mean + 2 * std, color="C1", alpha=0.25, label="±2σ (calibrated band, eq. B1)")
    ax[0].set_ylabel(f"{qu_name} ({unit})")
    ax[0].legend(fontsize=8)
    ax[0].set_title("held-out composite-sinusoid reference")
    ax[1].plot(t, mean - model, "C3", lw=1)
    ax[1].fill_between(t, -2 * std, 2 * std, color="C1", alpha=0.2)
    ax[1].set_ylabel(f"error ({unit})")
    ax[1].set_xlabel("t (s)")
    fig.tight_layout()
    return fig
