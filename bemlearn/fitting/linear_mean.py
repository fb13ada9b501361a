"""The linear prior mean of the BEM GP: a least-squares plane under the kernel (eq. L1).

Near the upright the unactuated row of the dynamics is, to first order, affine in the GP's
inputs (eq. 9 linearised at q_u = upright: gravity's stiffness against the inertial coupling of
q̈_a and the friction of q̇_a), so the BEM q_u^e(x) is a plane plus a curvature that grows with the
distance from the upright.  A zero-mean GP (eq. 11) learns the plane as well as the curvature from
the data and reverts to the data's mean beyond them; with the plane as its prior mean the kernel
only carries the curvature, and the BEM keeps the plane's trend where the design region reaches
past the excited states (docs/family.md: the two-link arms' corners).

    ỹ = β̃ᵀx̃ + f(x̃),   β̃ = argmin_β ‖(ỹ − ȳ) − (X̃ − x̄) β‖² + λ‖β‖²,   f ~ GP(0, k)          (L1)

on the normalized training split (x̄, ȳ the rows' means: zero when the normalization was fitted on
these rows, as the pipeline's is, so the plane needs no intercept; λ = 10⁻⁹ N keeps the solve
defined when a column is constant).  β̃ is estimated once,
before the kernel's hyperparameters, which are then fitted to the residual ỹ − X̃β̃.

Which mean (``train.mean: auto``) is decided by the data, jointly: both GPs are fitted and the plane is
kept when it raises the marginal likelihood of the labels by more than the Bayesian information
criterion's price of its coefficients,

    −log p(ỹ | plane) + ½ p log N  <  −log p(ỹ | zero mean)                             (L2)

(p the plane's nonzero coefficients, N the training rows; with the plane fixed, p(ỹ | plane) is the
residual's marginal likelihood).  Where the BEM bends away from a plane within the data (a yaw that
turns the slides' effect) the zero-mean GP explains the labels better and is kept.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from bemlearn.errors import ArgumentError

__all__ = ["least_squares_slope", "choose_prior_mean", "RIDGE"]

#: λ / N of (L1): a relative ridge that only matters for a (numerically) constant column.
RIDGE = 1e-9


def least_squares_slope(xn: torch.Tensor, yn: torch.Tensor, *, fixed: Sequence[int] = ()) -> torch.Tensor:
    """β̃ of (L1): ``(d,)`` normalized output per normalized input.

    Args:
        xn: ``(N, d)`` normalized training inputs.
        yn: ``(N,)`` normalized labels.
        fixed: columns the plane must not use (left-out inputs: β̃_j = 0).

    Raises:
        ArgumentError: shapes that do not match, fewer rows than columns, or a non-finite value.
    """
    if xn.ndim != 2 or yn.shape != (xn.shape[0],):
        raise ArgumentError(f"least_squares_slope: expected xn (N, d) and yn (N,), got {tuple(xn.shape)} and {tuple(yn.shape)}")
    n, d = xn.shape
    if n <= d:
        raise ArgumentError(f"least_squares_slope: {n} rows for {d} columns; a plane needs more rows than columns")
    if not (bool(torch.isfinite(xn).all()) and bool(torch.isfinite(yn).all())):
        raise ArgumentError("least_squares_slope: non-finite training inputs or labels")
    left = set(fixed)
    use = [j for j in range(d) if j not in left]
    beta = torch.zeros(d, dtype=torch.float64)
    if not use:
        return beta
    A = xn[:, use].to(torch.float64)
    A = A - A.mean(0)
    y = yn.to(torch.float64)
    gram = A.T @ A
    gram.diagonal().add_(RIDGE * n)
    beta[use] = torch.linalg.solve(gram, A.T @ (y - y.mean()))
    return beta


def choose_prior_mean(loss_linear: float, loss_zero: float, *, n: int, n_coefficients: int, explained: float) -> dict:
    """The choice of (L2) from the two fits' final losses (negative log marginal likelihood, or its bound for the
    sparse kinds, per training point, nats).

    Args:
        loss_linear: the kernel's fit to the plane's residual.
        loss_zero: the zero-mean fit to the labels.
        n: training rows N.
        n_coefficients: p, the plane's nonzero coefficients.
        explained: the share of the labels' variance the plane explains (reported only).

    Returns:
        ``{"chosen": "linear" | "zero", "nlml_linear", "nlml_zero", "penalty", "explained"}`` (nats; JSON-able).
    """
    if n < 1 or n_coefficients < 0:
        raise ArgumentError(f"choose_prior_mean: expected n >= 1 and n_coefficients >= 0, got {n}, {n_coefficients}")
    nlml_linear, nlml_zero = float(loss_linear) * n, float(loss_zero) * n
    penalty = 0.5 * n_coefficients * math.log(n)
    better = math.isfinite(nlml_linear) and (not math.isfinite(nlml_zero) or nlml_linear + penalty < nlml_zero)
    return {"chosen": "linear" if better else "zero", "nlml_linear": nlml_linear, "nlml_zero": nlml_zero,
            "penalty": penalty, "explained": float(explained)}
