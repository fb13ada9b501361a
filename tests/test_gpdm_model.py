"""GPDM math (bemlearn.models.gpdm): objective, gradients, sequences, prediction, reconstruction, input errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch.distributions import MultivariateNormal, Normal

from bemlearn.models.gpdm import GPDM, compare_latents, reconstruct_latent

F64 = torch.float64


def _sequences(lengths=(9, 12, 7), n=4, seed=0):
    gen = torch.Generator().manual_seed(seed)
    out = []
    for T in lengths:
        t = torch.linspace(0.0, 2.0, T, dtype=F64)[:, None]
        phase = torch.arange(1, n + 1, dtype=F64)
        out.append(torch.sin(t * phase + 0.3 * phase) + 0.05 * torch.randn(T, n, generator=gen, dtype=F64))
    return out


def _perturbed(model: GPDM, seed=1) -> GPDM:
    """Move every parameter off its initial value so no term is trivially zero."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=gen, dtype=F64))
    return model


def _reference_objective(model: GPDM, Q_list) -> tuple[float, float, float]:
    """Observation, dynamics and penalty terms from dense MultivariateNormal log-densities."""
    X = model.X.detach()
    Y = (torch.cat(Q_list) - model.q_mean) / model.q_scale
    N, D = Y.shape
    eye = lambda m: torch.eye(m, dtype=F64)  # noqa: E731
    K = torch.exp(-0.5 * (X[:, None] - X[None, :]) ** 2 / model.obs_lengthscale.detach() ** 2)
    K = K + model.obs_noise.detach() * eye(N)
    w = model.obs_w.detach()
    obs = -sum(float(MultivariateNormal(torch.zeros(N, dtype=F64), K / w[j] ** 2).log_prob(Y[:, j])) for j in range(D))
    # dynamics pairs built sequence by sequence, independently of the model's index buffers
    p, ins, outs, firsts = model.order, [], [], []
    for chi in model.latents:
        for t in range(p, len(chi)):
            ins.append([float(chi[t - k]) for k in range(1, p + 1)])
            outs.append(float(chi[t]))
        firsts.extend(float(v) for v in chi[:p])
    Z, x_out = torch.tensor(ins, dtype=F64), torch.tensor(outs, dtype=F64)
    ell, a = model.dyn_lengthscale.detach(), model.dyn_linear.detach()
    sq = (((Z[:, None, :] - Z[None, :, :]) / ell) ** 2).sum(-1)
    Kx = model.dyn_outputscale.detach() * torch.exp(-0.5 * sq) + (Z * a) @ Z.T + model.dyn_noise.detach() * eye(len(Z))
    dyn = -float(MultivariateNormal(torch.zeros(len(Z), dtype=F64), Kx).log_prob(x_out))
    dyn -= float(Normal(0.0, 1.0).log_prob(torch.tensor(firsts, dtype=F64)).sum())
    c = model.c_raw.detach() / model.c_raw.detach().norm()
    pen = float(((X - Y @ c) ** 2).sum())
    return obs, dyn, pen


@pytest.mark.parametrize("order", [1, 2])
def test_objective_matches_dense_multivariate_normal(order):
    Q = _sequences()
    model = _perturbed(GPDM(Q, order=order, penalty=3.0, jitter=0.0))
    obs, dyn, pen = _reference_objective(model, Q)
    with torch.no_grad():
        got = model.objective()
    assert float(got.observation) == pytest.approx(obs, rel=1e-10)
    assert float(got.dynamics) == pytest.approx(dyn, rel=1e-10)
    assert float(got.penalty) == pytest.approx(pen, rel=1e-10)
    assert pen > 1e-3  # the perturbation moved X off Ỹc̃
    # balanced GPDM: dynamics weighted by D/d = n = 4
    assert model.dynamics_weight == 4.0
    assert float(got.total) == pytest.approx(obs + 4.0 * dyn + 3.0 * pen, rel=1e-10)
    assert float(model().detach()) == float(got.total)


@pytest.mark.parametrize("order", [1, 2])
def test_objective_gradients_match_finite_differences(order):
    Q = _sequences(lengths=(5, 6), n=3)
    model = _perturbed(GPDM(Q, order=order, penalty=2.0, jitter=0.0))
    names = [name for name, _ in model.named_parameters()]
    values = tuple(p.detach().clone().requires_grad_(True) for p in model.parameters())

    def objective(*params):
        return torch.func.functional_call(model, dict(zip(names, params)), ())

    assert torch.autograd.gradcheck(objective, values, eps=1e-6, atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize("order", [1, 2])
def test_transitions_stay_inside_each_sequence(order):
    lengths = (5, 7, 4)
    model = GPDM(_sequences(lengths), order=order)
    seq_of = torch.repeat_interleave(torch.arange(3), torch.tensor(lengths))
    M = sum(T - order for T in lengths)
    assert model.dyn_in_idx.shape == (M, order)
    assert model.dyn_out_idx.shape == (M,)
    # every input lag is in the output's sequence, at t−1 … t−p
    for k in range(order):
        assert torch.equal(model.dyn_out_idx - model.dyn_in_idx[:, k], torch.full((M,), k + 1))
        assert torch.equal(seq_of[model.dyn_in_idx[:, k]], seq_of[model.dyn_out_idx])
    starts = [0, 5, 12]
    assert model.first_idx.tolist() == [s + k for s in starts for k in range(order)]
    assert [len(x) for x in model.latents] == list(lengths)


def test_normalization_and_unit_gait_vector():
    Q = _sequences()
    Qcat = torch.cat(Q)
    model = GPDM(Q)
    torch.testing.assert_close(model.q_mean, Qcat.mean(0), rtol=0, atol=1e-14)
    torch.testing.assert_close(model.q_scale, Qcat.std(0), rtol=0, atol=1e-14)
    assert float(model.c_normalized.detach().norm()) == pytest.approx(1.0, abs=1e-14)
    torch.testing.assert_close(model.c, model.c_normalized.detach() / Qcat.std(0), rtol=1e-14, atol=0)
    # X starts at the projection: χ = c·(q − q̄)
    torch.testing.assert_close(torch.cat(model.latents), model.project(Qcat), rtol=0, atol=1e-12)
    from_numpy = GPDM([q.numpy() for q in Q])
    assert torch.equal(from_numpy.q_mean, model.q_mean) and torch.equal(from_numpy.X, model.X)
    unscaled = GPDM(Q, scale_joints=False)
    assert torch.equal(unscaled.q_scale, torch.ones(4, dtype=F64))


def test_sign_flip_leaves_objective_unchanged_and_is_canonicalized():
    model = _perturbed(GPDM(_sequences()))
    model.canonicalize_sign_()
    c0, x0 = model.c_normalized.detach().clone(), model.X.detach().clone()
    assert c0[c0.abs().argmax()] > 0
    total = lambda: float(model.objective().total.detach())  # noqa: E731
    before = total()
    with torch.no_grad():
        model.c_raw.neg_()
        model.X.neg_()
    assert total() == pytest.approx(before, rel=1e-12)
    model.canonicalize_sign_()
    assert torch.equal(model.c_normalized.detach(), c0)
    assert torch.equal(model.X.detach(), x0)


def test_slow_direction_picks_the_slowly_varying_combination():
    # joint 0 + joint 1 is a slow ramp; joint 0 − joint 1 is a fast oscillation with 10× the variance
    t = torch.linspace(0.0, 1.0, 200, dtype=F64)
    slow, fast = t - 0.5, 3.0 * torch.sin(40.0 * t)
    Q = [torch.stack([slow + fast, slow - fast], dim=1)]
    model = GPDM(Q, scale_joints=False)
    expected = torch.tensor([1.0, 1.0], dtype=F64) / math.sqrt(2.0)
    assert float(model.slowest_direction() @ expected) ** 2 == pytest.approx(1.0, abs=1e-3)
    pca = GPDM(Q, init="pca", scale_joints=False)
    assert abs(float(pca.c_normalized.detach() @ expected)) < 0.2


def test_predict_q_matches_dense_posterior():
    Q = _sequences()
    model = _perturbed(GPDM(Q, jitter=0.0))
    X, Y, w = model.X.detach(), model.Y, model.obs_w.detach()
    ell2, noise = model.obs_lengthscale.detach() ** 2, model.obs_noise.detach()
    chi = torch.linspace(float(X.min()) - 0.5, float(X.max()) + 0.5, 17, dtype=F64)
    K = torch.exp(-0.5 * (X[:, None] - X[None, :]) ** 2 / ell2) + noise * torch.eye(len(X), dtype=F64)
    k = torch.exp(-0.5 * (chi[:, None] - X[None, :]) ** 2 / ell2)
    mean_ref = model.q_mean + model.q_scale * (k @ torch.linalg.solve(K, Y))
    var_ref = (1.0 - (k * torch.linalg.solve(K, k.T).T).sum(1))[:, None] * (model.q_scale / w) ** 2
    mean, var = model.predict_q(chi)
    assert mean.shape == var.shape == (17, 4)
    torch.testing.assert_close(mean, mean_ref, rtol=1e-9, atol=1e-10)
    torch.testing.assert_close(var, var_ref, rtol=1e-7, atol=1e-10)


@pytest.mark.parametrize("order", [1, 2])
def test_rollout_iterates_the_dense_dynamics_mean(order):
    model = _perturbed(GPDM(_sequences(), order=order, jitter=0.0))
    Z, x_out = model.X.detach()[model.dyn_in_idx], model.X.detach()[model.dyn_out_idx]
    ell, a = model.dyn_lengthscale.detach(), model.dyn_linear.detach()

    def k(A, B):
        sq = (((A[:, None, :] - B[None, :, :]) / ell) ** 2).sum(-1)
        return model.dyn_outputscale.detach() * torch.exp(-0.5 * sq) + (A * a) @ B.T

    weights = torch.linalg.solve(k(Z, Z) + model.dyn_noise.detach() * torch.eye(len(Z), dtype=F64), x_out)
    chi = [0.3, -0.1][:order]
    for _ in range(6):
        z = torch.tensor([chi[-1 - j] for j in range(order)], dtype=F64)[None, :]
        chi.append(float(k(z, Z) @ weights))
    got = model.rollout(torch.tensor(chi[:order], dtype=F64), 6)
    assert got.shape == (order + 6,)
    torch.testing.assert_close(got, torch.tensor(chi, dtype=F64), rtol=1e-9, atol=1e-11)


@pytest.mark.parametrize("index", [0, 2, 3])
def test_reconstruction_equals_latent_when_bem_equals_true_q_u(index):
    Q = _sequences()
    model = GPDM(Q)
    Qcat = torch.cat(Q)
    keep = [j for j in range(4) if j != index]
    chi = model.project(Qcat)
    kw = dict(unactuated_index=index, c=model.c, q_offset=model.q_mean)
    chi_hat = reconstruct_latent(Qcat[:, keep], Qcat[:, index], **kw)
    torch.testing.assert_close(chi_hat, chi, rtol=0, atol=1e-12)
    # a BEM error δ in q_u moves χ̂ by exactly c_u δ
    shifted = reconstruct_latent(Qcat[:, keep], Qcat[:, index] + 0.1, **kw)
    torch.testing.assert_close(shifted - chi, torch.full_like(chi, 0.1 * float(model.c[index])), rtol=1e-10, atol=1e-12)
    result = compare_latents(chi, shifted)
    assert result.corr == pytest.approx(1.0, abs=1e-12)
    assert result.rmse == pytest.approx(abs(0.1 * float(model.c[index])), rel=1e-10)


def test_reconstruction_and_comparison_closed_forms():
    c = torch.tensor([1.0, 2.0, 3.0], dtype=F64)
    q_a = torch.tensor([[1.0, 1.0], [0.0, 2.0]], dtype=F64)
    q_u = torch.tensor([2.0, -1.0], dtype=F64)
    # q = [1, 2, 1] and [0, −1, 2]: χ̂ = 1 + 4 + 3 = 8 and 0 − 2 + 6 = 4 (paper's χ̂ = c q, no offset)
    expected = torch.tensor([8.0, 4.0], dtype=F64)
    torch.testing.assert_close(reconstruct_latent(q_a, q_u, unactuated_index=1, c=c), expected)
    a = np.array([0.0, 1.0, 3.0, 2.0, 5.0])
    b = np.array([1.0, 0.5, 2.5, 3.0, 4.0])
    result = compare_latents(torch.tensor(a), torch.tensor(b))
    assert result.corr == pytest.approx(float(np.corrcoef(a, b)[0, 1]), abs=1e-12)
    assert result.rmse == pytest.approx(float(np.sqrt(np.mean((a - b) ** 2))), abs=1e-12)
    assert compare_latents(torch.tensor(a), -torch.tensor(a)).corr == pytest.approx(-1.0, abs=1e-12)


# -- bad inputs ---------------------------------------------------------------------------
def test_bad_sequences_raise_named_errors():
    good = torch.randn(10, 3, dtype=F64)
    with pytest.raises(ValueError, match=r"Q_list\[1\]: expected 3 columns"):
        GPDM([good, torch.randn(10, 4, dtype=F64)])
    bad = good.clone()
    bad[4, 2] = float("nan")
    with pytest.raises(ValueError, match=r"Q_list\[1\].*NaN or inf, first at row 4"):
        GPDM([good, bad])
    with pytest.raises(ValueError, match=r"Q_list\[1\]: a sequence needs at least order \+ 1 = 3 samples.*got 2"):
        GPDM([good, good[:2]], order=2)
    with pytest.raises(ValueError, match=r"Q_list\[0\]: expected shape \(N, d\)"):
        GPDM([torch.randn(10, dtype=F64)])
    with pytest.raises(TypeError, match="Q_list: expected a non-empty list"):
        GPDM([])
    with pytest.raises(TypeError, match="Q_list: expected a non-empty list"):
        GPDM(good)
    constant = good.clone()
    constant[:, 1] = 0.5
    with pytest.raises(ValueError, match=r"joint column\(s\) \[1\] are constant"):
        GPDM([constant])
    with pytest.raises(ValueError, match="order: expected 1 or 2"):
        GPDM([good], order=3)
    with pytest.raises(ValueError, match="init: expected"):
        GPDM([good], init="isomap")


def test_bad_prediction_arguments_raise_named_errors():
    model = GPDM([torch.randn(10, 3, dtype=F64)], order=2)
    with pytest.raises(ValueError, match="chi0 of 2 latent"):
        model.rollout(torch.zeros(1, dtype=F64), 3)
    with pytest.raises(ValueError, match="q: expected last dimension 3"):
        model.project(torch.zeros(5, 4, dtype=F64))
    c = torch.ones(3, dtype=F64)
    with pytest.raises(ValueError, match=r"expected c \(n,\), q_a \(T, n−1\), q_u_bem \(T,\)"):
        reconstruct_latent(torch.zeros(5, 3, dtype=F64), torch.zeros(5, dtype=F64), unactuated_index=0, c=c)
    with pytest.raises(ValueError, match="unactuated_index: expected 0 ≤ index < 3, got 3"):
        reconstruct_latent(torch.zeros(5, 2, dtype=F64), torch.zeros(5, dtype=F64), unactuated_index=3, c=c)
    with pytest.raises(ValueError, match="compare_latents"):
        compare_latents(torch.zeros(4, dtype=F64), torch.zeros(5, dtype=F64))
