"""The frozen posterior of a trained GP, in the one form every predictor kind shares.

For an ARD squared-exponential kernel (eq. 11)

    k(x, x') = σ_f² exp(−½ (x − x')ᵀ W (x − x')),   W = diag(1/ℓ²),

the posterior of every bemlearn GP kind (exact, sgpr, svgp) at a *normalized* input
x̃ = (x − x_mean) / x_std is, with k_Z(x̃) = k(x̃, Z) ∈ R^M,

    μ̃(x̃)  = k_Z(x̃)ᵀ α                          (eq. 12, mean)
    σ̃²(x̃) = σ_f² − k_Z(x̃)ᵀ S k_Z(x̃)             (eq. 12, latent variance)

    exact:  Z = X (training inputs), α = K⁻¹ Y,      S = K⁻¹,  K = K_XX + σ_0² I
    sgpr:   Z = inducing points,     α = Σ K_ZX Y / σ_0²,  S = K_ZZ⁻¹ − Σ,
            Σ = (K_ZZ + σ_0⁻² K_ZX K_XZ)⁻¹               (Titsias, 2009)
    svgp:   Z = inducing points, q(u) = N(μ_u, S_u) (un-whitened),
            α = K_ZZ⁻¹ μ_u,  S = K_ZZ⁻¹ − K_ZZ⁻¹ S_u K_ZZ⁻¹

A sparse S is also held *factored* (``S_chol`` L, ``S_inner`` C; states frozen before these
fields have only S):

    S = L⁻ᵀ C L⁻¹,   L Lᵀ = K_ZZ + j I (the jitter actually used),   σ̃² = σ_f² − vᵀ C v,  v = L⁻¹ k_Z

    sgpr:  C = I − B⁻¹,  B = I + A Aᵀ, A = L⁻¹ K_ZX / σ_0  (eigenvalues in [0, 1))
    svgp:  C = I − S_v,  S_v the whitened q(v) covariance  (possibly indefinite)

With κ(K_ZZ) of 10¹⁰ and more (near-linear BEMs, large σ_f²) the explicit S = L⁻ᵀ C L⁻¹ has
lost the digits of the small variances near the data (kᵀ S k ≈ σ_f² there); v from a
triangular solve and the well-conditioned C keep them.  When the factor is present it is
authoritative and S is only its explicit product.

and in physical units μ(x) = y_mean + y_std μ̃(x̃), σ(x) = y_std σ̃(x̃).

A *linear prior mean* (``mean_slope`` β̃, :mod:`bemlearn.fitting.linear_mean`) puts the GP on the
residual of a least-squares plane: the label is modelled as ỹ = β̃ᵀx̃ + f(x̃), so

    μ̃(x̃) = β̃ᵀx̃ + k_Z(x̃)ᵀ α                     (L1)

with α the weights of the residual ỹ − β̃ᵀx̃ (the training columns are centred by the normalization,
so the plane needs no intercept).  β̃ = 0 (the default) is the zero-mean GP of eq. (11).  The plane's
coefficients are uncertain too; with a vague prior on them (Rasmussen & Williams 2006, §2.7) the latent
variance gains

    σ̃²(x̃) += rᵀ A r,   r = x̃ − Pᵀ k_Z(x̃),   P = K⁻¹H,   A = (Hᵀ K⁻¹ H)⁻¹             (L3)

(H the training rows' plane columns, K = K_ZZ + σ_0² I; ``plane_weights`` P and ``plane_cov`` A, embedded in
d columns with zeros where β̃_j = 0, :mod:`bemlearn.models.plane_posterior`).  Near the data Pᵀk_Z ≈ x̃ and
the term vanishes; beyond them r → x̃ and it grows with the distance, where the plane is extrapolated.  The
term is the covariance of the generalized-least-squares coefficients β̄ = A Hᵀ K⁻¹ ỹ (eq. L4), and a state
that carries it holds β̃ = β̄ (the plane of (L1) moved to (L4) once the kernel is fitted, α with it); the
replica calibration c (which refits the plane on each replica the same way) scales the variance the term is
part of.  Without ``plane_cov`` (zero mean, a sparse kind, or a state frozen before it) there is no term,
and β̃ is the ordinary least-squares plane of (L1).

The calibrated band (docs/uncertainty.md) adds three fields: ``std_scale`` c (trial-split
replica calibration, :mod:`bemlearn.fitting.calibration`), ``input_std`` s (the
derivative estimator's quantization noise in each input column, :mod:`bemlearn.models.input_noise`)
and ``estimator_delta`` δ (how the mean weights move under the neighbouring derivative
estimators, :mod:`bemlearn.fitting.estimator_sensitivity`, and with the draw of the training rows,
:mod:`bemlearn.fitting.resample_sensitivity`):

    σ_band(x)² = c² y_std² σ̃²(x̃) + max(Σ_{i ∈ inputs} (s_i ∂μ/∂x_i)², (1/K) Σ_k (y_std k_Z(x̃)ᵀ δ_k)²)

over the columns the caller supplies (3m at x_0^e, all d for the full map).  Defaults
c = 1, s = 0, K = 0 give σ_band = σ (checkpoints written before these fields).  S need not be
positive definite (sgpr/svgp); it is symmetric.  The observation noise σ_0² is kept for
predictive (noisy) variances but is *not* part of σ̃² above.

This is what export (TorchScript / torch.export) consumes; it holds plain float64
tensors and nothing of GPyTorch.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

import torch

from bemlearn.errors import CheckpointError
from bemlearn.models.gp_kinds import GP_KINDS, gp_class
from bemlearn.models.kernels import se_gram, se_kernel

__all__ = ["PredictorState", "GPKind"]

#: The registered GP kind names (:data:`~bemlearn.models.gp_kinds.GP_KINDS`), as a type.
GPKind = Literal["exact", "sgpr", "svgp"]


@dataclass(frozen=True)
class PredictorState:
    """A GP posterior frozen for prediction (see module docstring for the formulas).

    Attributes:
        kind: ``"exact"``, ``"sgpr"`` or ``"svgp"``: a name of :data:`~bemlearn.models.gp_kinds.GP_KINDS`.
        Z: ``(M, d)`` normalized support inputs (training inputs for exact, inducing points otherwise).
        alpha: ``(M,)`` mean weights, normalized output units.
        S: ``(M, M)`` symmetric variance matrix, σ̃² = σ_f² − kᵀ S k.
        lengthscale: ``(d,)`` ARD lengthscales ℓ in normalized input units (W = diag(ℓ⁻²)).
        outputscale: ``()`` σ_f² (normalized output units squared).
        noise: ``()`` σ_0² (normalized output units squared).
        x_mean: ``(d,)`` input normalization's mean, physical units of each column.
        x_std: ``(d,)`` input normalization's std, physical units of each column.
        y_mean: ``()`` output normalization's mean, in q_u's unit (rad for a hinge, m for a slide).
        y_std: ``()`` output normalization's std, in q_u's unit.
        input_names: the d column names, in order, e.g. ``("qdd_theta", ..., "qd_alpha")``.
        n_train: number of training points the posterior was conditioned on.
        std_scale: ``()`` c ≥ 1 of the calibrated band (default 1).
        input_std: ``(d,)`` s ≥ 0, noise std of each input column, physical units (default 0).
        estimator_delta: ``(M, K)`` δ, the mean weights' shift columns of the band, normalized output units: one
            per neighbouring derivative estimator, and after ``bemlearn train`` one more for the mean's deviation
            from other draws of its training rows (eq. R2), scaled so that their mean square is the sum of both
            terms' variances (default K = 0: no such term).
        S_chol: ``(M, M)`` lower-triangular L, L Lᵀ = K_ZZ + j I (sparse kinds), or ``None``.
        S_inner: ``(M, M)`` symmetric C with S = L⁻ᵀ C L⁻¹ (given with ``S_chol``), or ``None``.
        mean_slope: ``(d,)`` β̃ of the linear prior mean (L1), normalized output per normalized input
            (default zeros: the zero-mean GP).
        plane_weights: ``(M, d)`` P = K⁻¹H of (L3), normalized units (zero columns where β̃_j = 0), or ``None``.
        plane_cov: ``(d, d)`` A = (Hᵀ K⁻¹ H)⁻¹ of (L3), the plane coefficients' covariance in normalized output
            units squared (zero rows and columns where β̃_j = 0), given with ``plane_weights``, or ``None``
            (no coefficient term).
    """

    kind: GPKind
    Z: torch.Tensor
    alpha: torch.Tensor
    S: torch.Tensor
    lengthscale: torch.Tensor
    outputscale: torch.Tensor
    noise: torch.Tensor
    x_mean: torch.Tensor
    x_std: torch.Tensor
    y_mean: torch.Tensor
    y_std: torch.Tensor
    input_names: tuple[str, ...]
    n_train: int
    std_scale: torch.Tensor | None = None
    input_std: torch.Tensor | None = None
    estimator_delta: torch.Tensor | None = None
    S_chol: torch.Tensor | None = None
    S_inner: torch.Tensor | None = None
    mean_slope: torch.Tensor | None = None
    plane_weights: torch.Tensor | None = None
    plane_cov: torch.Tensor | None = None

    def __post_init__(self) -> None:
        if self.kind not in GP_KINDS:
            raise CheckpointError(f"PredictorState.kind: unknown {self.kind!r}; valid kinds are {sorted(GP_KINDS)}")
        M, d = self.Z.shape
        if self.std_scale is None:
            object.__setattr__(self, "std_scale", torch.ones((), dtype=self.Z.dtype, device=self.Z.device))
        if self.input_std is None:
            object.__setattr__(self, "input_std", torch.zeros(d, dtype=self.Z.dtype, device=self.Z.device))
        if self.estimator_delta is None or (self.estimator_delta.ndim == 2 and self.estimator_delta.shape[1] == 0):
            # the empty default carries no information; it follows Z (e.g. through dataclasses.replace)
            object.__setattr__(self, "estimator_delta", torch.zeros(M, 0, dtype=self.Z.dtype, device=self.Z.device))
        if self.mean_slope is None:
            object.__setattr__(self, "mean_slope", torch.zeros(d, dtype=self.Z.dtype, device=self.Z.device))
        assert self.std_scale is not None and self.input_std is not None and self.estimator_delta is not None
        assert self.mean_slope is not None
        checks = {
            "alpha": (self.alpha, (M,)),
            "S": (self.S, (M, M)),
            "lengthscale": (self.lengthscale, (d,)),
            "outputscale": (self.outputscale, ()),
            "noise": (self.noise, ()),
            "x_mean": (self.x_mean, (d,)),
            "x_std": (self.x_std, (d,)),
            "y_mean": (self.y_mean, ()),
            "y_std": (self.y_std, ()),
            "std_scale": (self.std_scale, ()),
            "input_std": (self.input_std, (d,)),
            "mean_slope": (self.mean_slope, (d,)),
            "estimator_delta": (self.estimator_delta, (M, int(self.estimator_delta.shape[-1]) if self.estimator_delta.ndim == 2 else "K")),
        }
        for name, (t, shape) in checks.items():
            if tuple(t.shape) != shape:
                raise CheckpointError(f"PredictorState.{name}: expected shape {shape}, got {tuple(t.shape)}")
        if len(self.input_names) != d:
            raise CheckpointError(f"PredictorState.input_names: expected {d} names, got {len(self.input_names)}")
        self._check_factor(M)
        self._check_plane(M, d)

    def _check_plane(self, M: int, d: int) -> None:
        """plane_weights, plane_cov of (L3): both or neither, (M, d) and a symmetric (d, d), only with a plane."""
        if self.plane_weights is None and self.plane_cov is None:
            return
        if self.plane_weights is None or self.plane_cov is None:
            raise CheckpointError("PredictorState.plane_weights, plane_cov: give both (eq. L3) or neither")
        for name, shape in (("plane_weights", (M, d)), ("plane_cov", (d, d))):
            t = getattr(self, name)
            if tuple(t.shape) != shape:
                raise CheckpointError(f"PredictorState.{name}: expected shape {shape}, got {tuple(t.shape)}")
        if not bool(torch.equal(self.plane_cov, self.plane_cov.mT)):
            raise CheckpointError("PredictorState.plane_cov: expected a symmetric matrix (A = Aᵀ exactly)")
        if not self.linear_mean:
            raise CheckpointError("PredictorState.plane_weights, plane_cov: the coefficient term (L3) needs a plane "
                                  "(some mean_slope ≠ 0)")

    @property
    def plane_variance(self) -> bool:
        """Whether the latent variance carries the plane coefficients' term rᵀAr of (L3)."""
        return self.plane_cov is not None and bool((self.plane_cov != 0).any())

    @property
    def plane_estimate(self) -> str | None:
        """How the plane's coefficients were estimated: ``"generalized least squares"`` where the state carries their
        variance (eq. L4), ``"least squares"`` otherwise (eq. L1), ``None`` without a plane."""
        if not self.linear_mean:
            return None
        return "generalized least squares" if self.plane_variance else "least squares"

    def plane_term(self, x: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
        """rᵀ A r of (L3): ``(B,)`` in normalized output units squared, for physical ``x: (B, d)`` and their kernel
        row ``k: (B, M)`` (zeros without the term)."""
        if not self.plane_variance:
            return torch.zeros(k.shape[0], dtype=k.dtype, device=k.device)
        assert self.plane_weights is not None and self.plane_cov is not None
        r = self.normalize(x) - k @ self.plane_weights
        return ((r @ self.plane_cov) * r).sum(-1)

    def _check_factor(self, M: int) -> None:
        """S_chol, S_inner: both or neither, sparse kinds only, (M, M), L lower-triangular with a
        positive diagonal, C symmetric."""
        if self.S_chol is None and self.S_inner is None:
            return
        if self.S_chol is None or self.S_inner is None:
            raise CheckpointError("PredictorState.S_chol, S_inner: give both (S = L⁻ᵀ C L⁻¹) or neither")
        if not self.sparse:
            raise CheckpointError("PredictorState.S_chol, S_inner: only for the sparse kinds (sgpr, svgp); an exact "
                             "posterior solves with the Cholesky factor of K_ZZ + σ_0² I (gram_cholesky)")
        for name in ("S_chol", "S_inner"):
            t = getattr(self, name)
            if tuple(t.shape) != (M, M):
                raise CheckpointError(f"PredictorState.{name}: expected shape {(M, M)}, got {tuple(t.shape)}")
        L, C = self.S_chol, self.S_inner
        if bool((torch.triu(L, 1) != 0).any()) or not bool((torch.diagonal(L) > 0).all()):
            raise CheckpointError("PredictorState.S_chol: expected a lower-triangular Cholesky factor with a positive diagonal")
        if not bool(torch.equal(C, C.mT)):
            raise CheckpointError("PredictorState.S_inner: expected a symmetric matrix (C = Cᵀ exactly)")

    @property
    def sparse(self) -> bool:
        """Whether the support Z are inducing inputs (sgpr, svgp: S may be factored) rather than the
        training inputs (exact: S = (K_ZZ + σ_0² I)⁻¹, solved with :meth:`gram_cholesky`); the kind's
        ``sparse`` (:mod:`bemlearn.models.gp_kinds`)."""
        return gp_class(self.kind).sparse

    @property
    def n_support(self) -> int:
        return int(self.Z.shape[0])

    @property
    def dim(self) -> int:
        return int(self.Z.shape[1])

    @property
    def n_estimators(self) -> int:
        """K, the neighbouring derivative estimators of the band's estimator term (0: none)."""
        assert self.estimator_delta is not None  # filled by __post_init__
        return int(self.estimator_delta.shape[1])

    def tensors(self) -> dict[str, torch.Tensor]:
        """All tensor fields by name (for ``torch.save`` / ``weights_only`` loading)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if isinstance(getattr(self, f.name), torch.Tensor)}

    def to_dict(self) -> dict:
        """A ``torch.load(weights_only=True)``-safe dict (tensors, str, int, tuples)."""
        out: dict = dict(self.tensors())
        out["kind"] = self.kind
        out["input_names"] = list(self.input_names)
        out["n_train"] = int(self.n_train)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> PredictorState:
        kw = dict(data)
        kw["input_names"] = tuple(kw["input_names"])
        return cls(**kw)

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> PredictorState:
        moved: dict[str, Any] = {k: v.to(device=device, dtype=dtype) for k, v in self.tensors().items()}
        return dataclasses.replace(self, **moved)

    @property
    def linear_mean(self) -> bool:
        """Whether the prior mean is the plane β̃ᵀx̃ of (L1) (some β̃_i ≠ 0) rather than zero."""
        assert self.mean_slope is not None  # filled by __post_init__
        return bool((self.mean_slope != 0).any())

    def prior_mean(self, x: torch.Tensor) -> torch.Tensor:
        """y_std β̃ᵀx̃ of (L1): ``(B,)`` in q_u's unit for ``x: (B, d)`` physical inputs (zeros for a zero mean);
        μ = y_mean + prior_mean(x) + y_std k_Z(x̃)ᵀα."""
        assert self.mean_slope is not None  # filled by __post_init__
        return self.y_std * (self.normalize(x) @ self.mean_slope)

    def prior_mean_gradient(self) -> torch.Tensor:
        """∂(prior_mean)/∂x = y_std β̃ / x_std: ``(d,)``, q_u's unit per input unit (constant)."""
        assert self.mean_slope is not None  # filled by __post_init__
        return self.y_std * self.mean_slope / self.x_std

    def label_residual(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """ỹ − β̃ᵀx̃, the normalized label the kernel part of (L1) is conditioned on: ``(N,)`` for physical
        ``x: (N, d)`` and ``y: (N,)`` in q_u's unit."""
        yn = (y.to(torch.float64) - self.y_mean) / self.y_std
        assert self.mean_slope is not None  # filled by __post_init__
        return yn - self.normalize(x.to(torch.float64)) @ self.mean_slope

    @property
    def factored(self) -> bool:
        """Whether S is held as L⁻ᵀ C L⁻¹ (``S_chol``, ``S_inner``; sparse kinds)."""
        return self.S_chol is not None

    def gram(self) -> torch.Tensor:
        """K = K_ZZ + σ_0² I, K_ij = σ_f² exp(−½ ‖(z_i − z_j)/ℓ‖²) (eq. 11, :func:`~bemlearn.models.kernels.se_gram`);
        ``(M, M)``, normalized units."""
        K = se_gram(self.Z, self.lengthscale, self.outputscale)
        K.diagonal().add_(self.noise)
        return K

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        """x̃ = (x − x_mean) / x_std: ``(B, d)`` normalized inputs for ``x: (B, d)`` physical inputs."""
        return (x - self.x_mean) / self.x_std

    def kernel_row(self, x: torch.Tensor) -> torch.Tensor:
        """k_Z(x̃) = σ_f² exp(−½ ‖(x̃ − z_j)/ℓ‖²) (eq. 11, :func:`~bemlearn.models.kernels.se_kernel`):
        ``(B, M)`` for ``x: (B, d)`` physical inputs."""
        return se_kernel(self.normalize(x), self.Z, self.lengthscale, self.outputscale)

    def gram_cholesky(self) -> torch.Tensor | None:
        """L with L Lᵀ = K_ZZ + σ_0² I (exact kind; computed once per state), or ``None`` for the
        sparse kinds or when K is not numerically positive definite."""
        if self.sparse:
            return None
        cached = self.__dict__.get("_gram_cholesky")
        if cached is None:
            L, info = torch.linalg.cholesky_ex(self.gram())
            cached = (L if int(info) == 0 else None,)
            object.__setattr__(self, "_gram_cholesky", cached)
        return cached[0]

    # Reference (slow, obvious) evaluation, used by tests as the common ground truth.
    def predict_reference(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and latent std in physical units for ``x``: ``(B, d)`` physical inputs.

        For an exact GP the variance is σ_f² − ‖L⁻¹k‖² with L the Cholesky factor of
        K = K_ZZ + σ_0² I (a triangular solve, as the exported predictor does), not kᵀ S k with
        the explicit inverse S: with κ(K) ≳ 10⁹ (near-linear BEMs with a large outputscale) the
        explicit form loses all digits of the small variances near the data and returns 0.
        Factored sparse states likewise: σ_f² − vᵀ C v with v = L⁻¹ k (``S_chol``, ``S_inner``);
        sparse states without the factor (frozen before it existed) use S as given.

        Returns:
            mean ``(B,)`` and std ``(B,)`` in q_u's unit.
        """
        mean, std, _ = self.reference_terms(x)
        return mean, std

    def reference_terms(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`predict_reference`'s mean ``(B,)`` and std ``(B,)`` with the kernel row k_Z(x̃) ``(B, M)`` they
        came from, for the terms of the band (eq. B1) that use it again (∂μ/∂x, the estimator shifts)."""
        k = self.kernel_row(x)
        mean = k @ self.alpha
        L = self.gram_cholesky()
        if L is not None:
            v = torch.linalg.solve_triangular(L, k.mT, upper=False)
            var = self.outputscale - (v * v).sum(0)
        elif self.S_chol is not None:
            v = torch.linalg.solve_triangular(self.S_chol, k.mT, upper=False)
            var = self.outputscale - (v * (self.S_inner @ v)).sum(0)
        else:
            var = self.outputscale - ((k @ self.S) * k).sum(-1)
        std = (var.clamp_min(0.0) + self.plane_term(x, k)).sqrt()   # (L3) is a quadratic form of A ⪰ 0
        return self.y_mean + self.y_std * mean + self.prior_mean(x), self.y_std * std, k
