"""The estimator term of the calibrated band: how much the BEM moves with the derivative estimator.

The GP of eq. (11) is trained on q̇, q̈ *estimated* from recorded angles.  Their error is not
white noise: a smoothing estimator cannot see the fast part of the motion (e.g. the steps of
q̈ under a zero-order-hold input), and that error is common to every trial, so neither the
latent std of eq. (12) nor a split of the trials sees it; it can be most of the learned BEM's
error (docs/uncertainty.md, "Where μ's error comes from").  It is, however, visible in the data: the estimators next
to the chosen one (:meth:`~bemlearn.data.derivatives.DerivativeEstimator.neighbours`, e.g. a
narrower and a wider Savitzky–Golay window, one degree less and one more) are equally
plausible choices, and the BEM's spread over them measures its sensitivity to the choice.

With the fitted hyperparameters and the state's own support Z (its training inputs for an
exact GP, its inducing points otherwise), the projected-process (DTC / SGPR) mean of data
(X, ỹ) has weights (normalized units)

    α(X) = (σ_0² K_ZZ + K_ZX K_XZ)⁻¹ K_ZX ỹ,        μ̃(x̃) = k_Z(x̃)ᵀ α(X)                (E1)

(Titsias, 2009; for Z = X it is the exact posterior mean K (K + σ_0² I)⁻¹ ỹ).  With X_0 the
training rows' inputs from the chosen estimator and X_k from its k-th neighbour (same rows; for an
estimator that smooths, the neighbour's smoothed q and q_u label ỹ_k too), δ_k = α(X_k, ỹ_k) −
α(X_0, ỹ_0) and the estimator variance of the BEM is

    σ_est²(x) = (1/K) Σ_k (y_std k_Z(x̃)ᵀ δ_k)²                                         (E2)

one more ``(M, K)`` product with the kernel row the mean already computes.  Both α's come from
the same routine, so the projection's own error cancels in δ_k.  No model is used.
The band with and without (E2) on trained runs: docs/uncertainty.md.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np
import torch

from bemlearn.data.derivatives import DerivativeEstimator
from bemlearn.data.trajectory import Trajectory
from bemlearn.errors import ArgumentError
from bemlearn.models.kernels import se_kernel
from bemlearn.models.predictor_state import PredictorState

__all__ = ["EstimatorSensitivity", "estimator_sensitivity", "projected_weights"]

log = logging.getLogger(__name__)


def _cross(state: PredictorState, xn: torch.Tensor) -> torch.Tensor:
    """K_ZX: ``(M, N)`` kernel between the support and normalized inputs ``xn (N, d)``."""
    return se_kernel(state.Z, xn, state.lengthscale, state.outputscale)


def projected_weights(state: PredictorState, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """α(X) of (E1): ``(M,)`` normalized weights on ``state.Z`` for data ``x (N, d)``, ``y (N,)`` (physical units).

    Computed as α = L⁻ᵀ B⁻¹ A ỹ / σ_0 with L Lᵀ = K_ZZ (+ jitter), A = L⁻¹ K_ZX / σ_0,
    B = I + A Aᵀ, which stays accurate when K_ZZ is ill-conditioned.  With a linear prior mean (eq. L1 of
    :mod:`bemlearn.models.predictor_state`) ỹ is the residual from the state's plane, held fixed: δ is a shift of
    the kernel weights only.
    """
    xn = (x.to(torch.float64) - state.x_mean) / state.x_std
    yn = state.label_residual(x, y)
    sigma = float(state.noise) ** 0.5
    Kzz = _cross(state, state.Z)
    jitter = 1e-10 * float(state.outputscale)
    L, info = torch.linalg.cholesky_ex(Kzz)
    while int(info) != 0:
        Kzz.diagonal().add_(jitter)
        jitter *= 10.0
        L, info = torch.linalg.cholesky_ex(Kzz)
    A = torch.linalg.solve_triangular(L, _cross(state, xn), upper=False) / sigma      # (M, N)
    Bm = A @ A.mT
    Bm.diagonal().add_(1.0)
    c = torch.cholesky_solve((A @ yn[:, None]) / sigma, torch.linalg.cholesky(Bm))
    return torch.linalg.solve_triangular(L.mT, c, upper=True)[:, 0]


@dataclass(frozen=True)
class EstimatorSensitivity:
    """The result of :func:`estimator_sensitivity`.

    Attributes:
        delta: ``(M, K)`` δ_k of (E2), normalized output units (the state's ``estimator_delta``).
        estimators: a description of each neighbour, e.g. ``"savgol(window=49, polyorder=4)"``.
        rms_shift, median_shift: per neighbour, the RMS and the median over the queries of
            |y_std k_Zᵀ δ_k|, the output's unit (``None`` without queries).
        trials_kept_base: per neighbour, the trials with training rows where it has no valid
            estimate (too short, or within a wider kernel's edge), whose rows keep the chosen
            estimator's values there (their δ contribution is 0).
    """

    delta: torch.Tensor
    estimators: tuple[str, ...]
    rms_shift: tuple[float, ...] | None
    trials_kept_base: tuple[int, ...]
    median_shift: tuple[float, ...] | None = None

    def to_dict(self) -> dict:
        """JSON-able summary (for metadata and metrics)."""
        return {"estimators": list(self.estimators), "rms_shift": None if self.rms_shift is None else list(self.rms_shift),
                "median_shift": None if self.median_shift is None else list(self.median_shift),
                "trials_kept_base": list(self.trials_kept_base), "n_neighbours": len(self.estimators)}


def _describe(est: DerivativeEstimator) -> str:
    if not dataclasses.is_dataclass(est):   # an estimator class of the user's own: its repr
        return repr(est)
    opts = ", ".join(f"{f.name}={getattr(est, f.name)}" for f in dataclasses.fields(est) if getattr(est, f.name) is not None)
    return f"{est.name}({opts})"


def estimator_sensitivity(state: PredictorState, traj: Trajectory, estimator, rows: torch.Tensor, *,
                          queries: torch.Tensor | None = None, qu_window: float | None = None) -> EstimatorSensitivity:
    """δ of (E2) for the training rows ``rows`` of ``traj`` (module docstring).

    Args:
        state: the fitted posterior (hyperparameters, support Z and normalization are reused).
        traj: the trajectory the training inputs were built from (the rows index it).
        estimator: the derivative estimator that built them (its ``neighbours`` are used).
        rows: ``(N,)`` row indices in ``traj`` of the training points.
        queries: ``(Q, d)`` physical inputs at which to report each neighbour's RMS shift.
        qu_window: the dataset's window on |q_u|: an estimator that smooths filters the runs inside
            it separately, as :func:`~bemlearn.data.build_datasets` does.

    Returns:
        :class:`EstimatorSensitivity`; ``delta`` has K = 0 columns for an estimator without
        neighbours (e.g. central differences).
    """
    from bemlearn.data.derivative_choice import estimate_states_of
    from bemlearn.data.features import gp_inputs

    meta = traj.meta
    rate = meta.sample_rate_hz
    neighbours = tuple(estimator.neighbours(rate))
    rows_np = np.asarray(rows, dtype=np.int64)
    M = state.n_support
    if not neighbours:
        return EstimatorSensitivity(torch.zeros(M, 0, dtype=torch.float64), (), None, ())
    iu = meta.unactuated_index
    within = traj.qu_window_mask(qu_window)
    (q0, qd0, qdd0, valid0), *around = estimate_states_of(traj, (estimator, *neighbours), within=within)
    if not valid0[rows_np].all():
        bad = int(rows_np[~valid0[rows_np]][0])
        raise ArgumentError(f"estimator_sensitivity: rows: trial {int(traj.trial[bad])} holds training rows (row {bad}) where "
                         f"the chosen estimator {_describe(estimator)} has no valid estimate (the trial is too short, or the "
                         "row lies within its edge)")

    def inputs(q, qd, qdd) -> tuple[torch.Tensor, torch.Tensor]:
        x = gp_inputs(q[rows_np], qd[rows_np], qdd[rows_np], unactuated_index=iu)
        return torch.as_tensor(x, dtype=torch.float64), torch.as_tensor(q[rows_np, iu], dtype=torch.float64)

    x0, y0 = inputs(q0, qd0, qdd0)
    a0 = projected_weights(state, x0, y0)
    deltas, shorts = [], []
    for q, qd, qdd, valid in around:
        # rows where the neighbour has no valid estimate (a trial too short for it, or a wider
        # kernel's edge) keep the chosen estimator's values: their contribution to δ is 0
        keep0 = ~valid
        q[keep0], qd[keep0], qdd[keep0] = q0[keep0], qd0[keep0], qdd0[keep0]
        xk, yk = inputs(q, qd, qdd)
        deltas.append(projected_weights(state, xk, yk) - a0)
        shorts.append(len(set(traj.trial[rows_np][keep0[rows_np]].tolist())))
    delta = torch.stack(deltas, 1)
    rms = med = None
    if queries is not None:
        shift = state.y_std * (state.kernel_row(queries.to(torch.float64)) @ delta)      # (Q, K)
        rms = tuple(float(v) for v in shift.square().mean(0).sqrt())
        med = tuple(float(v) for v in shift.abs().median(0).values)
    out = EstimatorSensitivity(delta, tuple(_describe(e) for e in neighbours), rms, tuple(shorts), med)
    if rms is not None and med is not None:
        log.info("estimator term, BEM shift at the queries (RMS / median): %s",
                 ", ".join(f"{n}: {r:.3g} / {m:.3g}" for n, r, m in zip(out.estimators, rms, med)))
    return out
