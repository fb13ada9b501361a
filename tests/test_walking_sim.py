"""Walking simulation: foot kinematics vs MuJoCo, short walks, determinism, falls, logging, config."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from bemlearn.apps.biped.assets import PLANAR_XML
from bemlearn.apps.biped.gait import GaitConfig
from bemlearn.apps.biped.walker import (
    WalkConfig,
    foot_positions,
    load_walk_config,
    simulate_walk,
    stance_per_sample,
    walk_trajectories,
    walking_data,
)
from bemlearn.config import ConfigError
from bemlearn.data import ground_truth_path, read_ground_truth, read_trajectory, write_trajectory
from bemlearn.data.sensors import SensorConfig
from bemlearn.robots import load

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def walk4():
    """Four steps of the default gait with the model-based torso BEM in the loop."""
    return simulate_walk(WalkConfig(duration_s=4.0, max_steps=4), progress=False)


def test_pytorch_kinematics_feet_match_mujoco_sites():
    model = mujoco.MjModel.from_xml_path(str(PLANAR_XML))
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    qpos = np.c_[rng.uniform(-1, 1, (16, 2)), rng.uniform(-0.8, 0.8, (16, 5))]
    feet = foot_positions(qpos)
    sites = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, n) for n in ("foot1", "foot2")]
    for i in range(len(qpos)):
        data.qpos[:] = qpos[i]
        mujoco.mj_kinematics(model, data)
        np.testing.assert_allclose(feet[i], data.site_xpos[sites], rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match=r"shape \(T, 7\)"):
        foot_positions(qpos[:, :5])


def test_short_walk_with_model_bem(walk4):
    m = walk4.metrics
    assert m["steps"] == 4 and not m["fell"] and m["bem_invalid"] == 0
    assert 0.12 < m["step_length_mean"] < 0.16 and m["step_length_std"] < 0.01  # design: 0.15 m
    assert m["clearance_min"] > 0.015 and m["speed"] > 0.2
    assert m["torso_min"] > -0.2 and m["torso_max"] < 0.2
    assert m["torque_max"] <= 20.0
    np.testing.assert_array_equal(walk4.stance[walk4.steps], [1, 2, 1, 2])  # legs alternate


def test_step_lengths_agree_with_mujoco_contacts(walk4):
    """The pytorch-kinematics step length equals the touchdown x of MuJoCo's foot sites."""
    model = mujoco.MjModel.from_xml_path(str(PLANAR_XML))
    data = mujoco.MjData(model)
    sid = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, n) for n in ("foot1", "foot2")]
    lengths = []
    for k, qpos in zip(walk4.steps, walk4.touchdown_qpos):
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        leg = walk4.stance[k]
        lengths.append(data.site_xpos[sid[2 - leg], 0] - data.site_xpos[sid[leg - 1], 0])
    assert walk4.metrics["step_length_mean"] == pytest.approx(np.mean(lengths), abs=1e-12)


def test_short_walk_on_the_human_gait():
    r = simulate_walk(WalkConfig(duration_s=3.0, max_steps=3, gait=GaitConfig(kind="human")), progress=False)
    assert r.metrics["steps"] == 3 and not r.fell
    assert 0.13 < r.metrics["step_length_mean"] < 0.17


def test_same_seed_same_run_other_seed_differs():
    cfg = WalkConfig(duration_s=1.0, max_steps=2, initial_noise=0.01, seed=7,
                     sensor=SensorConfig(noise_std=1e-3))
    a, b = simulate_walk(cfg, progress=False), simulate_walk(cfg, progress=False)
    for name in ("qpos", "qvel", "u", "q_meas", "qu_e"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    c = simulate_walk(dataclasses.replace(cfg, seed=8), progress=False)
    assert not np.array_equal(a.qpos[:5], c.qpos[:5])


def test_too_slow_start_falls_and_is_logged_as_failed(tmp_path):
    r = simulate_walk(WalkConfig(duration_s=3.0, initial_phase_rate=0.1), progress=False)
    assert r.fell and r.metrics["steps"] == 0
    data, _ = walk_trajectories(r)
    assert data.meta.trial_failed == {0: True}
    write_trajectory(data, tmp_path / "fell.csv")  # no non-finite metric in the metadata
    assert read_trajectory(tmp_path / "fell.csv").meta.extra["metrics"]["step_length_mean"] is None


def test_logged_walk_round_trips_and_obeys_the_pinned_model(walk4, tmp_path):
    data, truth = walk_trajectories(walk4)
    path = tmp_path / "walk.npz"
    write_trajectory(data, path)
    write_trajectory(truth, ground_truth_path(path))
    d = read_trajectory(path, robot="biped")
    t = read_ground_truth(ground_truth_path(path), robot="biped")
    assert d.trial_ids == (0, 1, 2, 3) and d.meta.extra["stance_leg"] == {"0": 1, "1": 2, "2": 1, "3": 2}
    np.testing.assert_array_equal(stance_per_sample(d), walk4.stance)
    np.testing.assert_array_equal(d.q, data.q)
    # stance-relative: while leg 2 stands, column q2 is the walker's q4
    rows = t.trial == 1
    np.testing.assert_array_equal(t.q[rows][:, [1, 2, 3, 4]], walk4.qpos[: len(walk4.t)][rows][:, [5, 6, 3, 4]])
    # single support: the pinned model's unactuated row Γ (eq. 5) nearly vanishes on the truth
    X, y = walking_data(t, skip_after_impact=3)
    assert X.shape[1] == 14 and X.shape[0] == y.shape[0] == t.n_samples - 3 * 4
    biped = load("biped")
    keep = np.concatenate([np.arange(s.rows.start + 3, s.rows.stop) for s in t.trial_slices()])
    gam = biped.gamma(torch.from_numpy(t.q[keep]), torch.from_numpy(t.qd[keep]), torch.from_numpy(t.qdd[keep]))
    assert float(torch.median(gam.abs())) < 1.0  # N·m, vs ~24 N·m per rad of torso lean
    np.testing.assert_array_equal(X[:, 8:12], t.q[keep][:, 1:])
    np.testing.assert_array_equal(y, t.q[keep][:, 0])
    with pytest.raises(ValueError, match="no qd/qdd"):
        walking_data(d)


def test_config_file_parses_strictly(tmp_path):
    assert load_walk_config(ROOT / "configs" / "biped.yaml") == WalkConfig()
    bad = tmp_path / "b.yaml"
    bad.write_text("robot: biped\nwalk:\n  gait:\n    design:\n      step_lenght: 0.1\n")
    with pytest.raises(ConfigError, match=r"walk.gait.design: unknown key\(s\) \['step_lenght'\]"):
        load_walk_config(bad)
    bad.write_text("robot: furuta\nwalk: {}\n")
    with pytest.raises(ConfigError, match="needs 'biped'"):
        load_walk_config(bad)


@pytest.mark.parametrize("kind", ["default", "human"])
def test_twenty_steps_with_model_bem(kind):
    """The issue's target; about 1 s of wall time each, so not marked slow."""
    r = simulate_walk(WalkConfig(duration_s=15.0, max_steps=20, gait=GaitConfig(kind=kind)), progress=False)
    m = r.metrics
    assert m["steps"] == 20 and not m["fell"]
    assert abs(m["torso_mean"]) < 0.05 and m["torso_range"] < 0.7
