"""Input noise of the GP inputs and its propagation through the mean (noisy-input GP).

McHutchon & Rasmussen (2011) treat noisy inputs x̂ = x + ε, ε ~ N(0, Σ_x), by a first-order
expansion of the posterior mean: the output picks up the variance

    σ_in²(x) = ∇μ(x)ᵀ Σ_x ∇μ(x),   Σ_x = diag(s²)                                  (N1)

with, for the squared-exponential mean μ(x) = y_mean + y_std Σ_j α_j σ_f² exp(−½‖(x̃ − z_j)/ℓ‖²)
(eq. 11, 12), x̃ = (x − x_mean)/x_std,

    ∂μ/∂x_i = −(y_std / x_std_i) Σ_j α_j k_j (x̃_i − z_ji) / ℓ_i²  [+ y_std β̃_i / x_std_i]   (N2)

(a weighted sum of the same exponentials as μ; the bracket is the constant slope of a linear prior
mean, eq. L1 of :mod:`bemlearn.models.predictor_state`).  For Savitzky–Golay derivatives of
angles quantized with step Δ (white, variance Δ²/12), the filter is linear, so

    s(q) = Δ/√12 ‖h₀‖,   s(q̇) = Δ/√12 ‖h₁‖,   s(q̈) = Δ/√12 ‖h₂‖                     (N3)

with h₁, h₂ the centre-sample first- and second-derivative coefficients of the filter
(window w, polynomial order p, sample time 1/f_s) and h₀ those of the angle it passes on
(h₀ = the unit impulse, ‖h₀‖ = 1, for Savitzky–Golay, whose q is the recorded one; the
smoothing kernel for the Gaussian estimator, :mod:`bemlearn.data.gaussian_derivative`).  bemlearn measures (N1) in
``bemlearn bench uncertainty``; the default band takes the larger of (N1) and the estimator
term of :mod:`bemlearn.fitting.estimator_sensitivity` (eq. B1 of :mod:`bemlearn.models.band`).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from bemlearn.models.predictor_state import PredictorState

__all__ = ["GRADIENT_BLOCK", "estimator_noise_gains", "estimator_noise_gains3", "mean_gradient", "mean_gradient_from_row", "propagated_variance", "quantization_input_std", "savgol_noise_std"]


def mean_gradient(state: PredictorState, x: torch.Tensor) -> torch.Tensor:
    """∇μ of (N2): ``x (B, d)`` physical inputs → ``(B, d)`` q_u's unit per input unit."""
    return mean_gradient_from_row(state, x, state.kernel_row(x.to(torch.float64)))


#: Rows of x per block of :func:`mean_gradient_from_row`: its ``(rows, M, d)`` difference tensor stays a few MB.
GRADIENT_BLOCK = 512


def mean_gradient_from_row(state: PredictorState, x: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """:func:`mean_gradient` from the kernel row k_Z(x̃) ``(B, M)`` at ``x (B, d)`` that the caller already holds
    (:meth:`~bemlearn.models.predictor_state.PredictorState.reference_terms`).

    Computed in blocks of :data:`GRADIENT_BLOCK` rows (the same numbers as all rows at once: each row's sum
    over the M inducing points is its own), so that B rows need ``GRADIENT_BLOCK × M × d`` doubles, not ``B × M × d``.
    """
    x = x.to(torch.float64)
    xn = state.normalize(x)
    ak = k * state.alpha                                                     # (B, M)
    g = torch.empty(xn.shape, dtype=torch.float64, device=xn.device)
    for i in range(0, xn.shape[0], GRADIENT_BLOCK):
        rows = slice(i, i + GRADIENT_BLOCK)
        diff = (xn[rows, None, :] - state.Z[None, :, :]) / state.lengthscale  # (rows, M, d)
        g[rows] = -(ak[rows, :, None] * diff).sum(1) / state.lengthscale     # ∂μ̃/∂x̃
    return state.y_std * g / state.x_std + state.prior_mean_gradient()   # + y_std β̃/x_std of a linear prior mean (L1)


def savgol_noise_std(window: int, polyorder: int, sample_rate_hz: float, step: float) -> tuple[float, float]:
    """(s(q̇) rad/s, s(q̈) rad/s²) of (N3) for a centred Savitzky–Golay filter of ``window`` samples."""
    from scipy.signal import savgol_coeffs

    dt = 1.0 / sample_rate_hz
    base = step / math.sqrt(12.0)
    h1 = savgol_coeffs(window, polyorder, deriv=1, delta=dt)
    h2 = savgol_coeffs(window, polyorder, deriv=2, delta=dt)
    return base * float(np.linalg.norm(h1)), base * float(np.linalg.norm(h2))


def estimator_noise_gains(estimator, sample_rate_hz: float) -> tuple[float, float]:
    """(‖h₁‖ s⁻¹, ‖h₂‖ s⁻²) of any *linear* derivative estimator, from its impulse response.

    The estimator (``bemlearn.data.derivatives``) is applied to a unit impulse in the middle of
    a zero signal long enough for its interior; the centre responses are its coefficients, so
    white input noise of std σ gives q̇, q̈ noise of std σ‖h₁‖, σ‖h₂‖ (eq. N3).
    """
    return estimator_noise_gains3(estimator, sample_rate_hz)[1:]


def estimator_noise_gains3(estimator, sample_rate_hz: float) -> tuple[float, float, float]:
    """(‖h₀‖, ‖h₁‖ s⁻¹, ‖h₂‖ s⁻²): as :func:`estimator_noise_gains`, with the gain ‖h₀‖ of the angle
    the estimator passes on (1 for an estimator that passes the recorded angle, < 1 for one that
    smooths it, ``smooths = True``)."""
    n = max(estimator.min_samples(sample_rate_hz), 3)
    T = 4 * n + 1
    impulse = np.zeros((T, 1))
    impulse[T // 2] = 1.0
    if getattr(estimator, "smooths", False):
        q, qd, qdd = estimator.filter(impulse, sample_rate_hz=sample_rate_hz)
    else:
        (qd, qdd), q = estimator(impulse, sample_rate_hz=sample_rate_hz), impulse
    interior = slice(n, T - n)
    return tuple(float(np.linalg.norm(v[interior])) for v in (q, qd, qdd))  # type: ignore[return-value]


def quantization_input_std(input_names: tuple[str, ...], steps: dict[str, float], *, estimator,
                           sample_rate_hz: float) -> torch.Tensor:
    """s of (N3) for every GP column (``qdd_<j>``, ``qd_<j>``, ``q_<j>``): ``(d,)``, each column's unit.

    Args:
        steps: quantization step Δ of each joint ``{name: Δ}`` (rad or m); a joint without an
            entry (no quantization detected) gets s = 0.
        estimator: the derivative estimator that built the inputs.
    """
    g0, g1, g2 = estimator_noise_gains3(estimator, sample_rate_hz)
    out = []
    for name in input_names:
        prefix, joint = name.split("_", 1)
        base = steps.get(joint, 0.0) / math.sqrt(12.0)
        out.append(base * (g2 if prefix == "qdd" else g1 if prefix == "qd" else g0))
    return torch.tensor(out, dtype=torch.float64)


def propagated_variance(state: PredictorState, x: torch.Tensor, input_std: torch.Tensor) -> torch.Tensor:
    """σ_in² of (N1): ``x (B, d)``, ``input_std (d,)`` → ``(B,)`` in q_u's unit squared."""
    return ((mean_gradient(state, x) * input_std) ** 2).sum(-1)
