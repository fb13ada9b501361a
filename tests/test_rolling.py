"""Freedoms that move only by rolling (bemlearn.robots.rolling) on a wheeled inverted pendulum.

Reference (independent of the code under test): tests/robots/wheel_pendulum.xml is a chassis on a
slide x with a wheel (angle θ, hub h = 0.116 m above the plane, radius R = 0.12 m) and a pendulum
(angle φ about the chassis, centre of mass (c_x, c_z) = (0.02, 0.25) m in its frame).  Without slip
ẋ = r_eff θ̇ with MuJoCo's contact point midway through the penetration, r_eff = (h + R)/2.  The
pendulum's row of the dynamics at φ̇ = φ̈ = 0 is (its centre at p = R_y(φ) c, the chassis translating)

    Γ_0 = m ẍ ∂p_x/∂φ + m g ∂p_z/∂φ = m l [ẍ cos(φ + β) − g sin(φ + β)],   β = atan2(c_x, c_z),

so the hard-no-slip BEM is φ_e = atan(r_eff θ̈ / g) − β, whatever the wheel's angle and rate.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from bemlearn.errors import RobotModelError
from bemlearn.robots import load
from bemlearn.robots.rolling import kkt_acceleration, wheel_geoms

ROBOTS = Path(__file__).resolve().parent / "robots"
WHEEL = ROBOTS / "wheel_pendulum.xml"
HUB, RADIUS, CX, CZ, G = 0.116, 0.12, 0.02, 0.25, 9.81
R_EFF = 0.5 * (HUB + RADIUS)


@pytest.fixture(scope="module")
def robot():
    return load(WHEEL)


def test_the_rolling_base_is_dependent_and_the_wheel_unlimited(robot):
    assert robot.joint_names == ("spin", "pitch")
    assert robot.unactuated_name == "pitch"
    assert robot.coordinate_kinds == ("hinge", "hinge")
    assert not robot.model.jnt_limited[robot.model.joint("spin").id]
    assert robot.rolling is not None
    assert [robot.model.joint(j).name for j in robot.rolling.dependent] == ["travel"]
    (contact,) = robot.rolling.contacts
    assert contact.radius == pytest.approx(R_EFF, abs=1e-12)
    assert contact.geometric_radius == pytest.approx(RADIUS, abs=1e-12)
    # x = r_eff θ: the map's row of the slide
    np.testing.assert_allclose(robot.Tinv_np, [[R_EFF, 0.0], [1.0, 0.0], [0.0, 1.0]], atol=1e-12)
    assert "travel = 0.118·spin" in robot.rolling.describe(robot.model)


def test_the_slide_range_limits_the_wheel_through_the_radius(robot):
    wheel, pitch = robot.coordinate_limits
    assert wheel == pytest.approx((-3.0 / R_EFF, 3.0 / R_EFF), rel=1e-12)
    assert pitch == pytest.approx((-1.4, 1.4))
    assert robot.qu_range == pytest.approx((-1.4, 1.4))


def test_the_upright_is_the_centre_of_mass_above_the_axle(robot):
    assert robot.qu_nominal == pytest.approx(-math.atan2(CX, CZ), abs=1e-9)


@pytest.mark.parametrize("wheel_angle, wheel_rate", [(0.0, 0.0), (3.0, -6.0), (-11.0, 15.0)])
def test_the_model_bem_is_the_hard_no_slip_balance(robot, wheel_angle, wheel_rate):
    alpha = np.linspace(-20.0, 20.0, 41)
    B = alpha.size
    res = robot.bem(np.full((B, 1), wheel_angle), np.full((B, 1), wheel_rate), alpha[:, None])
    assert bool(res.valid.all())
    reference = np.arctan(R_EFF * alpha / G) - math.atan2(CX, CZ)
    err_deg = np.degrees(np.abs(res.qu.numpy() - reference))
    assert err_deg.max() <= 0.01
    assert err_deg.max() <= 1e-8   # the same equation: only the root finder's tolerance is left


def test_the_reduced_dynamics_are_the_kkt_solution(robot):
    """(R4) against the KKT system (R3) solved with MuJoCo's M, bias and contact Jacobians."""
    model = robot.model
    data = mujoco.MjData(model)
    wheels = wheel_geoms(model, _at_rest(model, data))
    S = robot.Tinv_np
    spin_dof = model.joint("spin").dofadr[0]
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = np.array([rng.uniform(-5, 5), rng.uniform(-0.8, 0.8)])
        qd = rng.uniform(-4, 4, 2)
        u = rng.uniform(-4, 4)
        D, h = robot.terms(q, qd)
        qdd = np.linalg.solve(D, robot.input_matrix_np[:, 0] * u - h)
        force = np.zeros(model.nv)
        force[spin_dof] = u * model.actuator_gear[0, 0]
        qdd_j, lam = kkt_acceleration(model, data, S @ q, S @ qd, force, wheels)
        np.testing.assert_allclose(qdd_j, S @ qdd, rtol=1e-7, atol=1e-7)
        assert qdd_j[model.joint("travel").dofadr[0]] == pytest.approx(R_EFF * qdd_j[spin_dof], rel=1e-9, abs=1e-9)
        assert lam.shape == (1,)


def _at_rest(model, data):
    data.qpos[:] = model.qpos0
    mujoco.mj_fwdPosition(model, data)
    return data


def test_mujoco_soft_contact_rolls_close_to_the_hard_constraint(robot):
    """The plant is MuJoCo's soft contact: over 0.5 s of drive the chassis travels r_eff θ within 2 %."""
    model = robot.model
    data = mujoco.MjData(model)
    data.qpos[:] = robot.Tinv_np @ np.array([0.0, robot.qu_nominal])
    data.ctrl[:] = 1.0
    for _ in range(500):
        mujoco.mj_step(model, data)
    x, theta = data.qpos[model.joint("travel").qposadr[0]], data.qpos[model.joint("spin").qposadr[0]]
    assert abs(theta) > 0.5
    assert x / theta == pytest.approx(R_EFF, rel=0.02)


def _steerable(tmp_path: Path) -> Path:
    """A chassis on x and y slides with a steered ball wheel (one contact point, so steering is free): rolling
    whose direction depends on the steering angle."""
    path = tmp_path / "steered.xml"
    path.write_text("""
<mujoco model="steered">
  <compiler angle="radian" inertiafromgeom="false"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.01"/>
    <body name="chassis" pos="0 0 0.099">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="y" type="slide" axis="0 1 0"/>
      <inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
      <body name="fork">
        <joint name="steer" type="hinge" axis="0 0 1" range="-1 1"/>
        <inertial pos="0 0 0" mass="0.1" diaginertia="0.001 0.001 0.001"/>
        <body name="wheel">
          <joint name="spin" type="hinge" axis="0 1 0"/>
          <inertial pos="0 0 0" mass="0.3" diaginertia="0.002 0.002 0.002"/>
          <geom name="tyre" type="sphere" size="0.1"/>
        </body>
      </body>
      <body name="pole">
        <joint name="pitch" type="hinge" axis="0 1 0" range="-1 1"/>
        <inertial pos="0 0 0.3" mass="1" diaginertia="0.01 0.01 0.001"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="steer"/><motor joint="spin"/></actuator>
</mujoco>""")
    return path


def test_rolling_that_depends_on_the_pose_is_refused(tmp_path):
    with pytest.raises(RobotModelError, match=r"steered.xml: the rolling constraint's velocity map changes with the pose"):
        load(_steerable(tmp_path))


@pytest.mark.parametrize("value", ["-inf 2", "nan nan"])
def test_a_joint_range_with_one_infinite_end_or_nan_is_refused(tmp_path, value):
    bad = tmp_path / "half_open.xml"
    bad.write_text(WHEEL.read_text().replace('range="-inf inf"', f'range="{value}"'))
    with pytest.raises(RobotModelError, match=rf'half_open.xml: <joint name="spin" range="{value}">: range is not finite'):
        load(bad)


def test_an_unbounded_range_in_a_model_compiled_elsewhere_is_unlimited():
    """The same rule for an MjModel handed over directly (no MJCF check): limited="true" with ±inf is no limit."""
    from bemlearn.robots import MujocoRobot

    model = mujoco.MjModel.from_xml_path(str(WHEEL))
    j = model.joint("spin").id
    assert model.jnt_limited[j] and math.isinf(model.jnt_range[j, 1])
    robot = MujocoRobot(model, source="wheel")
    assert not robot.model.jnt_limited[j]
    assert robot.coordinate_limits[0] is not None   # the wheel is still limited by the slide it rolls


def test_other_robots_keep_their_joints_as_coordinates():
    for name in ("cartpole.xml", "reaction_wheel.xml", "acrobot.xml"):
        robot = load(ROBOTS / name)
        assert robot.rolling is None
        assert robot.identity_coordinates
        assert robot.joint_names == robot.mjcf_joint_names


# ---- the class, not the example: seeded wheeled pendulums of other conventions -------------------------------

def _generated(rng: np.random.Generator, path: Path) -> dict:
    """A random planar wheeled pendulum: travel along x or y, wheel and pendulum axes of either sign, cylinder or
    ball wheel, 1–10 mm into the ground, an off-axis pendulum hinged at or above the axle, armature and damping."""
    along_x = bool(rng.integers(2))
    e = np.array([1.0, 0.0, 0.0]) if along_x else np.array([0.0, 1.0, 0.0])
    side = np.array([0.0, 1.0, 0.0]) if along_x else np.array([1.0, 0.0, 0.0])
    w = side * rng.choice([-1.0, 1.0])            # wheel axis
    a = side * rng.choice([-1.0, 1.0])            # pendulum axis
    radius = float(rng.uniform(0.05, 0.3))
    depth = float(rng.uniform(0.001, 0.01))
    hub = radius - depth
    c_t, c_z = float(rng.uniform(-0.03, 0.03)), float(rng.uniform(0.1, 0.6))
    lift = float(rng.choice([0.0, rng.uniform(0.01, 0.1)]))
    ball = bool(rng.integers(2))
    euler = "1.5707963267948966 0 0" if along_x else "0 1.5707963267948966 0"
    tyre = (f'<geom name="tyre" type="sphere" size="{radius!r}" contype="1" conaffinity="1"/>' if ball else
            f'<geom name="tyre" type="cylinder" size="{radius!r} 0.02" euler="{euler}" contype="1" conaffinity="1"/>')
    fmt = lambda v: " ".join(repr(float(x)) for x in v)  # noqa: E731
    com = c_t * e + np.array([0.0, 0.0, c_z - lift])
    arm, damp = float(rng.uniform(0.0, 0.5)), float(rng.uniform(0.0, 0.5))
    path.write_text(f"""
<mujoco model="generated">
  <compiler angle="radian" inertiafromgeom="false"/>
  <default><joint armature="{arm!r}" damping="{damp!r}"/><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <geom name="ground" type="plane" size="10 10 0.1" contype="1" conaffinity="1"/>
    <body name="base" pos="0 0 {hub!r}">
      <joint name="travel" type="slide" axis="{fmt(e)}" range="-4 4" limited="true"/>
      <inertial pos="0 0 0" mass="{rng.uniform(0.2, 3.0)!r}" diaginertia="0.01 0.01 0.01"/>
      <body name="wheel"><joint name="wheel" type="hinge" axis="{fmt(w)}" range="-inf inf" limited="true"/>
        <inertial pos="0 0 0" mass="{rng.uniform(0.1, 2.0)!r}" diaginertia="0.005 0.005 0.005"/>{tyre}</body>
      <body name="arm" pos="0 0 {lift!r}"><joint name="lean" type="hinge" axis="{fmt(a)}" range="-1.3 1.3" limited="true"/>
        <inertial pos="{fmt(com)}" mass="{rng.uniform(0.3, 5.0)!r}" diaginertia="0.02 0.02 0.003"/></body>
    </body>
  </worldbody>
  <actuator><motor joint="wheel" gear="{rng.uniform(0.5, 50.0)!r}"/></actuator>
</mujoco>""")
    return {"e": e, "w": w, "a": a, "r_eff": 0.5 * (hub + radius), "com": com}


def _oracle_pitch(p: dict, alpha: float) -> float:
    """Independent of MuJoCo: x-acceleration from no slip at the contact point r_eff below the hub,
    ẍ = r_eff α e·(w × ẑ); the pendulum's centre p(φ) = Rot(a, φ) com; balance (a × p)·(ẍ e + g ẑ) = 0."""
    from scipy.optimize import brentq

    z = np.array([0.0, 0.0, 1.0])
    xdd = p["r_eff"] * alpha * float(p["e"] @ np.cross(p["w"], z))
    a, c = p["a"], p["com"]

    def rot(phi: float) -> np.ndarray:   # Rodrigues
        return c * math.cos(phi) + np.cross(a, c) * math.sin(phi) + a * (a @ c) * (1 - math.cos(phi))

    f = lambda phi: float(np.cross(a, rot(phi)) @ (xdd * p["e"] + G * z))  # noqa: E731
    up = brentq(lambda phi: float(np.cross(a, rot(phi)) @ z), -0.5, 0.5)   # centre of mass straight above the hinge
    return brentq(f, up - 1.2, up + 1.2) if f(up - 1.2) * f(up + 1.2) < 0 else math.nan


def test_generated_wheeled_pendulums_match_the_independent_balance(tmp_path):
    rng = np.random.default_rng(20261127)
    alpha = np.linspace(-20.0, 20.0, 9)
    for k in range(8):
        path = tmp_path / f"generated_{k}.xml"
        p = _generated(rng, path)
        robot = load(path)
        assert robot.joint_names == ("wheel", "lean"), path.read_text()
        (contact,) = robot.rolling.contacts
        assert contact.radius == pytest.approx(p["r_eff"], abs=1e-9)
        res = robot.bem(np.zeros((alpha.size, 1)), np.full((alpha.size, 1), 3.0), alpha[:, None])
        ref = np.array([_oracle_pitch(p, float(x)) for x in alpha])
        ok = np.isfinite(ref)
        assert ok.sum() >= 5
        np.testing.assert_array_equal(res.valid.numpy()[ok], True)
        err = np.degrees(np.abs(res.qu.numpy()[ok] - ref[ok]))
        assert err.max() <= 0.01, (k, err.max())


# ---- the wheel hinged on the pendulum (its motor's stator in the body, as on most two-wheeled robots) ---------

M_CHASSIS, M_BODY, M_WHEEL, I_WHEEL, L_BODY, B_SLIDE = 0.5, 2.0, 0.4, 0.003, 0.3, 0.4
HUB2, RADIUS2 = 0.079, 0.08


def _body_mounted(path: Path) -> Path:
    path.write_text(f"""
<mujoco model="body_mounted">
  <compiler angle="radian" inertiafromgeom="false"/>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <geom name="ground" type="plane" size="10 10 0.1" contype="1" conaffinity="1"/>
    <body name="chassis" pos="0 0 {HUB2}">
      <joint name="x" type="slide" axis="1 0 0" damping="{B_SLIDE}"/>
      <inertial pos="0 0 0" mass="{M_CHASSIS}" diaginertia="0.001 0.001 0.001"/>
      <body name="body"><joint name="pitch" type="hinge" axis="0 1 0" range="-1.2 1.2"/>
        <inertial pos="0 0 {L_BODY}" mass="{M_BODY}" diaginertia="0.05 0.05 0.004"/>
        <body name="wheel"><joint name="wheel" type="hinge" axis="0 1 0"/>
          <inertial pos="0 0 0" mass="{M_WHEEL}" diaginertia="0.002 {I_WHEEL} 0.002"/>
          <geom name="tyre" type="cylinder" size="{RADIUS2} 0.015" euler="1.5707963267948966 0 0" contype="1" conaffinity="1"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="wheel"/></actuator>
</mujoco>""")
    return path


def test_a_wheel_hinged_on_the_pendulum_makes_the_slide_dependent(tmp_path):
    """x = r(θ + φ): both the slide and the pendulum could be solved for; the slide is taken.

    Reference: with θ the wheel's angle relative to the body and φ̇ = φ̈ = 0, the body's row in (θ, φ)
    (the generalized force of turning the body with the wheel locked to it, which rolls the chassis) is
    (I_w + M r² + m l r cos φ) θ̈ + b_x r² θ̇ − m g l sin φ = 0, M the mass that translates.
    """
    from scipy.optimize import brentq

    robot = load(_body_mounted(tmp_path / "body_mounted.xml"))
    assert robot.joint_names == ("pitch", "wheel") and robot.unactuated_name == "pitch"
    assert [robot.model.joint(j).name for j in robot.rolling.dependent] == ["x"]
    r = 0.5 * (HUB2 + RADIUS2)
    np.testing.assert_allclose(robot.Tinv_np[0], [r, r], rtol=1e-12)   # x = r (φ + θ)
    total = M_CHASSIS + M_BODY + M_WHEEL
    for alpha, omega in ((-15.0, 0.0), (-4.0, 6.0), (0.0, 20.0), (7.0, -3.0), (18.0, 2.0)):
        def balance(phi: float, alpha=alpha, omega=omega) -> float:
            return ((I_WHEEL + total * r**2 + M_BODY * L_BODY * r * math.cos(phi)) * alpha + B_SLIDE * r**2 * omega
                    - M_BODY * G * L_BODY * math.sin(phi))
        ref = brentq(balance, -1.2, 1.2)
        res = robot.bem(np.zeros((1, 1)), np.array([[omega]]), np.array([[alpha]]))
        assert math.degrees(abs(float(res.qu[0]) - ref)) <= 1e-6


def test_the_kkt_solve_keeps_a_steered_wheel_rolling(tmp_path):
    """kkt_acceleration's J̇ q̇ (central differences of the no-slip rows along q̇): for a steered, spinning ball
    wheel the rows turn with the steering, J̇ q̇ ≠ 0.  One step of the KKT accelerations keeps J(q) q̇ = 0 to
    O(h²); the same solve without J̇ q̇ leaves an O(h) slip."""
    from bemlearn.robots.rolling import _positions, rolling_rows

    model = mujoco.MjModel.from_xml_path(str(_steerable(tmp_path)))
    data = mujoco.MjData(model)
    qpos = np.array([0.0, 0.0, 0.3, 0.0, 0.1])            # x, y, steer, spin, pitch
    _positions(model, data, qpos)
    wheels = wheel_geoms(model, data)
    rows = rolling_rows(model, data, wheels)[0]
    qvel = np.array([0.0, 0.0, 1.0, 5.0, 0.5])
    qvel[:2] = np.linalg.lstsq(rows[:, :2], -rows[:, 2:] @ qvel[2:], rcond=None)[0]   # roll without slip
    assert float(np.abs(rows @ qvel).max()) < 1e-12
    force = np.zeros(model.nv)
    force[2], force[3] = 0.2, 0.1                         # steering and drive torques, N·m

    def slip_after(qacc: np.ndarray, h: float) -> float:
        q1, v1 = qpos + h * qvel + 0.5 * h * h * qacc, qvel + h * qacc
        _positions(model, data, q1)
        return float(np.abs(rolling_rows(model, data, wheels)[0] @ v1).max())

    qacc, _ = kkt_acceleration(model, data, qpos, qvel, force, wheels)
    qacc_no_jdot, _ = kkt_acceleration(model, data, qpos, qvel, force, wheels, drift=False)
    for h in (1e-3, 1e-4):
        assert slip_after(qacc, h) < 20 * h * h           # measured 15.8 h²
        assert slip_after(qacc_no_jdot, h) > 0.1 * h      # measured 0.49 h
