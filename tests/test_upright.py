"""The upright found from the physics, and the LQR's actuator limits (own robots written here).

References are closed forms: a point-mass pendulum's Γ_0 = −m g l sin(q_u − q*) has its unstable
equilibrium at q*, whatever convention puts q* at 0, π or elsewhere.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from bemlearn.control.lqr import actuator_limits, discrete_lqr, holds_in_mujoco, linearize
from bemlearn.errors import RobotModelError
from bemlearn.robots import MujocoRobot
from bemlearn.robots.scales import instability_rate, upright_stiffness
from bemlearn.robots.upright import find_upright


def _cartpole(*, pole_to: str = "0 0 0.6", ref: str = "", angle: str = "radian", extra_joint: str = "",
              actuator: str = '<motor joint="slider" ctrlrange="-20 20" ctrllimited="true"/>', nominal: str = "") -> str:
    custom = f'<custom><numeric name="bemlearn_qu_nominal" data="{nominal}"/></custom>' if nominal else ""
    return f"""<mujoco model="cp">
  <compiler angle="{angle}"/>
  <option timestep="0.002"/>
  {custom}
  <worldbody>
    <body name="cart">
      <joint name="slider" type="slide" axis="1 0 0" range="-1 1" limited="true" {extra_joint}/>
      <geom type="box" size="0.1 0.05 0.05" mass="1"/>
      <body name="pole">
        <joint name="hinge" type="hinge" axis="0 1 0" {ref}/>
        <geom type="capsule" fromto="0 0 0 {pole_to}" size="0.02" mass="0.2"/>
      </body>
    </body>
  </worldbody>
  <actuator>{actuator}</actuator>
</mujoco>"""


@pytest.mark.parametrize("q_star", [0.0, math.pi, 1.0, -2.5])
def test_find_upright_on_a_pendulum_closed_form(q_star):
    res = find_upright(lambda q: -2.0 * math.sin(q - q_star), kind="hinge")
    assert res.upright is not None
    assert math.remainder(res.upright.qu - q_star, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    assert res.upright.stiffness == pytest.approx(2.0, rel=1e-5)
    assert len(res.equilibria) == 2 and sum(e.unstable for e in res.equilibria) == 1


def test_a_spring_that_makes_the_top_stable_leaves_no_upright():
    # Γ_0 = −sin q + 3 q: the spring wins; the only equilibrium (q = 0) is stable
    res = find_upright(lambda q: -math.sin(q) + 3.0 * q, kind="hinge", limits=(-1.0, 1.0))
    assert res.upright is None and len(res.equilibria) == 1 and not res.equilibria[0].unstable
    assert "no unstable equilibrium" in res.describe()


@pytest.mark.parametrize("xml, expected", [
    (_cartpole(), 0.0),                                           # upright reads 0 by geometry
    (_cartpole(pole_to="0 0 -0.6"), math.pi),                     # hanging reads 0: the upright is π
    (_cartpole(ref='ref="180"', angle="degree"), math.pi),        # MuJoCo's ref puts the reset at 180°
    (_cartpole(pole_to="0.3 0 0.52"), -math.atan2(0.3, 0.52)),    # the pole leans in its own frame
])
def test_mujoco_robot_finds_the_upright_by_its_physics(xml, expected):
    robot = MujocoRobot.from_xml_string(xml, name="cp")
    assert math.remainder(robot.qu_nominal - expected, 2 * math.pi) == pytest.approx(0.0, abs=1e-8)
    assert upright_stiffness(robot)[0] > 0
    # the instability rate is that of the upright, √(m g l / D_uu) for a thin rod of length L (l = L/2)
    assert instability_rate(robot) > 0
    # the design region and the BEM search bracket sit around it
    lo, hi = robot.qu_range
    assert lo < robot.qu_nominal < hi


def test_a_declared_stable_nominal_is_refused_with_its_reason():
    robot = MujocoRobot.from_xml_string(_cartpole(pole_to="0 0 -0.6", nominal="0"), name="hanging")
    assert robot.qu_nominal == 0.0 and upright_stiffness(robot)[0] < 0
    with pytest.raises(RobotModelError, match="stable pose without control"):
        instability_rate(robot)


def test_dry_friction_does_not_collapse_the_linearisation():
    plain = MujocoRobot.from_xml_string(_cartpole(extra_joint='damping="0.5"'), name="plain")
    dry = MujocoRobot.from_xml_string(_cartpole(extra_joint='damping="0.5" frictionloss="1.5"'), name="dry")
    A0, B0, _, _ = linearize(plain, rate_hz=250.0)
    A1, B1, _, _ = linearize(dry, rate_hz=250.0)
    np.testing.assert_allclose(B1, B0, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(A1, A0, rtol=1e-6, atol=1e-9)
    res = discrete_lqr(dry, rate_hz=250.0)
    assert any("dry friction" in n for n in res.notes)
    assert res.u_peak <= 1.0


def _velocity_wheel(kv: float = 0.5, force: float = 0.45) -> str:
    return f"""<mujoco model="rw">
  <option timestep="0.002"/>
  <worldbody>
    <body name="pend">
      <joint name="pitch" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.015" mass="0.3"/>
      <body name="wheel" pos="0 0 0.3">
        <joint name="wheel" type="hinge" axis="0 1 0"/>
        <geom type="cylinder" size="0.08 0.01" euler="90 0 0" mass="0.4"/>
      </body>
    </body>
  </worldbody>
  <actuator><velocity joint="wheel" kv="{kv}" ctrlrange="-300 300" ctrllimited="true"
    forcerange="-{force} {force}" forcelimited="true"/></actuator>
</mujoco>"""


def test_actuator_limits_read_the_servo_force_law():
    robot = MujocoRobot.from_xml_string(_velocity_wheel(kv=0.5, force=0.45), name="rw")
    lim = actuator_limits(robot)
    assert lim.binding == ("forcerange",)
    assert lim.u_max[0] == pytest.approx(0.45 / 0.5)
    # f = kv (ctrl − q̇_wheel): the state part of the linearised force is −kv on the wheel rate
    iw = robot.joint_names.index("wheel")
    assert lim.f_state[0, robot.n + iw] == pytest.approx(-0.5)
    # against MuJoCo's own actuator force at a state and command
    data = mujoco.MjData(robot.model)
    data.qvel[robot._dadr[iw]] = 0.3
    data.ctrl[0] = 0.7
    mujoco.mj_forward(robot.model, data)
    x = np.zeros(2 * robot.n)
    x[robot.n + iw] = 0.3
    assert lim.gain[0] * 0.7 + lim.f_state[0] @ x == pytest.approx(float(data.actuator_force[0]), abs=1e-12)


def test_the_lqr_weighs_a_servo_forcerange_when_mujoco_says_it_must():
    """A velocity-servo wheel with a tight forcerange: the ctrl-only design saturates and falls in MuJoCo, so the
    derived design weighs the force and brings the robot back in MuJoCo; with a looser forcerange the ctrl-only
    design recovers and is kept (a short saturation is harmless)."""
    tight = MujocoRobot.from_xml_string(_velocity_wheel(force=0.2), name="rw")
    res = discrete_lqr(tight, rate_hz=250.0, qu0=0.05)
    assert any("weighs the actuator force" in n for n in res.notes)
    start = np.zeros(2 * tight.n)
    start[tight.unactuated_index] = 0.05
    assert holds_in_mujoco(tight, res.K, rate_hz=250.0, timestep=None, starts=[start], check_s=3.0, qu0=0.05)[0]
    # the ctrl-only gains of the looser wheel used on the tight one fall: the check has something to catch
    loose = MujocoRobot.from_xml_string(_velocity_wheel(force=0.45), name="rw")
    res_loose = discrete_lqr(loose, rate_hz=250.0, qu0=0.05)
    assert not any("weighs the actuator force" in n for n in res_loose.notes)
    holds, why = holds_in_mujoco(tight, res_loose.K, rate_hz=250.0, timestep=None, starts=[start], check_s=3.0, qu0=0.05)
    assert not holds and "MuJoCo" in why
