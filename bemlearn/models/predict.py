"""Posterior prediction of any bemlearn GP kind under the explicit Cholesky policy (eq. 12)."""

from __future__ import annotations

import gpytorch
import torch

from bemlearn.errors import ArgumentError
from bemlearn.models.gp_kinds import as_gp
from bemlearn.models.solver import DEFAULT_JITTER, DEFAULT_MAX_TRIES, cholesky_policy
from bemlearn.models.validation import check_inputs

__all__ = ["predict"]


def predict(
    model: torch.nn.Module,
    likelihood: gpytorch.likelihoods.GaussianLikelihood,
    x: torch.Tensor,
    *,
    noisy: bool = False,
    batch_size: int = 8192,
    jitter: float = DEFAULT_JITTER,
    max_tries: int = DEFAULT_MAX_TRIES,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Posterior mean μ(x) and variance Σ(x) of eq. (12) (or its sparse counterpart).

    Puts ``model`` and ``likelihood`` in eval mode (and leaves them there, so the
    posterior caches are reused by later calls) and evaluates in chunks of ``batch_size``
    rows inside :func:`~bemlearn.models.solver.cholesky_policy`, each by the kind's own
    ``posterior`` (:mod:`bemlearn.models.gp_kinds`), so every kind returns exactly
    σ_f² − k_Zᵀ S k_Z of :class:`~bemlearn.models.predictor_state.PredictorState`.

    Args:
        model: an ``ExactBEMGP``, ``SGPRBEMGP`` or ``SVGPBEMGP``.
        likelihood: its Gaussian likelihood.
        x: ``(B, d)`` normalized inputs, same dtype as the model.
        noisy: add the observation noise σ_0² to the variance.
        batch_size: rows per chunk (bounds memory).
        jitter, max_tries: Cholesky retry policy (see :func:`~bemlearn.models.solver.robust_cholesky`).

    Returns:
        mean ``(B,)`` and variance ``(B,)``, normalized output units (squared for the variance).
    """
    gp = as_gp(model)
    dtype = next(model.parameters()).dtype
    check_inputs(x, name="x", dim=gp.dim, dtype=dtype)
    if batch_size < 1:
        raise ArgumentError(f"batch_size: expected a positive integer, got {batch_size}")
    model.eval()
    likelihood.eval()
    means, variances = [], []
    with torch.no_grad(), cholesky_policy(jitter=jitter, max_tries=max_tries):
        for start in range(0, x.shape[0], batch_size):
            out = gp.posterior(x[start : start + batch_size])
            var = out.lazy_covariance_matrix.diagonal(dim1=-1, dim2=-2)
            means.append(out.mean)
            variances.append(var.clamp_min(0.0))
        mean, var = torch.cat(means), torch.cat(variances)
        if noisy:
            var = var + likelihood.noise.squeeze()
    return mean, var
