"""Exported predictor vs the GPyTorch model it came from (exact, sgpr, svgp), float64.

Each case builds a small GPyTorch model with fixed hyperparameters, converts it to a
PredictorState with a dense test helper (the formulas of bemlearn.models.predictor_state),
exports it with TorchScript and compares on 10⁴ random inputs: mean within 1e-10 rad, std
within 1e-8 relative.  GPyTorch's Cholesky is forced (max_cholesky_size) so the N = 1000
exact model is not solved by CG.
"""

import dataclasses

import gpytorch
import pytest
import torch

from bemlearn.export import BEMPredictor, PredictorMetadata, script_predictor
from bemlearn.models.predictor_state import PredictorState

F64 = torch.float64
N_QUERY = 10_000
MEAN_ATOL = 1e-10   # rad
STD_RTOL = 1e-8


class _ExactGP(gpytorch.models.ExactGP):
    def __init__(self, x, y, likelihood, d):
        super().__init__(x, y, likelihood)
        self.mean_module = gpytorch.means.ZeroMean()
        self.covar_module = gpytorch.kernels.ScaleKernel(gpytorch.kernels.RBFKernel(ard_num_dims=d))

    def forward(self, x):
        return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))


class _SGPR(gpytorch.models.ExactGP):
    def __init__(self, x, y, likelihood, d, inducing):
        super().__init__(x, y, likelihood)
        self.mean_module = gpytorch.means.ZeroMean()
        self.base = gpytorch.kernels.ScaleKernel(gpytorch.kernels.RBFKernel(ard_num_dims=d))
        self.covar_module = gpytorch.kernels.InducingPointKernel(self.base, inducing_points=inducing, likelihood=likelihood)

    def forward(self, x):
        return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))


class _SVGP(gpytorch.models.ApproximateGP):
    def __init__(self, inducing, d):
        q = gpytorch.variational.CholeskyVariationalDistribution(inducing.shape[0])
        # jitter_val = 0: GPyTorch adds jitter_val to the *test* prior variance as well, which a
        # PredictorState (σ̃² = σ_f² − kᵀSk) does not represent.
        strategy = gpytorch.variational.VariationalStrategy(self, inducing, q, learn_inducing_locations=True, jitter_val=0.0)
        super().__init__(strategy)
        self.mean_module = gpytorch.means.ZeroMean()
        self.covar_module = gpytorch.kernels.ScaleKernel(gpytorch.kernels.RBFKernel(ard_num_dims=d))

    def forward(self, x):
        return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))


def _set_kernel(kernel, lengthscale, outputscale):
    kernel.base_kernel.lengthscale = lengthscale
    kernel.outputscale = torch.tensor(outputscale, dtype=F64)  # a Python float would go through float32


def _problem(n, m, seed):
    g = torch.Generator().manual_seed(seed)
    d = 3 * m + 2
    X = torch.randn(n, d, generator=g, dtype=F64)
    y = torch.sin(X @ torch.linspace(1.0, -0.5, d, dtype=F64)) + 0.05 * torch.randn(n, generator=g, dtype=F64)
    lengthscale = 0.9 + torch.rand(d, generator=g, dtype=F64)
    norm = {
        "x_mean": torch.randn(d, generator=g, dtype=F64) * 0.2,
        "x_std": torch.tensor([20.0] * m + [3.0] * m + [1.0] * m + [30.0, 2.0], dtype=F64),
        "y_mean": torch.tensor(0.01, dtype=F64),
        "y_std": torch.tensor(0.05, dtype=F64),
    }
    names = tuple([f"qdd_a{i}" for i in range(m)] + [f"qd_a{i}" for i in range(m)] + [f"q_a{i}" for i in range(m)] + ["qdd_u", "qd_u"])
    lik = gpytorch.likelihoods.GaussianLikelihood(noise_constraint=gpytorch.constraints.GreaterThan(1e-12)).double()
    lik.noise = torch.tensor(1e-2, dtype=F64)
    return X, y, lengthscale, norm, names, lik, g


def _state(kind, Z, alpha, S, kernel, lik, norm, names, n):
    return PredictorState(
        kind=kind, Z=Z.detach().clone(), alpha=alpha.detach(), S=(0.5 * (S + S.T)).detach(),
        lengthscale=kernel.base_kernel.lengthscale.detach().reshape(-1).clone(),
        outputscale=kernel.outputscale.detach().clone(), noise=lik.noise.detach().reshape(()).clone(),
        input_names=names, n_train=n, **norm,
    )


def _exact_case(n, m, seed):
    """Exact GP: α = K⁻¹y, S = K⁻¹, K = K_XX + σ_0² I (GPyTorch's own K_XX)."""
    X, y, ls, norm, names, lik, _ = _problem(n, m, seed)
    model = _ExactGP(X, y, lik, X.shape[1]).double()
    _set_kernel(model.covar_module, ls, 1.3)
    model.eval(), lik.eval()
    with torch.no_grad():
        K = model.covar_module(X).to_dense() + lik.noise * torch.eye(n, dtype=F64)
    L = torch.linalg.cholesky(K)
    alpha = torch.cholesky_solve(y[:, None], L)[:, 0]
    return model, _state("exact", X, alpha, torch.cholesky_inverse(L), model.covar_module, lik, norm, names, n)


def _sgpr_case(n, m, seed, n_inducing=40):
    """Titsias SGPR: Σ = (K_ZZ + σ⁻² K_ZX K_XZ)⁻¹, α = σ⁻² Σ K_ZX y, S = K_ZZ⁻¹ − Σ.

    GPyTorch's eval-mode InducingPointKernel adds diag(K_XX − Q_XX) to the training
    covariance unless sgpr_diagonal_correction is off; the test switches it off (Titsias).
    """
    X, y, ls, norm, names, lik, g = _problem(n, m, seed)
    Z = X[torch.randperm(n, generator=g)[:n_inducing]].clone()
    model = _SGPR(X, y, lik, X.shape[1], Z).double()
    _set_kernel(model.base, ls, 1.3)
    model.eval(), lik.eval()
    s2 = lik.noise.detach().reshape(())
    with torch.no_grad():
        Kzz, Kzx = model.base(Z).to_dense(), model.base(Z, X).to_dense()
    eye = torch.eye(n_inducing, dtype=F64)
    Lz = torch.linalg.cholesky(Kzz)
    Lzi = torch.linalg.solve_triangular(Lz, eye, upper=False)
    A = Lzi @ Kzx / s2.sqrt()
    Binv = torch.cholesky_inverse(torch.linalg.cholesky(eye + A @ A.T))
    Sigma = Lzi.T @ Binv @ Lzi
    state = _state("sgpr", Z, Sigma @ Kzx @ y / s2, Lzi.T @ (eye - Binv) @ Lzi, model.base, lik, norm, names, n)
    return model, state


def _svgp_case(n, m, seed, n_inducing=40):
    """Whitened SVGP, q(v) = N(m_v, S_v): α = L⁻ᵀ m_v, S = L⁻ᵀ (I − S_v) L⁻¹, K_ZZ = L Lᵀ."""
    X, _, ls, norm, names, lik, g = _problem(n, m, seed)
    Z = X[torch.randperm(n, generator=g)[:n_inducing]].clone()
    model = _SVGP(Z, X.shape[1]).double()
    _set_kernel(model.covar_module, ls, 1.3)
    q = model.variational_strategy._variational_distribution
    with torch.no_grad():
        q.variational_mean.copy_(torch.randn(n_inducing, generator=g, dtype=F64))
        chol = 0.05 * torch.randn(n_inducing, n_inducing, generator=g, dtype=F64).tril(-1)
        q.chol_variational_covar.copy_(chol + torch.diag(0.3 + 0.5 * torch.rand(n_inducing, generator=g, dtype=F64)))
    model.variational_strategy.variational_params_initialized.fill_(1)  # keep these q(v), not the prior
    model.eval()
    with torch.no_grad():
        Kzz = model.covar_module(Z).to_dense()
    eye = torch.eye(n_inducing, dtype=F64)
    Lzi = torch.linalg.solve_triangular(torch.linalg.cholesky(Kzz), eye, upper=False)
    Lv = q.chol_variational_covar.detach().tril()
    S = Lzi.T @ (eye - Lv @ Lv.T) @ Lzi
    return model, _state("svgp", Z, Lzi.T @ q.variational_mean.detach(), S, model.covar_module, lik, norm, names, n)


def _sgpr_factored_case(n, m, seed, n_inducing=40):
    """:func:`_sgpr_case` with S factored: S = L⁻ᵀ (I − B⁻¹) L⁻¹, L = chol(K_ZZ), B = I + AAᵀ."""
    model, state = _sgpr_case(n, m, seed, n_inducing)
    X, Z, lik = model.train_inputs[0], state.Z, model.likelihood
    with torch.no_grad():
        Kzz, Kzx = model.base(Z).to_dense(), model.base(Z, X).to_dense()
    eye = torch.eye(n_inducing, dtype=F64)
    L = torch.linalg.cholesky(Kzz)
    A = torch.linalg.solve_triangular(L, Kzx, upper=False) / lik.noise.detach().reshape(()).sqrt()
    C = eye - torch.cholesky_inverse(torch.linalg.cholesky(eye + A @ A.T))
    return model, dataclasses.replace(state, S_chol=L, S_inner=0.5 * (C + C.T))


def _svgp_factored_case(n, m, seed, n_inducing=40):
    """:func:`_svgp_case` with S factored: S = L⁻ᵀ (I − S_v) L⁻¹, L = chol(K_ZZ)."""
    model, state = _svgp_case(n, m, seed, n_inducing)
    with torch.no_grad():
        Kzz = model.covar_module(state.Z).to_dense()
    Lv = model.variational_strategy._variational_distribution.chol_variational_covar.detach().tril()
    C = torch.eye(n_inducing, dtype=F64) - Lv @ Lv.T
    return model, dataclasses.replace(state, S_chol=torch.linalg.cholesky(Kzz), S_inner=0.5 * (C + C.T))


def _metadata(state, m):
    return PredictorMetadata(
        robot="test", joint_names=(*[f"a{i}" for i in range(m)], "u"), actuated_names=tuple(f"a{i}" for i in range(m)),
        unactuated_name="u", m=m, input_names=state.input_names, units={n: "rad" for n in state.input_names},
        n_train=state.n_train, n_inducing=None if state.kind == "exact" else state.n_support,
        hyperparameters={}, bemlearn_version="test", data_sha256="0" * 64,
    )


def _gpytorch_predict(model, state, x):
    """GPyTorch latent mean/std in physical units for physical ``x: (B, d)``."""
    xt = (x - state.x_mean) / state.x_std
    means, variances = [], []
    with torch.no_grad(), gpytorch.settings.max_cholesky_size(10**9), gpytorch.settings.sgpr_diagonal_correction(False):
        for chunk in xt.split(2500):
            f = model(chunk)
            means.append(f.mean)
            variances.append(f.variance)
    return state.y_mean + state.y_std * torch.cat(means), state.y_std * torch.cat(variances).sqrt()


CASES = {
    "exact-N300": (_exact_case, 300, 1),
    "exact-N1000-above-800": (_exact_case, 1000, 1),
    "sgpr-m2": (_sgpr_case, 400, 2),
    "svgp": (_svgp_case, 400, 1),
    "sgpr-m2-factored": (_sgpr_factored_case, 400, 2),
    "svgp-factored": (_svgp_factored_case, 400, 1),
}


@pytest.mark.parametrize("case", list(CASES))
def test_torchscript_matches_gpytorch(case):
    build, n, m = CASES[case]
    model, state = build(n, m, seed=7)
    predictor = script_predictor(BEMPredictor(state, _metadata(state, m)))
    g = torch.Generator().manual_seed(11)
    d = state.dim
    x = state.x_mean + 1.5 * state.x_std * torch.randn(N_QUERY, d, generator=g, dtype=F64)
    # full map f(x), eq. (11)
    ref_mean, ref_std = _gpytorch_predict(model, state, x)
    mean, std = predictor.predict_full(x)
    assert float((mean - ref_mean).abs().max()) <= MEAN_ATOL
    assert float(((std - ref_std) / ref_std).abs().max()) <= STD_RTOL
    # BEM, eq. (14): forward(x) is f at [x, 0, 0]
    x0 = x.clone()
    x0[:, 3 * m:] = 0.0
    ref_mean, ref_std = _gpytorch_predict(model, state, x0[:2000])
    mean, std = predictor(x0[:2000, : 3 * m].contiguous())
    assert float((mean - ref_mean).abs().max()) <= MEAN_ATOL
    assert float(((std - ref_std) / ref_std).abs().max()) <= STD_RTOL
    assert torch.equal(predictor.bem_mean(x0[:2000, : 3 * m].contiguous()), mean)


def test_gpytorch_default_sgpr_correction_is_not_titsias():
    """Guards the test's premise: with GPyTorch's default diagonal correction the eval-mode
    SGPR is a different posterior, so comparing against it would need another converter."""
    model, state = _sgpr_case(200, 1, seed=3)
    x = state.x_mean + state.x_std * torch.randn(200, state.dim, generator=torch.Generator().manual_seed(0), dtype=F64)
    xt = (x - state.x_mean) / state.x_std
    with torch.no_grad():
        corrected = state.y_mean + state.y_std * model(xt).mean
    mean, _ = state.predict_reference(x)
    assert float((corrected - mean).abs().max()) > 1e-6
