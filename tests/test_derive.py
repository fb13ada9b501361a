"""Model-derived defaults (pipeline/derive.py), LQR, actuator inverse, EIC guards, variants."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from bemlearn.control.actuator_inverse import MujocoActuatorInverse
from bemlearn.control.eic import EICGains
from bemlearn.control.lqr import discrete_lqr, linearize
from bemlearn.pipeline import derive
from bemlearn.robots import MujocoRobot, load

GAINS = EICGains(kp_a=4.0, kd_a=4.0, kp_u=200.0, kd_u=30.0)

ROBOTS = Path(__file__).parent / "robots"
TEST_ROBOTS = ["cartpole", "cartpole_coarse", "reaction_wheel", "acrobot"]


def _robot(name: str) -> MujocoRobot:
    return load("furuta") if name == "furuta" else MujocoRobot.from_xml(ROBOTS / f"{name}.xml")


@pytest.mark.parametrize("name", TEST_ROBOTS + ["furuta"])
def test_control_rate_whole_substeps(name):
    robot = _robot(name)
    r = derive.control_rate(robot).value
    assert r.rate_hz >= 100
    steps = 1 / (r.rate_hz * r.timestep)
    assert abs(steps - round(steps)) < 1e-9 and round(steps) == r.substeps
    assert r.timestep_changed == (r.timestep != robot.model.opt.timestep)
    if name == "cartpole_coarse":  # 20 ms file: simulated with a finer step, and says so
        assert r.timestep_changed and r.timestep < 0.01
        assert "coarser" in derive.control_rate(robot).note


@pytest.mark.parametrize("name", TEST_ROBOTS + ["furuta"])
def test_lqr_stabilises_discrete_linearisation(name):
    robot = _robot(name)
    r = derive.control_rate(robot).value
    res = discrete_lqr(robot, rate_hz=r.rate_hz, timestep=r.timestep)
    rho = np.max(np.abs(np.linalg.eigvals(res.A + res.B @ res.K)))  # u = K e
    assert rho < 1.0
    assert res.u_peak <= 1.0


def test_lqr_tick_map_matches_mujoco_steps():
    """(A_N, B_N) against finite differences of N real physics steps (independent of mjd_transitionFD)."""
    robot = _robot("cartpole")
    A, B, N, _ = linearize(robot, rate_hz=250.0)
    m, d = robot.model, mujoco.MjData(robot.model)

    def tick(x, u):
        d.qpos[:], d.qvel[:], d.ctrl[:] = x[:2], x[2:], u
        d.time = 0.0
        mujoco.mj_forward(m, d)
        for _ in range(N):
            mujoco.mj_step(m, d)
        return np.concatenate([d.qpos, d.qvel])

    eps = 1e-6
    x0 = np.zeros(4)
    A_fd = np.stack([(tick(x0 + eps * e, [0.0]) - tick(x0 - eps * e, [0.0])) / (2 * eps) for e in np.eye(4)], axis=1)
    B_fd = ((tick(x0, [eps]) - tick(x0, [-eps])) / (2 * eps))[:, None]
    np.testing.assert_allclose(A, A_fd, atol=1e-6)
    np.testing.assert_allclose(B, B_fd, atol=1e-6)


def test_actuator_inverse_reproduces_furuta_motor():
    from bemlearn.apps.furuta.motor import FurutaMotor

    robot = load("furuta")
    inv, ref = MujocoActuatorInverse(robot), FurutaMotor()
    rng = np.random.default_rng(1)
    for _ in range(200):
        tau = rng.normal(0, 1.0, 1)  # N·m: beyond ±10 V at times, so clipping is tested too
        q, qd = rng.normal(0, 1, 2), rng.normal(0, 10, 2)
        np.testing.assert_allclose(inv.command(tau, q, qd), ref.command(tau, q, qd), rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["cartpole_coarse", "reaction_wheel"])
def test_actuator_inverse_force_in_mujoco(name):
    """The command MuJoCo turns into exactly the requested generalized force (gear ≠ 1)."""
    robot = _robot(name)
    inv = MujocoActuatorInverse(robot)
    tau = np.array([0.3 * float(np.max(inv.limit)) * robot.model.actuator_gear[0, 0]])
    q, qd = np.array([0.1, -0.05]), np.array([0.4, 2.0])
    u = inv.command(tau, q, qd)
    d = mujoco.MjData(robot.model)
    d.qpos[:], d.qvel[:], d.ctrl[:] = q, qd, u
    mujoco.mj_forward(robot.model, d)
    ia = list(robot.actuated_index)
    np.testing.assert_allclose(d.qfrc_actuator[ia], tau, rtol=1e-12)
    assert abs(d.qfrc_actuator[robot.unactuated_index]) < 1e-15


class _FlakyBEM:
    """Returns NaN, inf or out-of-range values on chosen calls (measured-state rows only)."""

    def __init__(self, bad: dict[int, float]):
        self.bad, self.calls = bad, 0

    def __call__(self, x):
        return np.full(x.shape[0], 0.01)

    def full(self, x):
        self.calls += 1
        return np.array([self.bad.get(self.calls, 0.01)])


def test_eic_holds_last_valid_bem():
    from bemlearn.control.eic import EICController
    from bemlearn.robots.reference import CompositeSinusoid

    robot = _robot("cartpole")
    bem = _FlakyBEM({2: float("nan"), 3: float("inf"), 4: 5.0})
    ctrl = EICController(robot, bem, CompositeSinusoid.single([0.05], [0.3]), MujocoActuatorInverse(robot), GAINS, rate_hz=250.0)
    q, qd = np.array([0.0, 0.02]), np.zeros(2)
    outs = [ctrl(k / 250.0, q, qd) for k in range(6)]
    assert [o[1]["qu_e"] for o in outs] == [0.01] * 6
    assert ctrl.bem_rejected == 3
    assert all(np.all(np.isfinite(o[0])) for o in outs)


def test_eic_non_finite_command_never_leaves():
    from bemlearn.control.eic import EICController
    from bemlearn.robots.reference import CompositeSinusoid

    class NaNActuator:
        def command(self, tau, q, qd):
            return np.array([np.nan])

    robot = _robot("cartpole")
    ctrl = EICController(robot, _FlakyBEM({}), CompositeSinusoid.single([0.05], [0.3]), NaNActuator(), GAINS, rate_hz=250.0)
    u, _ = ctrl(0.0, np.zeros(2), np.zeros(2))
    assert np.all(u == 0.0) and ctrl.command_rejected == 1


def test_variants_scale_masses_inertias_lengths():
    from bemlearn.robots.variants import scaled_model

    path = ROBOTS / "acrobot.xml"
    m0 = mujoco.MjModel.from_xml_path(str(path))
    m1 = scaled_model(path, mass_scale=1.3, length_scale=0.8, bodies=("lower",))
    up, lo = m0.body("upper").id, m0.body("lower").id
    assert m1.body_mass[up] == m0.body_mass[up]
    assert abs(m1.body_mass[lo] - 1.3 * m0.body_mass[lo]) < 1e-12
    np.testing.assert_allclose(m1.body_inertia[lo], 1.3 * 0.8**2 * m0.body_inertia[lo], rtol=1e-12)
    np.testing.assert_allclose(m1.body_ipos[lo], 0.8 * m0.body_ipos[lo], rtol=1e-12)
    np.testing.assert_allclose(m1.body_pos[lo], 0.8 * m0.body_pos[lo], rtol=1e-12)  # elbow position on the upper link
    np.testing.assert_allclose(m1.body_inertia[up], m0.body_inertia[up], rtol=1e-12)
    with pytest.raises(ValueError, match="unknown bodies"):
        scaled_model(path, mass_scale=1.1, bodies=("nope",))


def test_slide_encoder_in_metres():
    from bemlearn.data.plant import SensedPlant
    from bemlearn.data.sensors import SensorConfig

    robot = _robot("cartpole")
    plant = SensedPlant(robot, rate_hz=250.0, sensor=SensorConfig(m_per_count=1e-4), rng=np.random.default_rng(0), where="t")
    y, _ = plant.measure(np.array([0.12345678, 0.0123]))
    assert abs(y[0] - 0.1235) < 1e-12  # slide: 0.1 mm counts
    step = 2 * np.pi / 4096
    assert abs(y[1] - step * round(0.0123 / step)) < 1e-15


def test_plant_timestep_override_keeps_robot_model():
    from bemlearn.data.plant import SensedPlant
    from bemlearn.data.sensors import SensorConfig

    robot = _robot("cartpole_coarse")
    plant = SensedPlant(robot, rate_hz=200.0, sensor=SensorConfig(), rng=np.random.default_rng(0), where="t", timestep=0.001)
    assert plant.substeps == 5 and plant.model.opt.timestep == 0.001 and robot.model.opt.timestep == 0.02


def test_furuta_derived_close_to_hand_tuned():
    """configs/furuta.yaml and the EICGains defaults were hand-tuned; the derivation lands near them."""
    robot = load("furuta")
    rate = derive.control_rate(robot).value
    g = derive.eic_gains(robot, rate).value
    assert abs(g.kp_u / 200.0 - 1) < 0.1 and abs(g.kd_u / 30.0 - 1) < 0.1
    assert abs(g.kp_a / 4.0 - 1) < 0.1 and abs(g.kd_a / 4.0 - 1) < 0.1
    assert abs(derive.fall_window(robot).value - 0.6) < 1e-12
    ex = derive.excitation_gains(robot, rate).value["gains"]
    assert np.all(np.sign(ex) == np.sign([2.97, -26.8, 2.64, -3.68]))


def test_bem_slopes_cartpole_closed_form():
    """Cart-pole with a uniform pole: q_u^e = atan(ẍ / g) exactly (no damping at rest), so s_a = 1/g."""
    from bemlearn.robots.scales import bem_slopes

    s = bem_slopes(_robot("cartpole"))
    assert abs(s[2, 0] - 1 / 9.81) < 1e-6 and abs(s[0, 0]) < 1e-9


def test_eic_linearisation_explains_which_robots_balance():
    """Derived EIC gains: the linearised loop is stable for the Furuta, cart-poles and reaction wheel,
    unstable for the acrobot (its BEM moves with the elbow angle, s_p = −0.26)."""
    from bemlearn.control.eic_linear import eic_linear_abscissa, eic_linear_matrix

    for name in ("furuta", "cartpole", "cartpole_coarse", "reaction_wheel", "acrobot"):
        robot = _robot(name)
        g = derive.eic_gains(robot, derive.control_rate(robot).value).value
        ab = eic_linear_abscissa(robot, g)
        assert (ab > 0) == (name == "acrobot"), (name, ab)
    # the matrix reproduces the closed-form loop of a cart-pole-like robot with s_p = 0:
    # q_u dynamics alone are q̈_u = −k_d,u q̇_u − k_p,u (q_u − s_a v_ext)
    robot = _robot("cartpole")
    g = derive.eic_gains(robot, derive.control_rate(robot).value).value
    A = eic_linear_matrix(robot, g)
    assert abs(A[2, 0] + g.kp_u) < 1e-9 and abs(A[2, 2] + g.kd_u) < 1e-9


@pytest.mark.parametrize("name", ["cartpole", "cartpole_coarse", "reaction_wheel"])  # acrobot: see the test above
def test_short_closed_loop_model_bem_stays_up(name):
    from bemlearn.config import from_dict
    from bemlearn.sim.closed_loop import ReferenceConfig, SimulateConfig, simulate

    robot = _robot(name)
    D = derive.derive_all(robot)
    cfg = SimulateConfig(
        duration_s=3.0, rate_hz=D["simulate.rate_hz"].value, physics_timestep=D["simulate.physics_timestep"].value,
        bem_source="model", reference=from_dict(ReferenceConfig, {k: list(v) if isinstance(v, tuple) else v for k, v in D["simulate.reference"].value.items()}),
        gains=D["simulate.gains"].value, fall_window=D["simulate.fall_window"].value,
    )
    m = simulate(str(ROBOTS / f"{name}.xml"), cfg, progress=False).metrics
    assert not m["fell"] and m["bem_rejected"] == 0 and m["command_rejected"] == 0
    assert m["qu_max"] < D["simulate.fall_window"].value / 2
    torch.set_num_threads(torch.get_num_threads())


@pytest.mark.slow
def test_zero_config_chain_cartpole(tmp_path):
    """Issue 13's targets on the cart-pole with derived values only (about a minute)."""
    from bemlearn.bench.robots_bench import robot_chain

    row = robot_chain(str(ROBOTS / "cartpole.xml"), tmp_path, n_trials=12, duration_s=20.0, sim_duration_s=10.0)
    assert row["bem"]["rmse"] <= 0.01 and row["bem"]["max_abs"] <= 0.04
    assert row["bem"]["bem_peak"] >= 0.19  # the held-out references reach the design bound
    assert not row["closed_loop"]["predictor"]["fell"] and not row["closed_loop"]["model"]["fell"]
    assert row["closed_loop"]["predictor"]["bem_rejected"] == 0


def test_lqr_in_mapped_coordinates():
    """A model with q = T q_joint: the tick map is S A_j S⁻¹, S B_j (S = diag(T, T)) and the
    gains in coordinates stabilise it; the actuator inverse still yields the requested force."""
    xml = (ROBOTS / "acrobot.xml").read_text().replace(
        "</actuator>",
        '</actuator>\n  <custom>\n    <numeric name="bemlearn_coordinates" data="1 1 0 1"/>\n'
        '    <text name="bemlearn_coordinate_names" data="lower_abs elbow"/>\n  </custom>',
    )
    mapped = MujocoRobot.from_xml_string(xml, name="acrobot_abs")
    plain = _robot("acrobot")
    assert mapped.unactuated_name == "lower_abs"
    A, B, _, _ = linearize(mapped, rate_hz=250.0)
    Aj, Bj, _, _ = linearize(plain, rate_hz=250.0)
    T = np.array([[1.0, 1.0], [0.0, 1.0]])
    S = np.block([[T, np.zeros((2, 2))], [np.zeros((2, 2)), T]])
    np.testing.assert_allclose(A, S @ Aj @ np.linalg.inv(S), atol=1e-9)
    np.testing.assert_allclose(B, S @ Bj, atol=1e-12)
    res = discrete_lqr(mapped, rate_hz=250.0)
    assert np.max(np.abs(np.linalg.eigvals(res.A + res.B @ res.K))) < 1.0
    inv = MujocoActuatorInverse(mapped)
    q, qd = np.array([0.1, 0.05]), np.array([0.2, -0.3])
    u = inv.command(np.array([0.5]), q, qd)
    d = mujoco.MjData(mapped.model)
    d.qpos[:], d.qvel[:], d.ctrl[:] = np.linalg.solve(T, q), np.linalg.solve(T, qd), u
    mujoco.mj_forward(mapped.model, d)
    tau = np.linalg.inv(T).T @ d.qfrc_actuator  # generalized force in coordinates
    np.testing.assert_allclose(tau, [0.0, 0.5], atol=1e-12)
