"""``bemlearn bench band RUN…``: the calibrated band's terms on trained runs (eq. B1).

For each run folder (a ``bemlearn run`` or ``bemlearn train`` output with a model to compare
with), the learned BEM μ(x_0^e) is evaluated on the run's own held-out references (its
``evaluate`` config) against the model-based BEM (eq. 9), and the band is scored term by term:

* ``latent``: σ̃ of eq. (12) (the exported ``forward_latent``);
* ``c·latent``: the replica-calibrated latent std alone;
* ``c·latent + input noise``: with the quantization term σ_in of eq. (N1) only;
* ``c·latent + estimator``: with the estimator term σ_est of eq. (E2) only;
* ``sum of both``: c² σ̃² + σ_in² + σ_est² (not used: the two model one error);
* ``exported band``: c² σ̃² + max(σ_in², σ_est²), eq. (B1), what ``forward`` returns.

Each row: fraction of model-BEM values inside μ ± 2σ and the median σ over the RMSE of μ.
Nothing is refitted; a run costs its references' model BEM (seconds).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from bemlearn.errors import ArgumentError

__all__ = ["format_band_bench", "run_band_bench"]


def _terms(state, x: torch.Tensor) -> dict[str, np.ndarray]:
    """Variances (rad²) of every row of the module docstring at physical BEM queries ``x (B, d)``."""
    from bemlearn.models.band import band_extra_variance

    n = state.dim - 2
    lat2 = state.predict_reference(x)[1].square().numpy()
    c2 = float(state.std_scale) ** 2
    q2 = band_extra_variance(dataclasses.replace(state, estimator_delta=None), x, n_inputs=n).numpy()
    e2 = band_extra_variance(dataclasses.replace(state, input_std=None), x, n_inputs=n).numpy()
    return {"latent": lat2, "c·latent": c2 * lat2, "c·latent + input noise": c2 * lat2 + q2,
            "c·latent + estimator": c2 * lat2 + e2, "sum of both": c2 * lat2 + q2 + e2,
            "exported band (eq. B1)": c2 * lat2 + np.maximum(q2, e2)}


def run_band_bench(runs: list[str | Path], *, progress=print) -> list[dict]:
    """Score the band's terms on each run (module docstring); one dict per run."""
    from bemlearn.export.checkpoint import load_checkpoint
    from bemlearn.pipeline.evaluation import reference_queries, run_truth_robot
    from bemlearn.pipeline.resolve import load_pipeline_config

    out = []
    for run in runs:
        run = Path(run)
        if not (run / "config.yaml").is_file():
            raise ArgumentError(f"{run}: not a run folder (no config.yaml; expected the output of `bemlearn run` or `bemlearn train`)")
        state = load_checkpoint(run).predictor_state
        assert state.std_scale is not None  # filled by PredictorState.__post_init__
        cfg = load_pipeline_config(run / "config.yaml")
        robot, _ = run_truth_robot(run)
        x, qu = reference_queries(robot, cfg.evaluate)
        err = state.predict_reference(x)[0].numpy() - qu
        rmse = float(np.sqrt(np.mean(err**2)))
        rows = {name: {"inside_2sigma": float(np.mean(np.abs(err) <= 2 * np.sqrt(v))),
                       "median_std_over_rmse": float(np.median(np.sqrt(v))) / rmse}
                for name, v in _terms(state, x).items()}
        out.append({"run": str(run), "robot": robot.name, "rmse": rmse, "n_points": int(err.size), "c": float(state.std_scale),
                    "n_estimators": state.n_estimators, "rows": rows})
        progress(f"{run}: {robot.name}, BEM RMSE {rmse:.5f} over {err.size} points")
    return out


def format_band_bench(results: list[dict]) -> str:
    """One Markdown table: a row per run, ``inside ±2σ / median σ ÷ RMSE`` per band."""
    if not results:
        return ""
    names = list(results[0]["rows"])
    lines = ["| run | BEM RMSE | c | K | " + " | ".join(names) + " |", "| --- | --- | --- | --- | " + " | ".join("---" for _ in names) + " |"]
    for r in results:
        cells = [f"{100 * r['rows'][n]['inside_2sigma']:.1f}% / {r['rows'][n]['median_std_over_rmse']:.2f}" for n in names]
        lines.append(f"| {Path(r['run']).name} ({r['robot']}) | {r['rmse']:.5f} | {r['c']:.2f} | {r['n_estimators']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
