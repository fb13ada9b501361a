"""Learned BEM vs model-based BEM on held-out composite-sinusoid trajectories (eq. 9 vs 14).

For each test reference q_a^d(t) the learned BEM is μ(x_0^e), x_0^e = [q̈_a^d, q̇_a^d, q_a^d, 0, 0]
(eq. 14), compared with the model-based root q_u^e of Γ_0 (eq. 9) of the true robot.
Calibration is the fraction of model-based values inside μ ± 2σ, reported for the latent
posterior std (eq. 12) and for the predictive std (latent + noise σ_0², eq. 11).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from bemlearn._lazy import lazy_module
from bemlearn.errors import CheckpointError, ConfigError
from bemlearn.robots.protocol import BalanceRobot
from bemlearn.robots.reference import CompositeSinusoid

if TYPE_CHECKING:  # bemlearn.models loads GPyTorch: not needed to read an EvaluationConfig
    import torch

    from bemlearn.models.predictor_state import PredictorState
else:
    torch = lazy_module("torch")

__all__ = ["EvaluationConfig", "held_out_references", "reference_queries", "evaluate_bem", "run_truth_robot", "BEMEvaluation",
           "BEMCurves", "ReferenceErrors", "DesignRegionErrors", "BoundViolation"]


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
        slope_signs: model-free runs: the sign (+1 or −1) your joints' conventions give the learned BEM's
            mean slope ∂μ/∂x_i, by input name (``{qdd_theta: -1}``: the pendulum leans into the arm's
            acceleration, docs/log-import.md); the report says when a slope the data resolve has the other
            sign (a flipped ``sign:`` in the import map). Empty: not checked.
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
    slope_signs: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        bad = {k: v for k, v in self.slope_signs.items() if v not in (1, -1)}
        if bad:
            raise ConfigError(f"evaluate.slope_signs: expected +1 or -1 per input name, got {bad}")


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


def reference_queries(robot: BalanceRobot, config: EvaluationConfig) -> tuple[torch.Tensor, np.ndarray]:
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


@dataclass(frozen=True)
class ReferenceErrors:
    """Learned minus model-based BEM along one held-out reference, in q_u's unit (rad or m).

    Attributes:
        rmse: root-mean-square error.
        max_abs: largest |error|.
    """

    rmse: float
    max_abs: float

    def as_dict(self) -> dict[str, float]:
        return {"rmse": self.rmse, "max_abs": self.max_abs}


@dataclass(frozen=True)
class DesignRegionErrors:
    """The errors at the points whose model BEM lies within ``bound`` of the nominal q_u.

    Attributes:
        bound: the design region's half width d, in q_u's unit.
        n_points: the points inside.
        rmse: RMSE over them, in q_u's unit (NaN without points).
        max_abs: largest |error| over them, in q_u's unit (NaN without points).
    """

    bound: float
    n_points: int
    rmse: float
    max_abs: float

    def as_dict(self) -> dict[str, float | int]:
        return {"bound": self.bound, "n_points": self.n_points, "rmse": self.rmse, "max_abs": self.max_abs}


@dataclass(frozen=True)
class BoundViolation:
    """How often the eq. (13)/(15) bound |error| ≤ κ σ_band fails.

    Attributes:
        kappa: κ (2).
        observed: fraction of points outside ±κ σ_band.
        nominal: the Gaussian rate 1 − erf(κ/√2) (0.0455 for κ = 2).
    """

    kappa: float
    observed: float
    nominal: float

    def as_dict(self) -> dict[str, float]:
        return {"kappa": self.kappa, "observed": self.observed, "nominal": self.nominal}


@dataclass(frozen=True, eq=False)
class BEMCurves:
    """The first reference's signals for plotting, each ``(T,)`` over ``t`` (s); q_u values in its unit.

    Attributes:
        t: sample times, s.
        model: model-based BEM (eq. 9), NaN where it has no root.
        mean: learned BEM μ(x_0^e) (eq. 14).
        std: latent posterior std (eq. 12).
        band_std: calibrated band σ_band (eq. B1, the exported ``std``).
    """

    t: np.ndarray
    model: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    band_std: np.ndarray


@dataclass(frozen=True, eq=False)
class BEMEvaluation:
    """What :func:`evaluate_bem` measured: learned vs model-based BEM along held-out references.

    Errors are learned minus model BEM in q_u's unit (rad or m); coverages are fractions in [0, 1].

    Attributes:
        rmse: RMSE over all points.
        max_abs: largest |error| over all points.
        coverage_2sigma_latent: fraction of points with |error| ≤ 2σ, σ the latent std (eq. 12).
        coverage_2sigma_predictive: the same with the predictive std √(σ² + σ_0²) (eq. 11).
        coverage_2sigma_band: the same with the calibrated band σ_band (:mod:`bemlearn.models.band`).
        median_band_std_over_rmse: median σ_band / RMSE (``inf`` when the RMSE is 0).
        bound_violation: the eq. (13)/(15) bound at κ = 2, observed and nominal violation rates.
        reliability: ``{"band": rows, "latent": rows}``, coverage vs nominal level 50–99 %
            (:func:`~bemlearn.pipeline.reliability.reliability_table`).
        design_region: the errors over the points whose model BEM is within the design bound.
        n_points: points evaluated (those with a model root).
        no_model_root: points left out because the model has no BEM there.
        per_reference: RMSE and max error per reference.
        curves: the first reference's signals, for plots (not serialized).
    """

    rmse: float
    max_abs: float
    coverage_2sigma_latent: float
    coverage_2sigma_predictive: float
    coverage_2sigma_band: float
    median_band_std_over_rmse: float
    bound_violation: BoundViolation
    reliability: dict[str, list[dict[str, float]]]
    design_region: DesignRegionErrors
    n_points: int
    no_model_root: int
    per_reference: tuple[ReferenceErrors, ...]
    curves: BEMCurves

    def as_dict(self) -> dict[str, Any]:
        """The JSON-ready summary (``metrics.json`` → ``bem_heldout``, ``evaluation.json``), without ``curves``."""
        return {
            "design_region": self.design_region.as_dict(),
            "coverage_2sigma_band": self.coverage_2sigma_band,
            "median_band_std_over_rmse": self.median_band_std_over_rmse,
            "bound_violation": self.bound_violation.as_dict(),
            "reliability": {k: [dict(row) for row in rows] for k, rows in self.reliability.items()},
            "rmse": self.rmse,
            "max_abs": self.max_abs,
            "coverage_2sigma_latent": self.coverage_2sigma_latent,
            "coverage_2sigma_predictive": self.coverage_2sigma_predictive,
            "n_points": self.n_points,
            "no_model_root": self.no_model_root,
            "per_reference": [r.as_dict() for r in self.per_reference],
        }


@dataclass(frozen=True, eq=False)
class _ReferencePoints:
    """One reference's points with a model root: errors, latent and band std, inside the design region."""

    error: np.ndarray
    latent_std: np.ndarray
    band_std: np.ndarray
    inside: np.ndarray
    no_model_root: int
    curves: BEMCurves


def _reference_points(state: PredictorState, robot: BalanceRobot, ref: CompositeSinusoid, t: np.ndarray,
                      design_bound: float) -> _ReferencePoints:
    """Learned (eq. 14) vs model (eq. 9) BEM along ``ref`` at times ``t``."""
    from bemlearn.models.band import band_reference  # GPyTorch: loaded when a BEM is evaluated

    qa, qad, qadd = ref.evaluate(t)
    bem = robot.bem(qa, qad, qadd)
    ok = bem.valid.numpy()
    x = np.concatenate([qadd, qad, qa, np.zeros((t.size, 2))], axis=1)
    mean, band, std = (v.numpy() for v in band_reference(state, torch.from_numpy(x), n_inputs=state.dim - 2))
    model = bem.qu.numpy()
    return _ReferencePoints(error=(mean - model)[ok], latent_std=std[ok], band_std=band[ok],
                            inside=np.abs(model[ok] - robot.qu_nominal) <= design_bound, no_model_root=int((~ok).sum()),
                            curves=BEMCurves(t=t, model=model, mean=mean, std=std, band_std=band))


def _design_region_errors(e: np.ndarray, bound: float) -> DesignRegionErrors:
    return DesignRegionErrors(bound=float(bound), n_points=int(e.size),
                              rmse=float(np.sqrt(np.mean(e**2))) if e.size else float("nan"),
                              max_abs=float(np.abs(e).max()) if e.size else float("nan"))


def evaluate_bem(state: PredictorState, robot: BalanceRobot, references: list[CompositeSinusoid], *, duration_s: float = 20.0,
                 rate_hz: float = 100.0, design_bound: float | None = None) -> BEMEvaluation:
    """RMSE, max error and calibration of the learned BEM along ``references`` (module docstring).

    Each reference is sampled at ``rate_hz`` for ``duration_s``; points where the model has no BEM
    are left out (counted in ``no_model_root``).  ``design_bound``: the half width of the design
    region in q_u's unit (default: :func:`~bemlearn.pipeline.derive.design_region`, the region the
    derived excitation is designed to cover).

    Returns:
        a :class:`BEMEvaluation`; :meth:`BEMEvaluation.as_dict` is what ``metrics.json`` records.
    """
    from bemlearn.pipeline.reliability import reliability_table  # SciPy: not needed to read an EvaluationConfig

    if design_bound is None:
        from bemlearn.pipeline.derive import design_region

        design_bound = design_region(robot).value
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    noise_std = float(state.y_std * state.noise.sqrt())
    points = [_reference_points(state, robot, ref, t, design_bound) for ref in references]
    e = np.concatenate([p.error for p in points])
    lat_all = np.concatenate([p.latent_std for p in points])
    band_all = np.concatenate([p.band_std for p in points])
    within_latent = np.abs(e) <= 2 * lat_all
    within_predictive = np.abs(e) <= 2 * np.sqrt(lat_all**2 + noise_std**2)
    rmse = float(np.sqrt(np.mean(e**2)))
    return BEMEvaluation(
        rmse=rmse,
        max_abs=float(np.abs(e).max()),
        coverage_2sigma_latent=float(np.mean(within_latent)),
        coverage_2sigma_predictive=float(np.mean(within_predictive)),
        coverage_2sigma_band=float(np.mean(np.abs(e) <= 2 * band_all)),
        median_band_std_over_rmse=float(np.median(band_all)) / rmse if rmse > 0 else math.inf,
        bound_violation=BoundViolation(kappa=2.0, observed=float(np.mean(np.abs(e) > 2 * band_all)),
                                       nominal=1.0 - math.erf(2.0 / math.sqrt(2.0))),
        reliability={"band": reliability_table(e, band_all), "latent": reliability_table(e, lat_all)},
        design_region=_design_region_errors(e[np.concatenate([p.inside for p in points])], design_bound),
        n_points=int(e.size),
        no_model_root=sum(p.no_model_root for p in points),
        per_reference=tuple(ReferenceErrors(rmse=float(np.sqrt(np.mean(p.error**2))), max_abs=float(np.abs(p.error).max()))
                            for p in points),
        curves=points[0].curves,
    )
