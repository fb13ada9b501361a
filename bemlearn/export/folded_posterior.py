"""The GP posterior with normalization and hyperparameters folded into a few constants.

With u = (x − x_mean) / (x_std ∘ ℓ) = a∘x − b the normalized, lengthscale-scaled input and
z_j = Z_j / ℓ, the squared-exponential exponent (eq. 11) is one affine map of [v, v∘v] for
either choice of the variable v:

    v = x (raw):       e_j = −½‖a∘x − (b + z_j)‖² = [x, x∘x] · [a∘(b + z_j), −½ a∘a] − ½‖b + z_j‖²
    v = u (centered):  e_j = −½‖u − z_j‖²         = [u, u∘u] · [z_j, −½ 1]          − ½‖z_j‖²

The raw form saves the ``addcmul`` that forms u but its terms grow like
(|b| + |u|)², so it is used only while Σ_i (|b_i| + 5)² ≤ 10³ (rounding in e_j stays below
~2·10⁻¹³), i.e. unless a column's mean is far from zero in units of its spread; otherwise the
centered form.  Either way a batch ``x: (B, n)`` costs one ``pow`` (which forms [v, v∘v] in one
call, one op fewer than ``cat`` of ``v`` and ``v * v``), one ``linear``, one ``exp`` and
one ``addmv`` for the mean (eq. 12) and one triangular solve or ``mm`` for the variance:

    μ(x) = y_mean + Σ_j w_j exp(e_j),                  w = y_std σ_f² α
    σ(x) = sqrt(max(0, y_std² σ_f² − Σ_i s_i v_i²)),   v = (y_std σ_f² F) exp(e)

with F, s from :func:`~bemlearn.export.variance_factor.variance_factor`; for an exact GP
F = L⁻¹ and v comes from one triangular solve, v (L / (y_std σ_f²))ᵀ = exp(e)ᵀ.  A factored
sparse S = L⁻ᵀ C L⁻¹ (C = Rᵀ diag(s) R) takes the same triangular solve and then one ``mm`` with
Rᵀ: Σ_i s_i (R v)_i² (``RT``, its sentinel row zero), never the explicit S.  Columns
n..d−1 of the GP input can be held at zero, which gives the BEM input
x_0^e = [q̈_a, q̇_a, q_a, 0, 0] of eq. (14): their terms are constant and move into the offsets.

The calibrated band (:mod:`bemlearn.models.band`, eq. B1) reuses the same row exp(e):
with ρ_i = 1 (raw) or a_i (centered), P the linear part of W (first n columns) and
q_i = W[·, n + i] (the same −½ a_i² or −½ in every row), ∂e_j/∂x_i = ρ_i (P_ji + 2 q_i v_i), so

    h = exp(e) G,   G = [w_j s_i ρ_i P_ji | w_j | y_std σ_f² δ_jk / √K]  (M + 1, n + 1 + K), sentinel row 0
    g_i = h_i + γ_i v_i h_n,   γ_i = 2 q_i s_i ρ_i           (g_i = s_i ∂μ/∂x_i, rad)
    σ_band(x) = sqrt(c² max(0, y_std² σ_f² − Σ_i s_i v_i²) + max(Σ_i g_i², Σ_k h_{n+1+k}²))

(one ``mm`` of the (B, M + 1) row with an (M + 1, n + 1 + K) matrix more than the latent std;
c = ``std_scale``, s = ``input_std``, δ = ``estimator_delta`` (K columns) of the state; with
s = 0 and K = 0 the ``mm`` is skipped).

A linear prior mean (eq. L1 of :mod:`bemlearn.models.predictor_state`, y_std β̃ᵀx̃) is affine in v as well:

    μ(x) += l_0 + Σ_i λ_i v_i,   λ = y_std β̃ / x_std (raw) or y_std β̃ ∘ ℓ (centered),

l_0 its constant (the x_mean terms in the raw form, the columns held at zero in both), and its
constant gradient adds s_i y_std β̃_i / x_std_i to g_i; with β̃ = 0 neither is computed.  Its coefficients'
variance (eq. L3 of :mod:`bemlearn.models.plane_posterior`, y_std² rᵀAr with r = x̃ − Pᵀk_Z) is a sum of
squares of a map affine in v and in the kernel row: with A = R Rᵀ (R ``(d, p)`` from A's eigenvectors),

    y_std rᵀR = v T_v + t_0 − exp(e) T_k,   T_k = y_std σ_f² P R  (sentinel row zero),
    T_v = y_std diag(1/x_std) R (raw) or y_std diag(ℓ) R (centered), over the free columns,

t_0 the rest (x_mean's terms, the columns held at zero); the latent variance adds ‖v T_v + t_0 − exp(e) T_k‖²
(``PV`` = [T_v; t_0], ``PK`` = T_k; one zero column without the term).

One extra *sentinel* column j = M guards the range in which float64 can evaluate the kernel:
its exponent is e_M = ‖u‖² − 10³⁰⁰ (zero linear weights; quadratic weights 1 on u∘u in the
centered form, a∘a on x∘x in the raw one, where u ≈ a∘x far from the data), its mean weight
w_M = 10⁻³⁰⁰, and the factor ignores it (zero row, or a 10³⁰⁰ diagonal entry in the triangular
case).  Since 10³⁰⁰ swamps every rounding, exp(e_M) is exactly 0 while ‖u‖ < 10¹⁵⁰ (the
column changes nothing: μ = y_mean + Σ_j w_j exp(e_j) with nothing taken off) and +inf beyond,
where the squares and the exponents of the other columns lose their meaning (x∘x overflows
near |x| ≈ 1.3·10¹⁵⁴); a NaN or ±inf input makes it NaN or +inf as well.  So an input whose
kernel cannot be evaluated in float64 always shows up as a non-finite μ, and one check of μ
replaces a pass over x (the C export applies the same rule: docs/c-export.md).
"""

from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from bemlearn.errors import ArgumentError
from bemlearn.export.variance_factor import VarianceFactor
from bemlearn.models.predictor_state import PredictorState

__all__ = ["FoldedPosterior", "RAW_FORM_LIMIT", "SENTINEL_BOUND"]

#: Mean weight w_M of the sentinel column (see module docstring): finite × it stays negligible, inf × it is inf.
SENTINEL_WEIGHT = 1e-300
#: ‖u‖² beyond which the kernel is not evaluated: the sentinel exponent is ‖u‖² − this (‖u‖ > 10¹⁵⁰ is an error).
SENTINEL_BOUND = 1e300
#: Diagonal entry of the triangular factor at the sentinel (its v entry underflows to 0).
SENTINEL_PIVOT = 1e300
#: The raw form is used while Σ_i (|b_i| + 5)² is at most this.
RAW_FORM_LIMIT = 1e3


class FoldedPosterior(nn.Module):
    """Mean and latent std of a :class:`PredictorState` for inputs in physical units.

    Scriptable (``torch.jit.script``) and exportable (``torch.export``).  It does not check
    its input (``x: (B, n_inputs)`` float64 with B ≥ 1; ``addmv`` mishandles B = 0);
    :class:`~bemlearn.export.bem_predictor.BEMPredictor` does.

    Args:
        state: the posterior (float64).
        factor: the variance factor of ``state``.
        n_inputs: the inputs are the first ``n_inputs`` GP columns; the remaining
            ``d − n_inputs`` are held at zero (physical units), e.g. ``3m`` for eq. (14).
        share: another FoldedPosterior of the same state whose weight and factor buffers
            are reused (no second copy of the M×M factor).
        chunk: batches larger than this are evaluated in row blocks of this size.
        form: ``"auto"`` (see module docstring), ``"raw"`` or ``"centered"``.
    """

    n_inputs: int
    chunk: int
    centered: bool
    signed: bool
    triangular: bool
    factored: bool
    banded: bool
    linear: bool
    plane_band: bool
    var0: float
    scale2: float
    # buffers (registered in __init__; declared for the type checker)
    a: torch.Tensor
    nb: torch.Tensor
    W: torch.Tensor
    c: torch.Tensor
    offset: torch.Tensor
    powers: torch.Tensor
    w: torch.Tensor
    FT: torch.Tensor
    RT: torch.Tensor
    signs: torch.Tensor
    G: torch.Tensor
    gamma: torch.Tensor
    plane: torch.Tensor
    sb: torch.Tensor
    PV: torch.Tensor
    PK: torch.Tensor

    def __init__(
        self,
        state: PredictorState,
        factor: VarianceFactor,
        *,
        n_inputs: int,
        share: "FoldedPosterior | None" = None,
        chunk: int = 1024,
        form: str = "auto",
    ) -> None:
        super().__init__()
        d, M = state.dim, state.n_support
        if not 1 <= n_inputs <= d:
            raise ArgumentError(f"n_inputs: expected 1..{d}, got {n_inputs}")
        if chunk < 1:
            raise ArgumentError(f"chunk: expected a positive row count, got {chunk}")
        if form not in ("auto", "raw", "centered"):
            raise ArgumentError(f"form: expected 'auto', 'raw' or 'centered', got {form!r}")
        f64: dict[str, Any] = dict(dtype=torch.float64)
        # filled in by PredictorState.__post_init__
        assert state.input_std is not None and state.estimator_delta is not None and state.std_scale is not None
        free, fixed = slice(0, n_inputs), slice(n_inputs, d)
        a = 1.0 / (state.x_std * state.lengthscale)
        b = state.x_mean * a
        zs = state.Z / state.lengthscale                        # (M, d)
        if form == "auto":
            form = "raw" if float(((b[free].abs() + 5.0) ** 2).sum()) <= RAW_FORM_LIMIT else "centered"
        self.centered = form == "centered"
        W = torch.zeros(M + 1, 2 * n_inputs, **f64)             # linear weights, rows j
        c = torch.zeros(M + 1, **f64)
        fixed_part = -0.5 * ((b[fixed] + zs[:, fixed]) ** 2).sum(1)   # columns held at x = 0
        if self.centered:
            W[:M, :n_inputs] = zs[:, free]
            W[:M, n_inputs:] = -0.5
            c[:M] = -0.5 * (zs[:, free] ** 2).sum(1) + fixed_part
        else:
            W[:M, :n_inputs] = a[free] * (b[free] + zs[:, free])
            W[:M, n_inputs:] = -0.5 * a[free] ** 2
            c[:M] = -0.5 * ((b[free] + zs[:, free]) ** 2).sum(1) + fixed_part
        W[M, n_inputs:] = 1.0 if self.centered else a[free] ** 2    # ‖u‖² (u ≈ a∘x far from the data)
        c[M] = -SENTINEL_BOUND
        gain = state.y_std * state.outputscale                  # y_std σ_f²
        self.n_inputs = n_inputs
        self.chunk = chunk
        self.register_buffer("a", a[free].contiguous())
        self.register_buffer("nb", -b[free].contiguous())
        self.register_buffer("W", W)
        self.register_buffer("c", c)
        self.register_buffer("offset", state.y_mean.reshape(1).to(**f64))
        self.register_buffer("powers", torch.tensor([[1.0], [2.0]], **f64))   # [v, v∘v] = v ** powers
        if share is None:
            w = torch.empty(M + 1, **f64)
            w[:M] = gain * state.alpha
            w[M] = SENTINEL_WEIGHT
            RT = torch.zeros(0, 0, **f64)
            if factor.L is not None:    # exact / factored: v = k̂ (L_ext / gain)⁻ᵀ, upper-triangular solve
                FT = torch.zeros(M + 1, M + 1, **f64)
                FT[:M, :M] = factor.L.T / gain
                FT[M, M] = SENTINEL_PIVOT
                if factor.F is not None:   # factored sparse: then r = v R_extᵀ (sentinel row zero)
                    RT = torch.zeros(M + 1, M, **f64)
                    RT[:M] = factor.F.T
            else:                       # v = k̂ (gain F)ᵀ
                assert factor.F is not None  # VarianceFactor holds F, L or both
                FT = torch.zeros(M + 1, M, **f64)
                FT[:M] = (gain * factor.F).T
            signs = factor.signs if factor.signs is not None else torch.zeros(0, **f64)
        else:
            w, FT, RT, signs = share.w, share.FT, share.RT, share.signs
        self.register_buffer("w", w)
        self.register_buffer("FT", FT)
        self.register_buffer("RT", RT)
        self.register_buffer("signs", signs)
        self.signed = factor.signs is not None
        self.triangular = factor.L is not None
        self.factored = factor.L is not None and factor.F is not None
        self.var0 = float(state.y_std**2 * state.outputscale)
        # calibrated band (module docstring): G and γ over the n free columns
        s_in = state.input_std[free].to(**f64)
        rho = a[free] if self.centered else torch.ones(n_inputs, **f64)
        K = state.n_estimators
        G = torch.zeros(M + 1, n_inputs + 1 + K, **f64)
        wM = gain * state.alpha
        G[:M, :n_inputs] = wM[:, None] * W[:M, :n_inputs] * (s_in * rho)
        G[:M, n_inputs] = wM
        if K:
            G[:M, n_inputs + 1:] = (gain / K**0.5) * state.estimator_delta.to(**f64)
        self.register_buffer("G", G)
        self.register_buffer("gamma", 2.0 * W[0, n_inputs:] * s_in * rho if M > 0 else torch.zeros(n_inputs, **f64))
        self.banded = bool((s_in > 0).any()) or K > 0
        self.scale2 = float(state.std_scale) ** 2
        # linear prior mean (module docstring): l_0 + λᵀv, and its gradient's band term s ∘ y_std β̃ / x_std
        assert state.mean_slope is not None  # filled by PredictorState.__post_init__
        beta = state.mean_slope.to(**f64)
        grad_lin = state.y_std * beta / state.x_std
        x0 = state.x_mean / state.x_std
        if self.centered:
            Lv = state.y_std * beta[free] * state.lengthscale[free]
            l0 = -state.y_std * (beta[fixed] * x0[fixed]).sum()
        else:
            Lv = grad_lin[free]
            l0 = -state.y_std * (beta * x0).sum()
        # one buffer [λ, l_0] (a separate constant equal to another one would share its name in the exported code
        # and change its layout: archive_check); the flags switch the plane and its band term on where nonzero
        self.linear = state.linear_mean
        sb = s_in * grad_lin[free]
        self.plane_band = self.linear and bool((sb != 0).any())
        self.register_buffer("plane", torch.cat([Lv, l0.reshape(1)]).to(**f64).contiguous())
        self.register_buffer("sb", sb.contiguous())
        PV, PK = _plane_variance_maps(state, n_inputs, self.centered)
        self.register_buffer("PV", PV)
        self.register_buffer("PK", share.PK if share is not None and share.PK.shape == PK.shape else PK)

    def _kernel(self, x: torch.Tensor) -> torch.Tensor:
        """exp(e): ``(B, M + 1)`` kernel row / σ_f² (last column: sentinel) for ``x: (B, n)``."""
        return self._kernel_v(x)[0]

    def _kernel_v(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(exp(e), v): the kernel row and the variable v (x raw, or u centered), ``(B, n)``."""
        v = torch.addcmul(self.nb, x, self.a) if self.centered else x
        vv = torch.pow(v.unsqueeze(1), self.powers).reshape(v.size(0), 2 * self.n_inputs)   # rows [v, v∘v]
        return F.linear(vv, self.W, self.c).exp_(), v

    def _chunked(self, x: torch.Tensor) -> bool:
        # Large batches run in row blocks so the (rows, M + 1) kernel block stays in cache;
        # not while torch.export traces a dynamic batch size.
        if torch.jit.is_scripting():
            return x.size(0) > self.chunk
        return not torch.compiler.is_exporting() and x.size(0) > self.chunk

    @torch.jit.export
    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """μ(x): ``(B,)`` in q_u's unit for ``x: (B, n_inputs)`` float64 physical inputs (eq. 12)."""
        if self._chunked(x):
            out = torch.empty(x.size(0), dtype=x.dtype)
            for i in range(0, x.size(0), self.chunk):
                out[i : i + self.chunk] = self._mean(x[i : i + self.chunk])
            return out
        return self._mean(x)

    @torch.jit.export
    def mean_std(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(μ(x), σ(x)): each ``(B,)`` in q_u's unit, σ the latent posterior std (eq. 12)."""
        return self._mean_and(x, False)

    @torch.jit.export
    def mean_band(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(μ(x), σ_band(x)): each ``(B,)`` in q_u's unit, σ_band the calibrated band (module docstring, eq. B1)."""
        return self._mean_and(x, True)

    def _mean_and(self, x: torch.Tensor, band: bool) -> tuple[torch.Tensor, torch.Tensor]:
        """μ with the band (``band``) or the latent std, in row chunks for large batches."""
        if not self._chunked(x):
            return self._mean_band(x) if band else self._mean_std(x)
        mean = torch.empty(x.size(0), dtype=x.dtype)
        std = torch.empty(x.size(0), dtype=x.dtype)
        for i in range(0, x.size(0), self.chunk):
            xi = x[i : i + self.chunk]
            mean[i : i + self.chunk], std[i : i + self.chunk] = self._mean_band(xi) if band else self._mean_std(xi)
        return mean, std

    def _latent_var(self, k: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Latent variance (eq. 12), with the plane coefficients' term (eq. L3) when there is a plane."""
        var = self._kernel_var(k)
        if self.linear:
            t = torch.addmm(self.PV[-1], v, self.PV[:-1]) - torch.mm(k, self.PK)
            var = var + torch.linalg.vecdot(t, t)
        return var

    def _kernel_var(self, k: torch.Tensor) -> torch.Tensor:
        if self.triangular:
            v = torch.linalg.solve_triangular(self.FT, k, upper=True, left=False)
            if self.factored:
                v = torch.mm(v, self.RT)
        else:
            v = torch.mm(k, self.FT)
        if self.signed:
            q = torch.mv(v * v, self.signs)
        else:
            q = torch.linalg.vecdot(v, v)
        return torch.rsub(q, self.var0).clamp_min_(0.0)

    def _plane(self, mean: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """``mean`` plus the linear prior mean l_0 + λᵀv (module docstring), when there is one."""
        if self.linear:
            return mean + torch.addmv(self.plane[-1:], v, self.plane[:-1])
        return mean

    def _mean_band(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        k, v = self._kernel_v(x)
        mean = self._plane(torch.addmv(self.offset, k, self.w), v)
        var = self._latent_var(k, v)
        if self.banded:
            h = torch.mm(k, self.G)
            n = self.n_inputs
            g = torch.addcmul(h[:, :n], v * h[:, n : n + 1], self.gamma)
            if self.plane_band:
                g = g + self.sb
            e = h[:, n + 1 :]
            extra = torch.maximum(torch.linalg.vecdot(g, g), torch.linalg.vecdot(e, e))
            return mean, torch.add(extra, var, alpha=self.scale2).sqrt_()
        return mean, var.mul_(self.scale2).sqrt_()

    def _mean(self, x: torch.Tensor) -> torch.Tensor:
        k, v = self._kernel_v(x)
        return self._plane(torch.addmv(self.offset, k, self.w), v)

    def _mean_std(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        k, v = self._kernel_v(x)
        return self._plane(torch.addmv(self.offset, k, self.w), v), self._latent_var(k, v).sqrt_()


def _plane_variance_maps(state: PredictorState, n_inputs: int, centered: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """``PV`` ``(n + 1, p)`` = [T_v; t_0] and ``PK`` ``(M + 1, p)`` = T_k of the plane coefficients' variance
    (module docstring; one zero column without the term)."""
    f64: dict[str, Any] = dict(dtype=torch.float64)
    d, M = state.dim, state.n_support
    if not state.plane_variance:   # one zero column (a frozen TorchScript module cannot hold a row view of an empty PV)
        return torch.zeros(n_inputs + 1, 1, **f64), torch.zeros(M + 1, 1, **f64)
    assert state.plane_weights is not None and state.plane_cov is not None
    lam, vec = torch.linalg.eigh(state.plane_cov.to(**f64))
    keep = lam > lam.max() * 1e-14
    R = state.y_std * vec[:, keep] * lam[keep].sqrt()        # (d, p): y_std² A = R Rᵀ
    free, fixed = slice(0, n_inputs), slice(n_inputs, d)
    x0 = state.x_mean / state.x_std                           # x̃ = x / x_std − x0
    PV = torch.zeros(n_inputs + 1, R.shape[1], **f64)
    if centered:                                              # x̃ = ℓ ∘ u on the free columns
        PV[:n_inputs] = state.lengthscale[free, None] * R[free]
        PV[n_inputs] = -(x0[fixed, None] * R[fixed]).sum(0)
    else:
        PV[:n_inputs] = R[free] / state.x_std[free, None]
        PV[n_inputs] = -(x0[:, None] * R).sum(0)
    PK = torch.zeros(M + 1, R.shape[1], **f64)
    PK[:M] = state.outputscale * (state.plane_weights.to(**f64) @ R)
    return PV.contiguous(), PK.contiguous()
