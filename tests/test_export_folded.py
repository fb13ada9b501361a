"""FoldedPosterior and the variance factor against independent dense computations."""

import dataclasses

import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.export import FoldedPosterior, VarianceFactor, variance_factor
from bemlearn.export.variance_factor import condition_number
from bemlearn.models.kernels import se_kernel

F64 = torch.float64


@pytest.fixture(scope="module")
def posterior():
    state, _ = synthetic_posterior(n_train=200, m=1, seed=3)
    return state


def _kernel_rows(state, xn):
    """k(x, Z) ``(B, M)`` for normalized ``xn: (B, d)``, by explicit differences (eq. 11, checked in test_gp_parity)."""
    return se_kernel(xn, state.Z, state.lengthscale, state.outputscale)


def _refined_kinv_k(state, k):
    """K⁻¹kᵀ ``(M, B)`` by a Cholesky solve with three steps of iterative refinement
    (accurate to ~1e-14 relative for a well-conditioned K, independent of S)."""
    K = state.gram()
    L = torch.linalg.cholesky(K)
    v = torch.cholesky_solve(k.T, L)
    for _ in range(3):
        v = v + torch.cholesky_solve(k.T - K @ v, L)
    return v


def _dense_truth(state, x):
    """μ and σ of eq. (12) for physical ``x: (B, d)`` (:func:`_kernel_rows`, :func:`_refined_kinv_k`)."""
    k = _kernel_rows(state, (x - state.x_mean) / state.x_std)
    var = state.outputscale - (k.T * _refined_kinv_k(state, k)).sum(0)
    return state.y_mean + state.y_std * (k @ state.alpha), state.y_std * var.sqrt()


def _inputs(state, n, seed, spread=2.0):
    g = torch.Generator().manual_seed(seed)
    return state.x_mean + spread * state.x_std * torch.randn(n, state.dim, generator=g, dtype=F64)


@pytest.mark.parametrize("form", ["raw", "centered"])
def test_exact_mean_std_match_dense_refined_solve(posterior, form):
    x = _inputs(posterior, 500, seed=0)
    folded = FoldedPosterior(posterior, variance_factor(posterior), n_inputs=posterior.dim, form=form)
    assert folded.centered == (form == "centered")
    mean, std = folded.mean_std(x)
    ref_mean, ref_std = _dense_truth(posterior, x)
    assert float((mean - ref_mean).abs().max()) <= 1e-13
    assert float(((std - ref_std) / ref_std).abs().max()) <= 1e-10
    assert torch.equal(folded.mean(x), mean)


def test_far_offset_columns_use_the_centered_form(posterior):
    """A column whose mean is 10⁴ spreads from zero: the raw expansion would lose ~10 digits."""
    x_mean = posterior.x_mean.clone()
    x_mean[2] = 1e4 * posterior.x_std[2]
    state = dataclasses.replace(posterior, x_mean=x_mean)
    factor = variance_factor(state)
    auto = FoldedPosterior(state, factor, n_inputs=state.dim)
    assert auto.centered
    assert not FoldedPosterior(posterior, variance_factor(posterior), n_inputs=posterior.dim).centered
    x = _inputs(state, 300, seed=7)
    mean, std = auto.mean_std(x)
    ref_mean, ref_std = _dense_truth(state, x)
    assert float((mean - ref_mean).abs().max()) <= 1e-13
    assert float(((std - ref_std) / ref_std).abs().max()) <= 1e-10
    raw_mean, _ = FoldedPosterior(state, factor, n_inputs=state.dim, form="raw").mean_std(x)
    assert float((raw_mean - ref_mean).abs().max()) > 1e-11  # why "auto" switches


def test_bem_inputs_hold_unactuated_columns_at_zero(posterior):
    """n_inputs = 3m evaluates f at x_0^e = [q̈_a, q̇_a, q_a, 0, 0] (eq. 14)."""
    factor = variance_factor(posterior)
    full = FoldedPosterior(posterior, factor, n_inputs=posterior.dim)
    bem = FoldedPosterior(posterior, factor, n_inputs=3, share=full)
    x = _inputs(posterior, 300, seed=1)[:, :3]
    x0 = torch.cat([x, torch.zeros(300, 2, dtype=F64)], 1)
    mean, std = bem.mean_std(x)
    ref_mean, ref_std = full.mean_std(x0)
    assert float((mean - ref_mean).abs().max()) <= 1e-14
    assert float(((std - ref_std) / ref_std).abs().max()) <= 1e-12
    assert bem.FT.data_ptr() == full.FT.data_ptr()  # shared, not copied


def test_chunked_batches_equal_one_block(posterior):
    factor = variance_factor(posterior)
    whole = FoldedPosterior(posterior, factor, n_inputs=3)
    blocks = FoldedPosterior(posterior, factor, n_inputs=3, chunk=7)
    x = _inputs(posterior, 45, seed=6)[:, :3]
    expected = whole.mean_std(x)
    for got in (blocks.mean_std(x), torch.jit.script(blocks).mean_std(x)):
        for a, b in zip(got, expected):
            assert torch.allclose(a, b, rtol=1e-13, atol=1e-15)
    assert torch.allclose(torch.jit.script(blocks).mean(x), expected[0], rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="chunk: expected a positive row count, got 0"):
        FoldedPosterior(posterior, factor, n_inputs=3, chunk=0)
    with pytest.raises(ValueError, match="form: expected 'auto', 'raw' or 'centered'"):
        FoldedPosterior(posterior, factor, n_inputs=3, form="fast")


def test_far_inputs_give_the_prior(posterior):
    """Far from the data k → 0: μ → y_mean and σ → y_std σ_f exactly (closed form)."""
    folded = FoldedPosterior(posterior, variance_factor(posterior), n_inputs=posterior.dim)
    x = posterior.x_mean + 1e6 * posterior.x_std * torch.ones(3, posterior.dim, dtype=F64)
    x[1] *= -1.0
    x[2] = 1e100
    mean, std = folded.mean_std(x)
    # every kernel value underflows to 0, the sentinel's too: the prior mean exactly
    assert torch.equal(mean, posterior.y_mean.expand(3).to(F64))
    assert torch.allclose(std, posterior.y_std * posterior.outputscale.sqrt(), rtol=1e-15, atol=0.0)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_input_makes_the_mean_non_finite(posterior, bad):
    folded = FoldedPosterior(posterior, variance_factor(posterior), n_inputs=3)
    x = _inputs(posterior, 4, seed=2)[:, :3]
    x[2, 1] = bad
    mean = folded.mean(x)
    assert bool(torch.isfinite(mean[[0, 1, 3]]).all())
    assert not bool(torch.isfinite(mean[2]))


def test_exact_factor_is_cholesky_of_k(posterior):
    factor = variance_factor(posterior)
    assert factor.L is not None and factor.signs is None
    assert torch.allclose(factor.L @ factor.L.T, posterior.gram(), rtol=0, atol=1e-12)
    k = torch.rand(5, posterior.n_support, generator=torch.Generator().manual_seed(0), dtype=F64)
    direct = ((k @ posterior.S) * k).sum(1)
    assert torch.allclose(factor.quadratic_form(k), direct, rtol=1e-7, atol=0)


def test_exact_state_with_foreign_s_is_rejected(posterior):
    wrong = dataclasses.replace(posterior, S=posterior.S * 1.01)
    with pytest.raises(ValueError, match=r"PredictorState.S \(exact\) is not"):
        variance_factor(wrong)


def _random_symmetric(n, seed, shift):
    g = torch.Generator().manual_seed(seed)
    A = torch.randn(n, n, generator=g, dtype=F64)
    return A @ A.T / n + shift * torch.eye(n, dtype=F64)


@pytest.mark.parametrize(("shift", "signed"), [(0.1, False), (-0.5, True)])
def test_eigen_factor_reproduces_quadratic_form(posterior, shift, signed):
    S = _random_symmetric(posterior.n_support, seed=5, shift=shift)
    state = dataclasses.replace(posterior, kind="sgpr", S=S)
    factor = variance_factor(state)
    assert (factor.signs is not None) == signed
    k = torch.rand(7, posterior.n_support, generator=torch.Generator().manual_seed(1), dtype=F64)
    direct = ((k @ S) * k).sum(1)
    assert torch.allclose(factor.quadratic_form(k), direct, rtol=1e-12, atol=1e-12)
    folded = FoldedPosterior(state, factor, n_inputs=state.dim)
    x = _inputs(state, 50, seed=4)
    ref_mean, ref_std = state.predict_reference(x)
    mean, std = folded.mean_std(x)
    assert float((mean - ref_mean).abs().max()) <= 1e-13
    assert float((std - ref_std).abs().max()) <= 1e-12 * float(state.y_std)


def test_variance_factor_requires_a_matrix():
    with pytest.raises(ValueError, match="give F, L or both"):
        VarianceFactor()
    eye = torch.eye(2, dtype=F64)
    with pytest.raises(ValueError, match="no signs"):
        VarianceFactor(L=eye, signs=torch.ones(2, dtype=F64))
    # both: a factored sparse S = L⁻ᵀ Fᵀ diag(s) F L⁻¹, kᵀSk = Σ s_i (F L⁻¹ k)_i²
    L, F = torch.tensor([[2.0, 0.0], [1.0, 1.0]], dtype=F64), torch.tensor([[1.0, 0.5], [0.0, 3.0]], dtype=F64)
    both = VarianceFactor(L=L, F=F, signs=torch.tensor([1.0, -1.0], dtype=F64))
    k = torch.tensor([[4.0, 3.0]], dtype=F64)   # L⁻¹k = [2, 1], F L⁻¹k = [2.5, 3]
    assert both.factored and float(both.quadratic_form(k)) == 2.5**2 - 3.0**2


def test_n_inputs_out_of_range(posterior):
    with pytest.raises(ValueError, match="n_inputs: expected 1..5, got 6"):
        FoldedPosterior(posterior, variance_factor(posterior), n_inputs=6)


def _ill_conditioned_exact(noise: float = 1e-12, lengthscale: float = 8.0):
    """An exact posterior on nearly noise-free data with a long lengthscale (κ(K) ~ 10¹³),
    its S inverted by LU (``torch.linalg.inv``) instead of the Cholesky route: a legitimate
    S that differs from L⁻ᵀL⁻¹ by rounding of order κ·ε."""
    state, _ = synthetic_posterior(n_train=200, m=1, seed=3, noise=noise)
    state = dataclasses.replace(state, lengthscale=torch.full_like(state.lengthscale, lengthscale))
    return dataclasses.replace(state, S=torch.linalg.inv(state.gram()))


def test_ill_conditioned_exact_state_is_accepted_within_the_rounding_bound(caplog):
    state = _ill_conditioned_exact()
    K = state.gram()
    L = torch.linalg.cholesky(K)
    rel = float(torch.linalg.matrix_norm(torch.cholesky_inverse(L) - state.S) / torch.linalg.matrix_norm(state.S))
    kappa = condition_number(K)
    assert rel > 1e-6, "precondition: the S of this state must fail the plain exact_rtol check"
    assert rel < kappa * torch.finfo(F64).eps
    with caplog.at_level("WARNING", logger="bemlearn.export.variance_factor"):
        factor = variance_factor(state)
    assert "ill-conditioned" in caplog.text and f"{kappa:.3g}" in caplog.text
    # the factor is the Cholesky one of the rebuilt K: kᵀK⁻¹k against an iteratively refined solve
    g = torch.Generator().manual_seed(1)
    k = _kernel_rows(state, torch.randn(50, state.dim, generator=g, dtype=F64))
    ref = (k.T * _refined_kinv_k(state, k)).sum(0)
    assert float((factor.quadratic_form(k) - ref).abs().max()) <= 1e-6 * float(state.outputscale)


def test_exact_state_with_a_foreign_S_is_rejected_even_when_ill_conditioned():
    """S of another lengthscale (1 % off) differs far beyond κ·ε: still an error, naming κ."""
    state = _ill_conditioned_exact()
    other = dataclasses.replace(state, lengthscale=state.lengthscale * 1.01)
    wrong = dataclasses.replace(state, S=torch.linalg.inv(other.gram()))
    expected = r"is not \(K_ZZ \+ σ_0² I\)⁻¹ .* above the rounding bound κ\(K\)·ε = .*\(κ = "
    with pytest.raises(ValueError, match=expected):
        variance_factor(wrong)
