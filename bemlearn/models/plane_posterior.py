"""The posterior of the plane under an exact GP: its coefficients (eq. L4) and their variance (eq. L3).

With the plane β̃ᵀx̃ as prior mean (eq. L1 of :mod:`bemlearn.models.predictor_state`) and a vague prior on
its coefficients, the posterior of the BEM is (Rasmussen & Williams 2006, eqs. 2.41–2.42 with B⁻¹ → 0) the
kernel's plus the coefficients':

    β̄ = A Hᵀ K⁻¹ ỹ,   μ̃(x̃) = h(x̃)ᵀβ̄ + k_Z(x̃)ᵀ K⁻¹ (ỹ − H β̄)                                (L4)
    σ̃²(x̃) += rᵀ A r,   r = h(x̃) − Hᵀ K⁻¹ k_Z(x̃),   A = (Hᵀ K⁻¹ H)⁻¹                       (L3)

β̄ is the generalized-least-squares plane under the fitted kernel: it weighs the rows by K⁻¹, so that a run of
correlated rows (one stretch of one trial) counts as the information it holds, not as many rows, where the
ordinary least-squares plane of (L1), fitted before the kernel, counts every row alike.  Given a state whose
α = K⁻¹(ỹ − Hβ̃) holds the residual of the ordinary plane β̃, (L4) is reached without the labels:

    β̄ = β̃ + A Hᵀ α,   α ← α − P (β̄ − β̃),   P = K⁻¹ H.

with H ``(M, p)`` the support rows' plane columns (the training inputs of an exact GP), h(x̃) the query's, and
K = K_ZZ + σ_0² I.  The state stores P = K⁻¹H and A embedded in all d columns (zeros where β̃_j = 0), so
that r = x̃ − Pᵀ k_Z(x̃) over every column (the unused ones meet zero rows of A).  The term vanishes where the
kernel reproduces the plane's columns from the data (near them, Pᵀk_Z ≈ x̃) and grows like the distance
squared beyond them, where the BEM is the extrapolated plane.
"""

from __future__ import annotations

import dataclasses

import torch

from bemlearn.errors import ArgumentError
from bemlearn.models.predictor_state import PredictorState
from bemlearn.models.solver import robust_cholesky

__all__ = ["with_plane_posterior"]


def with_plane_posterior(state: PredictorState, *, cholesky: torch.Tensor | None = None) -> PredictorState:
    """``state`` with the plane's posterior: β̄ and the matching α of (L4) (``mean_slope``, ``alpha``), and P and A
    of (L3) (``plane_weights``, ``plane_cov``).

    ``state.alpha`` must be K⁻¹ times the residual of ``state.mean_slope`` (as :func:`~bemlearn.models.freeze.predictor_state`
    and :func:`~bemlearn.fitting.calibration.condition_state` freeze it); columns with β̃_j = 0 stay out of the plane.

    Only for an exact posterior (Z the training inputs, K = K_ZZ + σ_0² I); a state without a plane is returned
    unchanged.  K's Cholesky factor is ``cholesky`` when the caller has it (``(M, M)`` lower, the one its α was
    solved with), else :meth:`~PredictorState.gram_cholesky`, or where K is not numerically positive definite
    :func:`~bemlearn.models.solver.robust_cholesky`'s (a growing jitter, with a warning).

    Raises:
        ArgumentError: a sparse kind (its Z are inducing points, not the rows the plane was fitted on), or a
            plane whose columns the data do not determine (Hᵀ K⁻¹ H singular).
    """
    if not state.linear_mean:
        return state
    if state.sparse:
        raise ArgumentError(f"with_plane_posterior: an exact posterior is needed (its Z are the training rows); got {state.kind!r}")
    assert state.mean_slope is not None  # filled by PredictorState.__post_init__
    used = (state.mean_slope != 0).nonzero().flatten()
    L = cholesky if cholesky is not None else state.gram_cholesky()
    if L is None:
        L, _ = robust_cholesky(state.gram(), what="K_ZZ + σ_0² I (the plane coefficients' variance, eq. L3)",
                               jitter=1e-10 * float(state.outputscale))
    H = state.Z[:, used]
    P_used = torch.cholesky_solve(H, L)                       # K⁻¹H (M, p)
    G = H.mT @ P_used
    G = 0.5 * (G + G.mT)
    chol, info = torch.linalg.cholesky_ex(G)
    if int(info) != 0:
        raise ArgumentError("with_plane_posterior: Hᵀ K⁻¹ H is singular: the data do not determine the plane's "
                            f"coefficients (columns {[state.input_names[int(j)] for j in used]})")
    A_used = torch.cholesky_inverse(chol)
    A_used = 0.5 * (A_used + A_used.mT)
    shift = A_used @ (H.mT @ state.alpha)                      # β̄ − β̃ of (L4)
    beta = state.mean_slope.clone()
    beta[used] = beta[used] + shift
    alpha = state.alpha - P_used @ shift
    d, M = state.dim, state.n_support
    P = torch.zeros(M, d, dtype=torch.float64, device=state.Z.device)
    A = torch.zeros(d, d, dtype=torch.float64, device=state.Z.device)
    P[:, used] = P_used
    A[used[:, None], used[None, :]] = A_used
    return dataclasses.replace(state, mean_slope=beta, alpha=alpha, plane_weights=P, plane_cov=A)
