"""A factor of the posterior-variance quadratic form, so one matvec gives σ̃² (eq. 12).

The latent variance of every GP kind is σ̃²(x) = σ_f² − k_Zᵀ S k_Z (see
:mod:`bemlearn.models.predictor_state`).  For fast evaluation we write

    k_Zᵀ S k_Z = Σ_i s_i (F k_Z)_i²,    F ∈ R^{M×M},  s_i ∈ {+1, −1},

    exact:       K = K_ZZ + σ_0² I = L Lᵀ,  S = K⁻¹ = L⁻ᵀ L⁻¹  ⇒  F = L⁻¹, s = +1, so
                 σ̃² = σ_f² − ‖L⁻¹ k‖², one triangular solve with L (reads half of an M×M matrix
                 and is backward stable).  K is rebuilt from Z and the hyperparameters (the same
                 Cholesky route GPyTorch takes); S is only checked against it.  Two computed
                 inverses of K agree only to about κ(K)·ε (first-order perturbation of K⁻¹), so
                 when they differ by more than ``exact_rtol`` the check falls back to that bound
                 (nearly noise-free data gives κ of 10¹⁰ and more) and logs a warning;
    sgpr, svgp,  S = L⁻ᵀ C L⁻¹ (``S_chol`` L, ``S_inner`` C),  C = U Λ Uᵀ  ⇒
    factored:    kᵀ S k = Σ_i s_i (R L⁻¹ k)_i²,  R = |Λ|^{1/2} Uᵀ,  s = sign(Λ): one triangular solve
                 with L (as for exact) and one dense M×M product with the well-conditioned C's
                 factor R.  C = I − B⁻¹ (sgpr) is positive semi-definite; C = I − S_v (svgp) may
                 not be, and then s is kept.  The explicit S = L⁻ᵀ C L⁻¹ is never used: with
                 κ(K_ZZ) ≳ 10¹⁰ it has lost the digits of the small variances near the data;
    sgpr, svgp,  S = V Λ Vᵀ (symmetric eigendecomposition)  ⇒  F = |Λ|^{1/2} Vᵀ,  s = sign(Λ);
    unfactored:  (states frozen before the factor existed) S is positive semi-definite for sgpr,
                 and for svgp whenever S_u ⪯ K_ZZ, in which case rounding-level negative
                 eigenvalues are set to zero and s is dropped.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import torch

from bemlearn.errors import ArgumentError, CheckpointError
from bemlearn.models.kernels import se_gram
from bemlearn.models.predictor_state import PredictorState
from bemlearn.warnings import NumericalWarning, warn

__all__ = ["VarianceFactor", "variance_factor", "condition_number", "GRAM_RTOL"]

log = logging.getLogger(__name__)

#: Largest accepted off-diagonal |L Lᵀ − K_ZZ| / σ_f² of a factored sparse state's L.
GRAM_RTOL = 1e-8


@dataclass(frozen=True)
class VarianceFactor:
    """kᵀ S k = Σ_i s_i (F k)_i² (F alone), ‖L⁻¹ k‖² (L alone) or Σ_i s_i (F L⁻¹ k)_i² (both).

    Attributes:
        F: ``(M, M)`` float64 factor (normalized output units), or ``None`` for a Cholesky factor.
            With ``L`` it is the inner factor R of a factored sparse S = L⁻ᵀ C L⁻¹ (C = Rᵀ diag(s) R).
        L: ``(M, M)`` lower-triangular Cholesky factor: of K = S⁻¹ (exact GPs; F = L⁻¹) alone, of
            K_ZZ + jitter with ``F`` (factored sparse), or ``None``.
        signs: ``(M,)`` float64 of ±1, or ``None`` when S is positive semi-definite (all +1).
    """

    F: torch.Tensor | None = None
    L: torch.Tensor | None = None
    signs: torch.Tensor | None = None

    def __post_init__(self) -> None:
        if self.F is None and self.L is None:
            raise ArgumentError("VarianceFactor: give F, L or both")
        if self.F is None and self.signs is not None:
            raise ArgumentError("VarianceFactor: a Cholesky factor alone has no signs")

    @property
    def factored(self) -> bool:
        """A factored sparse S = L⁻ᵀ Rᵀ diag(s) R L⁻¹ (both L and F)."""
        return self.L is not None and self.F is not None

    def transformed(self, k: torch.Tensor) -> torch.Tensor:
        """v = F k, L⁻¹ k or F L⁻¹ k for ``k``: ``(B, M)`` kernel rows; returns ``(B, M)``."""
        if self.L is not None:
            k = torch.linalg.solve_triangular(self.L, k.T, upper=False).T
        return k if self.F is None else k @ self.F.T

    def quadratic_form(self, k: torch.Tensor) -> torch.Tensor:
        """kᵀ S k for ``k``: ``(B, M)`` kernel rows; returns ``(B,)``."""
        v = self.transformed(k)
        return (v * v).sum(-1) if self.signs is None else (v * v) @ self.signs


def condition_number(K: torch.Tensor) -> float:
    """κ₂(K) = λ_max / λ_min of a symmetric ``(M, M)`` matrix; ``inf`` if λ_min ≤ 0."""
    lam = torch.linalg.eigvalsh(K)
    return float(lam[-1] / lam[0]) if float(lam[0]) > 0 else math.inf


def variance_factor(state: PredictorState, *, exact_rtol: float = 1e-6, psd_rtol: float = 1e-10) -> VarianceFactor:
    """Factor S of ``state`` (see module docstring).

    Args:
        state: the posterior.
        exact_rtol: for ``exact``, the largest accepted ‖L⁻ᵀL⁻¹ − S‖_F / ‖S‖_F (a larger value
            means S is not (K_ZZ + σ_0² I)⁻¹ of this state's own Z and hyperparameters), unless
            it is within the rounding bound κ(K)·ε (accepted with a warning).
        psd_rtol: eigenvalues of S above −psd_rtol · max|λ| count as zero (rounding).

    Raises:
        ValueError: K is not positive definite, or S disagrees with it beyond both
            ``exact_rtol`` and κ(K)·ε (exact).
    """
    if not state.sparse:
        K = state.gram()
        L, info = torch.linalg.cholesky_ex(K)
        if int(info) != 0:
            raise CheckpointError(
                "PredictorState (exact): K_ZZ + σ_0² I is not positive definite "
                f"(Cholesky failed at column {int(info)}); noise = {float(state.noise):.3g}"
            )
        rel = float(torch.linalg.matrix_norm(torch.cholesky_inverse(L) - state.S) / torch.linalg.matrix_norm(state.S))
        if not rel <= exact_rtol:
            kappa = condition_number(K)
            rounding = kappa * torch.finfo(K.dtype).eps
            if not rel <= rounding:
                raise CheckpointError(
                    "PredictorState.S (exact) is not (K_ZZ + σ_0² I)⁻¹ rebuilt from its own Z, lengthscale, "
                    f"outputscale and noise: relative difference {rel:.3g} > {exact_rtol:g}, and above the "
                    f"rounding bound κ(K)·ε = {rounding:.3g} (κ = {kappa:.3g})"
                )
            warn(NumericalWarning, log,
                "exact posterior: K_ZZ + σ_0² I is ill-conditioned (κ = %.3g, noise σ_0² = %.3g); S agrees with "
                "its rebuilt inverse to %.3g, within the rounding bound κ·ε = %.3g but above exact_rtol = %g. "
                "Variances come from the Cholesky factor of the rebuilt K; at this κ, those close to the noise "
                "floor σ_0² are not accurate.",
                kappa, float(state.noise), rel, rounding, exact_rtol,
            )
        log.debug("exact variance factor: ‖L⁻ᵀL⁻¹ − S‖/‖S‖ = %.3g", rel)
        return VarianceFactor(L=L)
    if state.S_chol is not None:
        return _factored(state, psd_rtol)
    S = 0.5 * (state.S + state.S.T)
    lam, V = torch.linalg.eigh(S)
    scale = float(lam.abs().max()) if lam.numel() else 0.0
    negative = lam < -psd_rtol * scale
    if bool(negative.any()):
        log.info(
            "%s posterior: S has %d negative eigenvalue(s) (min %.3g); using a signed factor",
            state.kind, int(negative.sum()), float(lam.min()),
        )
        return VarianceFactor(F=lam.abs().sqrt()[:, None] * V.T, signs=torch.sign(lam) + (lam == 0).to(lam.dtype))
    return VarianceFactor(F=lam.clamp_min(0.0).sqrt()[:, None] * V.T, signs=None)


def _factored(state: PredictorState, psd_rtol: float) -> VarianceFactor:
    """L = ``S_chol`` and R = |Λ|^{1/2} Uᵀ of C = ``S_inner`` = U Λ Uᵀ (module docstring).

    L must be a Cholesky factor of K_ZZ rebuilt from the state's Z and hyperparameters up to a
    diagonal (the jitter): off-diagonal |L Lᵀ − K_ZZ| ≤ GRAM_RTOL σ_f², else ValueError.
    """
    L, C = state.S_chol, state.S_inner
    assert L is not None and C is not None, "called for factored states only"
    K = se_gram(state.Z, state.lengthscale, state.outputscale)
    D = L @ L.T - K
    off = float((D - torch.diag(torch.diagonal(D))).abs().max()) if D.numel() else 0.0
    if not off <= GRAM_RTOL * float(state.outputscale):
        raise CheckpointError(
            f"PredictorState.S_chol ({state.kind}): L Lᵀ is not K_ZZ (+ jitter) rebuilt from its own Z, lengthscale and "
            f"outputscale: off-diagonal difference {off:.3g} > {GRAM_RTOL:g} σ_f² = {GRAM_RTOL * float(state.outputscale):.3g}"
        )
    lam, U = torch.linalg.eigh(C)
    scale = float(lam.abs().max()) if lam.numel() else 0.0
    negative = lam < -psd_rtol * scale
    if bool(negative.any()):
        log.info("%s posterior: C of S = L⁻ᵀ C L⁻¹ has %d negative eigenvalue(s) (min %.3g); using a signed factor",
                 state.kind, int(negative.sum()), float(lam.min()))
        return VarianceFactor(F=lam.abs().sqrt()[:, None] * U.T, L=L, signs=torch.sign(lam) + (lam == 0).to(lam.dtype))
    return VarianceFactor(F=lam.clamp_min(0.0).sqrt()[:, None] * U.T, L=L, signs=None)
