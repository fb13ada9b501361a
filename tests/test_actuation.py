"""One command per actuated coordinate (bemlearn.robots.actuation) against closed forms and MuJoCo's own forces."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from bemlearn.control.actuator_inverse import MujocoActuatorInverse
from bemlearn.control.lqr import actuator_limits
from bemlearn.errors import RobotModelError
from bemlearn.robots import MujocoRobot
from bemlearn.robots.actuation import actuator_groups

WHEELER = Path(__file__).parent / "robots" / "two_wheeler.xml"


def _wheeler(*, right_gear: float = 1.0, left_range: float = 1.5, right_range: float = 1.5) -> MujocoRobot:
    xml = WHEELER.read_text()
    xml = xml.replace('<motor name="left_motor" joint="left_spin" gear="1" ctrllimited="true" ctrlrange="-1.5 1.5"/>',
                      f'<motor name="left_motor" joint="left_spin" gear="1" ctrllimited="true" ctrlrange="-{left_range} {left_range}"/>')
    xml = xml.replace('<motor name="right_motor" joint="right_spin" gear="1" ctrllimited="true" ctrlrange="-1.5 1.5"/>',
                      f'<motor name="right_motor" joint="right_spin" gear="{right_gear}" ctrllimited="true" '
                      f'ctrlrange="-{right_range} {right_range}"/>')
    return MujocoRobot.from_xml_string(xml, name="two_wheeler")


def test_two_motors_on_one_wheel_coordinate_are_one_command():
    """Hinge axes of opposite sign: B_a = [1, −1]; least-norm split f = B_a⁺ τ = (τ/2, −τ/2); W = (1, −1)."""
    robot = MujocoRobot.from_xml(WHEELER)
    assert robot.actuator_mismatch() is None
    groups = robot.actuation
    np.testing.assert_allclose(robot.input_matrix_np[list(robot.actuated_index)], [[1.0, -1.0]], atol=1e-12)
    np.testing.assert_allclose(groups.force_split, [[0.5], [-0.5]], atol=1e-12)
    np.testing.assert_allclose(groups.W, [[1.0], [-1.0]], atol=1e-12)
    np.testing.assert_allclose(groups.ctrl(np.array([0.7])), [0.7, -0.7], atol=1e-15)
    np.testing.assert_allclose(groups.command_of(np.array([0.7, -0.7])), [0.7], atol=1e-15)
    assert groups.names == ("left_motor+right_motor",) and groups.grouped


def test_group_limit_is_its_most_restrictive_member():
    """Right motor gear 2: B_a = [1, −2], split (1/5, −2/5), W = (1, −2); |u| ≤ min(1.5/1, 1.0/2) = 0.5."""
    robot = _wheeler(right_gear=2.0, right_range=1.0)
    groups = robot.actuation
    np.testing.assert_allclose(groups.force_split, [[0.2], [-0.4]], atol=1e-12)
    np.testing.assert_allclose(groups.W, [[1.0], [-2.0]], atol=1e-12)
    lim = actuator_limits(robot)
    assert lim.u_ctrl == pytest.approx([0.5], abs=1e-12)
    x = np.zeros(2 * robot.n)
    # ctrl (0.25, −0.5) against the ranges (1.5, 1.0); motor forces = ctrl (gain 1, no bias) against the grip
    grip = robot.traction_limits
    assert lim.peak(np.array([0.25]), x) == pytest.approx(max(0.5, 0.25 / grip[0], 0.5 / grip[1]), abs=1e-12)
    # the left motor's range binds when it is the narrower one: min(0.4/1, 1.0/2) = 0.4
    assert actuator_limits(_wheeler(right_gear=2.0, left_range=0.4, right_range=1.0)).u_ctrl == pytest.approx([0.4], abs=1e-12)


def test_inverse_realises_the_coordinate_force_in_mujoco():
    """ctrl from a coordinate force τ_a (the EIC's command → ctrl): MuJoCo's actuator forces, projected by Sᵀ,
    give back τ_a (wheel row) and nothing on the pitch, each motor carrying half."""
    robot = _wheeler(right_gear=2.0, right_range=10.0)
    inv = MujocoActuatorInverse(robot)
    q, qd = np.array([0.3, 0.05]), np.array([1.0, -0.2])
    tau_a = np.array([0.8])
    ctrl = inv.command(tau_a, q, qd)
    model, data = robot.model, mujoco.MjData(robot.model)
    data.qpos[:], data.qvel[:] = robot.state_to_mujoco(q, qd)
    data.ctrl[:] = ctrl
    mujoco.mj_forward(model, data)
    tau = robot.Tinv_np.T @ data.qfrc_actuator
    assert tau[robot.actuated_index[0]] == pytest.approx(0.8, abs=1e-12)
    assert tau[robot.unactuated_index] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(data.actuator_force, [0.8 / 5, -1.6 / 5], atol=1e-12)   # f = B_a⁺ τ, B_a = [1, −2]


def test_wheel_grip_limits_the_wheel_motors():
    """μ N r: friction 1, each wheel carries half of 1.4 kg, r_eff ≈ 0.05 m (penetration < 0.5 %)."""
    robot = MujocoRobot.from_xml(WHEELER)
    expected = 1.0 * 0.5 * 1.4 * 9.81 * 0.05
    np.testing.assert_allclose(robot.traction_limits, [expected, expected], rtol=5e-3)
    lim = actuator_limits(robot)
    assert lim.binding == ("forcerange",)   # the grip (0.34 N·m) binds before the ctrlrange (1.5 N·m)
    assert lim.u_max == pytest.approx(robot.traction_limits[:1], rel=1e-12)


_SPREAD = """
<mujoco model="spread">
  <compiler angle="radian"/>
  <option timestep="0.002"/>
  <custom>
    <numeric name="bemlearn_coordinates" data="1 0 0  0 1 0  0 1 1"/>
    <text name="bemlearn_coordinate_names" data="base upper absolute"/>
  </custom>
  <worldbody>
    <body name="l0">
      <joint name="j0" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.02" mass="0.5"/>
      <body name="l1" pos="0 0 0.3">
        <joint name="j1" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.02" mass="0.3"/>
        <body name="l2" pos="0 0 0.3">
          <joint name="j2" type="hinge" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.02" mass="0.2"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="a" joint="j1"/>
    <motor name="b" joint="j1"/>
    <motor name="c" joint="j2"/>
  </actuator>
</mujoco>
"""


def test_one_actuator_on_several_coordinates_is_refused():
    """With the absolute angle q2 = j1 + j2 as a coordinate, B = T⁻ᵀ B_j puts motor c on (upper, absolute): with
    3 actuators for 2 coordinates that is no grouping, refused in one line naming the actuator."""
    robot = MujocoRobot.from_xml_string(_SPREAD, name="spread")
    np.testing.assert_allclose(robot.input_matrix_np[list(robot.actuated_index)], [[1, 1, -1], [0, 0, 1]], atol=1e-12)
    why = robot.actuator_mismatch()
    assert why is not None and "\n" not in why
    assert "actuator 'c' drives 2 actuated coordinates ['upper', 'absolute']" in why
    with pytest.raises(RobotModelError, match="actuator 'c' drives 2"):
        _ = robot.actuation


def test_one_actuator_per_coordinate_keeps_the_actuators_own_ctrl():
    """nu = m: W = I whatever B_a (one motor spread over two coordinates by a declared map is inverted as a whole)."""
    robot = MujocoRobot.from_xml_string(_SPREAD.replace('<motor name="b" joint="j1"/>', ""), name="spread2")
    groups = actuator_groups(robot.input_matrix_np[list(robot.actuated_index)], np.ones(2), ("a", "c"), ("upper", "absolute"))
    assert not isinstance(groups, str)
    np.testing.assert_allclose(groups.W, np.eye(2))
    np.testing.assert_allclose(groups.force_split, np.linalg.inv([[1.0, -1.0], [0.0, 1.0]]), atol=1e-12)
    assert robot.actuator_mismatch() is None
    assert isinstance(actuator_groups(np.ones((2, 1)), np.ones(1), ("a",), ("x", "y")), str)   # fewer actuators than coordinates


def _servo_wheeler(kv: float) -> MujocoRobot:
    """The two-wheeler with velocity servos (force kv·(ctrl − θ̇_k) on each wheel, gear 1) instead of motors."""
    xml = WHEELER.read_text()
    for side in ("left", "right"):
        xml = xml.replace(f'<motor name="{side}_motor" joint="{side}_spin" gear="1" ctrllimited="true" ctrlrange="-1.5 1.5"/>',
                          f'<velocity name="{side}_motor" joint="{side}_spin" kv="{kv}" ctrllimited="true" ctrlrange="-50 50"/>')
    return MujocoRobot.from_xml_string(xml, name="servo_wheeler")


def _mean_wheel_force(robot: MujocoRobot, ctrl: np.ndarray, dt: float) -> float:
    """The wheel coordinate's generalized actuator force averaged over a tick ``dt`` with ``ctrl`` held, from rest upright."""
    model, data = robot.model, mujoco.MjData(robot.model)
    data.qpos[:], data.qvel[:] = robot.state_to_mujoco(np.zeros(robot.n), np.zeros(robot.n))
    data.ctrl[:] = ctrl
    steps = int(round(dt / model.opt.timestep))
    total = 0.0
    for _ in range(steps):
        mujoco.mj_forward(model, data)
        total += float((robot.Tinv_np.T @ data.qfrc_actuator)[robot.actuated_index[0]])
        mujoco.mj_step(model, data)
    return total / steps


def test_held_servo_correction_only_where_the_servo_settles_within_the_tick():
    """A5: φ = κΔt / (1 − e^{−κΔt}) (A3) is applied only from φ ≥ 2 (κΔt ≥ 1.594).  κ = (D⁻¹)_θθ Σ kv_k (closed form:
    the wheel coordinate's mobility times the two servos' velocity feedback).  Below it the held command is the
    force-now inverse bit for bit (it delivers 0.67 of the force over the tick, above half); above it the tick's mean
    force in MuJoCo is the one asked for (measured 0.997 of it; 2 % allowed: the pitch's coupling and the contact are
    outside the one-coordinate relaxation), where the force-now command gives 1/φ of it (measured 0.1657, 1/φ = 0.1663)."""
    from bemlearn.robots.actuation import HOLD_CORRECTION_MIN, held_servo_factors, hold_factors, servo_relaxation

    dt = 1.0 / 200.0
    unit = _servo_wheeler(1.0)
    D = unit.terms(np.zeros(unit.n), np.zeros(unit.n))[0]
    mobility = float(np.linalg.inv(D)[unit.actuated_index[0], unit.actuated_index[0]])
    np.testing.assert_allclose(servo_relaxation(unit), [2.0 * mobility] * 2, rtol=1e-12)
    x_min = 1.5936242600400401   # φ(x) = 2: x / (1 − e^{−x}) = 2
    assert hold_factors(np.array([x_min]), 1.0)[0] == pytest.approx(HOLD_CORRECTION_MIN, rel=1e-9)
    tau_a = np.array([0.02])
    q = np.zeros(unit.n)
    # below: κΔt = 1 (φ = 1.58): no correction, the held command is the force-now command bit for bit
    slow = _servo_wheeler(1.0 / (2.0 * mobility * dt))
    assert held_servo_factors(slow, dt) is None
    assert np.array_equal(MujocoActuatorInverse(slow, hold_s=dt).command(tau_a, q, q, clip=False),
                          MujocoActuatorInverse(slow).command(tau_a, q, q, clip=False))
    # above: κΔt = 6 (φ = 6.015)
    fast = _servo_wheeler(6.0 / (2.0 * mobility * dt))
    phi = held_servo_factors(fast, dt)
    assert phi is not None
    np.testing.assert_allclose(phi, 6.0 / (1.0 - np.exp(-6.0)), rtol=1e-9)
    held = _mean_wheel_force(fast, MujocoActuatorInverse(fast, hold_s=dt).command(tau_a, q, q, clip=False), dt)
    now = _mean_wheel_force(fast, MujocoActuatorInverse(fast).command(tau_a, q, q, clip=False), dt)
    assert held == pytest.approx(tau_a[0], rel=0.02)
    assert now == pytest.approx(tau_a[0] / phi[0], rel=0.02)
