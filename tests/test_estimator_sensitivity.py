"""The estimator term of the band (eq. E1, E2): projected weights, neighbours, sensitivity.

References: the exact posterior weights K⁻¹y of a dense solve (E1 with Z = X), the SGPR
weights Σ K_ZX y / σ_0² from their textbook form, and the derivative inputs of
:func:`bemlearn.data.build_datasets` for the same rows.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from bemlearn.data import DatasetConfig, build_datasets
from bemlearn.data.finite_difference import CentralDifference
from bemlearn.data.savitzky_golay import SavitzkyGolay
from bemlearn.data.trajectory import Trajectory, TrajectoryMeta
from bemlearn.fitting.estimator_sensitivity import estimator_sensitivity, projected_weights
from bemlearn.models.kernels import se_gram, se_kernel
from bemlearn.models.predictor_state import PredictorState

F64 = torch.float64
NAMES = ("qdd_a", "qd_a", "q_a", "qdd_u", "qd_u")


def _exact_state(X: torch.Tensor, y: torch.Tensor, *, x_mean, x_std, noise=1e-3) -> PredictorState:
    n = X.shape[0]
    xn = (X - x_mean) / x_std
    ym, ys = y.mean(), y.std()
    base = PredictorState(
        kind="exact", Z=xn, alpha=torch.zeros(n, dtype=F64), S=torch.zeros(n, n, dtype=F64),
        lengthscale=torch.tensor([1.3, 2.0, 1.7, 1.1, 2.5], dtype=F64), outputscale=torch.tensor(0.9, dtype=F64),
        noise=torch.tensor(noise, dtype=F64), x_mean=x_mean, x_std=x_std, y_mean=ym, y_std=ys,
        input_names=NAMES, n_train=n,
    )
    L = torch.linalg.cholesky(base.gram())
    return dataclasses.replace(base, alpha=torch.cholesky_solve(((y - ym) / ys)[:, None], L)[:, 0], S=torch.cholesky_inverse(L))


def test_projected_weights_with_z_equal_x_are_the_exact_posterior_weights():
    g = torch.Generator().manual_seed(0)
    X = torch.randn(80, 5, generator=g, dtype=F64) * torch.tensor([3.0, 0.5, 0.2, 4.0, 0.7], dtype=F64)
    y = torch.sin(X[:, 0] / 3 + X[:, 2]) + 0.01 * torch.randn(80, generator=g, dtype=F64)
    st = _exact_state(X, y, x_mean=X.mean(0), x_std=X.std(0))
    torch.testing.assert_close(projected_weights(st, X, y), st.alpha, rtol=1e-7, atol=1e-9)


def test_projected_weights_are_the_sgpr_weights_on_other_data():
    g = torch.Generator().manual_seed(1)
    Z = torch.randn(25, 5, generator=g, dtype=F64)
    X = torch.randn(200, 5, generator=g, dtype=F64)
    y = torch.cos(X[:, 1]) + X[:, 3] + 0.05 * torch.randn(200, generator=g, dtype=F64)
    st = dataclasses.replace(_exact_state(Z, torch.zeros(25, dtype=F64) + torch.linspace(0, 1, 25, dtype=F64),
                                          x_mean=torch.zeros(5, dtype=F64), x_std=torch.ones(5, dtype=F64), noise=0.05),
                             kind="sgpr")
    yn = (y - st.y_mean) / st.y_std

    Kzx, Kzz = se_kernel(Z, X, st.lengthscale, st.outputscale), se_gram(Z, st.lengthscale, st.outputscale)
    sigma2 = float(st.noise)
    Sigma = torch.linalg.inv(Kzz + Kzx @ Kzx.T / sigma2)                 # Titsias (2009), textbook form
    ref = Sigma @ Kzx @ yn / sigma2
    torch.testing.assert_close(projected_weights(st, X, y), ref, rtol=1e-7, atol=1e-9)


def test_savgol_neighbours_and_central_has_none():
    est = SavitzkyGolay(window_s=0.3, polyorder=4)
    got = est.neighbours(250.0)   # w = 75 samples
    assert [(e.window, e.polyorder) for e in got] == [(49, 4), (113, 4), (75, 3), (75, 5)]
    assert [(e.window, e.polyorder) for e in SavitzkyGolay(window=5, polyorder=2).neighbours(100.0)] == [(3, 2), (7, 2), (5, 3)]
    assert CentralDifference().neighbours(400.0) == ()


def _trajectory(seed=0, n_trials=4, T=400, short_trial=False):
    """A two-joint trajectory whose q_u follows a smooth function of the actuated motion."""
    rng = np.random.default_rng(seed)
    rate = 200.0
    ts, qs, trials = [], [], []
    for i in range(n_trials):
        n = 60 if (short_trial and i == n_trials - 1) else T
        t = np.arange(n) / rate
        a = 0.3 * np.sin(2 * np.pi * (0.4 + 0.2 * rng.random()) * t + rng.random() * 6)
        u = 0.1 * np.sin(2 * np.pi * (0.7 + 0.3 * rng.random()) * t) + 0.05 * a
        qs.append(np.round(np.stack([a, u], 1) / 1e-3) * 1e-3)
        ts.append(t + 100 * i)
        trials.append(np.full(n, i))
    meta = TrajectoryMeta(robot="test", joint_names=("a", "u"), unactuated="u", actuator_names=("tau_a",),
                          sample_rate_hz=rate, trial_failed={i: False for i in range(n_trials)})
    q = np.concatenate(qs)
    return Trajectory(t=np.concatenate(ts), trial=np.concatenate(trials), q=q, u=np.zeros((q.shape[0], 1)), meta=meta)


def _fitted(traj, cfg):
    ds = build_datasets(traj, cfg)
    tr = ds.train
    return tr, _exact_state(tr.x, tr.y, x_mean=tr.normalization.x_mean, x_std=tr.normalization.x_std)


def test_sensitivity_uses_the_training_rows_and_is_zero_for_the_same_estimator():
    traj = _trajectory()
    cfg = DatasetConfig(derivative="savgol", derivative_options={"window": 21, "polyorder": 3}, n_points=120, val_fraction=0.25)
    tr, st = _fitted(traj, cfg)
    est = cfg.estimator()

    class Self:
        """The chosen estimator offered as its own neighbour: δ must vanish."""
        name = est.name

        def min_samples(self, rate):
            return est.min_samples(rate)

        def neighbours(self, rate):
            return (est,)

        def __call__(self, q, *, sample_rate_hz):
            return est(q, sample_rate_hz=sample_rate_hz)

    out = estimator_sensitivity(st, traj, Self(), tr.row)
    assert out.delta.shape == (st.n_support, 1)
    assert float(out.delta.abs().max()) <= 1e-9 * float(st.alpha.abs().max())
    real = estimator_sensitivity(st, traj, est, tr.row, queries=tr.x[:50])
    assert real.delta.shape == (st.n_support, 4) and len(real.rms_shift) == 4
    assert all(r > 0 for r in real.rms_shift)
    assert real.estimators[0] == "savgol(window=13, polyorder=3)"


def test_neighbour_too_long_for_a_trial_keeps_the_chosen_estimate():
    traj = _trajectory(short_trial=True)          # last trial: 60 samples
    cfg = DatasetConfig(derivative="savgol", derivative_options={"window": 41, "polyorder": 3}, n_points=200,
                        val_fraction=0.25, seed=3)
    tr, st = _fitted(traj, cfg)
    out = estimator_sensitivity(st, traj, cfg.estimator(), tr.row)
    assert bool(np.isin(tr.trial.numpy(), [3]).any())   # seed 3 trains on the short trial
    # the wider neighbour (61 samples) cannot run on the 60-sample trial: counted, its rows keep the chosen estimate
    assert out.trials_kept_base == (0, 1, 0, 0)


def test_central_differences_give_no_estimator_term():
    traj = _trajectory()
    cfg = DatasetConfig(derivative="central", derivative_options={}, n_points=100, val_fraction=0.25)
    tr, st = _fitted(traj, cfg)
    out = estimator_sensitivity(st, traj, cfg.estimator(), tr.row)
    assert out.delta.shape == (st.n_support, 0) and out.to_dict()["n_neighbours"] == 0


@pytest.mark.parametrize("bad", ["short_for_chosen"])
def test_rows_in_a_trial_too_short_for_the_chosen_estimator_are_an_error(bad):
    traj = _trajectory(short_trial=True)
    cfg = DatasetConfig(derivative="savgol", derivative_options={"window": 21, "polyorder": 3}, n_points=100, val_fraction=0.25)
    _tr, st = _fitted(traj, cfg)
    wide = SavitzkyGolay(window=81, polyorder=3)   # longer than the 60-sample trial
    rows = torch.as_tensor(np.flatnonzero(traj.trial == 3)[:10])
    with pytest.raises(ValueError, match="trial 3 holds training rows"):
        estimator_sensitivity(dataclasses.replace(st, Z=st.Z[:10], alpha=st.alpha[:10], S=st.S[:10, :10]), traj, wide, rows)
