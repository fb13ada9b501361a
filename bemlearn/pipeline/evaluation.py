"""Learned BEM vs model-based BEM on held-out composite-sinusoid trajectories (eq. 9 vs 14).

For each test reference q_a^d(t) the learned BEM is μ(x_0^e), x_0^e = [q̈_a^d, q̇_a^d, q_a^d, 0, 0]
(eq. 14), compared with the model-based root q_u^e of Γ_0 (eq. 9) of the true robot.
Calibration is the fraction of model-based values inside μ ± 2σ, reported for the latent
posterior std (eq. 12) and for the predictive std (latent + noise σ_0², eq. 11).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from bemlearn.errors import CheckpointError, ConfigError
from bemlearn.models.band import band_reference
from bemlearn.models.predictor_state import PredictorState
from bemlearn.pipeline.reliability import reliability_table
from bemlearn.robots.reference import CompositeSinusoid

__all__ = ["EvaluationConfig", "held_out_references", "reference_queries", "evaluate_bem", "run_truth_robot"]


@dataclass(frozen=True)
class EvaluationConfig:
    """Held-out test trajectories (``evaluate:`` section).

    Attributes:
        n_references: number of random composite sinusoids.
        n_sines: (min, max) components per reference (``null``: derived from the model).
        amplitude_max: max |q_a^d| bound: Σ|A_k| ≤ this, in q_a's unit (``null``: derived, inside what the
            excitation collected).
        amplitude_min: Σ|A_k| ≥ this, in q_a's unit (``null``: derived).
        frequency_hz: (min, max) component frequency, Hz (``null``: derived).
        duration_s: evaluated time per reference, s.
        rate_hz: evaluation grid, Hz.
        seed: seed of the references and of the design-region points (independent of training data).
        design_points: points drawn in the design region's box of actuated motions (learned vs model BEM
            over the whole design region, :mod:`bemlearn.pipeline.design_evaluation`); 0 turns it off.
    """

    n_references: int = 5
    n_sines: tuple[int, int] | None = None
    amplitude_max: float | None = None
    amplitude_min: float | None = None
    frequency_hz: tuple[float, float] | None = None
    duration_s: float = 20.0
    rate_hz: float = 100.0
    seed: int = 12345
    design_points: int = 4096


def held_out_references(config: EvaluationConfig, m: int) -> list[CompositeSinusoid]:
    """Random composite sinusoids within the configured amplitude and frequency ranges."""
    unset = [n for n in ("n_sines", "amplitude_max", "amplitude_min", "frequency_hz") if getattr(config, n) is None]
    if unset:
        raise ConfigError(f"evaluate: {unset} not set; derive them from the model with "
                         "bemlearn.pipeline.complete_section(robot, 'evaluate', config) or give them")
    assert config.n_sines is not None and config.frequency_hz is not None  # checked just above
    assert config.amplitude_min is not None and config.amplitude_max is not None
    rng = np.random.default_rng(config.seed)
    refs = []
    for _ in range(config.n_references):
        rows = []
        k = int(rng.integers(config.n_sines[0], config.n_sines[1] + 1))  # one count per reference: rows of equal length
        for j in range(m):
            if j:
                rng.integers(config.n_sines[0], config.n_sines[1] + 1)  # keeps the m = 1 draws as they were
            A = rng.uniform(0.05, 1.0, k)
            A = A / A.sum() * rng.uniform(config.amplitude_min, config.amplitude_max)
            rows.append((tuple(A), tuple(rng.uniform(*config.frequency_hz, k)), tuple(rng.uniform(0, 2 * math.pi, k))))
        refs.append(CompositeSinusoid(tuple(r[0] for r in rows), tuple(r[1] for r in rows), tuple(r[2] for r in rows), (0.0,) * m))
    return refs


def reference_queries(robot, config: EvaluationConfig) -> tuple[torch.Tensor, np.ndarray]:
    """The BEM queries x_0^e = [q̈_a, q̇_a, q_a, 0, 0] (eq. 14) along the held-out references of
    ``config``, sampled at ``config.rate_hz`` for ``config.duration_s``, and ``robot``'s model-based
    BEM there (eq. 9): ``(N, 3m + 2)`` physical inputs and ``(N,)`` q_u in its joint's unit, the
    points without a model root left out."""
    t = np.arange(0.0, config.duration_s, 1.0 / config.rate_hz)
    xs, qs = [], []
    for ref in held_out_references(config, robot.m):
        qa, qad, qadd = ref.evaluate(t)
        bem = robot.bem(qa, qad, qadd)
        ok = bem.valid.numpy()
        xs.append(np.concatenate([qadd, qad, qa, np.zeros((t.size, 2))], axis=1)[ok])
        qs.append(bem.qu.numpy()[ok])
    return torch.from_numpy(np.concatenate(xs)), np.concatenate(qs)


def run_truth_robot(run_dir, *, model=None):
    """The robot whose model-based BEM (eq. 9) is a run's ground truth, read from the run, never guessed.

    The run's checkpoint records the robot as a :class:`~bemlearn.robots.RobotRef` (MJCF path and
    sha256); the file must still hold the same model.  ``model`` (a registry name or MJCF path)
    compares a model-free run with a model.  Returns ``(robot, ref_dict)``.

    Raises:
        ValueError: the run records no robot (a model-free run without ``model``), or the MJCF changed.
    """
    from bemlearn.export.checkpoint import load_checkpoint
    from bemlearn.robots import RobotRef, resolve_robot

    ck = load_checkpoint(run_dir)
    if model is not None:
        robot, ref = resolve_robot(model)
        return robot, ref.to_dict()
    rec = ck.metadata.extra.get("robot_ref")
    if rec is None:
        raise CheckpointError(f"{ck.path}: the run records no robot (made by bemlearn < 0.2); pass the model to compare "
                         "with explicitly (--model NAME|PATH)")
    ref = RobotRef.from_dict(rec, where=f"{ck.path}: robot_ref")
    if ref.mjcf is None and ref.registry is None:
        raise CheckpointError(f"{ck.path}: a model-free run (trained on data alone); there is no model to compare with "
                         "unless you give one (--model NAME|PATH)")
    return ref.load(), ref.to_dict()


def evaluate_bem(state: PredictorState, robot, references: list[CompositeSinusoid], *, duration_s: float = 20.0, rate_hz: float = 100.0,
                 design_bound: float | None = None) -> dict:
    """RMSE, max error and calibration of the learned BEM along ``references``.

    Returns:
        a dict with ``rmse``, ``max_abs``, ``coverage_2sigma_latent``,
        ``coverage_2sigma_predictive`` (fractions), ``n_points``, ``no_model_root``
        (points where the model has no BEM, excluded), and ``per_reference`` lists; plus
        ``curves`` (t, model, mean, std of the first reference) for plotting.  For the
        calibrated band σ_band of :mod:`bemlearn.models.band` (the exported ``std``):
        ``coverage_2sigma_band``, ``median_band_std_over_rmse``, ``bound_violation`` (the
        eq. 13/15 bound at κ = 2: observed and nominal violation rates) and ``reliability``
        (coverage vs nominal level, 50–99 %, band and latent); ``curves`` gains ``band_std``.
        ``design_region``: RMSE and max error over the points whose model BEM lies within
        ``design_bound`` of the nominal q_u (default: :func:`~bemlearn.pipeline.derive.design_region`,
        the region the derived excitation is designed to cover), with their count.
    """
    if design_bound is None:
        from bemlearn.pipeline.derive import design_region

        design_bound = design_region(robot).value
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    errs, lat, pred, per, inside = [], [], [], [], []
    bands, lats = [], []
    curves = None
    noise_std = float(state.y_std * state.noise.sqrt())
    skipped = 0
    for i, ref in enumerate(references):
        qa, qad, qadd = ref.evaluate(t)
        bem = robot.bem(qa, qad, qadd)
        ok = bem.valid.numpy()
        skipped += int((~ok).sum())
        x = np.concatenate([qadd, qad, qa, np.zeros((t.size, 2))], axis=1)
        mean, band, std = (v.numpy() for v in band_reference(state, torch.from_numpy(x), n_inputs=state.dim - 2))
        bands.append(band[ok])
        lats.append(std[ok])
        e = (mean - bem.qu.numpy())[ok]
        inside.append(np.abs(bem.qu.numpy()[ok] - robot.qu_nominal) <= design_bound)
        s = std[ok]
        errs.append(e)
        lat.append(np.abs(e) <= 2 * s)
        pred.append(np.abs(e) <= 2 * np.sqrt(s**2 + noise_std**2))
        per.append({"rmse": float(np.sqrt(np.mean(e**2))), "max_abs": float(np.abs(e).max())})
        if i == 0:
            curves = {"t": t, "model": bem.qu.numpy(), "mean": mean, "std": std, "band_std": band}
    e = np.concatenate(errs)
    band_all, lat_all = np.concatenate(bands), np.concatenate(lats)
    rmse = float(np.sqrt(np.mean(e**2)))
    ein = e[np.concatenate(inside)]
    extra = {
        "design_region": {"bound": float(design_bound), "n_points": int(ein.size),
                          "rmse": float(np.sqrt(np.mean(ein**2))) if ein.size else float("nan"),
                          "max_abs": float(np.abs(ein).max()) if ein.size else float("nan")},
        "coverage_2sigma_band": float(np.mean(np.abs(e) <= 2 * band_all)),
        "median_band_std_over_rmse": float(np.median(band_all)) / rmse if rmse > 0 else math.inf,
        "bound_violation": {"kappa": 2.0, "observed": float(np.mean(np.abs(e) > 2 * band_all)),
                            "nominal": 1.0 - math.erf(2.0 / math.sqrt(2.0))},
        "reliability": {"band": reliability_table(e, band_all), "latent": reliability_table(e, lat_all)},
    }
    return extra | {
        "rmse": float(np.sqrt(np.mean(e**2))),
        "max_abs": float(np.abs(e).max()),
        "coverage_2sigma_latent": float(np.mean(np.concatenate(lat))),
        "coverage_2sigma_predictive": float(np.mean(np.concatenate(pred))),
        "n_points": int(e.size),
        "no_model_root": skipped,
        "per_reference": per,
        "curves": curves,
    }
