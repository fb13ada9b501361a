"""The learned BEM with its uncertainty and probabilistic bound (eq. 12–15).

    E_l = { q_u^e = μ(x_0^e) },   x_0^e = [q̈_a, q̇_a, q_a, 0, 0]                       (14)
    Σ(x*) = k* − kᵀ K⁻¹ k                                                           (12)

In the paper's notation the kernel includes the noise term (K_ij = σ_f² exp(·) + σ_0² δ_ij),
so k* = k(x*, x*) = σ_f² + σ_0² and Σ is the *predictive* variance.  Three stds are exposed:
``std`` is √Σ as printed (latent + σ_0²), ``latent_std`` the posterior std of f alone, and
``band_std`` the calibrated band of :mod:`bemlearn.models.band` (eq. B1, the exported
predictor's ``std``): the one whose ±κσ holds at the stated rate (docs/uncertainty.md).

Bound (eq. 13, 15): with probability ≥ η,
    |q_u^d − μ(x_0^e)| ≤ κ Σ^{1/2}(x_0^e) + ΔΓ_max / F_min.
The κ of Srinivas et al. (2012, Thm. 6) is available (:func:`srinivas_kappa`), but it is
very conservative (it grows like ln^{3/2} N and needs the RKHS norm and the information
gain); bemlearn's documented default is the Gaussian quantile κ = 2 with Σ^{1/2} = ``band_std``:
nominal η = erf(κ/√2) = 95.45 % (:meth:`LearnedBEM.nominal_confidence`).  Measured on held-out
Furuta references the band's violation rate at κ = 2 is 0 % (nominal 4.55 %); with the
latent std it was 27 % (``bemlearn bench uncertainty``).  ΔΓ_max / F_min (the BEM–zero-dynamics
gap of Lemma 1) is a model property; pass the measured max |q_u^d − q_u^e|
(``bemlearn robot lemma1``) or 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from bemlearn.errors import ArgumentError, PredictorInputError
from bemlearn.models.band import band_reference
from bemlearn.models.predictor_state import PredictorState

__all__ = ["LearnedBEM", "BEMPrediction", "srinivas_kappa"]


@dataclass(frozen=True)
class BEMPrediction:
    """Learned BEM for a batch: ``mean``, ``std`` (√Σ, eq. 12 as printed), ``latent_std`` and
    ``band_std`` (calibrated band, eq. B1; use it in :meth:`LearnedBEM.bound`), all ``(B,)`` rad."""

    mean: torch.Tensor
    std: torch.Tensor
    latent_std: torch.Tensor
    band_std: torch.Tensor


def srinivas_kappa(rkhs_norm: float, info_gain: float, n: int, eta: float) -> float:
    """κ = √(2‖q_u‖_k² + 300 γ ln³(N / (1 − η))) of Srinivas et al. (2012), Theorem 6 (eq. 13)."""
    if not 0 < eta < 1:
        raise ArgumentError(f"srinivas_kappa: eta must be in (0, 1), got {eta}")
    return math.sqrt(2 * rkhs_norm**2 + 300 * info_gain * math.log(n / (1 - eta)) ** 3)


class LearnedBEM:
    """The learned BEM of a trained run (module docstring).

    Args:
        state: the frozen posterior.
        robot, actuated_names, unactuated_name: what the columns mean.
    """

    def __init__(self, state: PredictorState, *, robot: str, actuated_names: tuple[str, ...], unactuated_name: str) -> None:
        self.state = state
        self.robot = robot
        self.actuated_names = tuple(actuated_names)
        self.unactuated_name = unactuated_name
        self.m = len(self.actuated_names)
        if state.dim != 3 * self.m + 2:
            raise ArgumentError(f"LearnedBEM: the posterior has d = {state.dim} inputs, expected 3m + 2 = {3 * self.m + 2}")

    def predict(self, x: torch.Tensor, *, n_inputs: int | None = None) -> BEMPrediction:
        """The full learned map f of eq. (11): ``x (B, 3m + 2)`` = [q̈_a, q̇_a, q_a, q̈_u, q̇_u] → q_u.

        ``n_inputs``: columns whose input noise enters ``band_std`` (default all; 3m at x_0^e)."""
        x = torch.as_tensor(x, dtype=torch.float64)
        if x.ndim != 2 or x.shape[1] != 3 * self.m + 2:
            raise PredictorInputError(f"LearnedBEM.predict: x must have shape (B, {3 * self.m + 2}) [q̈_a, q̇_a, q_a, q̈_u, q̇_u], got {tuple(x.shape)}")
        if not bool(torch.isfinite(x).all()):
            raise PredictorInputError("LearnedBEM.predict: x has non-finite values")
        out = []
        for chunk in x.split(4096):
            out.append(band_reference(self.state, chunk, n_inputs=n_inputs))
        mean = torch.cat([o[0] for o in out])
        band = torch.cat([o[1] for o in out])
        latent = torch.cat([o[2] for o in out])
        noise = self.state.y_std**2 * self.state.noise
        return BEMPrediction(mean, (latent**2 + noise).sqrt(), latent, band)

    def bem(self, qa, qad, qadd) -> BEMPrediction:
        """μ(x_0^e) and its std (eq. 14, 12): ``qa, qad, qadd (B, m)`` rad, rad/s, rad/s²."""
        parts = [torch.as_tensor(v, dtype=torch.float64) for v in (qadd, qad, qa)]
        for name, p in zip(("qadd", "qad", "qa"), parts):
            if p.ndim != 2 or p.shape[1] != self.m:
                raise PredictorInputError(f"LearnedBEM.bem: {name} must have shape (B, {self.m}), got {tuple(p.shape)}")
        x = torch.cat(parts + [torch.zeros(parts[0].shape[0], 2, dtype=torch.float64)], dim=1)
        return self.predict(x, n_inputs=3 * self.m)

    @staticmethod
    def bound(std: torch.Tensor, *, kappa: float = 2.0, zero_dynamics_gap: float = 0.0) -> torch.Tensor:
        """Half-width of eq. (15): κ Σ^{1/2} + ΔΓ_max/F_min, rad (see module docstring for κ).

        Pass ``band_std`` for a bound that holds at :meth:`nominal_confidence` (measured:
        ``bemlearn bench uncertainty``, ``metrics.json`` → ``bem_heldout.bound_violation``)."""
        return kappa * std + zero_dynamics_gap

    @staticmethod
    def nominal_confidence(kappa: float = 2.0) -> float:
        """η = P(|N(0, 1)| ≤ κ) = erf(κ/√2), the bound's stated confidence (0.9545 for κ = 2)."""
        if not kappa > 0:
            raise ArgumentError(f"nominal_confidence: kappa must be > 0, got {kappa}")
        return math.erf(kappa / math.sqrt(2.0))
