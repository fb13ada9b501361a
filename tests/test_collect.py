"""Simulated excitation collection: reproducibility, falls, what the file holds."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import furuta_section

from bemlearn.data.sensors import Encoder, FilteredDifferentiator, SensorConfig
from bemlearn.data.trajectory_io import ground_truth_path, read_ground_truth, read_trajectory, write_trajectory
from bemlearn.sim.collect import CollectConfig, collect

ROBOTS = Path(__file__).resolve().parent / "robots"
SMALL = furuta_section("collect", n_trials=4, duration_s=2.0, workers=1, seed=3)


def test_same_seed_is_bit_identical_and_independent_of_workers():
    a, ta = collect("furuta", SMALL, progress=False)
    b, tb = collect("furuta", SMALL, progress=False)
    c, tc = collect("furuta", dataclasses.replace(SMALL, workers=2), progress=False)
    for x, y in ((a, b), (a, c), (ta, tb), (ta, tc)):
        for name in ("t", "trial", "q", "u"):
            assert np.array_equal(getattr(x, name), getattr(y, name)), name
    assert np.array_equal(ta.qdd, tc.qdd)
    d, _ = collect("furuta", dataclasses.replace(SMALL, seed=4), progress=False)
    assert not np.array_equal(a.q[:100], d.q[:100])


def test_falls_are_kept_up_to_the_fall_and_marked():
    unstable = dataclasses.replace(SMALL, gains=(0.0, 0.0, 0.0, 0.0), initial_qu=(0.05, 0.05), duration_s=5.0)
    data, truth = collect("furuta", unstable, progress=False)
    assert all(data.meta.trial_failed.values())
    for s in data.trial_slices():
        assert s.failed
        assert s.n_samples < 5.0 * 400
        # the last kept sample is still inside the window, the trial stopped right at the fall
        assert np.abs(truth.q[s.rows, 1]).max() <= unstable.fall_window
        assert np.abs(truth.q[s.rows, 1][-1]) > 0.5 * unstable.fall_window


def test_mixture_of_successful_and_failed_trials_with_default_excitation():
    cfg = furuta_section("collect", n_trials=8, duration_s=8.0, workers=1, seed=0)
    data, _ = collect("furuta", cfg, progress=False)
    outcomes = list(data.meta.trial_failed.values())
    assert any(outcomes) and not all(outcomes)


def test_file_holds_only_rig_signals_quantized(tmp_path):
    data, truth = collect("furuta", SMALL, progress=False)
    out = tmp_path / "x.npz"
    write_trajectory(data, out)
    write_trajectory(truth, ground_truth_path(out))
    with np.load(out) as z:
        assert "qd" not in z.files and "qdd" not in z.files
    back = read_trajectory(out, robot="furuta")
    step = 2 * np.pi / 4096
    assert np.allclose(back.q / step, np.round(back.q / step), atol=1e-9)
    assert np.abs(back.u).max() <= 10.0
    gt = read_ground_truth(ground_truth_path(out))
    assert np.max(np.abs(gt.q - back.q)) <= step / 2 + 1e-12  # quantization error bound


def test_sensor_models():
    rng = np.random.default_rng(0)
    enc = Encoder(SensorConfig(counts_per_rev=4096), rng)
    q = np.linspace(-1, 1, 1001)
    assert np.max(np.abs(enc(q) - q)) <= np.pi / 4096 + 1e-15
    # the filtered differentiator tracks a ramp's slope after its transient (ω_c = 50 rad/s)
    f = FilteredDifferentiator(1, cutoff=50.0, dt=1 / 400)
    v = [f(np.array([2.0 * k / 400]))[0] for k in range(400)]
    assert abs(v[-1] - 2.0) < 1e-9


def test_bad_collect_config():
    with pytest.raises(ValueError, match="gains"):
        collect("furuta", dataclasses.replace(SMALL, gains=(1.0, 2.0)), progress=False)
    with pytest.raises(ValueError, match="min ≤ max"):
        CollectConfig(amplitude=(0.3, 0.1))
    with pytest.raises(ValueError, match="no MuJoCo model"):
        collect("furuta-analytic", SMALL, progress=False)


def test_trajectory_reference_solves_the_linearised_unactuated_row():
    """With ``reference_bem`` (m ≥ 2) the q_u target is the periodic motion the actuated sines drive:
    G = (s_p + iω s_v − s_a ω²)/(1 + ω²/λ²).  At small amplitude the unactuated row of the robot's own
    dynamics, (D q̈ + h)_u at the reference state, vanishes to second order (closed form vs the model's terms)."""
    from bemlearn.robots import load
    from bemlearn.robots.scales import bem_slopes, instability_rate
    from bemlearn.sim.collect import _reference_state, _trajectory_reference

    robot = load(str(ROBOTS / "arm2_pole.xml"))
    ia, iu, n = list(robot.actuated_index), robot.unactuated_index, robot.n
    S = (*bem_slopes(robot).ravel(), instability_rate(robot))
    A = 1e-3
    comps = [(np.array([A, 0.5 * A]), np.array([2.0, 7.0]), np.array([0.3, 1.1])),
             (np.array([0.7 * A]), np.array([4.5]), np.array([2.0]))]
    traj = _trajectory_reference(S, comps, robot.m)
    for t in np.linspace(0.0, 3.0, 13):
        q, qd, qdd = _reference_state(float(t), comps, traj, ia, iu, n, robot.qu_nominal)
        D, h = robot.terms(q, qd)
        row = D[iu] @ qdd + h[iu]
        scale = abs(D[iu, iu] * qdd[iu]) + np.abs(D[iu, ia] * qdd[ia]).sum() + 1e-12
        assert abs(row) <= 2e-3 * scale, (t, row, scale)
    # without the periodic target (the paper's q_u at nominal) the same row is far from zero
    q, qd, qdd = _reference_state(0.4, comps, None, ia, iu, n, robot.qu_nominal)
    D, h = robot.terms(q, qd)
    assert abs(D[iu] @ qdd + h[iu]) > 0.1 * (np.abs(D[iu, ia] * qdd[ia]).sum())
    assert _trajectory_reference((), comps, robot.m) is None


def test_reference_bem_and_excursion_are_checked():
    from bemlearn.errors import ConfigError
    from bemlearn.sim.collect import _trajectory_reference

    with pytest.raises(ConfigError, match="reference_bem"):
        _trajectory_reference((1.0, 2.0), [(np.ones(1), np.ones(1), np.zeros(1))] * 2, 2)
    with pytest.raises(ConfigError, match="reference_bem"):
        _trajectory_reference((0.0,) * 6 + (-1.0,), [(np.ones(1), np.ones(1), np.zeros(1))] * 2, 2)


def _anchored_draws(config: CollectConfig, j: int, seeds: range, anchored: bool) -> list[tuple]:
    """Coordinate j's sines as :func:`simulate_trial` draws them (then extents, then the anchors when ``anchored``)."""
    from bemlearn.sim.collect import _component_extent, _draw_sines, _two_band

    out = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        A, w, ph = _draw_sines(config, 1, rng)[0]
        comp = (A * _component_extent(config, j, w, False), w, ph)
        out.append(_two_band(config, j, comp, rng) if anchored else comp)
    return out


def test_two_band_anchors_put_position_and_acceleration_at_their_extents_together():
    """One sine has q̈ = −ω² q; the slow and the fast anchor (m ≥ 2, ``excursion``) make q > P/2 with q̈ > a/2 (same
    sign) a regular state of the reference instead of an absent one, within the stated bands and scaled with the level."""
    import math

    P, a = 0.2, 5.0
    config = CollectConfig(n_sines=(2, 4), amplitude=(0.1, 0.5), frequency_hz=(0.12, 1.8), excursion=(P, 0.3, a, 4.0))
    t = np.arange(0.0, 400.0, 0.01)

    def same_sign_share(comp):
        A, w, ph = comp
        s = np.sin(np.outer(t, w) + ph)
        q, qdd = s @ A / P, -(s @ (A * w**2)) / a
        return float(np.mean((np.abs(q) > 0.5) & (np.abs(qdd) > 0.5) & (np.sign(q) == np.sign(qdd)))), np.abs(q).max(), np.abs(qdd).max()

    plain = [same_sign_share(c) for c in _anchored_draws(config, 0, range(20), False)]
    anchored = [same_sign_share(c) for c in _anchored_draws(config, 0, range(20), True)]
    assert np.median([p[0] for p in plain]) < 0.002
    assert np.median([p[0] for p in anchored]) > 0.01
    # every anchored draw reaches ≥ 0.6 × both extents (the anchors' fraction) and stays within 1.5 × them
    assert min(p[1] for p in anchored) >= 0.6 and min(p[2] for p in anchored) >= 0.6
    assert max(p[1] for p in anchored) <= 1.5 and max(p[2] for p in anchored) <= 1.5
    # the anchors' frequencies lie in their bands: below √(ω_lo ω_c), above √(ω_c ω_hi)
    w_lo, w_hi, w_c = 2 * math.pi * 0.12, 2 * math.pi * 1.8, math.sqrt(a / P)
    for A, w, _ in _anchored_draws(config, 0, range(20), True):
        assert w_lo <= w[0] <= math.sqrt(w_lo * w_c) + 1e-12 and math.sqrt(w_c * w_hi) - 1e-12 <= w[1] <= w_hi
        assert 0.6 * P - 1e-12 <= A[0] <= 0.9 * P + 1e-12 and 0.6 * a - 1e-9 <= A[1] * w[1] ** 2 <= 0.9 * a + 1e-9
    # the level check's halving of ``amplitude`` halves the anchors too
    half = dataclasses.replace(config, amplitude=(0.05, 0.25))
    for (A1, w1, _), (A2, w2, _) in zip(_anchored_draws(config, 0, range(5), True), _anchored_draws(half, 0, range(5), True)):
        np.testing.assert_allclose(w2, w1)
        np.testing.assert_allclose(A2, 0.5 * A1, rtol=1e-12)
    # a coordinate whose crossover √(a/P) lies outside the band keeps its sines
    flat = dataclasses.replace(config, excursion=(P, 0.3, 1000.0, 4.0))
    for c1, c2 in zip(_anchored_draws(flat, 0, range(5), False), _anchored_draws(flat, 0, range(5), True)):
        for x1, x2 in zip(c1, c2):
            np.testing.assert_array_equal(x1, x2)
