"""Can the posterior be evaluated in float32?  Emulate the float32 C predictor and measure.

In float32 (ε = 6·10⁻⁸) the C predictor evaluates e_j = c_j − ½ Σ_i (u_i − z_ij)² with a
relative error of about ε·|e_j| (≈10⁻⁶ for |e_j| ≈ 20), so each kernel value k_j = exp(e_j)
carries that relative error and the mean μ = y_mean + Σ_j w_j k_j (eq. 12) an absolute error
of about 10⁻⁶ · Σ_j |w_j k_j|.  When the weights cancel — an exact GP on nearly noise-free
data has ‖α‖ ≫ |μ| (cond K of 10⁷ and more) — that is far above the model's own accuracy, and
no reordering of float32 operations removes it (the inputs themselves are only known to ε).
The std is worse: σ² = var0 − Σ v_i² cancels by var0/σ², so near the data, where σ ≪ √var0,
float32 loses all its digits.  The calibrated band σ_band² = c² σ² + max(Σ_i g_i², Σ_k ε_k²) (eq. B1)
adds the gradient terms g_i = h_i + γ_i u_i h_n, h = P k, h_n = Σ_j w_j k_j, whose rounding is about
10⁻⁶ · Σ_j |P_ij k_j| + ε|γ_i u_i| Σ_j |w_j k_j| — the same cancellation as the mean's — and the
estimator terms ε = E k (rounding about 10⁻⁶ · Σ_j |E_kj k_j|); both the band and the latent std
are measured.

:func:`float32_errors` runs the float32 algorithm in NumPy (same formulas and constants as the
generated C, float32 arithmetic throughout) on in-range inputs (the support points' own BEM
inputs, where σ is smallest, and random inputs) and returns the largest mean and std errors
against the float64 predictor; the export refuses float32 when they exceed the tolerances.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.linalg import solve_triangular

from bemlearn.export.c_posterior import CPosterior
from bemlearn.export.folded_posterior import FoldedPosterior

__all__ = ["Float32Errors", "float32_errors", "sample_inputs"]

F32 = np.float32


@dataclass(frozen=True)
class Float32Errors:
    """Largest float32-vs-float64 errors over the sample.

    Attributes:
        mean_abs: max |μ₃₂ − μ₆₄|, rad.
        std_rel: max |σ₃₂ − σ₆₄| / σ₆₄ of the calibrated band (the ``forward`` std).
        std_abs: max |σ₃₂ − σ₆₄|, rad, of the band.
        latent_std_rel, latent_std_abs: the same for the latent std (``forward_latent``).
        weight_sum: max Σ_j |w_j k_j| over the sample, rad (the scale of the mean's rounding).
        n: inputs in the sample.
    """

    mean_abs: float
    std_rel: float
    std_abs: float
    latent_std_rel: float
    latent_std_abs: float
    weight_sum: float
    n: int


def sample_inputs(Z: torch.Tensor, x_mean: torch.Tensor, x_std: torch.Tensor, n_inputs: int, lo: np.ndarray, hi: np.ndarray,
                  *, n_random: int = 1000, seed: int = 0) -> np.ndarray:
    """In-range inputs ``(M + n_random, n_inputs)``: support points (physical) and N(x_mean, x_std²) clipped to [lo, hi]."""
    phys = (Z * x_std + x_mean).numpy()[:, :n_inputs]
    g = np.random.default_rng(seed)
    rand = x_mean.numpy()[:n_inputs] + x_std.numpy()[:n_inputs] * g.standard_normal((n_random, n_inputs))
    return np.clip(np.concatenate([phys, rand]), lo[:n_inputs], hi[:n_inputs])


def _f32_var(post: CPosterior, k: np.ndarray) -> np.ndarray:
    """σ² from float32 kernel rows ``k (B, M)``, float32 arithmetic (the C loops, vectorized over B)."""
    M = post.n_support
    f = post.factor.astype(F32)
    if post.triangular:
        rows = np.zeros((M, M), dtype=F32)
        rows[np.tril_indices(M)] = f
        v = solve_triangular(rows, k.T, lower=True, check_finite=False).T    # float32 LAPACK (strsm)
        if post.inner is not None:     # factored sparse: r = R v, Σ s_i r_i²
            v = v @ post.inner.astype(F32).T
            sq = v * v * (post.signs.astype(F32) if post.signs is not None else F32(1))
        else:
            sq = v * v
    else:
        v = k @ f.reshape(M, M).T
        sq = v * v * (post.signs.astype(F32) if post.signs is not None else F32(1))
    q = sq.sum(1, dtype=F32)
    return np.maximum(F32(post.var0) - q, F32(0))


def _f32_gradient2(post: CPosterior, u: np.ndarray, k: np.ndarray, hn: np.ndarray) -> np.ndarray:
    """max(Σ_i g_i², Σ_k ε_k²) of the band from float32 ``u (B, n)``, ``k (B, M)``, ``hn (B,)``, float32 arithmetic."""
    grad = np.zeros(k.shape[0], dtype=F32)
    est = np.zeros(k.shape[0], dtype=F32)
    if post.banded:
        h = k @ post.P.astype(F32).T                           # (B, n)
        g = h + post.gamma.astype(F32) * (u * hn[:, None])
        if post.sb is not None:
            g = g + post.sb.astype(F32)
        grad = (g * g).sum(1, dtype=F32)
    if post.n_estimators:
        e = k @ post.E.astype(F32).T                           # (B, K)
        est = (e * e).sum(1, dtype=F32)
    return np.maximum(grad, est)


def float32_errors(post: CPosterior, reference: FoldedPosterior, x: np.ndarray) -> Float32Errors:
    """Errors of the float32 C algorithm for ``post`` (distance form) on ``x (B, n)`` against ``reference`` (float64)."""
    xf = x.astype(F32)
    u = xf * post.a.astype(F32) + post.nb.astype(F32)
    z = post.W.astype(F32)                                     # (n, M)
    d = u[:, :, None] - z[None]
    e = post.c.astype(F32)[None] - (F32(0.5) * d * d).sum(1, dtype=F32)
    k = np.exp(e).astype(F32)
    wk = k * post.w.astype(F32)
    hn = wk.sum(1, dtype=F32)
    mean = F32(post.y0) + hn
    if post.lin is not None:   # the linear prior mean l0 + Σ_i lin_i u_i (eq. L1)
        mean = mean + (F32(post.l0) + (u * post.lin.astype(F32)).sum(1, dtype=F32))
    var = _f32_var(post, k)
    if post.pv is not None:    # the plane coefficients' variance Σ_l t_l² (eq. L3)
        assert post.pv0 is not None and post.pk is not None
        t = post.pv0.astype(F32) - k @ post.pk.astype(F32).T + u @ post.pv.astype(F32).T
        var = var + (t * t).sum(1, dtype=F32)
    latent = np.sqrt(var)
    band = np.sqrt(F32(post.scale2) * var + _f32_gradient2(post, u, k, hn))
    x64 = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float64))
    with torch.no_grad():
        m64, l64 = (t.numpy() for t in reference.mean_std(x64))
        b64 = reference.mean_band(x64)[1].numpy()
    db, dl = np.abs(band.astype(np.float64) - b64), np.abs(latent.astype(np.float64) - l64)
    return Float32Errors(
        mean_abs=float(np.abs(mean.astype(np.float64) - m64).max()),
        std_rel=float((db / np.maximum(b64, 1e-300)).max()),
        std_abs=float(db.max()),
        latent_std_rel=float((dl / np.maximum(l64, 1e-300)).max()),
        latent_std_abs=float(dl.max()),
        weight_sum=float(np.abs(k.astype(np.float64) * post.w).sum(1).max()),
        n=int(x.shape[0]),
    )
