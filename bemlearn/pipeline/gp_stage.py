"""The train → checkpoint stage shared by every caller: fit the GP of eq. (11) and freeze it.

    q_u = f(x) + ε,  x = [q̈_a, q̇_a, q_a, q̈_u, q̇_u],  f ~ GP(0, k),  ε ~ N(0, σ_0²)      (11)

:func:`fit_bem_gp` takes the training points in physical units with their normalization,
builds and fits the configured GP (exact, sgpr, svgp) — with the configured prior mean: zero as in eq. (11), or a
least-squares plane under the kernel (``train.mean``, eq. L1–L2 of :mod:`bemlearn.fitting.linear_mean`) —,
logs the fit to TensorBoard, freezes
the posterior (:class:`~bemlearn.models.PredictorState`) and writes ``checkpoint.pt``.
The generic pipeline (:func:`bemlearn.pipeline.train.train_run`) and the applications (e.g.
the biped's torso BEM) both call it; exporting the predictor is the next shared stage,
:func:`bemlearn.export.export_run`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from bemlearn._version import __version__
from bemlearn.data.normalization import Normalization
from bemlearn.errors import ArgumentError
from bemlearn.export.checkpoint import load_checkpoint, write_checkpoint
from bemlearn.fitting import build_gp, fit_gp, hyperparameter_metrics
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.fitting.linear_mean import choose_prior_mean, least_squares_slope
from bemlearn.models import predictor_state
from bemlearn.models.kernels import LEFT_OUT_LENGTHSCALE
from bemlearn.models.predictor_state import PredictorState
from bemlearn.warnings import NumericalWarning, warn

__all__ = ["CheckpointProvenance", "GPStageResult", "fit_bem_gp"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class GPStageResult:
    """What :func:`fit_bem_gp` produced.

    Attributes:
        state: the frozen float64 posterior (eq. 12 in normalized coordinates + the normalization).
        model: the fitted GPyTorch model (eval mode), for further evaluation.
        likelihood: its fitted likelihood (eval mode).
        fit: ``loss``, ``steps``, ``seconds``, ``stop_reason`` of the fit.
        hyperparameters: :func:`~bemlearn.fitting.hyperparameter_metrics` (normalized units).
        lengthscale_physical: per input column, the lengthscale in the column's own unit (``None`` for a column left out).
        interrupted: the fit was stopped by Ctrl-C (the checkpoint holds the parameters reached).
        checkpoint: the file written.
        calibration: the summary returned by ``calibrate`` (``None`` without it).
    """

    state: PredictorState
    model: Any
    likelihood: Any
    fit: dict[str, Any]
    hyperparameters: dict[str, float]
    lengthscale_physical: dict[str, float | None]
    interrupted: bool
    checkpoint: Path
    calibration: dict | None = None


@dataclass(frozen=True)
class CheckpointProvenance:
    """What the checkpoint records about the data a GP was fitted on.

    Attributes:
        robot: the robot the data came from, as recorded by the run (``RobotRef.to_dict()``,
            or ``{"name": ..., "mjcf": None, ...}`` for a model-free run).
        joint_names: the coordinates, in the robot's order.
        unactuated_name: the unactuated coordinate (one of ``joint_names``).
        data_sha256: sha256 of the data file.
        extra: more provenance for the checkpoint's metadata (``extra``).
    """

    robot: Mapping[str, Any]
    joint_names: Sequence[str]
    unactuated_name: str
    data_sha256: str
    extra: Mapping[str, Any] = field(default_factory=dict)


def fit_bem_gp(
    x: torch.Tensor,
    y: torch.Tensor,
    out_dir: str | Path,
    *,
    normalization: Normalization,
    input_names: Sequence[str],
    units: Mapping[str, str],
    config: GPConfig,
    provenance: CheckpointProvenance,
    writer=None,
    resume: bool = False,
    progress: bool = True,
    calibrate: Callable[[PredictorState], tuple[PredictorState, dict]] | None = None,
    left_out: Sequence[str] = (),
) -> GPStageResult:
    """Fit the GP of eq. (11) on ``(x, y)`` and write ``out_dir/checkpoint.pt``.

    Args:
        x: ``(N, 3n − 1)`` float64 inputs in physical units (columns ``input_names``: q̈ in
            rad/s² or m/s², q̇ in rad/s or m/s, q in rad or m, by joint kind).
        y: ``(N,)`` float64 q_u, in its joint's unit.
        normalization: the training split's normalization (applied here).
        input_names: the columns.
        units: their units (``{column: unit}``).
        config: the GP options (kind, optimizer, device, dtype).
        provenance: the robot, coordinates and data file, recorded in the checkpoint's metadata.
        writer: a TensorBoard ``SummaryWriter`` (loss, noise, outputscale, lengthscale/<input>).
        resume: start from the hyperparameters of the checkpoint already in ``out_dir``.
        calibrate: ``calibrate(state) -> (state, summary)`` applied to the frozen posterior before it is
            written (the calibrated band of the exported std, :func:`~bemlearn.pipeline.uncertainty.calibrate_band`);
            its summary is stored in the checkpoint metadata (``extra.uncertainty``).  Skipped after Ctrl-C, so
            that the interrupted checkpoint is written within seconds (its std is then the latent one).
        left_out: input columns the map does not depend on (the position of a cyclic coordinate without a joint
            range: ``dataset.cyclic``): fitted as a constant column and frozen with ℓ_j =
            :data:`~bemlearn.models.kernels.LEFT_OUT_LENGTHSCALE`, so that μ and σ ignore them at any value (the
            predictor keeps the column; its physical lengthscale is recorded as ``None``).

    Ctrl-C during the fit keeps the parameters reached, writes the checkpoint (marked
    ``interrupted``) and returns with ``interrupted=True``; the caller decides what to do next.
    """
    out = Path(out_dir)
    names = tuple(input_names)
    dtype = config.torch_dtype
    xn, yn = normalization.normalize_x(x).to(dtype), normalization.normalize_y(y).to(dtype)
    unknown = [n for n in left_out if n not in names]
    if unknown:
        raise ArgumentError(f"left_out: {unknown} are not input columns; the columns are {list(names)}")
    left = [names.index(n) for n in left_out]
    if left:   # the map does not depend on them: a constant column, then ℓ = ∞ (LEFT_OUT_LENGTHSCALE)
        xn = xn.clone()
        xn[:, left] = 0.0
        log.info("GP inputs left out (ℓ = %g): %s", LEFT_OUT_LENGTHSCALE, ", ".join(left_out))

    def fit_to(labels: torch.Tensor, tag: str = "train"):
        """A GP of the configured kind fitted to ``labels`` (resumed from the checkpoint in ``out`` if asked)."""
        gp, likelihood = build_gp(xn, labels, config=config)
        if resume:
            _resume(gp, likelihood, out)
        summary, stopped = _fit(gp, likelihood, xn, labels, config=config, writer=writer, names=names, progress=progress, tag=tag)
        return gp, likelihood, summary, stopped

    slope: torch.Tensor | None = None
    mean_choice: dict[str, Any] | None = None
    if config.mean == "zero":
        model, lik, fit, interrupted = fit_to(yn)
        mean_choice = {"chosen": "zero", "by": "train.mean: zero"}
    else:   # eq. (L1): the plane first, the kernel on its residual
        slope = least_squares_slope(xn, yn, fixed=left)
        residual = yn - (xn.to(torch.float64) @ slope).to(dtype)
        explained = 1.0 - float(residual.var() / yn.var().clamp_min(1e-300))
        log.info("GP prior mean: a least-squares plane (eq. L1) explains %.4g %% of the label's variance", 100.0 * explained)
        model, lik, fit, interrupted = fit_to(residual)
        if config.mean == "auto" and not interrupted:
            zero_model, zero_lik, zero_fit, interrupted = fit_to(yn, "train_zero_mean")
            if not interrupted:
                mean_choice = choose_prior_mean(fit["loss"], zero_fit["loss"], n=int(yn.shape[0]),
                                                n_coefficients=int((slope != 0).sum()), explained=explained)
                log.info("GP prior mean (eq. L2): %s — −log p: plane %.1f + price %.1f vs zero mean %.1f nats",
                         mean_choice["chosen"], mean_choice["nlml_linear"], mean_choice["penalty"], mean_choice["nlml_zero"])
                if mean_choice["chosen"] == "zero":
                    slope, model, lik, fit = None, zero_model, zero_lik, zero_fit
        if mean_choice is None:   # as configured (or auto cut short by Ctrl-C)
            mean_choice = {"chosen": "linear", "by": f"train.mean: {config.mean}", "explained": explained}
    fit["prior_mean"] = mean_choice
    if left:
        kernel: Any = model.covar_module   # a gpytorch ScaleKernel: nn.Module attributes are untyped
        ls = kernel.base_kernel.lengthscale.detach().clone()
        ls[..., left] = LEFT_OUT_LENGTHSCALE
        kernel.base_kernel.lengthscale = ls
    model.eval()
    lik.eval()
    state = predictor_state(
        model, lik, x_mean=normalization.x_mean, x_std=normalization.x_std, y_mean=normalization.y_mean,
        y_std=normalization.y_std, input_names=names, n_train=int(y.shape[0]), mean_slope=slope,
    )
    if state.linear_mean and mean_choice is not None:   # eq. (L4): an exact GP freezes the generalized-least-squares plane (bemlearn.models.plane_posterior)
        mean_choice["estimate"] = state.plane_estimate
    latent_check = None if interrupted else _frozen_latent_check(state, model, lik, xn, dtype, config.device)
    calibration = None
    if calibrate is not None and not interrupted:  # Ctrl-C: write the best checkpoint at once, uncalibrated
        try:
            state, calibration = calibrate(state)
        except KeyboardInterrupt:  # Ctrl-C / SIGTERM during the calibration: the fit is done; keep it, uncalibrated
            log.warning("interrupted during the band calibration: writing the fitted checkpoint uncalibrated")
            interrupted = True
    hyp = hyperparameter_metrics(model, lik)
    phys_ls = {n: (None if n in left_out else float(state.lengthscale[j] * state.x_std[j])) for j, n in enumerate(names)}
    extra = {"interrupted": interrupted, "robot_ref": dict(provenance.robot), **dict(provenance.extra),
             "prior_mean": fit["prior_mean"],
             **({"frozen_latent_check": latent_check} if latent_check is not None else {}),
             **({"uncertainty": calibration} if calibration is not None else {})}
    path = write_checkpoint(
        out,
        read_back=not interrupted,
        model_state=_model_state(model, lik),
        predictor_state=state,
        metadata=_checkpoint_metadata(provenance, state, config=config, names=names, units=units, n_train=int(y.shape[0]),
                                      hyperparameters={**hyp, "lengthscale_physical": phys_ls}, extra=extra),
    )
    return GPStageResult(state, model, lik, fit, hyp, phys_ls, interrupted, path, calibration)


def _resume(model, lik, out: Path) -> None:
    """Load the hyperparameters of the checkpoint in ``out`` into ``model`` and ``lik``."""
    ck = load_checkpoint(out)
    model.load_state_dict(ck.model_state, strict=False)
    lik.load_state_dict({k[len("likelihood."):]: v for k, v in ck.model_state.items() if k.startswith("likelihood.")})
    log.info("resumed from %s", ck.path)


def _fit(model, lik, xn: torch.Tensor, yn: torch.Tensor, *, config: GPConfig, writer, names: tuple[str, ...],
         progress: bool, tag: str = "train") -> tuple[dict[str, Any], bool]:
    """Fit in place, logging to ``writer`` under ``tag``; returns the fit summary and whether Ctrl-C stopped it."""

    def callback(step: int, metrics: dict[str, float]) -> None:
        if writer is None:
            return
        for k, v in metrics.items():
            if k.startswith("lengthscale_"):   # the fit that is kept: lengthscale/<input>; a compared one under its tag
                name = f"lengthscale/{names[int(k.split('_')[1])]}"
                writer.add_scalar(name if tag == "train" else f"{tag}/{name}", v, step)
            else:
                writer.add_scalar(f"{tag}/{k}", v, step)

    log.info("fit: %s GP on %d points, %s", config.kind, int(yn.shape[0]), config.optimizer)
    t0 = time.perf_counter()
    try:
        result = fit_gp(model, lik, xn, yn, config=config, callback=callback, progress=progress)
    except KeyboardInterrupt:
        fit = {"stop_reason": "interrupted", "seconds": time.perf_counter() - t0}
        log.warning("interrupted: writing a checkpoint of the current hyperparameters")
        return fit, True
    return {"loss": result.loss, "steps": result.steps, "seconds": result.seconds, "stop_reason": result.stop_reason}, False


def _model_state(model, lik) -> dict[str, torch.Tensor]:
    """The fitted parameters and buffers on the CPU, the likelihood's under ``likelihood.``."""
    model_state = dict(model.state_dict())
    if not any(k.startswith("likelihood.") for k in model_state):  # likelihood not a submodule (sgpr/svgp)
        model_state.update({f"likelihood.{k}": v for k, v in lik.state_dict().items()})
    return {k: v.detach().cpu() for k, v in model_state.items() if isinstance(v, torch.Tensor)}


def _checkpoint_metadata(provenance: CheckpointProvenance, state: PredictorState, *, config: GPConfig, names: tuple[str, ...],
                         units: Mapping[str, str], n_train: int, hyperparameters: dict, extra: dict) -> dict[str, Any]:
    """The checkpoint's metadata (:class:`~bemlearn.export.metadata.PredictorMetadata` fields)."""
    joint_names = list(provenance.joint_names)
    actuated = [j for j in joint_names if j != provenance.unactuated_name]
    return {
        "robot": str(provenance.robot.get("name") or "robot"),
        "joint_names": joint_names,
        "actuated_names": actuated,
        "unactuated_name": provenance.unactuated_name,
        "m": len(actuated),
        "input_names": list(names),
        "units": {n: units[n] for n in names},
        "n_train": n_train,
        "n_inducing": int(state.n_support) if state.sparse else None,
        "hyperparameters": hyperparameters,
        "bemlearn_version": __version__,
        "data_sha256": provenance.data_sha256,
        "extra": extra,
    }


def _frozen_latent_check(state: PredictorState, model, lik, xn: torch.Tensor, dtype, device) -> dict | None:
    """For a sparse kind, the frozen latent std (σ_f² − vᵀ C v, v = L⁻¹k, when S is frozen factored as
    L⁻ᵀ C L⁻¹; else σ_f² − kᵀ S k with the explicit S) against the fitted model's own latent std at up to
    256 training inputs with q̈_u = q̇_u = 0.  With an ill-conditioned K_ZZ the explicit form loses its
    digits (e.g. a near-linear BEM with a large outputscale); the factored one agrees to rounding.  The check warns when they differ by more than 2×.
    ``None`` for an exact GP (its frozen variance is solved with the Cholesky factor, as exported)."""
    from bemlearn.models.predict import predict

    if not state.sparse:
        return None
    g = torch.Generator().manual_seed(0)
    q = xn[torch.randperm(xn.shape[0], generator=g)[:256]].clone()
    q[:, -2:] = (0.0 - state.x_mean[-2:].to(q)) / state.x_std[-2:].to(q)      # x_0^e: q̈_u = q̇_u = 0 (eq. 14)
    _, var = predict(model, lik, q.to(device=device, dtype=dtype))
    live = state.y_std * var.detach().cpu().to(torch.float64).clamp_min(0.0).sqrt()
    phys = q.to(torch.float64) * state.x_std + state.x_mean
    frozen = state.predict_reference(phys)[1]
    ratio = float((frozen / live.clamp_min(1e-300)).median())
    out = {"median_frozen_latent_std": float(frozen.median()), "median_model_latent_std": float(live.median()),
           "median_ratio": ratio, "n_queries": int(q.shape[0])}
    if not 0.5 <= ratio <= 2.0:
        warn(NumericalWarning, log, "the frozen %s posterior's latent std (median %.3g) differs from the fitted model's (median %.3g) by a "
                                    "factor %.3g at BEM queries: its explicit variance matrix S has lost its digits (ill-conditioned K_ZZ). "
                                    "The exported latent std is off by about that factor, and the band with it; an exact GP (kind: exact) "
                                    "solves with the Cholesky factor and does not lose them (docs/uncertainty.md).", state.kind, float(frozen.median()), float(live.median()), ratio)
    return out
