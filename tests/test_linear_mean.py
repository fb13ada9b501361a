"""The linear prior mean of the BEM GP (eq. L1, L2 of ``bemlearn.fitting.linear_mean``): the plane is fitted by least
squares, the kernel on its residual; the data choose between it and the zero mean by the marginal likelihood with the
plane's coefficients priced; the plane reaches the reference posterior, the band's gradient, the replica calibration,
the checkpoint and every export (TorchScript, C) — each checked against an independent computation here."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from test_export_c import N_ESTIMATORS, _banded, _build, _in_range
from test_export_parity import _exact_case, _metadata, _sgpr_factored_case, _svgp_case

from bemlearn.data.normalization import Normalization
from bemlearn.errors import CheckpointError
from bemlearn.export import BEMPredictor
from bemlearn.export.c_build import find_cc
from bemlearn.export.folded_posterior import FoldedPosterior
from bemlearn.export.variance_factor import variance_factor
from bemlearn.export.verify import verify_predictor
from bemlearn.fitting.calibration import condition_state
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.fitting.linear_mean import choose_prior_mean, least_squares_slope
from bemlearn.models.band import band_reference
from bemlearn.models.input_noise import mean_gradient
from bemlearn.models.plane_posterior import with_plane_posterior
from bemlearn.models.predictor_state import PredictorState
from bemlearn.pipeline.gp_stage import CheckpointProvenance, fit_bem_gp

NAMES = ("qdd_arm", "qd_arm", "q_arm", "qdd_pole", "qd_pole")
UNITS = dict(zip(NAMES, ("rad/s^2", "rad/s", "rad", "rad/s^2", "rad/s")))
#: The plane of the synthetic BEM (rad per input unit): q_u ≈ −0.02 q̈_a + 0.05 q̇_a − 0.3 q_a + 0.01 q̈_u.
PLANE = torch.tensor([-0.02, 0.05, -0.3, 0.01, 0.0], dtype=torch.float64)


def _inputs(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    scale = torch.tensor([4.0, 1.0, 0.3, 2.0, 0.5], dtype=torch.float64)
    return scale * torch.randn(n, 5, generator=g, dtype=torch.float64)


def _fit(tmp_path, x, y, mean: str):
    return fit_bem_gp(
        x, y, tmp_path, normalization=Normalization.fit(x, y, names=NAMES), input_names=NAMES, units=UNITS,
        config=GPConfig(kind="exact", max_iter=80, mean=mean),
        provenance=CheckpointProvenance(robot={"name": "synthetic", "mjcf": None}, joint_names=("arm", "pole"),
                                        unactuated_name="pole", data_sha256="0" * 64),
        progress=False,
    )


def test_least_squares_slope_recovers_a_plane_in_normalized_units_and_leaves_fixed_columns_out():
    x = _inputs(200, 0)
    norm = Normalization.fit(x, x @ PLANE, names=NAMES)
    xn, yn = norm.normalize_x(x), norm.normalize_y(x @ PLANE)
    beta = least_squares_slope(xn, yn)
    # ỹ = Σ β̃_i x̃_i  ⇔  y = y_mean + y_std Σ β̃_i (x_i − x_mean_i)/x_std_i: β̃ = PLANE x_std / y_std
    torch.testing.assert_close(beta, PLANE * norm.x_std / norm.y_std, rtol=1e-6, atol=1e-9)
    kept = least_squares_slope(xn, yn, fixed=[1, 4])
    assert float(kept[1]) == 0.0 and float(kept[4]) == 0.0 and float(kept[2]) != 0.0
    with pytest.raises(ValueError, match="more rows than columns"):
        least_squares_slope(xn[:5], yn[:5])


def test_the_plane_is_kept_only_when_it_pays_for_its_coefficients():
    n = 500
    price = 0.5 * 5 * math.log(n)
    # per-point losses: the plane gains one nat more, or one nat less, than its price ½ p log N (eq. L2)
    gain_more = choose_prior_mean(-2.0 - (price + 1.0) / n, -2.0, n=n, n_coefficients=5, explained=0.99)
    gain_less = choose_prior_mean(-2.0 - (price - 1.0) / n, -2.0, n=n, n_coefficients=5, explained=0.99)
    assert gain_more["chosen"] == "linear" and gain_less["chosen"] == "zero"
    assert gain_more["penalty"] == pytest.approx(price)
    assert choose_prior_mean(float("nan"), -2.0, n=n, n_coefficients=5, explained=0.5)["chosen"] == "zero"


def test_a_plane_is_learned_and_extrapolated_with_the_linear_mean_while_the_zero_mean_reverts(tmp_path):
    """q_u = plane + 0.02 cos(q̈_a / 2) + noise (a BEM that bends within the data, evenly): the data choose the plane (eq. L2);
    ten data spreads beyond the excited q̈_a the linear mean stays within twice the bend's amplitude of the truth and
    within its own ±2σ (the generalized-least-squares plane of eq. L4 partly takes the bend for slope, which the
    coefficients' variance of eq. L3 states: σ ≈ 0.077 there; the ordinary least-squares plane missed by 0.027), while
    the zero-mean GP, whose q̈_a lengthscale the bend keeps short, reverts to the data's mean and misses by the plane."""
    x = _inputs(400, 1)
    g = torch.Generator().manual_seed(2)

    def truth(x):
        return x @ PLANE + 0.02 * torch.cos(x[:, 0] / 2)

    y = truth(x) + 1e-3 * torch.randn(400, generator=g, dtype=torch.float64)
    auto = _fit(tmp_path / "auto", x, y, "auto")
    zero = _fit(tmp_path / "zero", x, y, "zero")
    assert auto.fit["prior_mean"]["chosen"] == "linear" and auto.state.linear_mean
    assert auto.fit["prior_mean"]["estimate"] == "generalized least squares"     # an exact GP: eq. (L4)
    assert zero.fit["prior_mean"]["chosen"] == "zero" and not zero.state.linear_mean
    q = torch.tensor([[40.0, 0.5, 0.1, 0.0, 0.0], [-40.0, -0.5, -0.2, 0.0, 0.0]], dtype=torch.float64)   # q̈_a at 10σ
    mu, sd = auto.state.predict_reference(q)[:2]
    assert float((mu - truth(q)).abs().max()) < 0.04                                    # the bend: ±0.02
    assert bool(((mu - truth(q)).abs() < 2 * sd).all())
    assert float((zero.state.predict_reference(q)[0] - truth(q)).abs().max()) > 0.3
    # inside the data both are right
    qi = x[:20].clone()
    qi[:, 3:] = 0.0
    for stage in (auto, zero):
        assert float((stage.state.predict_reference(qi)[0] - truth(qi)).abs().max()) < 5e-3


def test_a_label_without_a_linear_trend_keeps_the_zero_mean(tmp_path):
    """q_u = 0.1 cos(q̇_a) + 0.05 cos(2 q_a / 0.3): even in every input, so the best plane is flat and does not pay for
    its coefficients (eq. L2)."""
    x = _inputs(300, 3)
    g = torch.Generator().manual_seed(4)
    y = 0.1 * torch.cos(x[:, 1]) + 0.05 * torch.cos(2 * x[:, 2] / 0.3) + 1e-3 * torch.randn(300, generator=g, dtype=torch.float64)
    stage = _fit(tmp_path, x, y, "auto")
    choice = stage.fit["prior_mean"]
    assert choice["chosen"] == "zero" and not stage.state.linear_mean
    assert choice["explained"] < 0.05
    assert choice["nlml_linear"] + choice["penalty"] >= choice["nlml_zero"]


def _linear(state: PredictorState, seed: int = 3) -> PredictorState:
    g = torch.Generator().manual_seed(seed)
    return dataclasses.replace(state, mean_slope=torch.randn(state.dim, generator=g, dtype=torch.float64))


def _with_coefficients(state: PredictorState, seed: int = 4) -> PredictorState:
    """``state`` with the plane coefficients' variance (eq. L3): computed for an exact state, drawn (random P, a
    positive semi-definite A of rank d − 1, so that a direction without variance is exercised too) for a sparse one."""
    if not state.sparse:
        return with_plane_posterior(state)
    g = torch.Generator().manual_seed(seed)
    B = torch.randn(state.dim, state.dim - 1, generator=g, dtype=torch.float64)
    A = 0.05 * B @ B.T
    return dataclasses.replace(state, plane_weights=0.1 * torch.randn(state.n_support, state.dim, generator=g, dtype=torch.float64),
                               plane_cov=0.5 * (A + A.T))


def test_the_plane_enters_the_reference_mean_and_its_gradient():
    _, base = _exact_case(200, 1, seed=7)
    st = _linear(_banded(base))
    x = st.x_mean + st.x_std * torch.randn(64, st.dim, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    plane = st.y_std * ((x - st.x_mean) / st.x_std) @ st.mean_slope
    torch.testing.assert_close(st.predict_reference(x)[0], base.predict_reference(x)[0] + plane, rtol=0, atol=1e-12)
    torch.testing.assert_close(st.predict_reference(x)[1], base.predict_reference(x)[1], rtol=0, atol=0)
    # ∂μ/∂x (eq. N2 with the plane) against central differences of the reference mean
    h = 1e-6 * st.x_std
    fd = torch.stack([(st.predict_reference(x + h[i] * torch.eye(st.dim, dtype=torch.float64)[i])[0]
                       - st.predict_reference(x - h[i] * torch.eye(st.dim, dtype=torch.float64)[i])[0]) / (2 * h[i])
                      for i in range(st.dim)], 1)
    torch.testing.assert_close(mean_gradient(st, x), fd, rtol=1e-6, atol=1e-8)
    # the band's input-noise term (eq. N1) uses it: with s > 0 the band differs from the zero-mean state's
    assert float((band_reference(st, x)[1] - band_reference(_banded(base), x)[1]).abs().max()) > 1e-6


@pytest.mark.parametrize("build", [_exact_case, _sgpr_factored_case, _svgp_case], ids=["exact", "sgpr-factored", "svgp"])
def test_exports_carry_the_plane(build, tmp_path):
    """The eager predictor (raw and centred folded forms) and the TorchScript file against the dense reference with
    the plane, with the calibrated band (c ≠ 1, s > 0, K estimator columns); a predictor verified against the state
    without its plane is refused."""
    _, base = build(300, 2, seed=7)
    g = torch.Generator().manual_seed(5)
    st = _with_coefficients(_linear(dataclasses.replace(_banded(base), estimator_delta=1e-3 * torch.randn(
        base.n_support, N_ESTIMATORS, generator=g, dtype=torch.float64))))
    assert st.plane_variance
    meta = _metadata(st, 2)
    verify_predictor(BEMPredictor(st, meta), st)
    with pytest.raises(CheckpointError, match="disagrees with the dense posterior"):   # the term counts in the export
        verify_predictor(BEMPredictor(st, meta), dataclasses.replace(st, plane_weights=None, plane_cov=None))
    factor = variance_factor(st)
    x = st.x_mean + 2 * st.x_std * torch.randn(300, st.dim, generator=g, dtype=torch.float64)
    for form in ("raw", "centered"):
        for n in (6, st.dim):
            post = FoldedPosterior(st, factor, n_inputs=n, form=form)
            x0 = torch.cat([x[:, :n], torch.zeros(len(x), st.dim - n, dtype=torch.float64)], 1)
            ref_mean, ref_band, _ = band_reference(st, x0, n_inputs=n)
            mean, band = post.mean_band(x[:, :n].contiguous())
            torch.testing.assert_close(mean, ref_mean, rtol=0, atol=1e-10)
            torch.testing.assert_close(band, ref_band, rtol=1e-8, atol=0)
            torch.testing.assert_close(post.mean(x[:, :n].contiguous()), mean, rtol=0, atol=0)
    if find_cc() is None:
        pytest.skip("no C compiler (cc, gcc, clang or $CC) on PATH: the TorchScript file is checked, the C file is not")
    lib, ts = _build(st, meta, tmp_path)
    verify_predictor(ts, st)
    with pytest.raises(CheckpointError, match="disagrees with the dense posterior"):
        verify_predictor(ts, dataclasses.replace(st, mean_slope=None, plane_weights=None, plane_cov=None))
    for full in (False, True):
        x, _, _ = _in_range(st, 1000, seed=1, width=st.dim if full else 6)
        x = np.ascontiguousarray(x)
        ref_mean, ref_std = (t.numpy() for t in (ts.predict_full if full else ts.forward)(torch.from_numpy(x)))
        mean, std, codes = lib.forward(x, full=full)
        assert np.all(codes == 0)
        assert np.abs(mean - ref_mean).max() <= 1e-10
        assert np.abs(std / ref_std - 1).max() <= 1e-8
        assert np.array_equal(lib.mean(x, full=full), mean)


def test_float32_c_export_carries_the_plane(tmp_path):
    if find_cc() is None:
        pytest.skip("no C compiler (cc, gcc, clang or $CC) on PATH")
    _, base = _sgpr_factored_case(400, 2, seed=7)
    st = _with_coefficients(_linear(_banded(base)))
    meta = _metadata(st, 2)
    lib, ts = _build(st, meta, tmp_path, prefix="lin32", dtype="float32")
    x, _, _ = _in_range(st, 1000, seed=3, width=6)
    x = x.astype(np.float32).astype(np.float64)
    ref_mean, ref_std = (t.numpy() for t in ts.forward_latent(torch.from_numpy(x)))
    mean, std, codes = lib.forward(x, latent=True)
    assert np.all(codes == 0) and np.abs(std / ref_std - 1).max() <= 1e-3   # the coefficients' variance (eq. L3) too
    st = _linear(_banded(base))
    lib, ts = _build(st, meta, tmp_path / "plain", prefix="lin32", dtype="float32")
    x, _, _ = _in_range(st, 1000, seed=3, width=6)
    x = x.astype(np.float32).astype(np.float64)
    ref_mean = ts.forward(torch.from_numpy(x))[0].numpy()
    mean, _, codes = lib.forward(x)
    assert np.all(codes == 0) and np.abs(mean - ref_mean).max() <= 1e-4
    # the plane is a sizable part of the mean here, so a float32 file without it would be far off
    plane = (st.predict_reference(torch.cat([torch.from_numpy(x), torch.zeros(len(x), 2, dtype=torch.float64)], 1))[0]
             - base.predict_reference(torch.cat([torch.from_numpy(x), torch.zeros(len(x), 2, dtype=torch.float64)], 1))[0])
    assert float(plane.abs().max()) > 100 * 1e-4


def test_the_coefficients_variance_is_the_vague_prior_limit_of_a_gp_with_the_plane_in_its_kernel():
    """Eqs. (L3)–(L4) against an independent computation: the plane's coefficients drawn from N(0, b I) are a kernel
    b h(x)ᵀh(x') added to the GP's (Rasmussen & Williams 2006, §2.7); its exact posterior mean and variance with a
    large b tend to the generalized-least-squares plane's mean (L4) and to (L3).  The term vanishes at the training
    rows (to the noise's order) and grows beyond them."""
    _, base = _exact_case(120, 1, seed=7)
    ols = torch.tensor([0.4, 0.0, -0.3, 0.2, 0.0], dtype=torch.float64)
    st = with_plane_posterior(dataclasses.replace(base, mean_slope=ols))
    used = [0, 2, 3]
    labels = base.gram() @ base.alpha + base.Z @ ols          # the normalized labels the state was conditioned on
    assert float(st.mean_slope[1]) == 0.0 and float(st.mean_slope[4]) == 0.0 and not torch.equal(st.mean_slope, ols)
    assert st.plane_variance and torch.equal(st.plane_cov[1], torch.zeros(5, dtype=torch.float64))
    X, H = st.Z, st.Z[:, used]
    x = st.x_mean + 3 * st.x_std * torch.randn(40, 5, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    xn = st.normalize(x)
    b = 1e7
    k = st.kernel_row(x)
    kx = k + b * xn[:, used] @ H.T
    Kb = st.gram() + b * H @ H.T
    var_b = st.outputscale + b * xn[:, used].square().sum(1) - (kx * torch.linalg.solve(Kb, kx.T).T).sum(1)
    mean, latent = st.predict_reference(x)[:2]
    torch.testing.assert_close(latent.square(), st.y_std**2 * var_b, rtol=1e-5, atol=0)
    mean_b = kx @ torch.linalg.solve(Kb, labels)
    torch.testing.assert_close((mean - st.y_mean) / st.y_std, mean_b, rtol=0, atol=1e-6 * float(mean_b.abs().max()))
    # the ordinary plane's mean differs from that limit by more than the tolerance: the check sees (L4)
    ols_mean = (base.predict_reference(x)[0] - base.y_mean) / base.y_std + st.normalize(x) @ ols
    assert float((ols_mean - mean_b).abs().max()) > 1e-3 * float(mean_b.abs().max())
    # without the term: the kernel's own variance, smaller
    assert bool((latent > base.predict_reference(x)[1] * (1 + 1e-9)).all())
    # at the training rows the coefficients are known through the data: the term is of the noise's order there
    train = st.x_mean + st.x_std * X
    assert float(st.plane_term(train, st.kernel_row(train)).max()) < 10 * float(st.noise)
    # far out r → x̃: the term grows like the squared distance along a used column
    far = [st.plane_term(p, st.kernel_row(p)).item() for p in (st.x_mean + st.x_std * s * torch.eye(5, dtype=torch.float64)[0:1]
                                                               for s in (50.0, 100.0))]
    assert far[1] / far[0] == pytest.approx(4.0, rel=1e-6)


def test_the_coefficients_variance_names_what_it_cannot_compute():
    """A sparse state is refused, a plane column the rows do not vary is named, and a Gram matrix that is not
    numerically positive definite (repeated rows, no noise) is factored with a jitter and a warning."""
    from bemlearn.errors import ArgumentError
    from bemlearn.warnings import NumericalWarning

    _, sparse = _sgpr_factored_case(200, 1, seed=7)
    with pytest.raises(ArgumentError, match="an exact posterior is needed"):
        with_plane_posterior(_linear(sparse))
    _, base = _exact_case(60, 1, seed=7)
    slope = torch.tensor([0.4, 0.0, -0.3, 0.0, 0.0], dtype=torch.float64)
    flat = base.Z.clone()
    flat[:, 2] = 0.0
    with pytest.raises(ArgumentError, match=r"do not determine the plane's coefficients \(columns \['qdd_arm', 'q_arm'\]\)"):
        with_plane_posterior(dataclasses.replace(base, Z=flat, mean_slope=slope, input_names=NAMES))
    doubled = torch.cat([base.Z, base.Z])
    st = dataclasses.replace(base, Z=doubled, alpha=torch.cat([base.alpha, base.alpha]), S=torch.zeros(120, 120, dtype=torch.float64),
                             estimator_delta=None, noise=torch.tensor(0.0, dtype=torch.float64), mean_slope=slope)
    with pytest.warns(NumericalWarning, match="plane coefficients' variance"):
        st = with_plane_posterior(st)
    assert st.plane_variance and bool(torch.isfinite(st.plane_cov).all())


def test_an_exact_fit_with_the_plane_carries_its_coefficients_variance(tmp_path):
    x = _inputs(300, 1)
    g = torch.Generator().manual_seed(2)
    y = x @ PLANE + 0.02 * torch.sin(x[:, 1]) + 1e-3 * torch.randn(300, generator=g, dtype=torch.float64)
    st = _fit(tmp_path, x, y, "linear").state
    assert st.plane_variance
    expected = with_plane_posterior(dataclasses.replace(st, plane_weights=None, plane_cov=None))
    torch.testing.assert_close(st.plane_cov, expected.plane_cov, rtol=0, atol=0)
    # the frozen plane is already the generalized-least-squares one (eq. L4): a second pass leaves it where it is
    torch.testing.assert_close(expected.mean_slope, st.mean_slope, rtol=0, atol=1e-10)
    # a replica conditioned on other rows carries the term for its own rows
    rep = condition_state(st, x[:150], y[:150])
    assert rep.plane_variance and rep.plane_weights.shape == (150, 5)


def test_a_replica_refits_the_plane_on_its_own_data():
    _, base = _exact_case(200, 1, seed=7)
    st = _linear(base)
    x = st.x_mean + st.x_std * torch.randn(150, st.dim, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    other = torch.tensor([0.5, -0.2, 0.1, 0.3, -0.4], dtype=torch.float64)          # a different plane, normalized units
    y = st.y_mean + st.y_std * (((x - st.x_mean) / st.x_std) @ other)
    rep = condition_state(st, x, y)
    xn = (x - st.x_mean) / st.x_std
    expected = least_squares_slope(xn, (y - st.y_mean) / st.y_std)
    torch.testing.assert_close(rep.mean_slope, expected, rtol=0, atol=1e-12)
    torch.testing.assert_close(rep.mean_slope, other, rtol=1e-6, atol=1e-6)
    # a zero-mean state's replica stays zero-mean
    assert not condition_state(base, x, y).linear_mean


def test_the_plane_survives_the_checkpoint_and_an_older_state_reads_as_zero_mean():
    _, base = _exact_case(100, 1, seed=7)
    st = _linear(base)
    back = PredictorState.from_dict(st.to_dict())
    assert torch.equal(back.mean_slope, st.mean_slope)
    full = with_plane_posterior(dataclasses.replace(st, S=torch.cholesky_inverse(torch.linalg.cholesky(st.gram()))))
    back = PredictorState.from_dict(full.to_dict())
    assert torch.equal(back.plane_cov, full.plane_cov) and torch.equal(back.plane_weights, full.plane_weights)
    with pytest.raises(CheckpointError, match="give both"):
        dataclasses.replace(full, plane_weights=None)
    with pytest.raises(CheckpointError, match="needs a plane"):
        dataclasses.replace(full, mean_slope=None)
    old = st.to_dict()
    del old["mean_slope"]
    assert not PredictorState.from_dict(old).linear_mean
    with pytest.raises(CheckpointError, match=r"mean_slope: expected shape \(5,\)"):
        dataclasses.replace(st, mean_slope=torch.zeros(3, dtype=torch.float64))


def test_the_report_says_which_prior_mean_the_run_used_and_why():
    from bemlearn.pipeline.report import _prior_mean_text
    from bemlearn.pipeline.run_metrics import FitInfo

    def text(doc):
        return _prior_mean_text(FitInfo.from_dict({"prior_mean": doc}).prior_mean)

    assert text({"chosen": "zero", "by": "train.mean: zero"}) == ""       # eq. (11) as configured: nothing to say
    assert text({"chosen": "linear", "by": "train.mean: linear", "explained": 0.9987}) == (
        " Prior mean: a least-squares plane in the inputs (eq. L1, explaining 99.87 % of the label's variance).")
    chosen = choose_prior_mean(-3.0, -2.9, n=500, n_coefficients=5, explained=0.99)      # 50 nats gained, 15.5 priced
    assert "Prior mean: a least-squares plane" in text(chosen) and "−log p -1500.0 + 15.5" in text(chosen)
    assert text({**chosen, "estimate": "generalized least squares"}).startswith(
        " Prior mean: a least-squares plane in the inputs (eq. L1, explaining 99.00 % of the label's variance); its coefficients "
        "then by generalized least squares under the fitted kernel (eq. L4) (−log p")
    kept_zero = choose_prior_mean(-2.91, -2.9, n=500, n_coefficients=5, explained=0.02)  # 5 nats gained, 15.5 priced
    assert text(kept_zero).startswith(" Prior mean: zero; a least-squares plane in the inputs (eq. L1, explaining 2.00 %")


def test_the_exported_metadata_states_the_plane_in_physical_units():
    import json

    _, base = _exact_case(100, 1, seed=7)
    st = _linear(base)
    doc = json.loads(BEMPredictor(st, _metadata(st, 1)).metadata_json)
    slope = doc["prior_mean"]["slope"]
    assert doc["prior_mean"]["kind"] == "linear" and list(slope) == list(st.input_names)
    # ∂(plane)/∂x_i = y_std β̃_i / x_std_i, q_u's unit per the column's unit
    for i, name in enumerate(st.input_names):
        assert slope[name] == pytest.approx(float(st.y_std * st.mean_slope[i] / st.x_std[i]), rel=1e-15)
    assert doc["normalization"]["mean_slope"] == st.mean_slope.tolist()
    assert doc["prior_mean"]["coefficient_variance"] is False       # a plane without its coefficients' term
    full = with_plane_posterior(dataclasses.replace(st, S=torch.cholesky_inverse(torch.linalg.cholesky(st.gram()))))
    assert json.loads(BEMPredictor(full, _metadata(full, 1)).metadata_json)["prior_mean"]["coefficient_variance"] is True
    assert "prior_mean" not in json.loads(BEMPredictor(base, _metadata(base, 1)).metadata_json)   # zero mean: as before
