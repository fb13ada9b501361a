"""GP datasets of eq. (11): column layout, window filtering, split by trial, normalization."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
import torch
from test_data_helpers import QSTEP, make_trajectory

from bemlearn.config import ConfigError, from_dict
from bemlearn.data import (
    DatasetConfig,
    build_datasets,
    gp_input_names,
    gp_inputs,
    gp_output_name,
    split_trials,
)
from bemlearn.data.derivative_choice import estimate_states
from bemlearn.data.gaussian_derivative import gaussian_kernels

BIPED = ("q1", "q2", "q3", "q4", "q5")


def test_input_names_and_layout_furuta():
    assert gp_input_names(("theta", "alpha"), "alpha") == ("qdd_theta", "qd_theta", "q_theta", "qdd_alpha", "qd_alpha")
    assert gp_output_name("alpha") == "q_alpha"
    q, qd, qdd = np.array([[1.0, 2.0]]), np.array([[3.0, 4.0]]), np.array([[5.0, 6.0]])
    np.testing.assert_array_equal(gp_inputs(q, qd, qdd, unactuated_index=1), [[5.0, 3.0, 1.0, 6.0, 4.0]])


def test_input_layout_biped_numpy_and_torch():
    """n = 5, q_u = q1 first: x = [q̈2..5, q̇2..5, q2..5, q̈1, q̇1] ∈ R^14."""
    names = gp_input_names(BIPED, "q1")
    assert len(names) == 3 * 5 - 1
    assert names[:4] == ("qdd_q2", "qdd_q3", "qdd_q4", "qdd_q5") and names[-2:] == ("qdd_q1", "qd_q1")
    rng = np.random.default_rng(0)
    q, qd, qdd = (rng.normal(size=(7, 3, 5)) for _ in range(3))  # extra batch dims allowed
    x = gp_inputs(q, qd, qdd, unactuated_index=0)
    expected = np.concatenate([qdd[..., 1:], qd[..., 1:], q[..., 1:], qdd[..., :1], qd[..., :1]], axis=-1)
    np.testing.assert_array_equal(x, expected)
    xt = gp_inputs(*(torch.as_tensor(a) for a in (q, qd, qdd)), unactuated_index=0)
    assert isinstance(xt, torch.Tensor) and xt.dtype == torch.float64
    np.testing.assert_array_equal(xt.numpy(), expected)
    with pytest.raises(ValueError, match="must share one shape"):
        gp_inputs(q, qd[..., :4], qdd, unactuated_index=0)
    with pytest.raises(ValueError, match="unactuated_index 5 out of range"):
        gp_inputs(q, qd, qdd, unactuated_index=5)


@pytest.fixture(scope="module")
def traj():
    """10 trials, 2 failed, q_u partly outside 0.1 rad."""
    return make_trajectory((300, 260, 240, 400, 350, 200, 320, 280, 310, 290), quantize=True, failed=(2, 7), seed=4)


def test_dataset_shapes_and_columns(traj):
    cfg = DatasetConfig(n_points=500, qu_window=None, val_fraction=0.2, seed=1)
    data = build_datasets(traj, cfg)
    train, val = data.train, data.val
    assert train.x.shape == (500, 5) and train.y.shape == (500,) and train.x.dtype == torch.float64
    assert train.input_names == ("qdd_theta", "qd_theta", "q_theta", "qdd_alpha", "qd_alpha")
    assert train.output_name == "q_alpha" and train.dim == 5
    # Each point is x (eq. 11) of its source row, with the estimator the sets were built with (the
    # default Gaussian, σ chosen from the data: its smoothed q is the q_a input and the q_u label)
    assert data.config.estimator().resolved and data.report["derivative_choice"]["sigma_s"] == data.config.derivative_options["sigma_s"]
    q, qd, qdd, valid = estimate_states(traj, data.config.estimator())
    x_all = gp_inputs(q, qd, qdd, unactuated_index=1)
    for ds in (train, val):
        assert valid[ds.row.numpy()].all()
        np.testing.assert_array_equal(ds.x.numpy(), x_all[ds.row.numpy()])
        np.testing.assert_array_equal(ds.y.numpy(), q[ds.row.numpy(), 1])
        np.testing.assert_array_equal(ds.trial.numpy(), traj.trial[ds.row.numpy()])
    assert len(np.unique(train.row.numpy())) == 500
    assert len(val) == data.report["val_pool"] == int(valid[np.isin(traj.trial, val.trial_ids)].sum())


def test_dataset_close_to_ground_truth_inputs():
    """With Savitzky–Golay on quantized data the dataset x is close to the true x (interior)."""
    truth = make_trajectory((800, 900), ground_truth=True, seed=2)
    data = make_trajectory((800, 900), quantize=True, seed=2)
    sg = {"derivative": "savgol", "derivative_options": {"window_s": 0.3, "polyorder": 4}}
    ds = build_datasets(data, DatasetConfig(**sg, n_points=None, qu_window=None, val_fraction=0.0, drop_edges=True)).train
    x_true = gp_inputs(truth.q, truth.qd, truth.qdd, unactuated_index=1)[ds.row.numpy()]
    err = np.abs(ds.x.numpy() - x_true).max(0)
    scale = np.abs(x_true).max(0)
    assert (err < 0.05 * scale).all(), err / scale


def test_gaussian_inputs_are_the_smoothed_truth():
    """Eq. (G1): the Gaussian estimator's q, q̇, q̈ of quantized sines equal the true q, q̇, q̈
    passed through the same kernel (analytic: each sine scaled by exp(−ω²σ²/2)), to the
    quantization noise the kernel leaves; the label is the smoothed q_u."""
    from test_data_helpers import furuta_spec

    data = make_trajectory((900, 1000), quantize=True, seed=2)
    sigma = 0.05
    cfg = DatasetConfig(derivative_options={"sigma_s": sigma}, n_points=None, qu_window=None, val_fraction=0.0)
    ds = build_datasets(data, cfg)
    assert ds.report["samples_dropped_edges"] == 2 * 2 * int(np.ceil(5 * sigma * 400))
    spec = furuta_spec()
    g = np.exp(-0.5 * (spec.omegas * sigma) ** 2)          # the Gaussian's gain at each sine
    rng = np.random.default_rng(2)                          # the draws make_trajectory made: phases, then inputs
    truth = []
    for T in (900, 1000):
        ph = rng.uniform(0, 2 * np.pi, size=spec.amplitudes.shape)
        rng.normal(size=(T, 1))
        t = np.arange(T) / 400.0
        arg = spec.omegas[None] * t[:, None, None] + ph[None]
        A, w = (spec.amplitudes * g)[None], spec.omegas[None]
        truth.append(np.stack([(A * np.sin(arg)).sum(-1), (A * w * np.cos(arg)).sum(-1), (-A * w**2 * np.sin(arg)).sum(-1)]))
    q, qd, qdd = (np.concatenate([tr[k] for tr in truth]) for k in range(3))
    rows = ds.train.row.numpy()
    x_true = gp_inputs(q, qd, qdd, unactuated_index=1)[rows]
    # the noise the kernel leaves of white quantization noise (step²/12): ‖w_k‖ · step/√12, 6σ
    w0, w1, w2 = gaussian_kernels(sigma, 400.0)
    tol = 6 * QSTEP / np.sqrt(12) * np.array([np.linalg.norm(w) for w in (w2, w1, w0, w2, w1)])
    err = np.abs(ds.train.x.numpy() - x_true).max(0)
    assert (err < tol + 1e-4 * np.abs(x_true).max(0)).all(), (err, tol)
    np.testing.assert_allclose(ds.train.y.numpy(), q[rows, 1], atol=6 * QSTEP / np.sqrt(12) * np.linalg.norm(w0) + 1e-6)


def test_window_filtering_counts(traj, caplog):
    window = 0.1
    cfg = DatasetConfig(derivative="savgol", n_points=None, qu_window=window, val_fraction=0.3, seed=0)
    with caplog.at_level(logging.INFO, logger="bemlearn.data.dataset"):
        data = build_datasets(traj, cfg)
    outside = int((np.abs(traj.q[:, 1]) > window).sum())
    assert 0 < outside < traj.n_samples // 2  # the test trajectory exercises the window
    assert data.report["samples_outside_window"] == outside
    assert len(data.train) + len(data.val) == traj.n_samples - outside
    assert (data.train.y.abs() <= window).all() and (data.val.y.abs() <= window).all()
    assert f"dropped {outside} of {traj.n_samples} samples with |alpha| > 0.1 rad" in caplog.text


def test_split_by_trial(traj):
    cfg = DatasetConfig(n_points=300, qu_window=0.5, val_fraction=0.3, seed=7)
    data = build_datasets(traj, cfg)
    train_ids, val_ids = set(data.report["train_trials"]), set(data.report["val_trials"])
    assert not train_ids & val_ids and train_ids | val_ids == set(range(10))
    assert len(val_ids) == 3
    assert set(data.train.trial_ids) <= train_ids and set(data.val.trial_ids) == val_ids
    again = build_datasets(traj, cfg)
    assert torch.equal(again.train.row, data.train.row) and torch.equal(again.val.row, data.val.row)
    splits = {tuple(build_datasets(traj, dataclasses.replace(cfg, seed=s)).report["val_trials"]) for s in range(6)}
    assert len(splits) > 1  # the seed matters
    rng = np.random.default_rng(0)
    assert split_trials([4, 5], 0.01, rng)[1] and split_trials([4, 5], 0.99, rng)[0]  # ≥ 1 each side
    with pytest.raises(ValueError, match="needs at least 2 trials"):
        split_trials([3], 0.2, rng)


def test_normalization_from_training_points(traj):
    data = build_datasets(traj, DatasetConfig(n_points=400, qu_window=0.5, val_fraction=0.2, seed=3))
    x, y = data.train.x, data.train.y
    torch.testing.assert_close(data.train.x_mean, x.mean(0), rtol=0, atol=1e-12)
    torch.testing.assert_close(data.train.x_std, x.std(0, correction=0), rtol=1e-12, atol=0)
    torch.testing.assert_close(data.train.y_mean, y.mean(), rtol=0, atol=1e-15)
    torch.testing.assert_close(data.train.y_std, y.std(correction=0), rtol=1e-12, atol=0)
    assert data.train.x_mean.shape == (5,) and data.train.y_mean.shape == () and data.train.y_std.dtype == torch.float64
    xn, yn = data.train.x_normalized, data.train.y_normalized
    torch.testing.assert_close(xn.mean(0), torch.zeros(5, dtype=torch.float64), rtol=0, atol=1e-12)
    torch.testing.assert_close(xn.std(0, correction=0), torch.ones(5, dtype=torch.float64), rtol=0, atol=1e-12)
    assert data.val.normalization is data.train.normalization  # validation uses the training statistics
    xi, yi = data.val[3]
    torch.testing.assert_close(xi, (data.val.x[3] - x.mean(0)) / x.std(0, correction=0))
    torch.testing.assert_close(yi, (data.val.y[3] - y.mean()) / y.std(correction=0))
    assert data.train.normalization.denormalize_y(yn).sub(y).abs().max() < 1e-15


def test_subsampling_is_seeded(traj):
    cfg = DatasetConfig(n_points=250, qu_window=None, val_fraction=0.2, n_val_points=100, seed=11)
    a, b = build_datasets(traj, cfg), build_datasets(traj, cfg)
    assert len(a.train) == 250 and len(a.val) == 100
    assert torch.equal(a.train.row, b.train.row)
    c = build_datasets(traj, dataclasses.replace(cfg, n_points=10_000))  # more than the pool: all, warned
    assert len(c.train) == c.report["train_pool"] < 10_000


def test_short_failed_and_edge_samples_are_counted(caplog):
    traj = make_trajectory((300, 60, 300, 250, 70), failed=(3,), seed=5)
    # a 0.2 s Savitzky–Golay window at 400 Hz needs 81 samples (pinned: the default may change)
    cfg = DatasetConfig(derivative="savgol", derivative_options={"window_s": 0.2, "polyorder": 4}, n_points=None, qu_window=None,
                        val_fraction=0.0)
    with caplog.at_level(logging.INFO, logger="bemlearn.data.dataset"):
        data = build_datasets(traj, cfg)
    r = data.report
    assert (r["trials_dropped_short"], r["samples_dropped_short"]) == (2, 130)
    assert "dropped 2 short (< 81 samples) trial(s) (130 samples): [1, 4]" in caplog.text
    assert len(data.train) == 850 and len(data.val) == 0 and 3 in data.train.trial_ids
    no_failed = build_datasets(traj, dataclasses.replace(cfg, include_failed=False))
    assert (no_failed.report["trials_dropped_failed"], no_failed.report["samples_dropped_failed"]) == (1, 250)
    assert len(no_failed.train) == 600
    edges = build_datasets(traj, dataclasses.replace(cfg, drop_edges=True))
    assert edges.report["samples_dropped_edges"] == 3 * 2 * 40
    assert len(edges.train) == 850 - 240
    with pytest.raises(ValueError, match=r"trial\(s\) \[1, 4\] are shorter than the 81 samples"):
        build_datasets(traj, dataclasses.replace(cfg, short_trials="error"))


def test_config_parsing():
    cfg = from_dict(
        DatasetConfig,
        {"derivative": "central", "derivative_options": {}, "qu_window": 0.3, "n_points": 500, "seed": 2},
        where="cfg.yaml:dataset",
    )
    assert cfg.estimator().name == "central" and cfg.qu_window == 0.3
    # default: the Gaussian kernel with σ chosen from the data (docs/derivatives.md)
    assert DatasetConfig().estimator().name == "gaussian" and not DatasetConfig().estimator().resolved
    with pytest.raises(ConfigError, match=r"cfg\.yaml:dataset: unknown key\(s\) \['window'\]"):
        from_dict(DatasetConfig, {"window": 0.2}, where="cfg.yaml:dataset")
    with pytest.raises(ConfigError, match=r"valid names are \['central', 'gaussian', 'savgol'\]"):
        from_dict(DatasetConfig, {"derivative": "spline"}, where="cfg.yaml:dataset")
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['width'\]"):
        from_dict(DatasetConfig, {"derivative_options": {"width": 3}}, where="cfg.yaml:dataset")
    with pytest.raises(ConfigError, match=r"val_fraction: expected 0 <= val_fraction < 1"):
        from_dict(DatasetConfig, {"val_fraction": 1.0})
    with pytest.raises(ConfigError, match=r"qu_window: expected a positive angle"):
        from_dict(DatasetConfig, {"qu_window": -0.1})
    with pytest.raises(ConfigError, match=r"short_trials: expected one of \['drop', 'error'\]"):
        from_dict(DatasetConfig, {"short_trials": "skip"})


@pytest.mark.parametrize("derivative", ["savgol", "gaussian"])
def test_the_window_is_relative_to_the_datas_upright(traj, derivative, tmp_path):
    """A robot whose upright reads π: the same motion shifted by π, with meta.qu_upright = π, gives the same
    dataset (labels shifted by π, inputs equal) — and survives writing and reading the file."""
    from bemlearn.data import read_trajectory, write_trajectory

    q = traj.q.copy()
    q[:, 1] += np.pi
    shifted = dataclasses.replace(traj, q=q, meta=dataclasses.replace(traj.meta, qu_upright=np.pi))
    path = write_trajectory(shifted, tmp_path / "pi.npz")
    shifted = read_trajectory(path)
    assert shifted.meta.qu_upright == pytest.approx(np.pi)
    cfg = DatasetConfig(derivative=derivative, n_points=None, qu_window=0.1, val_fraction=0.3, seed=0)
    a, b = build_datasets(traj, cfg), build_datasets(shifted, cfg)
    assert a.report["samples_outside_window"] == b.report["samples_outside_window"] > 0
    np.testing.assert_allclose(b.train.y.numpy() - np.pi, a.train.y.numpy(), atol=1e-9)
    np.testing.assert_allclose(b.train.x.numpy(), a.train.x.numpy(), atol=1e-7)
