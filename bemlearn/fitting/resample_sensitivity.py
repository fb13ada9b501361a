"""The resample term of the calibrated band: how much the BEM moves with the draw of its training rows.

μ is conditioned on N rows drawn at random from a training pool of many more (``dataset.n_points``:
500 of the 10⁴–10⁵ samples of the training trials).  Another draw of N rows from the same pool is an
equally valid training set, and μ moves with it.  The latent std σ̃ of eq. (12) states how far if
the residuals were i.i.d. with the fitted noise and the hyperparameters right; the rows' derivative
errors are correlated along each trial, and the hyperparameters were fitted on this very draw.  The
move is measured instead.  With the fitted hyperparameters and the state's own support Z, the
projected-process mean (eq. E1 of :mod:`bemlearn.fitting.estimator_sensitivity`) of R other draws
X_r of N rows, each disjoint from the training rows X_0, has the weight shift

    ρ_r = α(X_r, ỹ_r) − α(X_0, ỹ_0),        r = 1..R                                      (R1)

and their mean ρ̄ = (1/R) Σ_r ρ_r is μ's deviation from the average fit over draws:

    σ_rs(x) = |y_std k_Z(x̃)ᵀ ρ̄| = |μ̂̄(x) − μ(x)|,      E σ_rs² = (μ − μ̄)² + Var μ_r / R          (R2)

(μ̄ the average fit over all draws).  That deviation is a smooth, systematic error of *this* μ over
the whole query region (e.g. a slope a few tenths of a per cent off) that σ̃, computed from μ's own
draw, cannot see.  The spread of the draws around μ̄ is what c σ̃ stands for (the replicas of C1), so
it is not counted again (the mean square (1/R) Σ_r (k_Zᵀ ρ_r)², which adds it, made the band 1–15 %
wider at the same coverage on the runs of docs/uncertainty.md).  μ̄'s own error, common to every draw,
is not seen (the estimator term E2 and the replicas address parts of it).  No model is used; the cost
is R projections of N rows onto the M support points at training, one column of the band.

For a state whose training rows are the whole pool (``n_points: null``) there is no other draw:
R = 0 and σ_rs = 0.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import torch

from bemlearn.errors import ArgumentError
from bemlearn.fitting.estimator_sensitivity import projected_weights
from bemlearn.models.predictor_state import PredictorState

__all__ = ["ResampleSensitivity", "resample_sensitivity", "stack_shift_columns", "N_DRAWS"]

log = logging.getLogger(__name__)

#: R of (R2): other draws of the training rows (their mean's noise is Var μ_r / R; the cost is training time only).
N_DRAWS = 16


@dataclass(frozen=True)
class ResampleSensitivity:
    """The result of :func:`resample_sensitivity`.

    Attributes:
        delta: ``(M, 1)`` ρ̄ of (R2), normalized output units (``(M, 0)``: no other draw was possible).
        n_draws: R.
        n_points: rows per draw (N, the training rows' count).
        pool_rows: rows of the pool outside the training rows, which the draws come from.
        rms_shift, median_shift: the RMS and the median over the queries of σ_rs = |y_std k_Zᵀ ρ̄|, the output's
            unit (``None`` without queries or draws).
        spread: the RMS over the queries and draws of |y_std k_Zᵀ (ρ_r − ρ̄)|, one draw's spread around their mean.
        reason: why there is no column, else ``None``.
    """

    delta: torch.Tensor
    n_draws: int
    n_points: int
    pool_rows: int
    rms_shift: float | None = None
    median_shift: float | None = None
    spread: float | None = None
    reason: str | None = None

    def to_dict(self) -> dict:
        """JSON-able summary (for metadata and metrics)."""
        return {"n_draws": self.n_draws, "n_points": self.n_points, "pool_rows": self.pool_rows,
                "rms_shift": self.rms_shift, "median_shift": self.median_shift, "spread": self.spread, "reason": self.reason}


def resample_sensitivity(state: PredictorState, x: torch.Tensor, y: torch.Tensor, row: torch.Tensor, train_rows: torch.Tensor, *,
                         n_draws: int = N_DRAWS, queries: torch.Tensor | None = None, seed: int = 0) -> ResampleSensitivity:
    """ρ̄ of (R2) from the training pool (module docstring).

    Args:
        state: the fitted posterior (hyperparameters, support Z and normalization are reused).
        x: ``(P, d)`` physical inputs of the training pool (every usable sample of the training trials).
        y: ``(P,)`` their q_u, in its joint's unit.
        row: ``(P,)`` the pool's row indices in the trajectory (``BEMDataset.row``).
        train_rows: ``(N,)`` the trajectory rows the posterior was trained on (a subset of ``row``).
        n_draws: R.
        queries: ``(Q, d)`` physical inputs at which to report the shift and the draws' spread.
        seed: seed of the draws.

    Raises:
        ArgumentError: a training row is not in the pool, or ``n_draws`` < 0.
    """
    if n_draws < 0:
        raise ArgumentError(f"resample_sensitivity: n_draws: expected ≥ 0, got {n_draws}")
    pool_row = np.asarray(row, dtype=np.int64)
    tr = np.asarray(train_rows, dtype=np.int64)
    is_train = np.isin(pool_row, tr)
    if int(is_train.sum()) != len(np.unique(tr)):
        raise ArgumentError(f"resample_sensitivity: train_rows: {len(np.unique(tr)) - int(is_train.sum())} of the {len(tr)} training "
                            "rows are not in the pool (pass the pool the training rows were drawn from)")
    n = len(tr)
    rest = np.flatnonzero(~is_train)
    M = state.n_support
    if n_draws == 0 or len(rest) < n:
        reason = ("no draws asked" if n_draws == 0 else
                  f"the pool holds {len(rest)} rows besides the {n} training rows: no other draw of {n}")
        log.info("resample term: none (%s)", reason)
        return ResampleSensitivity(torch.zeros(M, 0, dtype=torch.float64), 0, n, len(rest), reason=reason)
    x = x.to(torch.float64)
    y = y.to(torch.float64)
    at = torch.as_tensor(np.flatnonzero(is_train))
    a0 = projected_weights(state, x[at], y[at])
    rng = np.random.default_rng(seed)
    deltas = []
    for _ in range(n_draws):
        rows = torch.as_tensor(np.sort(rng.choice(rest, size=n, replace=False)))
        deltas.append(projected_weights(state, x[rows], y[rows]) - a0)
    each = torch.stack(deltas, 1)                                                          # (M, R): ρ_r
    delta = each.mean(1, keepdim=True)                                                     # (M, 1): ρ̄
    rms = med = spread = None
    if queries is not None:
        k = state.kernel_row(queries.to(torch.float64))
        shift = (state.y_std * (k @ delta))[:, 0].abs()
        rms, med = float(shift.square().mean().sqrt()), float(shift.median())
        spread = float((state.y_std * (k @ (each - delta))).square().mean().sqrt())
        log.info("resample term: %d draws of %d of %d pool rows; μ's deviation from their mean at the queries RMS %.3g, "
                 "median %.3g; one draw's spread %.3g", n_draws, n, len(rest), rms, med, spread)
    return ResampleSensitivity(delta, n_draws, n, len(rest), rms, med, spread)


def stack_shift_columns(*groups: torch.Tensor) -> torch.Tensor:
    """The columns d_j whose mean square is the sum of each group's mean square: ``(M, J)``, J = Σ_g K_g,

        (1/J) Σ_j (kᵀ d_j)² = Σ_g (1/K_g) Σ_{k ∈ g} (kᵀ δ_k)²,     d = [√(J/K_g) δ_g]_g

    (empty groups are left out), so that the exported band's one mean over ``estimator_delta`` columns
    (eq. E2) holds the estimator term and the resample term (R2) as the sum of their variances.
    """
    live = [g for g in groups if g.shape[1] > 0]
    if not live:
        return groups[0][:, :0] if groups else torch.zeros(0, 0, dtype=torch.float64)
    J = sum(int(g.shape[1]) for g in live)
    return torch.cat([g * (J / g.shape[1]) ** 0.5 for g in live], 1)
