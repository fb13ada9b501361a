"""The ARD squared-exponential kernel of the BEM GP (eq. 11) and its Gaussian likelihood.

    k(x, x') = σ_f² exp(−½ (x − x')ᵀ W (x − x')),   W = diag(ℓ_1⁻², …, ℓ_d⁻²)   (eq. 11)

ℓ and σ_f² are positive through GPyTorch constraints (softplus on raw parameters); the
observation noise σ_0² of the likelihood is bounded below by ``min_noise`` so that
K + σ_0² I stays numerically positive definite.
"""

from __future__ import annotations

import gpytorch
import torch
from gpytorch.constraints import GreaterThan, Positive

from bemlearn.errors import ArgumentError

__all__ = ["LEFT_OUT_LENGTHSCALE", "ard_se_kernel", "gaussian_likelihood", "kernel_matrix", "se_cross_covariance", "se_gram",
           "se_kernel"]

#: ℓ_j of an input column the map does not depend on (a cyclic coordinate's position, docs/wheeled.md), in
#: normalized units: for |Δ_j| < 10⁴ normalized units (a wheel's angle 10⁴ of its training spreads away) its term
#: (Δ_j/ℓ_j)² < 10⁻³² of eq. (11) lies below half an ulp of any sum it joins that is not itself < 10⁻¹⁵ (where the
#: kernel is 1 anyway), so the column drops out of k, μ and σ to the bit, while the input layout
#: x = [q̈_a, q̇_a, q_a, q̈_u, q̇_u] of every predictor stays as it is.  1/ℓ and ℓ·x_std stay finite in float32.
LEFT_OUT_LENGTHSCALE = 1e20


def ard_se_kernel(dim: int, *, dtype: torch.dtype = torch.float64) -> gpytorch.kernels.ScaleKernel:
    """σ_f² exp(−½ (x − x')ᵀ W (x − x')) with ARD W = diag(ℓ⁻²) (eq. 11).

    Args:
        dim: input dimension d (3n − 1; 5 for the Furuta pendulum).
        dtype: parameter dtype.

    Returns:
        ``ScaleKernel(RBFKernel(ard_num_dims=dim))`` with positive constraints on ℓ and σ_f².
    """
    if dim < 1:
        raise ArgumentError(f"dim: expected a positive input dimension, got {dim}")
    base = gpytorch.kernels.RBFKernel(ard_num_dims=dim, lengthscale_constraint=Positive())
    kernel = gpytorch.kernels.ScaleKernel(base, outputscale_constraint=Positive())
    return kernel.to(dtype=dtype)


def gaussian_likelihood(*, min_noise: float = 1e-6, dtype: torch.dtype = torch.float64) -> gpytorch.likelihoods.GaussianLikelihood:
    """Homoscedastic Gaussian noise w ~ N(0, σ_0²) of eq. (11), with σ_0² > ``min_noise``.

    Args:
        min_noise: lower bound of σ_0² in normalized output units squared.
        dtype: parameter dtype.
    """
    if not min_noise > 0.0:
        raise ArgumentError(f"min_noise: expected a positive noise floor, got {min_noise}")
    lik = gpytorch.likelihoods.GaussianLikelihood(noise_constraint=GreaterThan(min_noise))
    return lik.to(dtype=dtype)


def kernel_matrix(kernel: gpytorch.kernels.Kernel, x1: torch.Tensor, x2: torch.Tensor) -> torch.Tensor:
    """Dense K_ij = k(x1_i, x2_j) (eq. 11).

    Args:
        kernel: the ARD kernel from :func:`ard_se_kernel`.
        x1: ``(A, d)`` normalized inputs.
        x2: ``(B, d)`` normalized inputs.

    Returns:
        ``(A, B)`` kernel matrix, normalized output units squared.
    """
    with gpytorch.settings.lazily_evaluate_kernels(False):
        return kernel(x1, x2).to_dense()


def se_kernel(x1: torch.Tensor, x2: torch.Tensor, lengthscale: torch.Tensor, outputscale: torch.Tensor) -> torch.Tensor:
    """K_ij = σ_f² exp(−½ ‖(x1_i − x2_j)/ℓ‖²) (eq. 11): the one evaluation of the ARD kernel on
    frozen hyperparameters that every posterior, check, bench and test shares.

    The differences are formed directly (``cdist`` without the ‖a‖² + ‖b‖² − 2aᵀb expansion, so
    no cancellation near the data) and no ``(A, B, d)`` tensor is built.

    Args:
        x1: ``(A, d)`` normalized inputs.
        x2: ``(B, d)`` normalized inputs.
        lengthscale: ``(d,)`` ℓ, normalized input units.
        outputscale: ``()`` σ_f², normalized output units squared.

    Returns:
        ``(A, B)`` kernel matrix, normalized output units squared.
    """
    d2 = torch.cdist(x1 / lengthscale, x2 / lengthscale, compute_mode="donot_use_mm_for_euclid_dist").square()
    return outputscale * torch.exp(-0.5 * d2)


def se_gram(z: torch.Tensor, lengthscale: torch.Tensor, outputscale: torch.Tensor) -> torch.Tensor:
    """K_ZZ = :func:`se_kernel` ``(z, z)``: ``(M, M)`` for ``z (M, d)`` normalized inputs (no noise term;
    :meth:`~bemlearn.models.predictor_state.PredictorState.gram` adds σ_0² I)."""
    return se_kernel(z, z, lengthscale, outputscale)


def se_cross_covariance(
    z: torch.Tensor, x: torch.Tensor, lengthscale: torch.Tensor, outputscale: torch.Tensor
) -> torch.Tensor:
    """K_ZX of eq. (11) in one fused pass, for the O(N M) blocks of the sparse GPs.

    With z̃ = (z − c)/ℓ, x̃ = (x − c)/ℓ (c = mean of z, for accuracy),

        k(z, x) = exp(log σ_f² − ½|z̃|² − ½|x̃|² + z̃ᵀx̃),

    i.e. one matrix product, one broadcast add and one exp over the (M, B) block (about
    half the memory traffic of the generic GPyTorch kernel, with the same values to ~1e-15).

    Args:
        z: ``(M, d)`` normalized inputs (e.g. inducing points).
        x: ``(B, d)`` normalized inputs.
        lengthscale: ``(d,)`` or ``(1, d)`` ℓ.
        outputscale: ``()`` σ_f².

    Returns:
        ``(M, B)`` kernel matrix.
    """
    ls = lengthscale.reshape(-1)
    c = z.mean(0).detach()
    zt = (z - c) / ls
    xt = (x - c) / ls
    a = torch.log(outputscale.reshape(())) - 0.5 * (zt * zt).sum(-1)
    b = -0.5 * (xt * xt).sum(-1)
    return torch.exp(torch.addmm(b[None, :], zt, xt.mT) + a[:, None])
