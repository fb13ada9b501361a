"""The constants the C export compiles in, read from the TorchScript module's own buffers.

The C predictor evaluates the same folded posterior as
:class:`~bemlearn.export.folded_posterior.FoldedPosterior` (eq. 12, 14): for a query
x ∈ R^n (n = 3m for the BEM, n = 3m + 2 for the full map of eq. 11)

    μ(x) = y_mean + Σ_j w_j exp(e_j(x)),        w = y_std σ_f² α
    σ(x) = sqrt(max(0, var0 − Σ_i s_i v_i²)),   var0 = y_std² σ_f²

    exact:       v solves (L / (y_std σ_f²)) v = exp(e)   (forward substitution, L L^T = K)
    factored     v as exact (L L^T = K_ZZ + jitter), then r = R v and Σ_i s_i r_i² in place
    sgpr, svgp:  of Σ_i s_i v_i² (S = L⁻ᵀ Rᵀ diag(s) R L⁻¹, ``inner`` R; never the explicit S)
    sgpr, svgp:  v = G exp(e),  G = y_std σ_f² F           (dense matvec; unfactored states)

and the calibrated band of ``forward`` / ``predict_full`` (eq. B1, :mod:`bemlearn.models.band`)
from the same kernel row, with the FoldedPosterior's band matrix ``G = [P | w | E]`` (columns
[0, n) the gradient weights P, column n the mean weights w, columns n + 1 .. n + K the
estimator weights E = y_std σ_f² δ / √K), h_i = Σ_j P_ij exp(e_j), h_n = Σ_j w_j exp(e_j) = μ − y_mean
and ε_k = Σ_j E_kj exp(e_j) = y_std k_Z(x̃)ᵀ δ_k / √K:

    g_i = h_i + γ_i v_i h_n                     (g_i = s_i ∂μ/∂x_i, rad)
    σ_band(x) = sqrt(c² σ(x)² + max(Σ_i g_i², Σ_k ε_k²)),  c² = ``scale2``

A linear prior mean (eq. L1, :mod:`bemlearn.export.folded_posterior`) adds l_0 + Σ_i λ_i v_i to μ after the
kernel sum (h_n stays the kernel sum) and s_i y_std β̃_i / x_std_i (``sb``) to g_i, and its coefficients'
variance (eq. L3) adds Σ_l t_l² to σ(x)², t_l = t0_l + Σ_i Tv_li v_i − Σ_j Tk_lj exp(e_j) (computed before the
latent variance, which overwrites the kernel row).

Only e_j differs between the two C forms:

* ``"folded"`` (float64): e_j = c_j + q(v) + Σ_i W_ij v_i with v = x (raw) or v = a∘x − b
  (centered) and q(v) = Σ_i W2_i v_i², where ``W2`` is the quadratic row of the folded
  linear weights — the same for every j, so it costs n multiply-adds per query, not per
  support point;
* ``"distance"`` (float32): e_j = c_j − ½ Σ_i (u_i − z_ij)², u = a∘x − b, z = Z/ℓ.  Its
  rounding error is ε·|e_j| instead of ε·max(|c_j|, |W v|), which float32 needs (see
  docs/c-export.md).

The columns held at zero (q̈_u, q̇_u in eq. 14) are already folded into ``c``.  Every array
comes from the buffers of a :class:`FoldedPosterior` (the std formula therefore lives in
one place: the latent std reaches the C export through ``var0``, ``factor`` and ``signs``, the
band through ``G``, ``gamma`` and ``scale2``), never from the GP hyperparameters directly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from bemlearn.errors import ArgumentError
from bemlearn.export.folded_posterior import FoldedPosterior

__all__ = ["CPosterior", "c_posterior", "support_box", "RANGE_LENGTHSCALES"]

#: Out-of-range inputs: farther than this many lengthscales outside the box of the support points.
RANGE_LENGTHSCALES = 3.0


@dataclass(frozen=True)
class CPosterior:
    """One folded posterior (BEM or full map) as NumPy float64 arrays for the C generator.

    Attributes:
        form: ``"folded"`` (raw or centered folded exponent) or ``"distance"``.
        centered: whether v = a∘x − b (else v = x); always True for ``"distance"``.
        a, nb: ``(n,)`` input scale 1/(x_std ℓ) and offset −x_mean/(x_std ℓ).
        W: ``(n, M)`` linear weights (folded) or scaled support points z = Z/ℓ (distance), column-major
            by input so the loop over support points is contiguous.
        W2: ``(n,)`` quadratic weights of the folded form (zeros for distance).
        c: ``(M,)`` exponent offsets (columns held at zero folded in).
        w: ``(M,)`` mean weights y_std σ_f² α, rad.
        y0: output offset y_mean, rad.
        var0: prior variance y_std² σ_f², rad².
        triangular: exact GP or factored sparse: ``factor`` is the packed lower-triangular L/(y_std σ_f²).
        factor: packed lower triangle ``(M(M+1)/2,)`` (triangular) or dense ``(M, M)`` G.
        signs: ``(M,)`` ±1 of a signed factor, or ``None``.
        inner: ``(M, M)`` R of a factored sparse state (row-major, applied after the triangular
            solve), or ``None``.
        banded: whether the band has an input-noise (gradient) term, i.e. some input column has
            s_i > 0 (then γ_i ≠ 0); else P and γ are zero.  Not ``FoldedPosterior.banded``,
            which is also true for estimator columns alone.
        P: ``(n, M)`` gradient weights w_j s_i ρ_i W_ji (input-major), rad.
        gamma: ``(n,)`` γ_i = 2 q_i s_i ρ_i of the band's gradient term.
        scale2: c², the square of the band's ``std_scale``.
        E: ``(K, M)`` estimator weights y_std σ_f² δ_jk / √K (estimator-major), rad; K = 0: no
            estimator term.
        lin: ``(n,)`` λ of a linear prior mean (weights on v), or ``None`` (zero mean).
        l0: its constant, rad (0 without one).
        sb: ``(n,)`` its band-gradient term s_i y_std β̃_i / x_std_i, rad (zeros without one).
        pv: ``(p, n)`` T_v of the plane coefficients' variance (eq. L3), rad per input unit (row-major by
            term), or ``None`` (no term).
        pv0: ``(p,)`` its constant t_0, rad.
        pk: ``(p, M)`` its kernel weights T_k, rad.
    """

    form: Literal["folded", "distance"]
    centered: bool
    a: np.ndarray
    nb: np.ndarray
    W: np.ndarray
    W2: np.ndarray
    c: np.ndarray
    w: np.ndarray
    y0: float
    var0: float
    triangular: bool
    factor: np.ndarray
    signs: np.ndarray | None
    banded: bool
    P: np.ndarray
    gamma: np.ndarray
    scale2: float
    E: np.ndarray
    inner: np.ndarray | None = None
    lin: np.ndarray | None = None
    l0: float = 0.0
    sb: np.ndarray | None = None
    pv: np.ndarray | None = None
    pv0: np.ndarray | None = None
    pk: np.ndarray | None = None

    @property
    def n_plane_terms(self) -> int:
        """p, the squares of the plane coefficients' variance (0: no term)."""
        return 0 if self.pv is None else int(self.pv.shape[0])

    @property
    def n_inputs(self) -> int:
        return int(self.a.shape[0])

    @property
    def n_estimators(self) -> int:
        """K, the band's estimator columns."""
        return int(self.E.shape[0])

    @property
    def n_support(self) -> int:
        return int(self.c.shape[0])


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().numpy().astype(np.float64, copy=True)


def c_posterior(post: FoldedPosterior, *, form: Literal["folded", "distance"] = "folded") -> CPosterior:
    """Read the C constants from ``post``'s buffers (module docstring).

    Args:
        post: a FoldedPosterior; for ``form="distance"`` it must be in the centered form
            (``FoldedPosterior(..., form="centered")``), whose linear weights are z = Z/ℓ.
        form: ``"folded"`` or ``"distance"``.

    Raises:
        ValueError: ``form="distance"`` on a raw-form posterior, or folded quadratic weights
            that differ between support points, or a band matrix ``G`` whose column n is not
            the mean weights or whose sentinel row is not zero (not a FoldedPosterior as documented).
    """
    n = post.n_inputs
    W = _np(post.W)
    M = W.shape[0] - 1                              # the last row is the sentinel (the C code checks x itself)
    lin, quad, c = W[:M, :n], W[:M, n:], _np(post.c)[:M]
    if M > 0 and not np.all(quad == quad[0]):
        raise ArgumentError("FoldedPosterior.W: quadratic weights differ between support points")
    W2 = quad[0] if M > 0 else np.zeros(n)
    if form == "distance":
        if not post.centered:
            raise ArgumentError("c_posterior(form='distance'): needs a centered FoldedPosterior (form='centered')")
        c = c + 0.5 * (lin**2).sum(1)               # −½‖z_j‖² + fixed part, back to the fixed part only
        W2 = np.zeros(n)
    elif form != "folded":
        raise ArgumentError(f"form: expected 'folded' or 'distance', got {form!r}")
    FT = _np(post.FT)
    if post.triangular:
        Lg = FT[:M, :M].T                           # FT = (L / gain)ᵀ
        factor = Lg[np.tril_indices(M)]             # row-major packed lower triangle
    else:
        factor = np.ascontiguousarray(FT[:M, :M].T)  # v = G k, G = (gain F)
    inner = np.ascontiguousarray(_np(post.RT)[:M].T) if post.factored else None   # RT = R_extᵀ
    w = _np(post.w)[:M]
    G = _np(post.G)                                 # (M + 1, n + 1 + K): [P | w | E]
    if G.shape[1] < n + 1 or not np.array_equal(G[:M, n], w) or np.any(G[M:] != 0):
        raise ArgumentError(f"FoldedPosterior.G: expected (M + 1, n + 1 + K) = ({M + 1}, {n + 1} + K) with column n the "
                         f"mean weights w and the sentinel row zero, got shape {G.shape}")
    gamma, P = _np(post.gamma), np.ascontiguousarray(G[:M, :n].T)
    y0 = float(_np(post.offset)[0])                 # = y_mean: the sentinel adds exactly 0 to evaluable inputs
    return CPosterior(
        form=form, centered=bool(post.centered) or form == "distance", a=_np(post.a), nb=_np(post.nb),
        W=np.ascontiguousarray(lin.T), W2=W2, c=c, w=w, y0=y0, var0=float(post.var0),
        triangular=bool(post.triangular), factor=factor, signs=_np(post.signs) if post.signed else None,
        banded=bool(post.banded) and bool(np.any(gamma != 0) or np.any(P != 0)), P=P, gamma=gamma,
        scale2=float(post.scale2), E=np.ascontiguousarray(G[:M, n + 1 :].T), inner=inner,
        lin=_np(post.plane)[:-1] if post.linear else None, l0=float(_np(post.plane)[-1]) if post.linear else 0.0,
        sb=_np(post.sb) if post.plane_band else None,
        **_plane_variance(post, M),
    )


def _plane_variance(post: FoldedPosterior, M: int) -> dict[str, np.ndarray | None]:
    """``pv``, ``pv0``, ``pk`` of the plane coefficients' variance from ``PV``, ``PK`` (``None`` without the term)."""
    PV, PK = _np(post.PV), _np(post.PK)
    if not post.linear or not (np.any(PV != 0) or np.any(PK != 0)):
        return {"pv": None, "pv0": None, "pk": None}
    if np.any(PK[M:] != 0):
        raise ArgumentError("FoldedPosterior.PK: expected the sentinel row zero")
    return {"pv": np.ascontiguousarray(PV[:-1].T), "pv0": np.ascontiguousarray(PV[-1]),
            "pk": np.ascontiguousarray(PK[:M].T)}


def support_box(Z: torch.Tensor, x_mean: torch.Tensor, x_std: torch.Tensor, lengthscale: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Accepted input range per column: the support points' box ± RANGE_LENGTHSCALES lengthscales.

    Args:
        Z: ``(M, d)`` normalized support points; x_mean, x_std, lengthscale: ``(d,)``.

    Returns:
        (lo, hi), each ``(d,)`` in physical units.  Farther out every kernel value is below
        exp(−½·3²) ≈ 0.011 of σ_f² and the GP reverts to its prior (mean y_mean).
    """
    phys = _np(Z) * _np(x_std) + _np(x_mean)
    margin = RANGE_LENGTHSCALES * _np(lengthscale) * _np(x_std)
    return phys.min(0) - margin, phys.max(0) + margin
