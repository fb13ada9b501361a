"""Data-only evaluation: held-out q_u prediction and the learned BEM on slices, vs NumPy references."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from bemlearn.data import BEMDataset, Normalization, TrajectoryMeta
from bemlearn.models import LearnedBEM
from bemlearn.models.kernels import se_gram
from bemlearn.models.predictor_state import PredictorState
from bemlearn.pipeline.data_evaluation import (
    SliceSpec,
    bem_slice_figure,
    bem_slices,
    heldout_prediction,
)

NAMES = ("qdd_theta", "qd_theta", "q_theta", "qdd_alpha", "qd_alpha")
META = TrajectoryMeta(robot="rig", joint_names=("theta", "alpha"), unactuated="alpha", actuator_names=("motor",),
                      sample_rate_hz=400.0, trial_failed={0: False, 1: False, 2: False})


def truth(x: np.ndarray) -> np.ndarray:
    return -0.02 * x[:, 0] + 0.1 * np.sin(x[:, 1])


def dataset(n: int, seed: int, norm: Normalization | None = None, trials=(0,)) -> BEMDataset:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 5)) * np.array([10.0, 1.0, 0.3, 5.0, 0.5])
    y = truth(x) + rng.normal(scale=0.003, size=n)
    xt, yt = torch.from_numpy(x), torch.from_numpy(y)
    norm = norm or Normalization.fit(xt, yt, names=NAMES)
    trial = torch.as_tensor(np.resize(np.asarray(trials), n))
    return BEMDataset(xt, yt, normalization=norm, input_names=NAMES, output_name="q_alpha", meta=META,
                      trial=trial, row=torch.arange(n))


def exact_state(train: BEMDataset, lengthscale: np.ndarray, noise: float = 1e-3) -> PredictorState:
    """An exact-GP posterior built with a dense solve (the reference formulas of eq. 12)."""
    Z = train.x_normalized
    ls = torch.as_tensor(lengthscale, dtype=torch.float64)
    K = se_gram(Z, ls, torch.tensor(1.0, dtype=torch.float64)) + noise * torch.eye(len(Z), dtype=torch.float64)
    Kinv = torch.linalg.inv(K)
    return PredictorState(
        kind="exact", Z=Z, alpha=Kinv @ train.y_normalized, S=Kinv, lengthscale=ls,
        outputscale=torch.tensor(1.0, dtype=torch.float64), noise=torch.tensor(noise, dtype=torch.float64),
        x_mean=train.x_mean, x_std=train.x_std, y_mean=train.y_mean, y_std=train.y_std, input_names=NAMES,
        n_train=len(Z),
    )


def numpy_posterior(state: PredictorState, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and predictive std in physical units, from the formulas, in NumPy."""
    s = {k: v.numpy() for k, v in state.tensors().items()}
    k = state.kernel_row(torch.from_numpy(x)).numpy()   # σ_f² = 1 here
    mean = s["y_mean"] + s["y_std"] * (k @ s["alpha"])
    var = 1.0 - np.einsum("bi,ij,bj->b", k, s["S"], k) + s["noise"]
    return mean, s["y_std"] * np.sqrt(np.maximum(var, 0.0))


@pytest.fixture(scope="module")
def fitted():
    train = dataset(150, 0)
    return train, exact_state(train, np.array([1.5, 1.5, 3.0, 3.0, 3.0]))


def test_heldout_prediction_matches_numpy(fitted):
    train, state = fitted
    held = dataset(300, 1, train.normalization, trials=(1, 2))
    got = heldout_prediction(state, held)
    mean, sd = numpy_posterior(state, held.x.numpy())
    err = mean - held.y.numpy()
    assert got["rmse"] == pytest.approx(math.sqrt(np.mean(err**2)), rel=1e-9)
    assert got["coverage"] == pytest.approx(np.mean(np.abs(err) <= 2 * sd), abs=1e-12)
    assert got["n_points"] == 300 and got["unit"] == "rad" and set(got["per_trial"]) == {1, 2}
    odd = held.trial.numpy() == 2
    assert got["per_trial"][2]["rmse"] == pytest.approx(math.sqrt(np.mean(err[odd] ** 2)), rel=1e-9)
    bem = LearnedBEM(state, robot="rig", actuated_names=("theta",), unactuated_name="alpha")
    assert heldout_prediction(bem, held)["rmse"] == got["rmse"]


def test_heldout_rejects_other_inputs(fitted):
    train, state = fitted
    other = dataclasses.replace(state, input_names=("a", "b", "c", "d", "e"))
    with pytest.raises(ValueError, match=r"predictor's inputs \['a', .*differ from the dataset's"):
        heldout_prediction(other, train)


def test_slices_mean_band_and_coverage(fitted, tmp_path):
    train, state = fitted
    spec = SliceSpec(n_grid=41)
    res = bem_slices(state, train, spec)
    x = train.x.numpy()
    assert len(res["slices"]) == 5
    s = res["slices"][2]  # q̇ at the 90 % quantile, q at the median
    assert s["qd"] == pytest.approx(np.quantile(x[:, 1], 0.9)) and s["q"] == pytest.approx(np.median(x[:, 2]))
    query = np.zeros((41, 5))
    query[:, 0] = s["grid"]
    query[:, 1], query[:, 2] = s["qd"], s["q"]  # q̈_u = q̇_u = 0: the BEM (eq. 14)
    mean, sd = numpy_posterior(state, query)
    np.testing.assert_allclose(s["mean"], mean, rtol=0, atol=1e-10)
    np.testing.assert_allclose(s["std_pred"], sd, rtol=0, atol=1e-10)
    # covered: grid points with a training point within 3 median nearest-neighbour spacings, Mahalanobis
    # distance under the training inputs' covariance (scipy, independent of the module's whitening)
    from scipy.spatial.distance import cdist

    vi = np.linalg.inv(np.cov(x, rowvar=False))
    dtt = cdist(x, x, "mahalanobis", VI=vi)
    np.fill_diagonal(dtt, np.inf)
    spacing = np.median(dtt.min(1))
    dq = cdist(query, x, "mahalanobis", VI=vi)
    sup = dq.min(1) <= 3.0 * spacing
    assert s["covered"] == pytest.approx([s["grid"][sup].min(), s["grid"][sup].max()])
    assert s["n_near"] == int((dq.min(0) <= 3.0 * spacing).sum()) >= 5
    # the band is wider outside the data than inside
    assert res["summary"]["std_pred_mean_extrapolated"] > 2 * res["summary"]["std_pred_mean_covered"]
    fig = bem_slice_figure(res, tmp_path / "slices.png", unactuated="alpha")
    assert (tmp_path / "slices.png").stat().st_size > 10_000 and len(fig.axes) == 6


def test_slice_coverage_ignores_the_gp_lengthscales(fitted):
    """A lengthscale of 1000 (or 1e-3) on an input must not make the data cover more (or less): the
    coverage is the data's own (S1), whatever the fit."""
    train, state = fitted
    spec = SliceSpec(n_grid=11)
    ref = bem_slices(state, train, spec)
    for ls in (1e-3, 1e3):
        other = bem_slices(dataclasses.replace(state, lengthscale=torch.full((5,), ls, dtype=torch.float64)), train, spec)
        assert [s["covered"] for s in other["slices"]] == [s["covered"] for s in ref["slices"]]


def test_resolution_ranges_are_the_covered_quantiles(fitted):
    """Each input's range in bem_resolution is the 2.5–97.5 % quantile range of the training data (the report
    quotes it; it once quoted ±1 std)."""
    from bemlearn.pipeline.data_evaluation import COVERED_QUANTILES, bem_resolution

    train, state = fitted
    res = bem_resolution(state, train)
    x = train.x.numpy()
    assert COVERED_QUANTILES == (0.025, 0.975)
    for w in res["inputs"]:
        i = NAMES.index(w["input"])
        np.testing.assert_allclose(w["range"], np.quantile(x[:, i], [0.025, 0.975]), rtol=0, atol=1e-12)
        assert w["range"][1] - w["range"][0] > 3 * w["amplitude"]  # about ±2 std for these normal inputs, not ±1
