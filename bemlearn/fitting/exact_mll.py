r"""The exact GP's training loss, −log p(y | X, θ) / N (eq. 13), with a cheap, interruptible gradient.

    L(θ) = ( ½ rᵀ K⁻¹ r + ½ log |K| + ½ N log 2π ) / N,     K = K_θ(X, X) + σ₀² I,  r = y − m(X)

The gradient with respect to K is  ∂L/∂K = ½ (K⁻¹ − α αᵀ) / N  with α = K⁻¹ r  (Rasmussen &
Williams 2006, eq. 5.9), one ``cholesky_inverse`` of the factor the forward pass computed.
Differentiating through the Cholesky factor instead (what GPyTorch's
``ExactMarginalLogLikelihood`` does under the dense-Cholesky policy) costs about four
n³ operations inside one autograd node (5 s at N = 3,000 on one loaded core), during which
Ctrl-C cannot be noticed; here the backward pass is Python with a SIGINT check between its
steps (:func:`bemlearn.interrupts.check_interrupt`).
"""

from __future__ import annotations

import math

import torch
from linear_operator.utils.cholesky import psd_safe_cholesky

from bemlearn.errors import ArgumentError
from bemlearn.interrupts import check_interrupt

__all__ = ["gaussian_nll"]


class _GaussianNLL(torch.autograd.Function):
    @staticmethod
    def forward(ctx, K: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
        L = psd_safe_cholesky(K)
        alpha = torch.cholesky_solve(r.unsqueeze(-1), L).squeeze(-1)
        n = r.numel()
        loss = 0.5 * (r @ alpha) + L.diagonal().log().sum() + 0.5 * n * math.log(2 * math.pi)
        ctx.save_for_backward(L, alpha)
        return loss / n

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        L, alpha = ctx.saved_tensors
        n = alpha.numel()
        check_interrupt()
        W = torch.cholesky_inverse(L)
        check_interrupt()
        W.sub_(torch.outer(alpha, alpha)).mul_(0.5 * grad / n)
        return W, alpha * (grad / n)


def gaussian_nll(K: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """``()`` loss −log N(r; 0, K) / N for ``K: (N, N)`` symmetric positive definite and ``r: (N,)``.

    The Cholesky factorization follows the active jitter policy
    (:func:`~bemlearn.models.solver.cholesky_policy`).
    """
    if K.dim() != 2 or K.shape[0] != K.shape[1] or r.shape != K.shape[:1]:
        raise ArgumentError(f"gaussian_nll: expected K (N, N) and r (N,), got {tuple(K.shape)} and {tuple(r.shape)}")
    return _GaussianNLL.apply(K, r)
