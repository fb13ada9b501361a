"""The calibrated BEM band (eq. B1): gradient, folded form, export parity, calibration, coverage.

References: ∂μ/∂x by central finite differences of the dense mean; the band by autograd of
the dense mean and the dense latent std; the exported artifacts against the eager module
and the dense band; the noise gains against scipy's Savitzky–Golay coefficients and the
closed form of central differences; coverage on a synthetic map with known input noise.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from bemlearn.data import make_estimator
from bemlearn.export import (
    BEMPredictor,
    PredictorMetadata,
    load_pt2_predictor,
    save_pt2,
    script_predictor,
)
from bemlearn.export.checkpoint import load_checkpoint, write_checkpoint
from bemlearn.export.folded_posterior import FoldedPosterior
from bemlearn.export.variance_factor import variance_factor
from bemlearn.export.verify import verify_predictor
from bemlearn.fitting.calibration import (
    calibrate_replicas,
    condition_state,
    gaussian_quantile,
)
from bemlearn.models.band import band_and_gradient, band_reference
from bemlearn.models.input_noise import (
    estimator_noise_gains,
    mean_gradient,
    quantization_input_std,
    savgol_noise_std,
)
from bemlearn.models.learned_bem import LearnedBEM
from bemlearn.models.predictor_state import PredictorState
from bemlearn.pipeline.reliability import reliability_table

F64 = torch.float64
NAMES = ("qdd_a", "qd_a", "q_a", "qdd_u", "qd_u")


def _state(n=120, seed=0, x_mean=None, std_scale=1.3, input_std=(0.4, 0.05, 0.01, 0.3, 0.02), n_estimators=3) -> PredictorState:
    """An exact posterior of a smooth map, fixed hyperparameters, dense solve; ``n_estimators``
    random columns of estimator_delta (the estimator term of the band, eq. E2)."""
    g = torch.Generator().manual_seed(seed)
    d = 5
    X = torch.randn(n, d, generator=g, dtype=F64)
    y = torch.sin(X @ torch.tensor([0.8, -0.5, 0.6, 0.3, -0.2], dtype=F64)) + 0.02 * torch.randn(n, generator=g, dtype=F64)
    base = PredictorState(
        kind="exact", Z=X, alpha=torch.zeros(n, dtype=F64), S=torch.zeros(n, n, dtype=F64),
        lengthscale=torch.tensor([1.2, 1.5, 1.1, 1.4, 2.0], dtype=F64), outputscale=torch.tensor(1.1, dtype=F64),
        noise=torch.tensor(4e-4, dtype=F64),
        x_mean=torch.tensor([0.3, -0.1, 0.05, 0.2, 0.1], dtype=F64) if x_mean is None else x_mean,
        x_std=torch.tensor([20.0, 3.0, 0.5, 30.0, 2.0], dtype=F64), y_mean=torch.tensor(0.01, dtype=F64),
        y_std=torch.tensor(0.05, dtype=F64), input_names=NAMES, n_train=n,
        std_scale=torch.tensor(std_scale, dtype=F64), input_std=torch.tensor(input_std, dtype=F64),
    )
    L = torch.linalg.cholesky(base.gram())
    alpha = torch.cholesky_solve(y[:, None], L)[:, 0]
    delta = 0.004 * alpha.abs().max() * torch.randn(n, n_estimators, generator=g, dtype=F64)
    return dataclasses.replace(base, alpha=alpha, S=torch.cholesky_inverse(L), estimator_delta=delta)


def _estimator_term(state, x):
    """(1/K) Σ_k (μ_k − μ)², μ_k the mean with weights α + δ_k (dense, eq. E2)."""
    base = state.predict_reference(x)[0]
    shifts = [dataclasses.replace(state, alpha=state.alpha + state.estimator_delta[:, k]).predict_reference(x)[0] - base
              for k in range(state.n_estimators)]
    return torch.stack(shifts).square().mean(0) if shifts else torch.zeros_like(base)


def _meta(state) -> PredictorMetadata:
    return PredictorMetadata(
        robot="test", joint_names=("a", "u"), actuated_names=("a",), unactuated_name="u", m=1,
        input_names=state.input_names, units={n: "rad" for n in state.input_names}, n_train=state.n_train,
        n_inducing=None, hyperparameters={}, bemlearn_version="test", data_sha256="0" * 64,
    )


def _x(state, n=300, seed=1):
    g = torch.Generator().manual_seed(seed)
    return state.x_mean + 1.5 * state.x_std * torch.randn(n, state.dim, generator=g, dtype=F64)


def test_mean_gradient_matches_finite_differences():
    state = _state()
    x = _x(state, 40)
    g = mean_gradient(state, x)
    for i in range(state.dim):
        h = 1e-5 * float(state.x_std[i])
        dx = torch.zeros(state.dim, dtype=F64)
        dx[i] = h
        fd = (state.predict_reference(x + dx)[0] - state.predict_reference(x - dx)[0]) / (2 * h)
        torch.testing.assert_close(g[:, i], fd, rtol=1e-6, atol=1e-12)


def test_mean_gradient_in_blocks_equals_all_rows_at_once():
    """Rows across three blocks (GRADIENT_BLOCK each) give the bits of eq. (N2) computed on all rows at once,
    written out here as the dense ``(B, M, d)`` sum; and agree with finite differences (above) row by row."""
    from bemlearn.models.input_noise import GRADIENT_BLOCK, mean_gradient_from_row

    state = _state()
    x = _x(state, 2 * GRADIENT_BLOCK + 77, seed=4)
    k = state.kernel_row(x)
    diff = (state.normalize(x)[:, None, :] - state.Z[None, :, :]) / state.lengthscale   # every row at once
    dense = state.y_std * (-((k * state.alpha)[:, :, None] * diff).sum(1) / state.lengthscale) / state.x_std
    blocked = mean_gradient_from_row(state, x, k)
    assert blocked.shape == dense.shape == (x.shape[0], state.dim)
    assert torch.equal(blocked, dense)
    assert mean_gradient_from_row(state, x[:0], k[:0]).shape == (0, state.dim)


@pytest.mark.parametrize("n_inputs", [3, 5])
def test_band_reference_matches_autograd_formula(n_inputs):
    state = _state()
    x = _x(state, 50).requires_grad_(True)
    mean, latent = state.predict_reference(x)
    (grad,) = torch.autograd.grad(mean.sum(), x)
    s = state.input_std.clone()
    s[n_inputs:] = 0
    dense = torch.sqrt(1.3**2 * latent.detach() ** 2 + torch.maximum(((grad * s) ** 2).sum(1), _estimator_term(state, x.detach())))
    _, band, lat = band_reference(state, x.detach(), n_inputs=n_inputs)
    torch.testing.assert_close(band, dense, rtol=1e-10, atol=0)
    no_est = band_reference(dataclasses.replace(state, estimator_delta=None), x.detach(), n_inputs=n_inputs)[1]
    no_in = band_reference(dataclasses.replace(state, input_std=None), x.detach(), n_inputs=n_inputs)[1]
    # the larger of the two terms: each one decides somewhere
    assert bool((band >= torch.maximum(no_est, no_in)).all()) and bool((band > no_est).any()) and bool((band > no_in).any())
    torch.testing.assert_close(lat, latent.detach(), rtol=0, atol=0)
    # the same terms from one kernel row, with the gradient autograd gives
    mean4, band4, lat4, grad4 = band_and_gradient(state, x.detach(), n_inputs=n_inputs)
    torch.testing.assert_close(grad4, grad, rtol=1e-10, atol=1e-14)
    torch.testing.assert_close(band4, band, rtol=1e-12, atol=0)
    torch.testing.assert_close(mean4, mean.detach(), rtol=1e-12, atol=1e-15)
    torch.testing.assert_close(lat4, lat, rtol=0, atol=0)


@pytest.mark.parametrize("kind", ["exact", "sgpr"])
@pytest.mark.parametrize("form", ["raw", "centered"])
@pytest.mark.parametrize("n_inputs", [3, 5])
@pytest.mark.parametrize("terms", ["all", "no estimator term", "estimator term only"])
def test_folded_band_matches_dense(form, n_inputs, kind, terms):
    state = _state(n_estimators=0 if terms == "no estimator term" else 3,
                   input_std=(0.0,) * 5 if terms == "estimator term only" else (0.4, 0.05, 0.01, 0.3, 0.02))
    if kind == "sgpr":  # same S read as a general symmetric matrix: the eigen-factor path, no triangular solve
        state = dataclasses.replace(state, kind="sgpr")
    fp = FoldedPosterior(state, variance_factor(state), n_inputs=n_inputs, form=form)
    x = _x(state)
    x0 = x.clone()
    x0[:, n_inputs:] = 0
    mean, band = fp.mean_band(x[:, :n_inputs].contiguous())
    ref_mean, ref_band, _ = band_reference(state, x0, n_inputs=n_inputs)
    torch.testing.assert_close(mean, ref_mean, rtol=0, atol=1e-10)
    torch.testing.assert_close(band, ref_band, rtol=1e-8, atol=0)
    # chunked evaluation agrees with one block
    fp_chunked = FoldedPosterior(state, variance_factor(state), n_inputs=n_inputs, form=form, chunk=7)
    torch.testing.assert_close(fp_chunked.mean_band(x[:, :n_inputs].contiguous())[1], band, rtol=1e-12, atol=0)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    state = _state()
    eager = BEMPredictor(state, _meta(state))
    path = save_pt2(eager, tmp_path_factory.mktemp("band") / "bem_predictor.pt2")
    return state, eager, script_predictor(eager), load_pt2_predictor(path)


def test_export_parity_band_and_latent(exported):
    state, eager, scripted, pt2 = exported
    x = _x(state, 200)
    xb = x[:, :3].contiguous()
    x0 = torch.cat([xb, torch.zeros(200, 2, dtype=F64)], 1)
    _, ref_band, ref_lat = band_reference(state, x0, n_inputs=3)
    _, ref_full, ref_full_lat = band_reference(state, x)
    for name, inp, ref in (("forward", xb, ref_band), ("predict_full", x, ref_full),
                           ("forward_latent", xb, ref_lat), ("predict_full_latent", x, ref_full_lat)):
        m0, s0 = getattr(eager, name)(inp)
        torch.testing.assert_close(s0, ref, rtol=1e-8, atol=0)
        for other in (scripted, pt2):
            m1, s1 = getattr(other, name)(inp)
            torch.testing.assert_close(m1, m0, rtol=0, atol=1e-12)
            torch.testing.assert_close(s1, s0, rtol=1e-8, atol=0)
    verify_predictor(scripted, state, where="scripted")


def test_metadata_documents_the_band(exported):
    import json

    state, _, scripted, _ = exported
    doc = json.loads(scripted.metadata())
    assert doc["uncertainty"]["std_scale"] == pytest.approx(1.3, rel=0, abs=0)
    assert doc["normalization"]["input_std"] == state.input_std.tolist()
    assert doc["uncertainty"]["n_estimators"] == state.n_estimators == 3
    assert "latent_std" in doc["outputs"] and doc["outputs"]["forward_latent"] == ["mean", "latent_std"]


def test_old_checkpoint_without_band_fields_loads_as_latent(tmp_path):
    state = _state()
    path = write_checkpoint(tmp_path, model_state={}, predictor_state=state, metadata=_meta(state))
    data = torch.load(path, weights_only=True)
    for key in ("std_scale", "input_std", "estimator_delta"):
        del data["predictor_state"][key]
    data.pop("content_sha256", None)  # a checkpoint from before the band had no content hash either
    torch.save(data, path)
    old = load_checkpoint(path).predictor_state
    assert float(old.std_scale) == 1.0 and bool((old.input_std == 0).all()) and old.n_estimators == 0
    x = _x(state, 20)
    _, std = BEMPredictor(old, _meta(old))(x[:, :3].contiguous())
    _, ref_lat = old.predict_reference(torch.cat([x[:, :3], torch.zeros(20, 2, dtype=F64)], 1))
    torch.testing.assert_close(std, ref_lat, rtol=1e-8, atol=0)
    again = load_checkpoint(write_checkpoint(tmp_path / "new", model_state={}, predictor_state=state, metadata=_meta(state)))
    torch.testing.assert_close(again.predictor_state.input_std, state.input_std, rtol=0, atol=0)
    torch.testing.assert_close(again.predictor_state.estimator_delta, state.estimator_delta, rtol=0, atol=0)


def test_noise_gains_match_closed_forms():
    dt = 1 / 400.0
    g1, g2 = estimator_noise_gains(make_estimator("savgol", {"window": 121, "polyorder": 4}), 400.0)
    from scipy.signal import savgol_coeffs

    assert g1 == pytest.approx(np.linalg.norm(savgol_coeffs(121, 4, deriv=1, delta=dt)), rel=1e-10)
    assert g2 == pytest.approx(np.linalg.norm(savgol_coeffs(121, 4, deriv=2, delta=dt)), rel=1e-10)
    c1, c2 = estimator_noise_gains(make_estimator("central"), 400.0)
    assert c1 == pytest.approx(math.sqrt(2) / (2 * dt), rel=1e-12) and c2 == pytest.approx(math.sqrt(6) / dt**2, rel=1e-12)
    step = 2 * math.pi / 4096
    s = quantization_input_std(NAMES, {"a": step}, estimator=make_estimator("savgol", {"window": 121, "polyorder": 4}),
                               sample_rate_hz=400.0)
    sd, sdd = savgol_noise_std(121, 4, 400.0, step)
    torch.testing.assert_close(s, torch.tensor([sdd, sd, step / math.sqrt(12), 0.0, 0.0], dtype=F64), rtol=1e-10, atol=0)


def test_noisy_input_band_covers_truth_with_known_input_noise():
    """f known; training and test inputs observed with known Gaussian noise s: the band with
    input_std = s covers f(x_true) at ≈ the nominal rate, the latent std far less often."""
    g = torch.Generator().manual_seed(3)
    s = torch.tensor([0.15, 0.15, 0.15, 0.15, 0.15], dtype=F64)
    w = torch.tensor([0.9, -0.6, 0.5, 0.4, -0.3], dtype=F64)

    def f(x):
        return torch.sin(x @ w)

    xt = torch.randn(1500, 5, generator=g, dtype=F64)
    xh = xt + s * torch.randn(1500, 5, generator=g, dtype=F64)
    st = _state(n=3, std_scale=1.0, input_std=tuple(s.tolist()))
    st = dataclasses.replace(st, x_mean=torch.zeros(5, dtype=F64), x_std=torch.ones(5, dtype=F64),
                             y_mean=torch.tensor(0.0, dtype=F64), y_std=torch.tensor(1.0, dtype=F64),
                             lengthscale=torch.full((5,), 1.5, dtype=F64), noise=torch.tensor(0.03, dtype=F64))
    post = condition_state(st, xh, f(xt))
    post = dataclasses.replace(post, std_scale=torch.tensor(1.0, dtype=F64), input_std=s)
    xq = torch.randn(4000, 5, generator=g, dtype=F64) * 0.6
    xq_obs = xq + s * torch.randn(4000, 5, generator=g, dtype=F64)
    mean, band, lat = band_reference(post, xq_obs)
    err = (mean - f(xq)).numpy()
    cov_band = float(np.mean(np.abs(err) <= 2 * band.numpy()))
    cov_lat = float(np.mean(np.abs(err) <= 2 * lat.numpy()))
    assert 0.90 <= cov_band <= 0.995, cov_band
    assert cov_lat < 0.8, cov_lat


def test_replica_calibration_sees_trial_correlated_errors():
    """i.i.d. noise as modelled → c = 1 (raw ≤ 1.4: replicas never inflate an honest σ̃); a
    per-trial offset the GP does not model → c at least twice that."""
    g = torch.Generator().manual_seed(5)
    n_trials, per = 20, 60
    x = torch.randn(n_trials * per, 5, generator=g, dtype=F64)
    trial = torch.arange(n_trials).repeat_interleave(per)
    f = torch.sin(x @ torch.tensor([0.9, -0.6, 0.5, 0.4, -0.3], dtype=F64))
    st = _state(n=3, std_scale=1.0)
    st = dataclasses.replace(st, x_mean=torch.zeros(5, dtype=F64), x_std=torch.ones(5, dtype=F64),
                             y_mean=torch.tensor(0.0, dtype=F64), y_std=torch.tensor(1.0, dtype=F64),
                             lengthscale=torch.full((5,), 1.5, dtype=F64), noise=torch.tensor(0.01, dtype=F64), n_train=300)
    q = torch.randn(500, 5, generator=g, dtype=F64) * 0.7
    iid = f + 0.1 * torch.randn(len(f), generator=g, dtype=F64)
    c_iid = calibrate_replicas(st, x, iid, trial, q, n_points=300, n_pairs=4)
    offset = 0.5 * torch.randn(n_trials, generator=g, dtype=F64)[trial]
    c_off = calibrate_replicas(st, x, iid + offset, trial, q, n_points=300, n_pairs=4)
    assert c_iid.raw_scale <= 1.4 and c_iid.scale == 1.0, c_iid
    assert c_off.raw_scale >= 2.0 * c_iid.raw_scale and c_off.scale >= 1.5, (c_iid, c_off)
    with pytest.raises(ValueError, match="2 distinct trials"):
        calibrate_replicas(st, x, iid, torch.zeros_like(trial), q)


def test_residual_split_replicas_see_the_lockstep_extrapolation():
    """Inputs [a, ȧ, q, u, u̇] where u moves in lockstep with a (u = −0.8 a + 0.15 ε, u̇ = 0.6 ȧ + 0.15 ε'),
    f = sin(x·w) + u², a GP whose lengthscale (3) is too long for that curvature, queries at u = u̇ = 0 (the BEM
    slice), six seeds.  Every trial has the same lockstep, so trial halves agree (mean raw c ≈ 0.95) while
    μ ± 1.96 σ̃ holds the true f at the queries on about 62 %; halves split by u's residual from the actuated
    columns (C2) disagree more (mean raw ≥ 1.25 × the trial split's) and raise the mean coverage by ≥ 4 points
    (measured 62 → 69 %: the split sees part of the extrapolation error, not all of it).  With independent
    inputs and a lengthscale that fits (1.5, no u² term) no split inflates σ̃ (every raw ≤ 1.4, c = 1)."""
    w = torch.tensor([0.9, -0.6, 0.5, 0.4, -0.3], dtype=F64)
    n_trials, per = 20, 60
    trial = torch.arange(n_trials).repeat_interleave(per)

    def state(ls):
        st = _state(n=3, std_scale=1.0)
        return dataclasses.replace(st, x_mean=torch.zeros(5, dtype=F64), x_std=torch.ones(5, dtype=F64),
                                   y_mean=torch.tensor(0.0, dtype=F64), y_std=torch.tensor(1.0, dtype=F64),
                                   lengthscale=torch.full((5,), ls, dtype=F64), noise=torch.tensor(0.01, dtype=F64), n_train=300)

    kw = dict(n_points=300, n_pairs=4, lockstep_columns=(3, 4), motion_columns=3, column_names=NAMES)
    raw_t, raw_u, cov_t, cov_u = [], [], [], []
    for seed in range(6):
        g = torch.Generator().manual_seed(seed)
        x = torch.randn(n_trials * per, 5, generator=g, dtype=F64)
        q = torch.randn(500, 5, generator=g, dtype=F64) * 0.7
        q[:, 3:] = 0.0
        noise = 0.1 * torch.randn(len(x), generator=g, dtype=F64)
        if seed < 2:
            honest = calibrate_replicas(state(1.5), x, torch.sin(x @ w) + noise, trial, q, seed=seed, **kw)
            assert max(honest.raw_by_split.values()) <= 1.4 and honest.scale == 1.0, honest
            assert set(honest.raw_by_split) == {"trials", NAMES[3], NAMES[4]}
        xl = x.clone()
        xl[:, 3] = -0.8 * x[:, 0] + 0.15 * x[:, 3]
        xl[:, 4] = 0.6 * x[:, 1] + 0.15 * x[:, 4]
        y = torch.sin(xl @ w) + xl[:, 3] ** 2 + noise
        st = state(3.0)
        cal = calibrate_replicas(st, xl, y, trial, q, seed=seed, **kw)
        raw_t.append(cal.raw_by_split["trials"])
        raw_u.append(cal.raw_by_split[NAMES[3]])
        mean, lat = condition_state(st, xl[::4], y[::4]).predict_reference(q)
        err = (mean - torch.sin(q @ w)).abs()
        cov_t.append(float((err <= 1.96 * max(1.0, raw_t[-1]) * lat).double().mean()))
        cov_u.append(float((err <= 1.96 * cal.scale * lat).double().mean()))
    assert np.mean(raw_u) >= 1.25 * np.mean(raw_t), (raw_t, raw_u)
    assert np.mean(cov_t) < 0.75 and np.mean(cov_u) >= np.mean(cov_t) + 0.04, (cov_t, cov_u)
    only = calibrate_replicas(st, xl, y, trial, q, n_points=300, n_pairs=4)
    assert only.raw_by_split == {"trials": only.raw_scale} and only.method == "trial-split replicas"


def test_reliability_table_on_gaussian_errors():
    rng = np.random.default_rng(0)
    std = rng.uniform(0.5, 2.0, 40_000)
    e = std * rng.standard_normal(std.size)
    for row in reliability_table(e, std):
        assert row["coverage"] == pytest.approx(row["level"], abs=0.01)
        assert row["kappa"] == pytest.approx(gaussian_quantile(row["level"]), rel=1e-12)
    assert gaussian_quantile(0.95) == pytest.approx(1.959963984540054, rel=1e-12)
    assert LearnedBEM.nominal_confidence(2.0) == pytest.approx(0.9544997361036416, rel=1e-12)


def test_calibrate_band_takes_the_datasets_resolved_config():
    """The σ the datasets chose from the data is calibrated with, not chosen again: a config that still leaves
    it to the data is an argument error naming the config to pass (GPDatasets.config)."""
    from bemlearn.data import DatasetConfig
    from bemlearn.errors import ArgumentError
    from bemlearn.pipeline.uncertainty import calibrate_band

    assert not DatasetConfig().estimator().resolved
    with pytest.raises(ArgumentError, match="GPDatasets.config"):
        calibrate_band(None, None, DatasetConfig())  # type: ignore[arg-type]  # refused before either is read
