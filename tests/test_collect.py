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
