"""Gaussian process dynamical model (GPDM) with a 1-D latent tied to the joints by χ = c·q.

Paper Section III-C, eq. (16)–(17); Wang, Fleet & Hertzmann, "Gaussian Process Dynamical
Models for Human Motion", TPAMI 2008 (GPDM); Urtasun, Fleet & Fua, CVPR 2006 (balanced
GPDM).  The latent χ ∈ R is the zero-dynamics (gait phase) coordinate of eq. (16):

    S_l:  χ_t = f(χ_{t−1}, …, χ_{t−p}) + w_f,    q_t = g(χ_t) + w_g,

in discrete time with order p ∈ {1, 2} (p = 1 maps χ_{t−1} → χ_t; p = 2 maps
[χ_{t−1}, χ_{t−2}] → χ_t).  Joint data q ∈ R^n are centered (and optionally scaled) per
joint, ỹ = (q − q̄) / s, and the model minimizes the modified eq. (17)

    L = −log p(Ỹ | X, β, W) + (D/d) · (−log p(X | α)) + λ ‖X − Ỹ c̃‖²,

    −log p(Ỹ | X, β, W) = D/2 log|K_Y| + ½ tr(K_Y⁻¹ Ỹ W² Ỹᵀ) − N log|W| + ND/2 log 2π,
        K_Y = exp(−(χ − χ')² / (2ℓ_g²)) + σ_g² I,  W = diag(w_1 … w_D),
    −log p(X | α) = ½ log|K_X| + ½ X_outᵀ K_X⁻¹ X_out + ½ Σ χ_first² + const,
        k_X(z, z') = σ_f² exp(−½ Σ_k (z_k − z'_k)² / ℓ_k²) + Σ_k a_k z_k z'_k + σ_f,n² δ,

where X_out stacks the latents that have p predecessors in their sequence, z the lag
vectors [χ_{t−1}, …, χ_{t−p}] (the RBF + linear dynamics kernel of Wang 2008, with one
lengthscale and one linear weight per lag), and χ_first the first p latents of each
sequence, which get an N(0, 1) prior.  D = n (joint dimension), d = 1 (latent
dimension): the balanced GPDM raises the dynamics density to the power D/d, i.e. the
whole dynamics negative log likelihood (log-determinant, quadratic and first-point
terms) is multiplied by D/d (Urtasun 2006).  Hyperparameters get flat priors (Wang's
1/θ priors are omitted).  The observation kernel has unit signal variance: a free one
would be redundant with W.  The penalty is applied in normalized joint units.

Transitions exist only inside a sequence: with sequences of lengths T_i the dynamics GP
sees Σ_i (T_i − p) input/output pairs (one dynamics function shared by all sequences).

Scale and sign: ‖X − Ỹc̃‖² alone is minimized by shrinking X and c̃ together, so c̃ is
kept on the unit sphere (c̃ = v / ‖v‖, in normalized joint units); X then follows the
projection Ỹc̃ whose scale is fixed by the data.  The objective is invariant under
(X, c̃) → (−X, −c̃); :meth:`GPDM.canonicalize_sign_` picks the sign whose largest-magnitude
entry of c̃ is positive.  In physical joint units χ = c·(q − q̄) with c = c̃ / s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal, NamedTuple

import torch
from gpytorch.constraints import GreaterThan, Interval, Positive
from torch import Tensor, nn

from bemlearn.errors import ArgumentError, DataError
from bemlearn.models.solver import robust_cholesky
from bemlearn.models.validation import check_inputs

__all__ = ["GPDM", "GPDMObjective", "LatentComparison", "reconstruct_latent", "compare_latents"]

_LOG_2PI = math.log(2.0 * math.pi)
_DTYPE = torch.float64


class GPDMObjective(NamedTuple):
    """The terms of the modified eq. (17); ``total`` is what is minimized (all scalars)."""

    total: Tensor
    observation: Tensor  # −log p(Ỹ | X, β, W)
    dynamics: Tensor  # −log p(X | α), unweighted
    penalty: Tensor  # ‖X − Ỹ c̃‖², unweighted


def _sq_dist(a: Tensor, b: Tensor) -> Tensor:
    """Pairwise squared distances of ``a``: (N, p) and ``b``: (M, p) → (N, M)."""
    return ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)


def _cholesky(K: Tensor, noise: Tensor, jitter: float, what: str) -> Tensor:
    """Lower Cholesky factor of K + noise·I (jittered retries by :func:`robust_cholesky`)."""
    eye = torch.eye(K.shape[0], dtype=K.dtype, device=K.device)
    return robust_cholesky(K + noise * eye, what=f"GPDM {what} kernel matrix", jitter=jitter)[0]


def _as_sequences(Q_list: Sequence, order: int) -> list[Tensor]:
    """Check and convert ``Q_list`` (sequences of (T_i, n) joint angles) to float64 tensors."""
    if isinstance(Q_list, (Tensor, str, bytes)) or not isinstance(Q_list, Sequence) or len(Q_list) == 0:
        raise ArgumentError("Q_list: expected a non-empty list of (T_i, n) arrays, one per sequence")
    seqs: list[Tensor] = []
    for i, q in enumerate(Q_list):
        n = seqs[0].shape[1] if seqs else None
        q = check_inputs(torch.as_tensor(q, dtype=_DTYPE), name=f"Q_list[{i}]", dim=n)
        if q.shape[0] < order + 1:
            raise DataError(
                f"Q_list[{i}]: a sequence needs at least order + 1 = {order + 1} samples for one "
                f"transition of the order-{order} dynamics, got {q.shape[0]}"
            )
        seqs.append(q)
    return seqs


class GPDM(nn.Module):
    """GPDM with a 1-D latent and the ‖X − c̃Ỹ‖² penalty (modified eq. 17); see module docstring.

    Args:
        Q_list: one (T_i, n) array per sequence, joint angles in rad (any float dtype;
            stored as float64).  Sequences are independent dynamics chains.
        order: dynamics order p (1: χ_{t−1} → χ_t, 2: [χ_{t−1}, χ_{t−2}] → χ_t).
        penalty: λ ≥ 0, weight of ‖X − Ỹc̃‖² (normalized units).
        dynamics_weight: weight of −log p(X | α); ``None`` is the balanced D/d = n.
        scale_joints: divide each centered joint by its standard deviation (else s = 1).
        init: start of c̃: ``"slow"`` (the slowest linear projection, see
            :meth:`slowest_direction`), ``"pca"`` (first principal direction of Ỹ) or
            ``"random"`` (seeded uniform direction); X starts at Ỹc̃ in every case.
        seed: seed of the ``"random"`` initialization.
        jitter: first diagonal jitter of :func:`robust_cholesky` when a kernel matrix
            (which already includes its noise variance) fails to factorize.
    """

    # buffers, raw parameters and their constraints (registered in __init__; declared for the type checker)
    q_mean: Tensor
    q_scale: Tensor
    Y: Tensor
    dyn_in_idx: Tensor
    dyn_out_idx: Tensor
    first_idx: Tensor
    raw_obs_lengthscale: nn.Parameter
    raw_obs_lengthscale_constraint: Interval
    raw_obs_noise: nn.Parameter
    raw_obs_noise_constraint: Interval
    raw_obs_w: nn.Parameter
    raw_obs_w_constraint: Interval
    raw_dyn_lengthscale: nn.Parameter
    raw_dyn_lengthscale_constraint: Interval
    raw_dyn_outputscale: nn.Parameter
    raw_dyn_outputscale_constraint: Interval
    raw_dyn_linear: nn.Parameter
    raw_dyn_linear_constraint: Interval
    raw_dyn_noise: nn.Parameter
    raw_dyn_noise_constraint: Interval

    def __init__(
        self,
        Q_list: Sequence,
        *,
        order: Literal[1, 2] = 1,
        penalty: float = 100.0,
        dynamics_weight: float | None = None,
        scale_joints: bool = True,
        init: Literal["slow", "pca", "random"] = "slow",
        seed: int = 0,
        jitter: float = 1e-8,
    ) -> None:
        super().__init__()
        if order not in (1, 2):
            raise ArgumentError(f"order: expected 1 or 2, got {order!r}")
        if init not in ("slow", "pca", "random"):
            raise ArgumentError(f"init: expected 'slow', 'pca' or 'random', got {init!r}")
        for name, value in (("penalty", penalty), ("dynamics_weight", dynamics_weight), ("jitter", jitter)):
            if value is not None and not value >= 0:
                raise ArgumentError(f"{name}: expected ≥ 0, got {value}")
        seqs = _as_sequences(Q_list, order)
        Q = torch.cat(seqs)
        n = Q.shape[1]
        self.order, self.penalty_weight, self.jitter = order, float(penalty), float(jitter)
        self.dynamics_weight = float(n if dynamics_weight is None else dynamics_weight)
        self.lengths = [int(q.shape[0]) for q in seqs]

        q_mean, q_std = Q.mean(0), Q.std(0)
        const = (q_std <= 1e-12 * (1.0 + q_mean.abs())).nonzero().flatten().tolist()
        if const:
            raise DataError(f"Q_list: joint column(s) {const} are constant over all samples; remove them")
        q_scale = q_std if scale_joints else torch.ones_like(q_std)
        self.register_buffer("q_mean", q_mean)  # (n,) rad
        self.register_buffer("q_scale", q_scale)  # (n,) rad
        self.register_buffer("Y", (Q - q_mean) / q_scale)  # (N, n) normalized joints
        self._build_transitions()

        if init == "slow":
            c0 = self.slowest_direction()
        elif init == "pca":
            c0 = torch.linalg.svd(self.Y, full_matrices=False).Vh[0]
        else:
            gen = torch.Generator().manual_seed(seed)
            c0 = torch.randn(n, generator=gen, dtype=_DTYPE)
            c0 = c0 / c0.norm()
        x0 = self.Y @ c0
        self.c_raw = nn.Parameter(c0.clone())  # (n,), direction of c̃ (any norm)
        self.X = nn.Parameter(x0.clone())  # (N,) stacked latents, normalized units

        self._constrained("obs_lengthscale", Positive(), x0.std())
        self._constrained("obs_noise", GreaterThan(1e-6), torch.tensor(1e-2))
        self._constrained("obs_w", Positive(), 1.0 / self.Y.std(0))
        self._constrained("dyn_lengthscale", Positive(), torch.full((order,), float(x0.std())))
        self._constrained("dyn_outputscale", Positive(), x0.var())
        self._constrained("dyn_linear", Positive(), torch.full((order,), 1.0 / order))
        self._constrained("dyn_noise", GreaterThan(1e-6), torch.tensor(1e-2) * x0.var())
        self.canonicalize_sign_()

    # -- parameters ------------------------------------------------------------------
    def _constrained(self, name: str, constraint: Interval, value: Tensor) -> None:
        """Register ``raw_<name>`` with ``constraint``; ``self.<name>`` is the constrained value."""
        value = torch.as_tensor(value, dtype=_DTYPE)
        self.register_parameter(f"raw_{name}", nn.Parameter(constraint.inverse_transform(value)))
        self.register_module(f"raw_{name}_constraint", constraint)

    @property
    def obs_lengthscale(self) -> Tensor:
        """ℓ_g: () observation RBF lengthscale, latent units."""
        return self.raw_obs_lengthscale_constraint.transform(self.raw_obs_lengthscale)

    @property
    def obs_noise(self) -> Tensor:
        """σ_g²: () observation noise variance, relative to the unit signal variance."""
        return self.raw_obs_noise_constraint.transform(self.raw_obs_noise)

    @property
    def obs_w(self) -> Tensor:
        """W: (n,) per-joint scales w_j (Ỹ_j has prior variance 1/w_j²), 1/normalized units."""
        return self.raw_obs_w_constraint.transform(self.raw_obs_w)

    @property
    def dyn_lengthscale(self) -> Tensor:
        """ℓ: (p,) dynamics RBF lengthscales per lag, latent units."""
        return self.raw_dyn_lengthscale_constraint.transform(self.raw_dyn_lengthscale)

    @property
    def dyn_outputscale(self) -> Tensor:
        """σ_f²: () dynamics RBF signal variance, latent units²."""
        return self.raw_dyn_outputscale_constraint.transform(self.raw_dyn_outputscale)

    @property
    def dyn_linear(self) -> Tensor:
        """a: (p,) dynamics linear-kernel variances per lag, dimensionless."""
        return self.raw_dyn_linear_constraint.transform(self.raw_dyn_linear)

    @property
    def dyn_noise(self) -> Tensor:
        """σ_f,n²: () dynamics noise variance, latent units²."""
        return self.raw_dyn_noise_constraint.transform(self.raw_dyn_noise)

    def _build_transitions(self) -> None:
        """Index buffers of the dynamics pairs, never crossing a sequence boundary."""
        p, ins, outs, firsts, start = self.order, [], [], [], 0
        for T in self.lengths:
            t = torch.arange(start + p, start + T)
            outs.append(t)
            ins.append(torch.stack([t - k for k in range(1, p + 1)], dim=1))
            firsts.append(torch.arange(start, start + p))
            start += T
        self.register_buffer("dyn_in_idx", torch.cat(ins))  # (M, p): [t−1, …, t−p]
        self.register_buffer("dyn_out_idx", torch.cat(outs))  # (M,): t
        self.register_buffer("first_idx", torch.cat(firsts))  # (S·p,)

    def slowest_direction(self) -> Tensor:
        """Unit (n,) c̃ minimizing Σ_t (c̃·(ỹ_t − ỹ_{t−1}))² / Σ_t (c̃·ỹ_t)², t within sequences.

        The slow-feature direction, the default start of c̃: a gait phase varies slowly
        and steadily while the curved joint motions around it vary faster, so this lands
        near the phase direction even when that direction carries little of the variance
        (where the first principal direction does not).  Solved as a generalized
        symmetric eigenproblem by whitening Ỹ (directions with variance below 1e-10 of
        the largest are dropped).  Sign as returned by ``eigh``.
        """
        dY = self.Y[self.dyn_out_idx] - self.Y[self.dyn_in_idx[:, 0]]
        lam, V = torch.linalg.eigh(self.Y.T @ self.Y / len(self.Y))
        keep = lam > 1e-10 * lam.max()
        white = V[:, keep] / lam[keep].sqrt()
        _, U = torch.linalg.eigh(white.T @ (dY.T @ dY / len(dY)) @ white)
        c0 = white @ U[:, 0]
        return c0 / c0.norm()

    @property
    def c_normalized(self) -> Tensor:
        """c̃: (n,) unit vector, χ = c̃·ỹ in normalized joint units."""
        return self.c_raw / self.c_raw.norm()

    @property
    def c(self) -> Tensor:
        """c: (n,) gait vector in physical units, χ = c·(q − q̄), 1/rad (detached)."""
        return (self.c_normalized / self.q_scale).detach()

    @property
    def latents(self) -> list[Tensor]:
        """The MAP latents χ, one (T_i,) tensor per sequence (detached)."""
        return list(self.X.detach().split(self.lengths))

    @torch.no_grad()
    def canonicalize_sign_(self) -> None:
        """Flip (X, c̃) → (−X, −c̃) if the largest-magnitude entry of c̃ is negative."""
        if self.c_raw[self.c_raw.abs().argmax()] < 0:
            self.c_raw.neg_()
            self.X.neg_()

    # -- objective -------------------------------------------------------------------
    def _obs_kernel(self, a: Tensor, b: Tensor) -> Tensor:
        """k_g(χ, χ') = exp(−(χ − χ')²/(2ℓ_g²)) for a: (N,), b: (M,) → (N, M)."""
        return torch.exp(-0.5 * (a[:, None] - b[None, :]) ** 2 / self.obs_lengthscale**2)

    def _dyn_kernel(self, a: Tensor, b: Tensor) -> Tensor:
        """RBF + linear k_X (no noise) for lag vectors a: (N, p), b: (M, p) → (N, M)."""
        ell = self.dyn_lengthscale
        rbf = self.dyn_outputscale * torch.exp(-0.5 * _sq_dist(a / ell, b / ell))
        return rbf + (a * self.dyn_linear) @ b.T

    def _obs_chol(self) -> Tensor:
        """Cholesky factor of K_Y: (N, N)."""
        return _cholesky(self._obs_kernel(self.X, self.X), self.obs_noise, self.jitter, "observation")

    def _dyn_chol(self) -> tuple[Tensor, Tensor, Tensor]:
        """Cholesky factor of K_X: (M, M), the lag inputs Z: (M, p) and the outputs X_out: (M,)."""
        Z, x_out = self.X[self.dyn_in_idx], self.X[self.dyn_out_idx]
        return _cholesky(self._dyn_kernel(Z, Z), self.dyn_noise, self.jitter, "dynamics"), Z, x_out

    def objective(self) -> GPDMObjective:
        """The modified eq. (17) and its terms (see module docstring), scalars."""
        N, D = self.Y.shape
        L = self._obs_chol()
        YW = self.Y * self.obs_w
        obs = (
            D * torch.log(torch.diagonal(L)).sum()
            + 0.5 * (YW * torch.cholesky_solve(YW, L)).sum()
            - N * torch.log(self.obs_w).sum()
            + 0.5 * N * D * _LOG_2PI
        )
        Lx, _, x_out = self._dyn_chol()
        x_first = self.X[self.first_idx]
        dyn = (
            torch.log(torch.diagonal(Lx)).sum()
            + 0.5 * (x_out * torch.cholesky_solve(x_out[:, None], Lx)[:, 0]).sum()
            + 0.5 * (x_first**2).sum()
            + 0.5 * (len(x_out) + len(x_first)) * _LOG_2PI
        )
        pen = ((self.X - self.Y @ self.c_normalized) ** 2).sum()
        total = obs + self.dynamics_weight * dyn + self.penalty_weight * pen
        return GPDMObjective(total, obs, dyn, pen)

    def forward(self) -> Tensor:
        """The minimized scalar L of the modified eq. (17) (``objective().total``)."""
        return self.objective().total

    # -- prediction ------------------------------------------------------------------
    def project(self, q: Tensor) -> Tensor:
        """χ = c·(q − q̄) for q: (T, n) or (n,) joint angles, rad → (T,) or () latent."""
        q = torch.as_tensor(q, dtype=_DTYPE)
        if q.shape[-1] != len(self.q_mean):
            raise ArgumentError(f"q: expected last dimension {len(self.q_mean)} (joints), got shape {tuple(q.shape)}")
        return (q - self.q_mean) @ self.c

    @torch.no_grad()
    def predict_q(self, chi: Tensor) -> tuple[Tensor, Tensor]:
        """Observation GP posterior q = g(χ) (eq. 16) at chi: (T,) latents.

        Returns:
            mean (T, n) rad and variance (T, n) rad² of the noise-free g(χ).
        """
        chi = torch.as_tensor(chi, dtype=_DTYPE).reshape(-1)
        L = self._obs_chol()
        k = self._obs_kernel(chi, self.X)  # (T, N)
        mean = k @ torch.cholesky_solve(self.Y, L)
        v = torch.linalg.solve_triangular(L, k.T, upper=False)
        var = (1.0 - (v**2).sum(0)).clamp_min(0.0)[:, None] / self.obs_w**2
        return self.q_mean + self.q_scale * mean, var * self.q_scale**2

    @torch.no_grad()
    def rollout(self, chi0: Tensor, steps: int) -> Tensor:
        """Iterate the dynamics GP mean χ_t = E[f(χ_{t−1}, …, χ_{t−p})] (eq. 16).

        Args:
            chi0: (p,) the first p latents in time order [χ_0, …, χ_{p−1}].
            steps: number of predicted steps, ≥ 0.

        Returns:
            (p + steps,) latent sequence starting with ``chi0``.
        """
        chi0 = torch.as_tensor(chi0, dtype=_DTYPE).reshape(-1)
        if chi0.numel() != self.order or steps < 0:
            raise ArgumentError(
                f"rollout: expected chi0 of {self.order} latent(s) and steps ≥ 0, got {tuple(chi0.shape)}, {steps}"
            )
        Lx, Z, x_out = self._dyn_chol()
        weights = torch.cholesky_solve(x_out[:, None], Lx)[:, 0]
        seq = list(chi0)
        for _ in range(steps):
            z = torch.stack(seq[-1 : -self.order - 1 : -1])[None, :]  # [χ_{t−1}, …, χ_{t−p}]
            seq.append((self._dyn_kernel(z, Z) @ weights)[0])
        return torch.stack(seq)


def reconstruct_latent(
    q_a: Tensor, q_u_bem: Tensor, *, unactuated_index: int, c: Tensor, q_offset: Tensor | None = None
) -> Tensor:
    """χ̂ = c·([q_a, μ(x_0^e)] − q̄): the latent with q_u replaced by the BEM (paper Sec. III-C).

    Args:
        q_a: (T, n−1) actuated joint angles, rad, in joint order without the unactuated one.
        q_u_bem: (T,) BEM prediction μ(x_0^e) of the unactuated angle, rad.
        unactuated_index: position of q_u in the full joint vector q ∈ R^n.
        c: (n,) gait vector, 1/rad (e.g. ``GPDM.c``).
        q_offset: (n,) q̄ subtracted before projecting (``GPDM.q_mean``); ``None`` is 0,
            the paper's χ̂ = c q.

    Returns:
        (T,) reconstructed latent χ̂.
    """
    q_a, q_u_bem, c = (torch.as_tensor(t, dtype=_DTYPE) for t in (q_a, q_u_bem, c))
    n = c.shape[0] if c.ndim == 1 else -1
    if n < 2 or q_a.ndim != 2 or q_a.shape[1] != n - 1 or q_u_bem.shape != (q_a.shape[0],):
        raise ArgumentError(
            f"reconstruct_latent: expected c (n,), q_a (T, n−1), q_u_bem (T,), got "
            f"{tuple(c.shape)}, {tuple(q_a.shape)}, {tuple(q_u_bem.shape)}"
        )
    if not 0 <= unactuated_index < n:
        raise ArgumentError(f"unactuated_index: expected 0 ≤ index < {n}, got {unactuated_index}")
    q = torch.cat([q_a[:, :unactuated_index], q_u_bem[:, None], q_a[:, unactuated_index:]], dim=1)
    if q_offset is not None:
        q = q - torch.as_tensor(q_offset, dtype=_DTYPE)
    return q @ c


class LatentComparison(NamedTuple):
    """Agreement of a reconstructed latent χ̂ with χ: Pearson correlation and RMSE (latent units)."""

    corr: float
    rmse: float


def compare_latents(chi: Tensor, chi_hat: Tensor) -> LatentComparison:
    """Correlation and RMSE between chi: (T,) and chi_hat: (T,) (paper Fig. 4–5, χ vs χ̂)."""
    chi, chi_hat = (torch.as_tensor(t, dtype=_DTYPE).reshape(-1) for t in (chi, chi_hat))
    if chi.shape != chi_hat.shape or chi.numel() < 2:
        raise ArgumentError(
            f"compare_latents: expected two (T,) tensors with T ≥ 2, got {tuple(chi.shape)}, {tuple(chi_hat.shape)}"
        )
    a, b = chi - chi.mean(), chi_hat - chi_hat.mean()
    corr = float((a @ b) / (a.norm() * b.norm()).clamp_min(1e-300))
    return LatentComparison(corr=corr, rmse=float(((chi - chi_hat) ** 2).mean().sqrt()))
