"""Derivative estimators against closed-form derivatives, clean and quantized to 2π/4096 at 400 Hz.

Reference numbers (10 s sum of three sines per joint, up to 1.9 Hz, 400 Hz, interior
and edges included) measured when these tolerances were set:

    estimator                  clean q̈ RMS err   quantized q̈ RMS err   (rad/s²)
    central                    ~5e-4             ~1.7e2
    savgol 0.2 s, order 3      ~0.7              ~0.7
    savgol 0.2 s, order 4      ~0.06             ~0.14
"""

from __future__ import annotations

import numpy as np
import pytest
from test_data_helpers import QSTEP, make_trajectory

from bemlearn.config import ConfigError
from bemlearn.data import (
    DERIVATIVE_ESTIMATORS,
    CentralDifference,
    SavitzkyGolay,
    estimate_derivatives,
    make_estimator,
)

RATE = 400.0


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(a**2)))


@pytest.fixture(scope="module")
def long_trial():
    """One 10 s trial, clean and quantized, with true q̇, q̈."""
    clean = make_trajectory((4000,), ground_truth=True, seed=1)
    quant = make_trajectory((4000,), ground_truth=True, quantize=True, seed=1)
    return clean, quant


def test_registry_lists_names_on_error():
    assert set(DERIVATIVE_ESTIMATORS) == {"central", "gaussian", "savgol"}
    with pytest.raises(ValueError, match=r"unknown derivative estimator 'spline'; valid names are \['central', 'gaussian', 'savgol'\]"):
        make_estimator("spline")
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['width'\]"):
        make_estimator("savgol", {"width": 3})
    with pytest.raises(ConfigError, match=r"window_s .* or window .*not both"):
        make_estimator("savgol", {"window_s": 0.2, "window": 81})
    with pytest.raises(ConfigError, match=r"polyorder: q̈ needs a polynomial degree >= 2"):
        make_estimator("savgol", {"polyorder": 1})
    with pytest.raises(ConfigError, match=r"odd number of samples"):
        make_estimator("savgol", {"window": 80})
    assert isinstance(make_estimator("central"), CentralDifference)


def test_savgol_window_in_seconds_or_samples():
    assert SavitzkyGolay().window_samples(400.0) == 81  # default 0.2 s
    assert SavitzkyGolay(window_s=0.2).window_samples(115.0) == 23
    assert SavitzkyGolay(window_s=0.1).window_samples(400.0) == 41
    assert SavitzkyGolay(window=31).window_samples(400.0) == 31
    assert SavitzkyGolay(window=31).edge_samples(400.0) == 15
    with pytest.raises(ValueError, match="only 3 samples at 20.0 Hz"):
        SavitzkyGolay(window_s=0.1, polyorder=3).window_samples(20.0)


@pytest.mark.parametrize(
    ("estimator", "degree"),
    [(CentralDifference(), 2), (SavitzkyGolay(window=21, polyorder=3), 3), (SavitzkyGolay(window=41, polyorder=5), 5)],
)
def test_exact_on_polynomials_including_edges(estimator, degree):
    """Both are exact (to round-off) for polynomials they can represent, at every sample."""
    rng = np.random.default_rng(0)
    t = np.arange(120) / RATE
    c = rng.normal(size=(degree + 1, 2))
    powers = np.arange(degree + 1)
    q = (t[:, None, None] ** powers[None, :, None] * c[None]).sum(1)
    qd = (powers[1:, None] * c[1:] * t[:, None, None] ** (powers[1:, None] - 1)).sum(1)
    qdd = (powers[2:, None] * (powers[2:, None] - 1) * c[2:] * t[:, None, None] ** (powers[2:, None] - 2)).sum(1)
    est_qd, est_qdd = estimator(q, sample_rate_hz=RATE)
    np.testing.assert_allclose(est_qd, qd, rtol=0, atol=1e-7 * np.abs(qd).max() + 1e-9)
    np.testing.assert_allclose(est_qdd, qdd, rtol=0, atol=1e-6 * np.abs(qdd).max() + 1e-7)


def test_central_differences_second_order_on_clean_signal(long_trial):
    clean, _ = long_trial
    qd, qdd = CentralDifference()(clean.q, sample_rate_hz=RATE)
    # Truncation error h²/6 q⃛ (q̇) and h²/12 q⁗ (q̈): ~1e-4 rad/s and ~1e-3 rad/s² here.
    assert rms(qd - clean.qd) < 2e-4
    assert rms(qdd - clean.qdd) < 2e-3
    # Halving h quarters the error (second order).
    fine = make_trajectory((8000,), rate=800.0, ground_truth=True, seed=1)
    qd_f, _ = CentralDifference()(fine.q, sample_rate_hz=800.0)
    ratio = rms(qd - clean.qd) / rms(qd_f - fine.qd)
    assert 3.5 < ratio < 4.5


def test_quantization_ruins_central_accelerations_not_savgol(long_trial):
    clean, quant = long_trial
    cd = CentralDifference()
    sg = make_estimator("savgol", {"window_s": 0.2, "polyorder": 4})
    cd_clean = rms(cd(clean.q, sample_rate_hz=RATE)[1] - clean.qdd)
    cd_quant = rms(cd(quant.q, sample_rate_hz=RATE)[1] - quant.qdd)
    sg_qd, sg_qdd = sg(quant.q, sample_rate_hz=RATE)
    sg_quant = rms(sg_qdd - quant.qdd)
    signal = rms(quant.qdd)  # ~7.5 rad/s²
    # Quantization noise δ/√12 through the (1, −2, 1)/h² stencil: √6 δ/√12 / h² ≈ 177 rad/s².
    expected_cd = np.sqrt(6.0) * QSTEP / np.sqrt(12.0) * RATE**2
    assert cd_quant == pytest.approx(expected_cd, rel=0.1)
    assert cd_quant > 1e4 * cd_clean  # degradation
    assert cd_quant > 10 * signal  # too noisy to learn from
    assert sg_quant < 0.25 and sg_quant < 0.05 * signal
    assert sg_quant < cd_quant / 500  # savgol's advantage
    assert rms(sg_qd - quant.qd) < 0.01  # rad/s, against ~1 rad/s signal


def test_savgol_bias_shrinks_with_order_and_window(long_trial):
    clean, _ = long_trial
    err = {
        (w, p): rms(SavitzkyGolay(window_s=w, polyorder=p)(clean.q, sample_rate_hz=RATE)[1] - clean.qdd)
        for w in (0.1, 0.2) for p in (3, 4)
    }
    assert err[(0.1, 3)] < err[(0.2, 3)]
    assert err[(0.2, 4)] < err[(0.2, 3)] / 5
    assert err[(0.2, 3)] < 1.0


def test_per_trial_independence():
    """A trial's estimates do not depend on its neighbours (no stencil crosses a boundary)."""
    traj = make_trajectory((300, 200, 250), quantize=True)
    for est in (CentralDifference(), SavitzkyGolay()):
        qd, qdd = estimate_derivatives(traj, est)
        for s in traj.trial_slices():
            alone_qd, alone_qdd = est(traj.q[s.rows], sample_rate_hz=RATE)
            assert np.array_equal(qd[s.rows], alone_qd) and np.array_equal(qdd[s.rows], alone_qdd)
    # The same trial after a different neighbour gives the same numbers.
    other = make_trajectory((300, 200, 250), quantize=True, seed=9)
    mixed_q = np.concatenate([other.q[:300], traj.q[300:]])
    mixed = type(traj)(t=traj.t, trial=traj.trial, q=mixed_q, u=traj.u, meta=traj.meta)
    a = estimate_derivatives(traj, SavitzkyGolay())[1][300:]
    b = estimate_derivatives(mixed, SavitzkyGolay())[1][300:]
    assert np.array_equal(a, b)


def test_short_trial_is_named():
    traj = make_trajectory((300, 50, 300))
    with pytest.raises(ValueError, match=r"trial 1 \(rows 300\.\.349\) has 50 samples; the 'savgol' estimator needs at least 81"):
        estimate_derivatives(traj, SavitzkyGolay())
    qd, _ = estimate_derivatives(traj, CentralDifference())
    assert qd.shape == traj.q.shape and np.isfinite(qd).all()
