"""Two more test robots of the class: a pendubot (m = 1, hinge–hinge) and an XY cart-pole
(m = 2, two slides carrying a pole). Each loads, has the expected partition, a model BEM
with closed-form values, whole physics steps per control tick, and a short closed loop with
the model BEM and the derived gains."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from bemlearn.pipeline import derive
from bemlearn.robots import MujocoRobot

ROBOTS = Path(__file__).parent / "robots"
G = 9.81  # m/s², both files

# name → (joint kinds in model order, unactuated index, m)
PARTITION = {
    "pendubot": (("hinge", "hinge"), 1, 1),
    "xy_cartpole": (("slide", "slide", "hinge"), 2, 2),
}


def _robot(name: str) -> MujocoRobot:
    return MujocoRobot.from_xml(ROBOTS / f"{name}.xml")


def _bem(robot: MujocoRobot, qa, qad, qadd) -> np.ndarray:
    """Model BEM q_u^e (rad) for ``(B, m)`` actuated positions, velocities, accelerations."""
    t = [torch.as_tensor(np.atleast_2d(v), dtype=torch.float64) for v in (qa, qad, qadd)]
    return robot.bem(*t).qu.numpy()


@pytest.mark.parametrize("name", sorted(PARTITION))
def test_partition_and_joint_kinds(name):
    kinds, iu, m = PARTITION[name]
    robot = _robot(name)
    assert robot.joint_kinds == kinds and robot.coordinate_kinds == kinds
    assert robot.unactuated_index == iu and robot.m == m and robot.n == len(kinds)
    assert sorted(robot.actuated_index) == sorted(set(range(robot.n)) - {iu})
    B = robot.input_matrix.numpy()
    assert np.all(B[iu] == 0) and np.linalg.matrix_rank(B[list(robot.actuated_index)]) == m


@pytest.mark.parametrize("name", sorted(PARTITION))
def test_model_bem_at_rest_is_nominal(name):
    robot = _robot(name)
    z = np.zeros((1, robot.m))
    qu = _bem(robot, z, z, z)
    assert robot.qu_nominal == 0.0 and abs(qu[0] - robot.qu_nominal) < 1e-9


def test_pendubot_static_bem_keeps_lower_link_vertical():
    """At rest the elbow's gravity torque vanishes only with the lower link vertical:
    q_u^e = −q_a exactly (its COM lies on the link axis; damping acts on velocities only)."""
    robot = _robot("pendubot")
    qa = np.array([[-0.3], [-0.1], [0.05], [0.2]])
    qu = _bem(robot, qa, np.zeros_like(qa), np.zeros_like(qa))
    np.testing.assert_allclose(qu, -qa[:, 0], atol=1e-7)


def test_xy_cartpole_bem_is_atan_of_x_acceleration_only():
    """Uniform pole pinned to the cart, swinging in x–z: at θ̇ = 0 the pole is balanced iff
    g sin θ = ẍ cos θ, so q_u^e = atan(ẍ / g) whatever x, y, their rates and ÿ are."""
    robot = _robot("xy_cartpole")
    rng = np.random.default_rng(3)
    qa = rng.uniform(-0.3, 0.3, (6, 2))
    qad = rng.uniform(-0.5, 0.5, (6, 2))
    qadd = rng.uniform(-3.0, 3.0, (6, 2))
    qu = _bem(robot, qa, qad, qadd)
    np.testing.assert_allclose(qu, np.arctan(qadd[:, 0] / G), atol=1e-6)


@pytest.mark.parametrize("name", sorted(PARTITION))
def test_control_rate_whole_physics_steps(name):
    robot = _robot(name)
    r = derive.control_rate(robot).value
    assert r.rate_hz >= 100
    steps = 1 / (r.rate_hz * r.timestep)
    assert abs(steps - round(steps)) < 1e-9 and round(steps) == r.substeps
    assert not r.timestep_changed and r.timestep == robot.model.opt.timestep  # both files use ≤ 2 ms


def _loop_config(name: str, source: str):
    """3 s EIC closed loop with the derived rate, gains, reference and fall window (the pipeline's resolution)."""
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    cfg = {"robot": str(ROBOTS / f"{name}.xml"), "simulate": {"duration_s": 3.0, "bem_source": source}}
    return resolve_pipeline_config(cfg).config.simulate


def _short_loop(name: str, source: str) -> dict:
    from bemlearn.robots import load
    from bemlearn.sim.closed_loop import simulate

    return simulate(load(str(ROBOTS / f"{name}.xml")), _loop_config(name, source), progress=False).metrics


@pytest.mark.parametrize("name", ["pendubot", "xy_cartpole"])
def test_short_closed_loop_model_bem_stays_up(name):
    m = _short_loop(name, "model")
    assert not m["fell"] and m["bem_rejected"] == 0 and m["command_rejected"] == 0
    assert m["qu_max"] < _loop_config(name, "model").fall_window / 2
    assert math.isfinite(m["tracking_rmse"])


def test_pendubot_zero_bem_falls():
    """The same loop with q_u^e ≡ 0 falls: the pendubot's BEM moves with the shoulder (s_p = −1),
    so the model-BEM loop above stays up because of the BEM, not the gains alone."""
    m = _short_loop("pendubot", "zero")
    assert m["fell"] and m["duration_s"] < 3.0


def test_derived_held_out_references_for_two_actuated_joints():
    """The xy cart-pole's derived evaluation references (the pipeline's resolution): two rows each, Σ|A| of
    each row inside [amplitude_min, amplitude_max], frequencies in the derived band, and the BEM they
    exercise, atan(ẍ/g) in closed form, peaking between a quarter of and twice the design bound d
    (the rule of docs/derived-defaults.md: one sine of Σ|A|/2 at the band's top moves the BEM by d)."""
    from bemlearn.pipeline.evaluation import held_out_references
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    ev = resolve_pipeline_config({"robot": str(ROBOTS / "xy_cartpole.xml")}).config.evaluate
    refs = held_out_references(ev, 2)
    assert len(refs) == ev.n_references == 5
    t = np.arange(0.0, ev.duration_s, 1.0 / ev.rate_hz)
    peaks = []
    for ref in refs:
        assert ref.m == 2
        for amps, freqs in zip(ref.amplitudes, ref.frequencies):
            assert ev.amplitude_min - 1e-12 <= sum(map(abs, amps)) <= ev.amplitude_max + 1e-12
            assert all(ev.frequency_hz[0] <= f <= ev.frequency_hz[1] for f in freqs)
        qa, _, qadd = ref.evaluate(t)
        assert np.all(np.abs(qa) <= np.array([sum(map(abs, a)) for a in ref.amplitudes]) + 1e-12)
        peaks.append(float(np.abs(np.arctan(qadd[:, 0] / G)).max()))
    d = 0.2
    assert d / 4 <= max(peaks) <= 2 * d, peaks
