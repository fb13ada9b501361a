"""Derivatives by segments (bemlearn.data.segmented_derivatives) and the velocity-jump detector
(bemlearn.data.velocity_jumps) against closed forms.

The signal: two cubics joined at t* with q continuous and a velocity jump Δv there (an impact),

    q(t) = p(t)                       t < t*
    q(t) = p(t*) + (v(t*) + Δv)(t − t*) + r(t − t*)        t ≥ t*,   r a cubic with r(0) = r'(0) = 0,

sampled at 100 Hz (float64).  Savitzky–Golay of degree 3 is exact on a cubic, so within each
segment (one-sided windows at the segment's ends included) q̇ and q̈ are exact; a window that spans
t* is not.  The Gaussian is exact on parabolas (q̇, q̈) away from segment ends.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bemlearn.data import Trajectory, TrajectoryMeta, make_estimator
from bemlearn.data.derivative_choice import estimate_states
from bemlearn.data.segmented_derivatives import estimate_segmented, segment_bounds
from bemlearn.data.velocity_jumps import detect_velocity_jumps, jump_statistic
from bemlearn.errors import ArgumentError

RATE = 100.0
T = 200
JUMP_ROW = 97            # first sample after the jump
DV = np.array([3.0, -2.0])   # rad/s, velocity jump per joint


def _piecewise(theta: float = 0.4, degree: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, q̇, q̈ ``(T, 2)``: a polynomial of ``degree`` on each side of t* = (JUMP_ROW − 1 + θ) h, jump DV at t*."""
    h = 1.0 / RATE
    t = np.arange(T) * h
    ts = (JUMP_ROW - 1 + theta) * h
    c3 = 1.0 if degree == 3 else 0.0
    # left: p(t) = a0 + a1 t + a2 t² + a3 t³ per joint
    a = np.array([[0.1, -0.2], [0.5, 1.0], [-2.0, 3.0], [4.0 * c3, -5.0 * c3]])
    b2, b3 = np.array([6.0, -1.0]), np.array([-3.0 * c3, 7.0 * c3])        # right: r(s) = b2 s² + b3 s³
    p = lambda x: a[0] + a[1] * x + a[2] * x**2 + a[3] * x**3            # noqa: E731
    pd = lambda x: a[1] + 2 * a[2] * x + 3 * a[3] * x**2                 # noqa: E731
    pdd = lambda x: 2 * a[2] + 6 * a[3] * x                              # noqa: E731
    tt = t[:, None]
    s = tt - ts
    left = tt < ts
    q = np.where(left, p(tt), p(ts) + (pd(ts) + DV) * s + b2 * s**2 + b3 * s**3)
    qd = np.where(left, pd(tt), pd(ts) + DV + 2 * b2 * s + 3 * b3 * s**2)
    qdd = np.where(left, pdd(tt), 2 * b2 + 6 * b3 * s)
    return q, qd, qdd


def _traj(q: np.ndarray) -> Trajectory:
    meta = TrajectoryMeta(robot="test", joint_names=("qu", "qa"), unactuated="qu", actuator_names=("u",),
                          sample_rate_hz=RATE, trial_failed={0: False})
    n = q.shape[0]
    return Trajectory(t=np.arange(n) / RATE, trial=np.zeros(n, dtype=np.int64), q=q, u=np.zeros((n, 1)), meta=meta)


def _events(row: int = JUMP_ROW) -> np.ndarray:
    ev = np.zeros(T, dtype=bool)
    ev[row] = True
    return ev


def test_segment_bounds_trials_and_events() -> None:
    trial = np.array([0, 0, 0, 0, 1, 1, 1, 1, 1, 2, 2])
    ev = np.zeros(11, dtype=bool)
    ev[[2, 4, 6]] = True          # row 4 is a trial start: no new segment there
    assert segment_bounds(trial, ev) == [(0, 2, False, True), (2, 4, True, False), (4, 6, False, True),
                                         (6, 9, True, False), (9, 11, False, False)]
    assert segment_bounds(trial, None) == [(0, 4, False, False), (4, 9, False, False), (9, 11, False, False)]
    with pytest.raises(ArgumentError):
        segment_bounds(trial, ev[:5])


@pytest.mark.parametrize("edges", ["drop", "one-sided"])
def test_savgol_segmented_is_exact_on_both_sides_unsegmented_is_smeared(edges: str) -> None:
    q, qd, qdd = _piecewise()
    traj = _traj(q)
    est = make_estimator("savgol", {"window": 15, "polyorder": 3})
    half = est.edge_samples(RATE)
    _, qd_s, qdd_s, valid, rep = estimate_segmented(traj, est, events=_events(), edges=edges)
    # segmented: exact (degree-3 fits of cubics) at every valid row, one-sided ones included
    assert valid.sum() == T - (2 * half if edges == "drop" else 0)
    np.testing.assert_allclose(qd_s[valid], qd[valid], rtol=0, atol=1e-8)
    np.testing.assert_allclose(qdd_s[valid], qdd[valid], rtol=0, atol=1e-5)
    assert rep.events == 1 and rep.segments == 2 and rep.segments_too_short == 0
    assert (rep.rows_event_dropped, rep.rows_one_sided) == ((2 * half, 0) if edges == "drop" else (0, 2 * half))
    assert rep.edges == edges
    # the rows a drop leaves out are exactly the half windows either side of the jump
    if edges == "drop":
        assert not valid[JUMP_ROW - half:JUMP_ROW + half].any()
    # unsegmented (the trial as one): within a half window of the jump, q̈ is off by ~Δv / window
    _, qd_u, qdd_u, _ = estimate_states(traj, est)
    near = slice(JUMP_ROW - 2, JUMP_ROW + 2)
    assert np.abs(qdd_u[near] - qdd[near]).max() > 0.1 * np.abs(DV).max() * RATE / 15
    assert np.abs(qd_u[near] - qd[near]).max() > 0.2 * np.abs(DV).max()
    far = np.r_[0:JUMP_ROW - half - 1, JUMP_ROW + half + 1:T]
    np.testing.assert_allclose(qdd_u[far], qdd[far], rtol=0, atol=1e-5)   # only the windows over the jump


def test_gaussian_segmented_drops_incomplete_kernels_and_is_exact_on_parabolas() -> None:
    q, qd, qdd = _piecewise(degree=2)
    traj = _traj(q)
    est = make_estimator("gaussian", {"sigma_s": 0.02})
    K = est.edge_samples(RATE)
    for edges in ("drop", "one-sided"):    # the Gaussian never keeps an incomplete kernel
        _, qd_s, qdd_s, valid, rep = estimate_segmented(traj, est, events=_events(), edges=edges)
        expect = np.zeros(T, dtype=bool)
        expect[K:JUMP_ROW - K] = True
        expect[JUMP_ROW + K:T - K] = True
        np.testing.assert_array_equal(valid, expect)
        np.testing.assert_allclose(qd_s[valid], qd[valid], rtol=0, atol=1e-9)
        np.testing.assert_allclose(qdd_s[valid], qdd[valid], rtol=0, atol=1e-6)
        assert rep.rows_trial_edges == 2 * K and rep.rows_event_dropped == 2 * K and rep.rows_one_sided == 0
    _, _, qdd_u, valid_u = estimate_states(traj, est)
    assert valid_u[JUMP_ROW]                        # the unsegmented estimator keeps the jump's row…
    assert abs(qdd_u[JUMP_ROW, 0] - qdd[JUMP_ROW, 0]) > 10.0   # …with a q̈ spike of ≈ Δv g_σ(0)


def test_settle_and_short_segments_are_counted() -> None:
    q, _, _ = _piecewise()
    traj = _traj(q)
    est = make_estimator("savgol", {"window": 15, "polyorder": 3})
    _, _, _, valid, rep = estimate_segmented(traj, est, events=_events(), edges="one-sided", settle=4)
    assert not valid[JUMP_ROW:JUMP_ROW + 4].any() and valid[JUMP_ROW + 4] and rep.rows_settle == 4
    ev = _events()
    ev[JUMP_ROW + 10] = True                    # a 10-sample segment: shorter than the 15-sample window
    _, _, _, valid, rep = estimate_segmented(traj, est, events=ev, edges="one-sided")
    assert rep.segments == 3 and rep.segments_too_short == 1 and rep.rows_too_short == 10
    assert not valid[JUMP_ROW:JUMP_ROW + 10].any()
    with pytest.raises(ArgumentError):
        estimate_segmented(traj, est, events=ev, edges="sideways")  # type: ignore[arg-type]


@pytest.mark.parametrize("theta", [0.0, 0.25, 0.5, 0.9])
def test_jump_statistic_is_the_velocity_jump_and_zero_on_cubics(theta: float) -> None:
    q, _, _ = _piecewise(theta=theta, degree=3)
    D = jump_statistic(q, RATE)
    k = JUMP_ROW - 1                                   # the interval k … k + 1 holds t*
    # (J2): exactly Δv at the jump's interval up to the cubics' own third-order terms, which (J2) cancels
    np.testing.assert_allclose(D[k], DV, rtol=0, atol=0.05 * np.abs(DV).max())
    t = np.arange(T) / RATE
    cubic = np.c_[1 + 2 * t - 3 * t**2 + 5 * t**3, -t**3 + 0.5 * t]
    Dc = jump_statistic(cubic, RATE)
    assert np.isnan(Dc[:3]).all() and np.isnan(Dc[-4:]).all() and not np.isnan(Dc[3:-4]).any()
    np.testing.assert_allclose(Dc[3:-4], 0.0, atol=1e-9)


def test_detector_finds_the_jump_in_quantized_data_and_nothing_in_smooth_data() -> None:
    step = 2 * math.pi / 4096
    rng = np.random.default_rng(0)
    t = np.arange(T) / RATE
    smooth = np.c_[0.3 * np.sin(2 * math.pi * 1.3 * t), 0.2 * np.cos(2 * math.pi * 0.7 * t + 0.4)]
    q, _, _ = _piecewise()
    for sig, expect in ((smooth, []), (smooth + q, [JUMP_ROW])):
        qq = np.round((sig + rng.uniform(-0.5, 0.5, 2) * step) / step) * step     # a 4096-count encoder
        det = detect_velocity_jumps(qq, RATE, noise_std=step / math.sqrt(12.0))
        assert np.flatnonzero(det.starts).tolist() == expect
    # never across trials: a jump at a trial boundary is the trial start, not a reported jump
    trial = (np.arange(T) >= JUMP_ROW).astype(np.int64)
    det = detect_velocity_jumps(np.round(q / step) * step, RATE, trial=trial, noise_std=step / math.sqrt(12.0))
    assert det.count == 0
