"""Check an exported predictor against an independent dense evaluation of eq. (12).

The reference evaluates the kernel row by explicit differences,
k_j = σ_f² exp(−½ ‖(x̃ − z_j)/ℓ‖²) (:meth:`PredictorState.kernel_row`), not by the folded
exponent the exported predictor uses, and

    exact:       μ = y_mean + y_std (kᵀα + β̃ᵀx̃)  (β̃ = 0 but for a linear prior mean, eq. L1),   σ² = y_std² (σ_f² − kᵀ v),  K v = k solved by Cholesky
                 with two steps of iterative refinement (accurate even when K is ill-conditioned,
                 where kᵀ S k with the explicit inverse S = K⁻¹ loses digits); the predictor's
                 σ_f² − ‖L⁻¹k‖² comes from one triangular solve, and the rounding bound per
                 input is the componentwise first-order error of that route (Cholesky factor and
                 triangular solve, ``_cholesky_route_bound``): nearly noise-free data give κ₂(K)
                 of 10¹⁰ and more, where a bound blind to the conditioning is too tight;
    sgpr, svgp   σ² = y_std² (σ_f² − vᵀ C v), v = L⁻¹ k (triangular solve with ``S_chol``, one
    (factored):  step of iterative refinement), C = ``S_inner`` used directly (the export uses an
                 eigen-factor of C); rounding bound 64 M ε ‖C‖₂ σ_f² y_std² (‖v‖² ≤ σ_f²:
                 kᵀ (K_ZZ + jI)⁻¹ k ≤ k(x, x) for a kernel row);
    sgpr, svgp:  :meth:`PredictorState.predict_reference` (S is given as is), with the variance
    (unfactored) compared up to the rounding bound 64 M ε ‖S‖₂ σ_f⁴ y_std² of forming kᵀ S k.

With a linear prior mean the plane coefficients' variance y_std² rᵀAr (eq. L3) is added: for the exact kind
with r = x̃ − Zᵀ(K⁻¹k) from the refined solve (the stored P = K⁻¹H is not used; its rounding enters the bound,
``_plane_term_bound``), for the sparse kinds with the stored P.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from bemlearn.errors import CheckpointError
from bemlearn.models.band import band_extra_variance
from bemlearn.models.predictor_state import PredictorState

__all__ = ["VerificationCase", "reference_posterior", "verification_cases", "verify_predictor"]

_EPS = float(torch.finfo(torch.float64).eps)


def reference_posterior(state: PredictorState, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, float | torch.Tensor]:
    """Dense μ, σ (q_u's unit) for physical ``x: (B, d)`` float64, and the variance rounding bound (its
    square; a float, or ``(B,)`` per input for the exact kind)."""
    if state.factored:
        return _factored_reference(state, x)
    if state.sparse:
        mean, std = state.predict_reference(x)
        s_norm = float(torch.linalg.matrix_norm(state.S, ord=2))
        bound = 64 * state.n_support * _EPS * s_norm * float(state.outputscale) ** 2 * float(state.y_std) ** 2
        return mean, std, bound
    k = state.kernel_row(x)
    K = state.gram()
    L = torch.linalg.cholesky(K)
    v = torch.cholesky_solve(k.T, L)
    for _ in range(2):
        v = v + torch.cholesky_solve(k.T - K @ v, L)
    var = (state.outputscale - (k.T * v).sum(0)).clamp_min(0.0)
    route = _cholesky_route_bound(state, L, k, v)
    if state.plane_variance:   # eq. (L3) with Hᵀ K⁻¹ k from the refined solve, not from the stored P = K⁻¹H
        assert state.plane_cov is not None and state.plane_weights is not None
        xn = state.normalize(x)
        r = xn - v.T @ state.Z
        var = var + ((r @ state.plane_cov) * r).sum(1)
        route = route + _plane_term_bound(state, L, k, v, xn, r) * float(state.y_std) ** 2
    return state.y_mean + state.y_std * (k @ state.alpha) + state.prior_mean(x), state.y_std * var.sqrt(), route


def _plane_term_bound(state: PredictorState, L: torch.Tensor, k: torch.Tensor, v: torch.Tensor, xn: torch.Tensor,
                      r: torch.Tensor) -> torch.Tensor:
    """Rounding bound (normalized units squared, ``(B,)``) of the exported rᵀAr of eq. (L3), r = x̃ − Pᵀk.

    First order: P = K⁻¹H from the computed factor moves Pᵀk by at most γ_{M+1} |P|ᵀ|L||Lᵀ||v| (as in
    :func:`_cholesky_route_bound`), and forming r from x̃, Pᵀk and the folded maps rounds by
    (M + d) ε (|x̃| + |P|ᵀ|k|); then |Δ(rᵀAr)| ≤ 2 |r|ᵀ|A| δr + δrᵀ|A| δr.
    """
    assert state.plane_cov is not None and state.plane_weights is not None
    M, d = state.n_support, state.dim
    gamma = (M + 1) * _EPS / (1 - (M + 1) * _EPS)
    P, A = state.plane_weights.abs(), state.plane_cov.abs()
    L_abs = L.abs()
    dr = gamma * (L_abs @ (L_abs.T @ v.abs())).T @ P + 64 * (M + d) * _EPS * (xn.abs() + k.abs() @ P)
    return 2 * ((r.abs() @ A) * dr).sum(1) + ((dr @ A) * dr).sum(1)


def _cholesky_route_bound(state: PredictorState, L: torch.Tensor, k: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Rounding bound (q_u's unit squared, ``(B,)``) of the exported σ_f² − ‖L̂⁻¹k‖², L̂ a computed Cholesky factor.

    First order, per kernel row ``k: (B, M)`` with v = K⁻¹k ``(M, B)`` and w = L⁻¹k:

    * the factor: L̂L̂ᵀ = K + ΔK, |ΔK| ≤ γ_{M+1} |L||Lᵀ|, moves kᵀK⁻¹k by vᵀΔK v, so by at most
      γ_{M+1} ‖ |Lᵀ| |v| ‖²;
    * the triangular solve: (L + ΔL) ŵ = k, |ΔL| ≤ γ_M |L|, so |Δw| ≤ γ_M |L⁻¹| |L| |w| and
      |Δ‖w‖²| ≤ 2 |w|ᵀ |Δw|;

    plus 64 ε σ_f² for the subtraction (γ_n = n ε / (1 − n ε)).  Componentwise, this stays far
    below the normwise M ε κ₂(K) σ_f² when κ₂(K) is large (nearly noise-free data).
    """
    M = L.shape[0]
    w = torch.linalg.solve_triangular(L, k.T, upper=False).abs()
    L_abs = L.abs()
    L_inv = torch.linalg.solve_triangular(L, torch.eye(M, dtype=L.dtype), upper=False).abs()
    gamma = (M + 1) * _EPS / (1 - (M + 1) * _EPS)
    solve = 2 * (w * (gamma * (L_inv @ (L_abs @ w)))).sum(0)
    factor = gamma * (L_abs.T @ v.abs()).square().sum(0)
    return (solve + factor + 64 * _EPS * float(state.outputscale)) * float(state.y_std) ** 2


def _factored_reference(state: PredictorState, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, float]:
    """μ, σ and the rounding bound of a factored sparse state (module docstring)."""
    k = state.kernel_row(x)
    L, C = state.S_chol, state.S_inner
    v = torch.linalg.solve_triangular(L, k.T, upper=False)
    v = v + torch.linalg.solve_triangular(L, k.T - L @ v, upper=False)
    var = (state.outputscale - (v * (C @ v)).sum(0)).clamp_min(0.0) + state.plane_term(x, k)   # eq. (L3), if any
    c_norm = float(torch.linalg.matrix_norm(C, ord=2))
    bound = 64 * state.n_support * _EPS * c_norm * float(state.outputscale) * float(state.y_std) ** 2
    return state.y_mean + state.y_std * (k @ state.alpha) + state.prior_mean(x), state.y_std * var.sqrt(), bound


def _estimator_rounding(state: PredictorState, x: torch.Tensor) -> torch.Tensor:
    """Rounding allowance (q_u's unit squared, ``(B,)``) of the band's estimator term (eq. E2): each shift
    y_std kᵀδ_k is a sum of M terms that cancel like the mean's (δ inherits α's size), so its
    error is up to M ε y_std |k|ᵀ|δ_k|, and its square's up to 2 |shift| times that."""
    if not state.n_estimators:
        return torch.zeros(x.shape[0], dtype=torch.float64)
    assert state.estimator_delta is not None  # n_estimators > 0
    k = state.kernel_row(x)
    shift = state.y_std * (k @ state.estimator_delta)
    err = state.n_support * _EPS * state.y_std * (k @ state.estimator_delta.abs())
    return (2 * shift.abs() * err + err**2).mean(-1)


@dataclass(frozen=True, eq=False)
class VerificationCase:
    """One method's reference in :func:`verify_predictor`: inputs ``x (n, n_in)`` (physical units) and the
    dense mean, std (q_u's unit) and variance rounding bound (q_u's unit squared; a float or ``(n,)``)."""

    name: str
    x: torch.Tensor
    mean: torch.Tensor
    std: torch.Tensor
    bound: float | torch.Tensor


def verification_cases(state: PredictorState, *, n: int = 256, seed: int = 0, latent: bool = True) -> tuple[VerificationCase, ...]:
    """The references :func:`verify_predictor` compares a predictor with (its docstring): ``forward`` and
    ``predict_full`` with the calibrated band, and with ``latent`` also ``forward_latent`` and
    ``predict_full_latent`` with the latent std.  Computed once, they serve every file exported from ``state``
    (the dense posterior of each input set is evaluated once)."""
    g = torch.Generator().manual_seed(seed)
    d = state.dim
    x_full = state.x_mean + 2.0 * state.x_std * torch.randn(n, d, generator=g, dtype=torch.float64)
    x_bem = x_full[:, : d - 2].contiguous()
    x0 = torch.cat([x_bem, torch.zeros(n, 2, dtype=torch.float64)], 1)
    cases = []
    for name, x, ref_x, n_in in (("forward", x_bem, x0, d - 2), ("predict_full", x_full, x_full, d)):
        ref_mean, ref_std, bound = reference_posterior(state, ref_x)
        if latent:
            cases.append(VerificationCase(f"{name}_latent", x, ref_mean, ref_std, bound))
        # eq. (B1): c² σ² + max(Σ_{i < n_in} (s_i ∂μ/∂x_i)², the estimator term)
        assert state.std_scale is not None  # filled by PredictorState.__post_init__
        band_std = (state.std_scale**2 * ref_std.square() + band_extra_variance(state, ref_x, n_inputs=n_in)).sqrt()
        band_bound = bound * float(state.std_scale) ** 2 + _estimator_rounding(state, ref_x)
        cases.append(VerificationCase(name, x, ref_mean, band_std, band_bound))
    order = ("forward", "predict_full", "forward_latent", "predict_full_latent")
    return tuple(sorted(cases, key=lambda c: order.index(c.name)))


def verify_predictor(
    predictor: Any,
    state: PredictorState,
    *,
    n: int = 256,
    seed: int = 0,
    mean_atol: float = 1e-9,
    var_rtol: float = 1e-6,
    where: str = "predictor",
    cases: tuple[VerificationCase, ...] | None = None,
) -> tuple[float, float]:
    """Compare a predictor with :func:`reference_posterior` on ``n`` random inputs.

    Inputs are x_mean + 2 x_std · N(0, 1) per column; ``forward`` (at x_0^e, eq. 14) and
    ``predict_full`` (eq. 11) are checked with the calibrated band (eq. B1 of
    :mod:`bemlearn.models.band`, gradient by eq. N2), ``forward_latent`` and
    ``predict_full_latent`` (when present) with the latent std, and ``bem_mean`` must equal
    ``forward``'s mean.

    Args:
        predictor: anything with ``forward``, ``bem_mean`` and ``predict_full`` (a loaded
            TorchScript module, a :class:`~bemlearn.export.pt2.Pt2Predictor`, a BEMPredictor).
        state: the posterior it was built from.
        mean_atol: accepted |Δμ| in q_u's unit, plus the rounding allowance 10⁻¹² y_std σ_f² ‖α‖₁ (and
            10⁻¹² y_std Σ_i |β̃_i| (|x_mean_i| / x_std_i + 10) for a linear prior mean).
        var_rtol: accepted |Δσ²| / σ²_ref, plus the reference's rounding bound.
        cases: the references, :func:`verification_cases` of ``state`` (with ``n``, ``seed``), when the
            caller checks several predictors of one state; default: computed here.

    Returns:
        (max |Δμ| in q_u's unit, max |Δσ²| / (σ²_ref + bound)) over forward and predict_full.

    Raises:
        ValueError: a difference is above tolerance; the message names ``where``.
    """
    if cases is None:
        cases = verification_cases(state, n=n, seed=seed, latent=hasattr(predictor, "forward_latent"))
    elif not hasattr(predictor, "forward_latent"):
        cases = tuple(c for c in cases if not c.name.endswith("_latent"))
    mean_tol = mean_atol + 1e-12 * float(state.y_std * state.outputscale) * float(state.alpha.abs().sum())
    if state.linear_mean:   # the plane y_std β̃ᵀx̃ of eq. (L1), summed from physical (raw) or centred inputs
        assert state.mean_slope is not None
        mean_tol += 1e-12 * float(state.y_std * (state.mean_slope.abs() * (state.x_mean.abs() / state.x_std + 10.0)).sum())
    worst_mean, worst_var = 0.0, 0.0
    for case in cases:
        name, x = case.name, case.x
        mean, std = getattr(predictor, name)(x)
        dm = float((mean - case.mean).abs().max())
        dv = float(((std.square() - case.std.square()).abs() / (case.std.square() + case.bound / var_rtol)).max())
        worst_mean, worst_var = max(worst_mean, dm), max(worst_var, dv)
        if not (dm <= mean_tol and dv <= var_rtol):
            raise CheckpointError(
                f"{where}: {name} disagrees with the dense posterior (eq. 12): max |Δmean| = {dm:.3g} rad "
                f"(tol {mean_tol:.3g}), max relative |Δvar| = {dv:.3g} (tol {var_rtol:g})"
            )
        if name == "forward":
            dbm = float((predictor.bem_mean(x) - mean).abs().max())
            if not dbm <= mean_tol:
                raise CheckpointError(f"{where}: bem_mean differs from forward's mean by {dbm:.3g} rad")
    return worst_mean, worst_var
