"""Freeze a trained GP of any kind into a :class:`PredictorState` (μ = k_Zᵀ α, Σ = σ_f² − k_Zᵀ S k_Z;
sparse kinds also with S factored as L⁻ᵀ C L⁻¹)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, cast

import gpytorch
import torch

from bemlearn.models.gp_kinds import as_gp
from bemlearn.models.plane_posterior import with_plane_posterior
from bemlearn.models.predictor_state import GPKind, PredictorState
from bemlearn.models.solver import DEFAULT_JITTER, DEFAULT_MAX_TRIES, cholesky_policy

__all__ = ["predictor_state", "posterior_weights", "variance_cholesky_factor"]


def posterior_weights(
    model: torch.nn.Module,
    likelihood: gpytorch.likelihoods.GaussianLikelihood,
    *,
    jitter: float = DEFAULT_JITTER,
    max_tries: int = DEFAULT_MAX_TRIES,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Support inputs Z, mean weights α and variance matrix S of eq. (12) in frozen form.

    exact: Z = X, α = K⁻¹Y, S = K⁻¹ (K = K_XX + σ_0² I);  sgpr: Titsias α, S;
    svgp: α = L⁻ᵀ m, S = L⁻ᵀ (I − S_v) L⁻¹: each kind's ``posterior_weights`` (see the model
    modules), in eval mode, without gradients, under ``cholesky_policy(jitter, max_tries)``.

    Returns:
        ``(M, d)`` Z, ``(M,)`` α, ``(M, M)`` S in normalized units.
    """
    gp = as_gp(model)
    model.eval()
    likelihood.eval()
    with torch.no_grad(), cholesky_policy(jitter=jitter, max_tries=max_tries):
        return gp.posterior_weights()


def variance_cholesky_factor(
    model: torch.nn.Module,
    likelihood: gpytorch.likelihoods.GaussianLikelihood,
    *,
    jitter: float = DEFAULT_JITTER,
    max_tries: int = DEFAULT_MAX_TRIES,
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """L and C of a sparse posterior's S = L⁻ᵀ C L⁻¹ (L Lᵀ = K_ZZ + jitter), or ``None`` (exact).

    sgpr: C = I − B⁻¹ (:meth:`SGPRBEMGP.variance_factor`);  svgp: C = I − S_v.  The latent
    variance σ_f² − vᵀ C v, v = L⁻¹ k_Z, keeps the digits the explicit S loses when K_ZZ is
    ill-conditioned (:mod:`bemlearn.models.predictor_state`).

    Returns:
        ``(M, M)`` lower-triangular L and ``(M, M)`` symmetric C, normalized units; ``None`` for an exact GP.
    """
    gp = as_gp(model)
    model.eval()
    likelihood.eval()
    with torch.no_grad(), cholesky_policy(jitter=jitter, max_tries=max_tries):
        return gp.variance_factor()


def predictor_state(
    model: torch.nn.Module,
    likelihood: gpytorch.likelihoods.GaussianLikelihood,
    *,
    x_mean: torch.Tensor,
    x_std: torch.Tensor,
    y_mean: torch.Tensor | float,
    y_std: torch.Tensor | float,
    input_names: Sequence[str],
    n_train: int,
    mean_slope: torch.Tensor | None = None,
) -> PredictorState:
    """The frozen float64 posterior of ``model`` (any kind), detached from GPyTorch.

    Args:
        model: a trained ``ExactBEMGP``, ``SGPRBEMGP`` or ``SVGPBEMGP``.
        likelihood: its Gaussian likelihood (σ_0²).
        x_mean: ``(d,)`` input normalization's mean, physical units of each column.
        x_std: ``(d,)`` input normalization's std, physical units of each column.
        y_mean: ``()`` output normalization's mean, in q_u's unit (rad for a hinge, m for a slide).
        y_std: ``()`` output normalization's std, in q_u's unit.
        input_names: the d column names in order.
        n_train: number of training points the posterior was conditioned on.
        mean_slope: ``(d,)`` β̃ of a linear prior mean (eq. L1 of :mod:`bemlearn.models.predictor_state`) when
            ``model`` was fitted to the residual ỹ − β̃ᵀx̃; ``None``: a zero mean.

    Returns:
        a :class:`PredictorState` whose ``predict_reference`` equals :func:`~bemlearn.models.predict.predict`
        mapped to physical units (plus the plane y_std β̃ᵀx̃ of ``mean_slope``, and for an exact GP with a plane its
        coefficients' posterior: its generalized-least-squares plane and that plane's variance, eqs. L3–L4 of
        :mod:`bemlearn.models.plane_posterior`; the sparse kinds keep the plane of ``mean_slope`` and carry no such term).
    """
    kind = as_gp(model).kind
    Z, alpha, S = posterior_weights(model, likelihood)
    factor = variance_cholesky_factor(model, likelihood)
    if factor is not None:   # S as the explicit product of the (authoritative) factor
        L, C = factor
        Li = torch.linalg.solve_triangular(L, torch.eye(L.shape[0], dtype=L.dtype, device=L.device), upper=False)
        S = Li.mT @ C @ Li
        S = 0.5 * (S + S.mT)
    kernel: Any = model.covar_module  # a gpytorch ScaleKernel: nn.Module attributes are untyped
    f64: dict[str, Any] = dict(dtype=torch.float64, device="cpu")

    def _t(v: torch.Tensor | float) -> torch.Tensor:
        if not isinstance(v, torch.Tensor):  # a Python float must not pass through float32
            return torch.tensor(v, **f64)
        return v.detach().to(**f64).clone()

    state = PredictorState(
        kind=cast(GPKind, kind),  # the registered kinds are the three PredictorState knows
        Z=_t(Z),
        alpha=_t(alpha),
        S=_t(S),
        lengthscale=_t(kernel.base_kernel.lengthscale.reshape(-1)),
        outputscale=_t(kernel.outputscale.reshape(())),
        noise=_t(likelihood.noise.reshape(())),
        x_mean=_t(x_mean).reshape(-1),
        x_std=_t(x_std).reshape(-1),
        y_mean=_t(y_mean).reshape(()),
        y_std=_t(y_std).reshape(()),
        input_names=tuple(str(n) for n in input_names),
        n_train=int(n_train),
        S_chol=None if factor is None else _t(factor[0]),
        S_inner=None if factor is None else _t(factor[1]),
        mean_slope=None if mean_slope is None else _t(mean_slope).reshape(-1),
    )
    # the plane's posterior (eqs. L3–L4) where Z are the rows the plane was fitted on
    return state if state.sparse else with_plane_posterior(state)
