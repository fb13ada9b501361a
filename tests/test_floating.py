"""A free-floating body on two driven wheels (bemlearn.robots.floating) against references computed without the reduction.

tests/robots/two_wheeler.xml: a body of mass m_b whose centre of mass is l above the axle, on two wheels
(radius R, mass m_w, inertia I_w about the axle each), both driven.  Planar closed form, derived here:
with the body not rotating (φ̇ = φ̈ = 0) the whole robot translates with a = r θ̈ and the wheels turn at
θ̈ (θ the wheel angle relative to the body, r the rolling radius).  Pitching by δφ with the wheels held to
the body rotates the whole robot about the contact line (the wheel rolls), so the motor does no work and
d'Alembert's principle for that virtual displacement (point displacement (d_z, −d_x) δφ at offset d from
the contact line, d_x along travel) reads

    m_b g l sin φ − m_b a (r + l cos φ) − 2 m_w a r − 2 I_w a / r = 0,                             (P)

independent of θ̇ (wheel damping acts on the relative joint, which does not move).  MuJoCo's contact point
lies midway through the penetration: r = r_eff = (h + R) / 2 with h the hub's height above the floor on the
pose of rest, where the contacts carry the weight.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
from scipy.optimize import brentq

from bemlearn.errors import RobotModelError
from bemlearn.robots import MujocoRobot, load
from bemlearn.robots.rolling import kkt_acceleration, wheel_geoms

ROBOTS = Path(__file__).resolve().parent / "robots"
TWO = ROBOTS / "two_wheeler.xml"
M_B, L, M_W, I_W, R, G = 1.2, 0.08, 0.1, 1.5e-4, 0.05, 9.81
I_B = 0.010   # the body's inertia about its centre of mass, about the axle


@pytest.fixture(scope="module")
def robot() -> MujocoRobot:
    r = load(TWO)
    assert isinstance(r, MujocoRobot)
    return r


def _hub_height(robot: MujocoRobot) -> float:
    d = mujoco.MjData(robot.model)
    d.qpos[:] = robot.state_to_mujoco(np.zeros(2))[0]
    mujoco.mj_kinematics(robot.model, d)
    return float(d.xanchor[robot.model.joint("left_spin").id][2])


def _closed_form(alpha: float, r: float) -> float:
    a = r * alpha
    return brentq(lambda p: M_B * G * L * math.sin(p) - M_B * a * (r + L * math.cos(p)) - 2 * M_W * a * r - 2 * I_W * a / r,
                  -1.2, 1.2, xtol=1e-15)


def test_pitch_is_unactuated_and_the_wheels_roll_together(robot):
    assert robot.joint_names == ("left_spin", "chassis_pitch")
    assert robot.unactuated_name == "chassis_pitch"
    assert robot.coordinate_kinds == ("hinge", "hinge")
    fl = robot.floating
    assert fl is not None and [robot.model.joint(j).name for j in fl.wheels] == ["left_spin", "right_spin"]
    np.testing.assert_array_equal(fl.signs, [1.0, -1.0])
    np.testing.assert_allclose(fl.T @ fl.S, np.eye(2), atol=1e-15)
    r = 0.5 * (_hub_height(robot) + R)
    # travel along x = r (θ + φ) (the wheel's world angle), both wheels alike: B's wheel row = (1, −1)
    np.testing.assert_allclose(fl.S[:3].T, [[r, 0, 0], [r, 0, 0]], atol=1e-9)
    np.testing.assert_allclose(robot.input_matrix_np, [[1.0, -1.0], [0.0, 0.0]], atol=1e-15)
    assert [c.radius for c in fl.contacts] == pytest.approx([r, r], abs=1e-9)


def test_the_pose_of_rest_carries_the_weight(robot):
    m, d = robot.model, mujoco.MjData(robot.model)
    d.qpos[:] = robot.state_to_mujoco(np.zeros(2))[0]
    mujoco.mj_forward(m, d)
    force = np.zeros(6)
    normal = 0.0
    for i in range(d.ncon):
        mujoco.mj_contactForce(m, d, i, force)
        normal += force[0]
    weight = (M_B + 2 * M_W) * G
    assert normal == pytest.approx(weight, rel=1e-6)
    assert 0 < R - _hub_height(robot) < 1e-3   # pressed in, not far


def test_positions_round_trip_and_the_axle_stays_level(robot):
    rng = np.random.default_rng(3)
    d = mujoco.MjData(robot.model)
    h = _hub_height(robot)
    r = 0.5 * (h + R)
    x0 = robot.floating.qpos_ground[0]
    for _ in range(5):
        q = np.array([rng.uniform(-20, 20), rng.uniform(-1.0, 1.0)])
        qpos, _ = robot.state_to_mujoco(q)
        np.testing.assert_allclose(robot.coordinates_of(qpos), q, atol=1e-12)
        d.qpos[:] = qpos
        mujoco.mj_kinematics(robot.model, d)
        axle = d.xanchor[robot.model.joint("left_spin").id]
        assert axle[2] == pytest.approx(h, abs=1e-12)
        assert axle[0] - x0 == pytest.approx(r * (q[0] + q[1]), abs=1e-9)
        # the body's up axis leans by the pitch about +y
        up = d.xmat[robot.model.body("chassis").id].reshape(3, 3)[:, 2]
        np.testing.assert_allclose(up, [math.sin(q[1]), 0.0, math.cos(q[1])], atol=1e-12)


@pytest.mark.parametrize("rate", [0.0, 10.0])
def test_model_bem_matches_the_planar_closed_form(robot, rate):
    r = 0.5 * (_hub_height(robot) + R)
    alpha = np.linspace(-20.0, 20.0, 21)
    res = robot.bem(np.zeros((21, 1)), np.full((21, 1), rate), alpha[:, None])
    assert bool(res.valid.all())
    ref = np.array([_closed_form(a, r) for a in alpha])
    np.testing.assert_allclose(res.qu.numpy(), ref, atol=1e-10)
    assert abs(ref[-1]) > 0.15   # the range is not trivial


def test_pitch_inertia_is_the_whole_robot_about_the_contact_line(robot):
    """Pitching with the wheels held to the body turns the whole robot about the contact line:
    D_φφ = I_b + m_b (r² + l² + 2 r l cos φ) + 2 (m_w r² + I_w), which depends on φ (Lemma 1's premise
    ∂D_uu/∂q_u = 0 does not hold for this robot)."""
    r = 0.5 * (_hub_height(robot) + R)
    for phi in (-0.7, 0.0, 0.4):
        D, _ = robot.terms(np.array([2.0, phi]), np.zeros(2))
        ref = I_B + M_B * (r * r + L * L + 2 * r * L * math.cos(phi)) + 2 * (M_W * r * r + I_W)
        assert D[1, 1] == pytest.approx(ref, rel=1e-12)


def _kkt_pitch_accel(robot: MujocoRobot, q: np.ndarray, qd: np.ndarray, alpha: float) -> float:
    """φ̈ of the full model's hard-constraint dynamics (all dofs, no-slip and normal rows) when equal
    and opposite motor torques give the wheel the acceleration ``alpha``."""
    m = robot.model
    d = mujoco.MjData(m)
    wheels = wheel_geoms(m, _kin(robot, q))
    qpos, qvel = robot.state_to_mujoco(q, qd)
    dofs = [int(m.jnt_dofadr[m.actuator_trnid[i, 0]]) for i in range(m.nu)]
    acc = []
    for tau in (0.0, 1.0):
        f = np.zeros(m.nv)
        f[dofs] = tau * robot.floating.signs
        acc.append(robot.T_np @ kkt_acceleration(m, d, qpos, qvel, f, wheels, normal=True)[0])
    tau = (alpha - acc[0][0]) / (acc[1][0] - acc[0][0])
    return float(acc[0][1] + tau * (acc[1][1] - acc[0][1]))


def _kin(robot: MujocoRobot, q: np.ndarray) -> mujoco.MjData:
    d = mujoco.MjData(robot.model)
    d.qpos[:] = robot.state_to_mujoco(q)[0]
    mujoco.mj_kinematics(robot.model, d)
    return d


@pytest.mark.parametrize(("theta", "rate", "alpha"), [(0.0, 0.0, 20.0), (1.3, 10.0, -15.0), (-4.0, -6.0, 7.5)])
def test_model_bem_matches_the_hard_no_slip_kkt_reference(robot, theta, rate, alpha):
    res = robot.bem(np.array([[theta]]), np.array([[rate]]), np.array([[alpha]]))
    ref = brentq(lambda p: _kkt_pitch_accel(robot, np.array([theta, p]), np.array([rate, 0.0]), alpha), -1.0, 1.0, xtol=1e-14)
    assert float(res.qu[0]) == pytest.approx(ref, abs=1e-8)


def test_reduced_dynamics_match_the_kkt_system_while_pitching(robot):
    """With φ̇ ≠ 0 the reference needs J̇ q̇; the reduced D q̈ + h = B u has it through the constant map."""
    rng = np.random.default_rng(7)
    m = robot.model
    for _ in range(4):
        q = np.array([rng.uniform(-3, 3), rng.uniform(-0.6, 0.6)])
        qd = np.array([rng.uniform(-8, 8), rng.uniform(-3, 3)])
        u = rng.uniform(-1.5, 1.5, size=2)
        D, h = robot.terms(q, qd)
        qdd = np.linalg.solve(D, robot.input_matrix_np @ u - h)
        qpos, qvel = robot.state_to_mujoco(q, qd)
        f = np.zeros(m.nv)
        f[[int(m.jnt_dofadr[m.actuator_trnid[i, 0]]) for i in range(m.nu)]] = u
        d = mujoco.MjData(m)
        full, _ = kkt_acceleration(m, d, qpos, qvel, f, wheel_geoms(m, _kin(robot, q)), normal=True)
        # the yaw mode (unequal torques) is left out of the reduction: compare the planar part
        np.testing.assert_allclose(robot.T_np @ full, qdd, rtol=1e-6, atol=1e-6)


def _variant(old: str, new: str) -> str:
    xml = TWO.read_text()
    assert old in xml
    return xml.replace(old, new)


def test_refusals_name_the_problem():
    with pytest.raises(RobotModelError, match=r"ball/free.*\[.arm.\] do not turn a wheel"):
        MujocoRobot.from_xml_string(_variant('<geom name="box"', '<body name="arm"><joint name="arm" type="hinge" axis="1 0 0"/>'
                                             '<inertial pos="0 0 0.1" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/></body><geom name="box"'))
    with pytest.raises(RobotModelError, match="no actuator"):
        MujocoRobot.from_xml_string(_variant('<motor name="right_motor" joint="right_spin" gear="1" ctrllimited="true" ctrlrange="-1.5 1.5"/>', ""))
    with pytest.raises(RobotModelError, match="touch it together"):
        MujocoRobot.from_xml_string(_variant('<body name="right" pos="0 -0.11 -0.1">', '<body name="right" pos="0 -0.11 -0.09">'))
    with pytest.raises(RobotModelError, match="one horizontal axle"):
        MujocoRobot.from_xml_string(_variant('<body name="right" pos="0 -0.11 -0.1">', '<body name="right" pos="0 -0.11 -0.1" euler="0.1 0 0">'))


def test_the_plant_reads_and_writes_the_coordinates(robot):
    from bemlearn.data.sensors import SensorConfig
    from bemlearn.sim.plant import SensedPlant

    plant = SensedPlant(robot, rate_hz=100.0, sensor=SensorConfig(), rng=np.random.default_rng(0), where="test")
    q0, qd0 = np.array([0.7, 0.05]), np.array([1.5, -0.2])
    plant.reset(q0, qd0)
    np.testing.assert_allclose(plant.true_q(), q0, atol=1e-12)
    np.testing.assert_allclose(robot.T_np @ plant.data.qvel, qd0, atol=1e-12)


def test_two_motors_on_one_coordinate_are_commanded_together(capsys):
    """The LQR of the two-wheeler has one command for its wheel coordinate, reaching the motors as (1, −1)
    (bemlearn.robots.actuation; the grouping's closed forms are in tests/test_actuation.py)."""
    from bemlearn.cli import main

    assert main(["robot", "lqr", str(TWO)]) == 0
    out = capsys.readouterr().out
    assert "left_spin ← left_motor (×1) + right_motor (×-1)" in out
    assert "left_motor+right_motor" in out


def test_the_pipeline_refuses_a_motor_on_two_coordinates(tmp_path):
    """Three motors for two actuated coordinates, one of them on both (a declared coordinate map): no grouping."""
    from bemlearn.errors import ConfigError
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from tests.test_actuation import _SPREAD

    xml = tmp_path / "spread.xml"
    xml.write_text(_SPREAD)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"robot: {xml}\n")
    with pytest.raises(ConfigError, match=r"actuator 'c' drives 2 actuated coordinates \['upper', 'absolute'\]") as info:
        resolve_pipeline_config(cfg)
    assert "\n" not in str(info.value)


def _generated(rng: np.random.Generator) -> tuple[str, dict[str, float]]:
    """A two-wheeled robot with seeded parameters: axle along the body's x or y, hinge axes of either sign,
    the body's frame origin above or below the axle, the robot turned about the vertical and placed
    above (or into) the floor, a cylinder or ball wheels."""
    p = {"R": rng.uniform(0.03, 0.12), "l": rng.uniform(0.03, 0.3), "mb": rng.uniform(0.3, 3.0), "mw": rng.uniform(0.02, 0.4),
         "Ib": rng.uniform(0.002, 0.05), "hoff": rng.uniform(-0.05, 0.15), "gap": rng.uniform(-0.0005, 0.05),
         "w": rng.uniform(0.06, 0.2), "yaw": rng.uniform(-math.pi, math.pi)}
    p["Iw"] = 0.5 * p["mw"] * p["R"] ** 2
    ball = bool(rng.integers(2))
    if ball:
        p["Iw"] = 0.4 * p["mw"] * p["R"] ** 2
    along_y = bool(rng.integers(2))
    a = np.array([0.0, 1.0, 0.0]) if along_y else np.array([1.0, 0.0, 0.0])
    inertia = lambda on_axle, other: " ".join(f"{on_axle if k else other:.17g}" for k in a)  # noqa: E731
    euler = "1.5707963267948966 0 0" if along_y else "0 1.5707963267948966 0"
    tyre = f'type="sphere" size="{p["R"]:.17g}"' if ball else f'type="cylinder" size="{p["R"]:.17g} 0.01" euler="{euler}"'
    wheels = ""
    for side, s in (("left", 1.0), ("right", -1.0)):
        sign = rng.choice([-1.0, 1.0])
        pos = " ".join(f"{v:.17g}" for v in s * p["w"] * a + np.array([0.0, 0.0, -p["hoff"]]))
        wheels += (f'<body name="{side}" pos="{pos}"><joint name="{side}_spin" type="hinge" axis="{" ".join(f"{sign * v:.17g}" for v in a)}"/>'
                   f'<inertial pos="0 0 0" mass="{p["mw"]:.17g}" diaginertia="{inertia(p["Iw"], p["Iw"])}"/>'
                   f'<geom name="{side}_tyre" {tyre} contype="1" conaffinity="1"/></body>')
    z0 = p["R"] + p["gap"] + p["hoff"]
    xml = f"""<mujoco model="gen"><compiler angle="radian" inertiafromgeom="false"/><option timestep="0.001"/>
      <worldbody><geom name="floor" type="plane" size="10 10 0.01" friction="1 0.01 0.001"/>
      <body name="base" pos="0.1 0.2 {z0:.17g}" euler="0 0 {p["yaw"]:.17g}"><freejoint/>
      <inertial pos="0 0 {p["l"] - p["hoff"]:.17g}" mass="{p["mb"]:.17g}" diaginertia="{inertia(p["Ib"], 2 * p["Ib"])}"/>
      {wheels}</body></worldbody>
      <actuator><motor joint="left_spin"/><motor joint="right_spin"/></actuator></mujoco>"""
    return xml, p


@pytest.mark.parametrize("seed", range(8))
def test_generated_two_wheelers_match_the_closed_form(seed):
    xml, p = _generated(np.random.default_rng(seed))
    robot = MujocoRobot.from_xml_string(xml, name="gen")
    assert robot.unactuated_name == "base_pitch"
    d = mujoco.MjData(robot.model)
    d.qpos[:] = robot.state_to_mujoco(np.zeros(2))[0]
    mujoco.mj_kinematics(robot.model, d)
    h = float(d.xanchor[robot.model.joint("left_spin").id][2])
    r = 0.5 * (h + p["R"])
    alpha = np.array([-20.0, -5.0, 10.0, 20.0])
    res = robot.bem(np.zeros((4, 1)), np.full((4, 1), 3.0), alpha[:, None])
    g, mb, mw, iw, l = 9.81, p["mb"], p["mw"], p["Iw"], p["l"]

    def closed(al: float) -> float:
        acc = r * al
        return brentq(lambda f: mb * g * l * math.sin(f) - acc * (mb * (r + l * math.cos(f)) + 2 * mw * r + 2 * iw / r),
                      -1.5, 1.5, xtol=1e-15)

    ref = np.array([closed(a) for a in alpha])
    np.testing.assert_allclose(res.qu.numpy(), ref, atol=1e-9)
    D, _ = robot.terms(np.array([0.0, 0.3]), np.zeros(2))
    assert D[1, 1] == pytest.approx(p["Ib"] + mb * (r * r + l * l + 2 * r * l * math.cos(0.3)) + 2 * (mw * r * r + iw), rel=1e-9)
