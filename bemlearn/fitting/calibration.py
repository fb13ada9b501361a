"""Calibration of the learned BEM's band by trial-split replicas (model-free).

The latent posterior std σ̃ of eq. (12) assumes i.i.d. label noise.  The BEM's training
data violate that: q̇, q̈ come from Savitzky–Golay smoothing of quantized angles, so the
residuals of one trial are correlated over the filter window and share the trial's
excitation, and μ's error is larger than σ̃ says (coverage of ±2σ̃ on trained runs: docs/uncertainty.md).
The calibrated std is a scaled latent std,

    σ(x) = c · σ̃(x),   c ≥ 1,                                                       (C1)

with one scalar c learned *without a model* from the data themselves:

1. split the training trials at random into two disjoint halves A, B (``n_pairs`` times);
2. condition the GP with the *fitted* hyperparameters (no refit) on ``n_points`` points
   drawn from each half: two replica posteriors μ_A, σ̃_A and μ_B, σ̃_B (eq. 12);
3. at BEM queries x_0^e = [q̈_a, q̇_a, q_a, 0, 0] taken from held-out (validation) trials,
   the standardized disagreement z = (μ_A − μ_B) / √(σ̃_A² + σ̃_B²) would be N(0, 1) if
   σ̃ were honest and the replicas' errors independent; with errors inflated by c it is
   N(0, c²);
4. c = max(1, q_level(|z|) / Φ⁻¹((1 + level)/2)), the split-conformal quantile of |z|
   over all pairs (``level`` = 0.95 by default).

Replicas drawn from the *same* trials share each trial's derivative errors and
understate c (docs/uncertainty.md); trial-disjoint halves see them.

**Residual splits.**  The BEM query sets q̈_u = q̇_u = 0 at the actuated motion; under a balancing
loop the unactuated rates move nearly in lockstep with the actuated motion, so the queries lie off
the data, along the part of q̈_u (q̇_u) that the actuated motion does not explain, and μ there is an
extrapolation across the data's thin direction.  Every trial has the same lockstep, so trial halves
extrapolate alike and agree.  For each such column (``lockstep_columns``) the residual

    r = x_col − [x_motion, 1] β,   β the least-squares fit on the actuated columns     (C2)

splits the pool at its median into two halves that see the thin direction from either side; their
disagreement at the same queries gives c_col as in step 4.  c is the largest of the trial split's and
every column's (each is a test σ̃ must pass).  Measured on two family robots whose learned BEM is
right but whose band held 78–79 % of the model BEM over the design region (a cart-pole on a position
servo, corr(q̈_a, q̈_u) = −0.97; a rotary arm): trial-split c = 1.09 and 1.00, residual-split c = 1.35
and 1.27, design-region coverage 100 % and 84.6 %; on eight robots already covered c rose on four
and the median σ by at most 1.26 × (docs/uncertainty.md).

The cost is 2 · ``n_pairs`` (+ 2 · ``n_pairs`` per lockstep column) Cholesky factorizations of
``n_points`` points; prediction cost is one scalar multiply.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from bemlearn.errors import ArgumentError, DataError
from bemlearn.models.plane_posterior import with_plane_posterior
from bemlearn.warnings import UncertaintyWarning, warn

if TYPE_CHECKING:  # bemlearn.models loads GPyTorch: not needed for gaussian_quantile
    from bemlearn.models.predictor_state import PredictorState

__all__ = ["ReplicaCalibration", "calibrate_replicas", "condition_state", "gaussian_quantile"]

log = logging.getLogger(__name__)

#: The residual splits (C2) condition one replica on the samples below this quantile of the residual and the other
#: on those above 1 − it.
RESIDUAL_SPLIT = 0.5


def gaussian_quantile(level: float) -> float:
    """κ with P(|N(0, 1)| ≤ κ) = ``level`` (0 < level < 1): 1.96 for 0.95, 2.576 for 0.99."""
    if not 0.0 < level < 1.0:
        raise ArgumentError(f"level: expected 0 < level < 1, got {level}")
    return math.sqrt(2.0) * float(torch.special.erfinv(torch.tensor(level, dtype=torch.float64)))


@dataclass(frozen=True)
class ReplicaCalibration:
    """The result of :func:`calibrate_replicas`.

    Attributes:
        scale: c of (C1), ≥ 1.
        raw_scale: q_level(|z|) / Φ⁻¹((1 + level)/2) before the floor at 1.
        level: the calibrated nominal level (0.95: μ ± 1.96 σ holds 95 %).
        z_std: RMS of z over all pairs (c if z were Gaussian).
        n_pairs: replica pairs.
        n_points: points per replica.
        n_queries: queries per pair.
        method: ``"trial-split replicas"``, or ``"trial- and residual-split replicas"`` with lockstep columns.
        raw_by_split: the raw scale of each split (``"trials"``, then each lockstep column's name or index).
    """

    scale: float
    raw_scale: float
    level: float
    z_std: float
    n_pairs: int
    n_points: int
    n_queries: int
    method: str = "trial-split replicas"
    raw_by_split: dict[str, float] = dataclasses.field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-able summary (for metadata and metrics)."""
        return dataclasses.asdict(self)


def condition_state(state: PredictorState, x: torch.Tensor, y: torch.Tensor) -> PredictorState:
    """The exact posterior with ``state``'s hyperparameters conditioned on other data (eq. 12).

    Args:
        state: supplies kernel, noise and normalization (any kind).
        x: ``(N, d)`` physical inputs; y: ``(N,)`` outputs, in q_u's unit.

    Returns:
        an exact-kind state (α = K⁻¹ỹ, S = K⁻¹, K = K_XX + σ_0² I on normalized data).  A state with a linear
        prior mean (eq. L1) gets its plane refitted to these data (:func:`~bemlearn.fitting.linear_mean.least_squares_slope`,
        the columns ``state`` does not use kept out), and α is that of the residual: a replica is the whole fit on
        other data, so the spread of the plane between replicas reaches the calibration, and where ``state`` carries
        the plane's posterior (eqs. L3–L4 of :mod:`bemlearn.models.plane_posterior`: the generalized-least-squares
        plane and its coefficients' variance) so does the replica, for its own rows.
    """
    xn = (x.to(torch.float64) - state.x_mean) / state.x_std
    yn = (y.to(torch.float64) - state.y_mean) / state.y_std
    n = xn.shape[0]
    assert state.mean_slope is not None  # filled by PredictorState.__post_init__
    slope = state.mean_slope
    if state.linear_mean:
        from bemlearn.fitting.linear_mean import least_squares_slope

        slope = least_squares_slope(xn, yn, fixed=[j for j in range(state.dim) if float(state.mean_slope[j]) == 0.0])
        yn = yn - xn @ slope
    probe = dataclasses.replace(state, kind="exact", Z=xn, alpha=torch.zeros(n, dtype=torch.float64),
                                S=torch.zeros(n, n, dtype=torch.float64), n_train=n, estimator_delta=None,
                                S_chol=None, S_inner=None, mean_slope=slope, plane_weights=None, plane_cov=None)
    K = probe.gram()
    L, info = torch.linalg.cholesky_ex(K)
    jitter = 1e-10 * float(state.outputscale)
    while int(info) != 0:
        K.diagonal().add_(jitter)
        jitter *= 10
        L, info = torch.linalg.cholesky_ex(K)
    alpha = torch.cholesky_solve(yn[:, None], L)[:, 0]
    replica = dataclasses.replace(probe, alpha=alpha, S=torch.cholesky_inverse(L))
    # the replica's own plane posterior (eqs. L3–L4) where the fitted state carries it
    return with_plane_posterior(replica, cholesky=L) if state.plane_variance else replica


def calibrate_replicas(
    state: PredictorState,
    x: torch.Tensor,
    y: torch.Tensor,
    trial: torch.Tensor,
    queries: torch.Tensor,
    *,
    n_points: int | None = None,
    n_pairs: int = 4,
    level: float = 0.95,
    seed: int = 0,
    lockstep_columns: tuple[int, ...] = (),
    motion_columns: int = 0,
    column_names: tuple[str, ...] | None = None,
) -> ReplicaCalibration:
    """c of (C1) from trial-split and residual-split replicas (module docstring).

    Args:
        state: the fitted posterior (its hyperparameters are reused).
        x: ``(N, d)`` physical inputs of the training *pool* (all training-trial samples).
        y: ``(N,)`` q_u, in its joint's unit.
        trial: ``(N,)`` trial id of each row (at least 2 distinct trials).
        queries: ``(Q, d)`` physical BEM queries x_0^e (held-out trials' actuated states,
            q̈_u = q̇_u = 0).
        n_points: points per replica (default: ``state.n_train``, capped at half the pool
            and at 2000).
        n_pairs: random trial splits.
        level: nominal level the band is calibrated to.
        seed: seed of the splits and draws.
        lockstep_columns: columns of ``x`` whose residual (C2) from the first ``motion_columns`` columns also
            splits the pool (the unactuated rates q̈_u, q̇_u, which the BEM queries set to 0).
        motion_columns: the actuated columns the residual is taken from (C2).
        column_names: names of ``x``'s columns (for ``raw_by_split``).

    Raises:
        ValueError: fewer than 2 trials, no queries, or a level outside (0, 1).
    """
    kappa = gaussian_quantile(level)
    ids = np.unique(trial.numpy())
    if len(ids) < 2:
        raise DataError(f"calibrate_replicas: trial: need at least 2 distinct trials to split, got {len(ids)}")
    if queries.ndim != 2 or queries.shape[0] == 0 or queries.shape[1] != state.dim:
        raise ArgumentError(f"calibrate_replicas: queries: expected shape (Q >= 1, {state.dim}), got {tuple(queries.shape)}")
    if n_pairs < 1:
        raise ArgumentError(f"calibrate_replicas: n_pairs: expected a positive integer, got {n_pairs}")
    rng = np.random.default_rng(seed)
    tr = trial.numpy()
    n = min(n_points or state.n_train, 2000)

    def disagreement(pools: list[np.ndarray], zs: list[np.ndarray]) -> tuple[int, int]:
        """|z| of one replica pair conditioned on ``pools`` (row indices) appended to ``zs``; (points, dropped)."""
        k = min(n, *(len(p) for p in pools))
        reps = []
        for pool in pools:
            rows = torch.as_tensor(np.sort(rng.choice(pool, size=k, replace=False)))
            reps.append(condition_state(state, x[rows], y[rows]).predict_reference(queries))
        (ma, sa), (mb, sb) = reps
        # where both replicas' latent variance is (numerically) zero z is not defined: those queries are
        # left out of the quantile and counted (predict_reference solves with the Cholesky factor, so
        # this no longer happens merely because K is ill-conditioned, as with the explicit inverse)
        s2 = torch.sqrt(sa**2 + sb**2)
        ok = s2 > 1e-6 * float(state.y_std)
        zs.append(((ma - mb)[ok] / s2[ok]).abs().numpy())
        return k, int((~ok).sum())

    zs: list[np.ndarray] = []
    dropped = 0
    for _ in range(n_pairs):
        perm = rng.permutation(ids)
        halves = (perm[: len(ids) // 2], perm[len(ids) // 2:])
        k, dr = disagreement([np.flatnonzero(np.isin(tr, h)) for h in halves], zs)
        dropped += dr
    z = np.concatenate(zs)
    if z.size < 0.5 * n_pairs * queries.shape[0]:
        warn(UncertaintyWarning, log, "band calibration: the latent std cancels to zero at %d of %d replica queries (a near-linear fit, "
                                      "ill-conditioned K); std_scale = 1 and the band is the input-noise term", dropped, n_pairs * queries.shape[0])
        z = np.zeros(1)
    elif dropped:
        warn(UncertaintyWarning, log, "band calibration: %d of %d replica queries have a latent std that cancels to zero; left out",
                                      dropped, n_pairs * queries.shape[0])
    raws = {"trials": float(np.quantile(z, level)) / kappa}
    z_all = [z]
    if lockstep_columns:   # (C2): halves on either side of the data's thin direction
        xs = x.to(torch.float64).numpy()
        motion = np.column_stack([xs[:, :motion_columns], np.ones(len(xs))])
        n_res = n_pairs
        for col in lockstep_columns:
            r = xs[:, col] - motion @ np.linalg.lstsq(motion, xs[:, col], rcond=None)[0]
            lo_r, hi_r = np.quantile(r, [RESIDUAL_SPLIT, 1.0 - RESIDUAL_SPLIT])
            halves_r = [np.flatnonzero(r >= hi_r), np.flatnonzero(r <= lo_r)]
            if min(len(h) for h in halves_r) < 2:
                continue
            zc: list[np.ndarray] = []
            for _ in range(n_res):
                disagreement(halves_r, zc)
            zcol = np.concatenate(zc)
            if zcol.size >= 0.5 * n_res * queries.shape[0]:
                raws[column_names[col] if column_names else str(col)] = float(np.quantile(zcol, level)) / kappa
                z_all.append(zcol)
    raw = max(raws.values())
    zz = np.concatenate(z_all)
    cal = ReplicaCalibration(scale=max(1.0, raw), raw_scale=raw, level=level, z_std=float(np.sqrt(np.mean(zz**2))),
                             n_pairs=n_pairs, n_points=int(k), n_queries=int(queries.shape[0]),
                             method="trial- and residual-split replicas" if len(raws) > 1 else "trial-split replicas",
                             raw_by_split=raws)
    log.info("band calibration (%s): c = %.3f (raw %s) at level %.2f", cal.method, cal.scale,
             ", ".join(f"{k_} {v:.3f}" for k_, v in raws.items()), level)
    return cal
