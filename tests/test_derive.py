"""Model-derived defaults (pipeline/derive.py), LQR, actuator inverse, EIC guards, variants."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

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


@pytest.mark.parametrize("name", [*TEST_ROBOTS, "furuta"])
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


@pytest.mark.parametrize("name", [*TEST_ROBOTS, "furuta"])
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
    from bemlearn.data.sensors import SensorConfig
    from bemlearn.sim.plant import SensedPlant

    robot = _robot("cartpole")
    plant = SensedPlant(robot, rate_hz=250.0, sensor=SensorConfig(m_per_count=1e-4), rng=np.random.default_rng(0), where="t")
    y, _ = plant.measure(np.array([0.12345678, 0.0123]))
    assert abs(y[0] - 0.1235) < 1e-12  # slide: 0.1 mm counts
    step = 2 * np.pi / 4096
    assert abs(y[1] - step * round(0.0123 / step)) < 1e-15


def test_plant_timestep_override_keeps_robot_model():
    from bemlearn.data.sensors import SensorConfig
    from bemlearn.sim.plant import SensedPlant

    robot = _robot("cartpole_coarse")
    plant = SensedPlant(robot, rate_hz=200.0, sensor=SensorConfig(), rng=np.random.default_rng(0), where="t", timestep=0.001)
    assert plant.substeps == 5 and plant.model.opt.timestep == 0.001 and robot.model.opt.timestep == 0.02


def _mujoco_instability_rate(robot: MujocoRobot, step: float = 1e-6) -> float:
    """λ = √(|∂τ_g,u/∂q_u| / D_uu) at upright straight from MuJoCo (qfrc_bias at rest, mj_fullM),
    independent of bemlearn.robots.scales (which differences Γ_0 of the BEM root-find)."""
    from bemlearn.robots._mujoco_compat import full_mass_matrix

    assert np.allclose(robot.T.numpy(), np.eye(robot.n))   # coordinates are the joints
    model, data = robot.model, mujoco.MjData(robot.model)
    iu = robot.unactuated_index
    adr, dof = model.jnt_qposadr[iu], model.jnt_dofadr[iu]
    bias = []
    for q in (robot.qu_nominal + step, robot.qu_nominal - step):
        data.qpos[:], data.qvel[:] = 0.0, 0.0
        data.qpos[adr] = q
        mujoco.mj_forward(model, data)
        bias.append(data.qfrc_bias[dof])
    data.qpos[adr] = robot.qu_nominal
    mujoco.mj_forward(model, data)
    duu = full_mass_matrix(model, data, np.zeros((model.nv, model.nv)))[dof, dof]
    return math.sqrt(abs(bias[0] - bias[1]) / (2 * step) / duu)


def test_instability_rate_cartpole_closed_form():
    """Cart held, the pole is a pendulum about its pin: λ = √(m g l_c / I_pin) = √(3 g / 2 L) for a thin
    rod of length L (0.6 m, radius 12 mm: within 2 %); bemlearn's λ (differenced BEM root-find) agrees
    with MuJoCo's bias forces and mass matrix to 1e-4."""
    from bemlearn.robots.scales import instability_rate

    robot = _robot("cartpole")
    lam = instability_rate(robot)
    assert lam == pytest.approx(_mujoco_instability_rate(robot), rel=1e-4)
    assert lam == pytest.approx(math.sqrt(3 * 9.81 / (2 * 0.6)), rel=0.02)


@pytest.mark.parametrize("name", ["furuta", "cartpole", "reaction_wheel"])
def test_eic_gains_follow_the_rule_from_an_independent_instability_rate(name):
    """The derived EIC gains obey their rule (docs/derived-defaults.md) with λ measured in MuJoCo directly:
    critically damped loops, ω_a = ω_u / 7, and 1.2 λ ≤ ω_u ≤ min(2.2 λ, 2π·rate/20) (equal to the
    upper end unless the ctrlrange lowered it, which these motors never need); the fall window is
    min(3 d, 0.9 × half range) with d = min(0.2, half range) from the model's q_u range."""
    robot = _robot(name)
    lam = _mujoco_instability_rate(robot)
    rate = derive.control_rate(robot).value
    g = derive.eic_gains(robot, rate).value
    w_u, w_a = math.sqrt(g.kp_u), math.sqrt(g.kp_a)
    assert g.kd_u == pytest.approx(2 * w_u, rel=1e-12) and g.kd_a == pytest.approx(2 * w_a, rel=1e-12)
    assert w_a == pytest.approx(w_u / 7, rel=1e-12)
    assert w_u == pytest.approx(min(2.2 * lam, 2 * math.pi * rate.rate_hz / 20), rel=1e-4)
    lo, hi = robot.qu_range
    half = min(hi - robot.qu_nominal, robot.qu_nominal - lo)
    d = min(0.2, half)
    assert derive.fall_window(robot).value == pytest.approx(min(3 * d, 0.9 * half), rel=1e-12)


def test_bem_slopes_cartpole_closed_form():
    """Cart-pole with a uniform pole: q_u^e = atan(ẍ / g) exactly (no damping at rest), so s_a = 1/g."""
    from bemlearn.robots.scales import bem_slopes

    s = bem_slopes(_robot("cartpole"))
    assert abs(s[2, 0] - 1 / 9.81) < 1e-6 and abs(s[0, 0]) < 1e-9


def _rule_gains(robot) -> EICGains:
    """The EIC rule's gains (ω_u = min(2.2 λ, 2π·rate/20), ω_a = ω_u/7, critically damped), written out here."""
    from bemlearn.robots.scales import instability_rate

    w_u = min(2.2 * instability_rate(robot), 2 * math.pi * derive.control_rate(robot).value.rate_hz / 20)
    w_a = w_u / 7
    return EICGains(kp_a=w_a**2, kd_a=2 * w_a, kp_u=w_u**2, kd_u=2 * w_u)


def test_eic_linearisation_explains_which_robots_balance():
    """The rule's EIC gains: the continuous linearised loop is stable for the Furuta, cart-poles and reaction wheel,
    unstable for the acrobot (its BEM moves with the elbow angle, s_p = −0.26); the derived gains of the first
    four are the rule's (their loop sampled with its velocity filter is stable), the acrobot's come from the search
    (tests/test_eic_sampled.py)."""
    from bemlearn.control.eic_linear import eic_linear_abscissa, eic_linear_matrix

    for name in ("furuta", "cartpole", "cartpole_coarse", "reaction_wheel", "acrobot"):
        robot = _robot(name)
        rule = _rule_gains(robot)
        ab = eic_linear_abscissa(robot, rule)
        assert (ab > 0) == (name == "acrobot"), (name, ab)
        g = derive.eic_gains(robot, derive.control_rate(robot).value).value
        same = all(getattr(g, k) == pytest.approx(getattr(rule, k), rel=1e-12) for k in ("kp_a", "kd_a", "kp_u", "kd_u"))
        assert same == (name != "acrobot"), name
    # the matrix reproduces the closed-form loop of a cart-pole-like robot with s_p = 0:
    # q_u dynamics alone are q̈_u = −k_d,u q̇_u − k_p,u (q_u − s_a v_ext)
    robot = _robot("cartpole")
    g = derive.eic_gains(robot, derive.control_rate(robot).value).value
    A = eic_linear_matrix(robot, g)
    assert abs(A[2, 0] + g.kp_u) < 1e-9 and abs(A[2, 2] + g.kd_u) < 1e-9


@pytest.mark.parametrize("name", ["cartpole", "cartpole_coarse", "reaction_wheel"])  # acrobot: see the test above
def test_short_closed_loop_model_bem_stays_up(name):
    """The closed loop a config naming only the file gets (derived rate, gains, reference, fall window)
    keeps the robot up for 3 s with the model BEM."""
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.sim.closed_loop import simulate

    path = str(ROBOTS / f"{name}.xml")
    cfg = resolve_pipeline_config({"robot": path, "simulate": {"duration_s": 3.0, "bem_source": "model"}}).config.simulate
    m = simulate(load(path), cfg, progress=False).metrics
    assert not m["fell"] and m["bem_rejected"] == 0 and m["command_rejected"] == 0
    assert m["qu_max"] < cfg.fall_window / 2


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


_SENSOR_KEYS = ("counts_per_rev", "noise_std", "velocity_cutoff", "m_per_count")
#: (derivation skipped, {config prefix: the keys of that group the config gives})
_GIVEN_GROUPS = {
    "excitation_gains": {"collect": ("gains", "gain_scale")},
    "excitation_directions": {"collect": ("reference_bem", "excursion")},
    "eic_gains": {"simulate.gains": ("kp_a", "kd_a", "kp_u", "kd_u")},
    "sensor": {"collect.sensor": _SENSOR_KEYS, "simulate.sensor": _SENSOR_KEYS},
    "closed_loop_reference": {"simulate.reference": ("amplitudes", "frequencies_hz", "phases", "offset")},
    "evaluation": {"evaluate": ("n_sines", "amplitude_max", "amplitude_min", "frequency_hz")},
}


def test_derived_groups_list_every_key_their_derivation_writes():
    """Each group's declared keys are exactly the leaves its derivation writes (a group is skipped when the
    config gives all of its declared keys, so a leaf missing from the list would never be derived)."""
    from bemlearn.pipeline import derived_defaults as dd
    from bemlearn.pipeline.config import PipelineConfig

    robot = _robot("cartpole")
    keys = set(dd.derive_pipeline_values(robot, PipelineConfig(robot="cartpole")))
    declared = {"collect.sensor": dd._SENSOR, "simulate.sensor": dd._SENSOR, "simulate.gains": dd._EIC_GAINS,
                "simulate.reference": dd._REFERENCE}
    for prefix, leaves in declared.items():
        assert {k for k in keys if k.startswith(prefix + ".")} == {f"{prefix}.{k}" for k in leaves}, prefix
    assert {k.split(".", 1)[1] for k in keys if k.startswith("evaluate.")} == set(dd._EVALUATE)
    assert set(dd._SIGNALS) <= {k.split(".", 1)[1] for k in keys if k.startswith("collect.")}


@pytest.mark.parametrize("skipped", sorted(_GIVEN_GROUPS))
def test_a_group_the_config_gives_in_full_is_not_derived(skipped, monkeypatch):
    """Giving every key of a group skips its derivation (``config show`` stays fast: no LQR when the gains
    are given); the other derived keys keep the values of a derivation from the model alone."""
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    xml = str(ROBOTS / "cartpole.xml")
    values = resolve_pipeline_config({"robot": xml}).to_json_dict()
    part: dict = {}
    for prefix, keys in _GIVEN_GROUPS[skipped].items():
        node = part
        for name in prefix.split("."):
            node = node.setdefault(name, {})
        node.update({k: values[f"{prefix}.{k}"]["value"] for k in keys})

    def refuse(*args, **kwargs):
        raise AssertionError(f"derive.{skipped} ran although the config gives its keys")

    monkeypatch.setattr(derive, skipped, refuse)
    partial = resolve_pipeline_config({"robot": xml, **part}).to_json_dict()
    assert {k: v["value"] for k, v in partial.items()} == {k: v["value"] for k, v in values.items()}
    given = {f"{prefix}.{k}" for prefix, keys in _GIVEN_GROUPS[skipped].items() for k in keys}
    assert {k for k, v in partial.items() if v["origin"] == "given"} == given | {"robot"}


def test_initial_actuated_range_keeps_the_bem_offset_within_the_qu_start_range():
    """A serial arm's static BEM keeps the pole vertical, q_u^e = q_u* − q_a (s_p = −1 in closed form), so the
    pendubot's shoulder starts within (d/4)/|s_p| = 0.05 rad; a cart-pole's BEM does not move with the cart
    (s_p = 0) and keeps min(0.1, 0.1 × half range)."""
    from bemlearn.robots.scales import bem_slopes, qa_half_ranges

    pendubot = _robot("pendubot")
    assert bem_slopes(pendubot)[0, 0] == pytest.approx(-1.0, abs=1e-6)
    d = derive.design_region(pendubot).value
    assert derive.initial_ranges(pendubot).value["initial_qa"] == pytest.approx((-d / 4, d / 4), rel=1e-6)
    cart = _robot("cartpole")
    qa = min(0.1, 0.1 * float(np.min(qa_half_ranges(cart))))
    assert derive.initial_ranges(cart).value["initial_qa"] == pytest.approx((-qa, qa), rel=1e-12)


def test_excitation_directions_one_actuated_keeps_the_papers_excitation_two_get_their_own_extents():
    """m = 1: no reference_bem, no excursion, the amplitudes of excitation_signals (joint units).  m = 2 (a two-link
    arm with a pole, whose BEM depends on both joints): the linearised BEM and λ for the q_u target, per-joint extents
    P_j ≤ min(d/|s_p,j|, 0.8 × half range), a_j ≤ 1.3 d/|s_a,j|, within half the actuator limits (independent check
    with MuJoCo's mj_inverse), and dimensionless amplitude fractions."""
    from bemlearn.robots.scales import bem_slopes, instability_rate, qa_half_ranges

    cart = _robot("cartpole")
    rate = derive.control_rate(cart).value
    sig = derive.excitation_signals(cart, rate).value
    one = derive.excitation_directions(cart, rate, sig).value
    assert one == {"reference_bem": (), "excursion": (), "amplitude": sig["amplitude"]}

    arm = load(str(ROBOTS / "arm2_pole.xml"))
    rate = derive.control_rate(arm).value
    sig = derive.excitation_signals(arm, rate).value
    out = derive.excitation_directions(arm, rate, sig).value
    sp, sv, sa = bem_slopes(arm)
    np.testing.assert_allclose(out["reference_bem"], [*sp, *sv, *sa, instability_rate(arm)], rtol=1e-5, atol=1e-9)
    P, a = np.array(out["excursion"][:2]), np.array(out["excursion"][2:])
    d = derive.design_region(arm).value
    assert np.all(P > 0) and np.all(np.minimum(d / np.abs(sp), 0.8 * qa_half_ranges(arm)) + 1e-6 >= P)
    assert np.all(a > 0) and np.all(a <= 1.3 * d / np.abs(sa) + 1e-6)
    n_max = sig["n_sines"][1]
    np.testing.assert_allclose(out["amplitude"], (0.2 / np.sqrt(n_max), 1 / np.sqrt(n_max)))
    model = arm.model
    data = mujoco.MjData(model)
    for j in range(2):
        for sign in (1.0, -1.0):
            data.qpos[:] = 0.0
            data.qvel[:] = 0.0
            data.qacc[:] = 0.0
            data.qpos[arm.actuated_index[j]] = sign * P[j]
            data.qacc[arm.actuated_index[j]] = -sign * a[j]
            mujoco.mj_inverse(model, data)
            tau = data.qfrc_inverse[list(arm.actuated_index)]
            assert np.all(np.abs(tau) <= 0.5 * model.actuator_ctrlrange[:, 1] + 1e-6), (j, sign, tau)


def test_eic_linearisation_with_two_actuated_joints():
    """m = 2: the x-y cart-pole's y slide does not enter the pole's row (D_u,y = 0, the pole swings in x-z), so the
    null-space projector hands it the external loop alone: q̈_y = −k_p,a q_y − k_d,a q̇_y exactly.  On the two-link arm
    with a pole the fastest-decaying critically damped pair is stable and at least as fast as the fixed ratio 7 rule."""
    from types import SimpleNamespace

    from bemlearn.control.eic_linear import eic_fastest_gains, eic_linear_matrix
    from bemlearn.robots.scales import instability_rate

    robot = load(str(ROBOTS / "xy_cartpole.xml"))
    g = SimpleNamespace(kp_a=4.0, kd_a=4.0, kp_u=150.0, kd_u=24.0)
    A = eic_linear_matrix(robot, g)
    n = robot.n
    y = 1 + list(robot.actuated_index).index(robot.joint_names.index("y"))  # x = [q_u, q_a..., q̇_u, q̇_a...]
    expect = np.zeros(2 * n)
    expect[y], expect[n + y] = -g.kp_a, -g.kd_a
    np.testing.assert_allclose(A[n + y], expect, atol=1e-6)
    arm = load(str(ROBOTS / "arm2_pole.xml"))
    lam = instability_rate(arm)
    w_u, w_a, ab = eic_fastest_gains(arm, lam, 1e3)
    fixed = SimpleNamespace(kp_a=(2.2 * lam / 7) ** 2, kd_a=2 * 2.2 * lam / 7, kp_u=(2.2 * lam) ** 2, kd_u=4.4 * lam)
    assert ab < 0 and ab <= float(np.max(np.linalg.eigvals(eic_linear_matrix(arm, fixed)).real)) + 1e-12
    g2 = SimpleNamespace(kp_a=w_a**2, kd_a=2 * w_a, kp_u=w_u**2, kd_u=2 * w_u)
    assert abs(float(np.max(np.linalg.eigvals(eic_linear_matrix(arm, g2)).real)) - ab) < 1e-9


def test_closed_loop_reference_peaks_at_half_the_design_bound_with_two_actuated_joints():
    """The reference drives every actuated joint with the same sines; the linearised BEM of that motion, summed over the
    joints and evaluated on a time grid (independent of the derivation's complex gains), peaks near d/2, not d."""
    from bemlearn.robots.scales import bem_slopes

    arm = load(str(ROBOTS / "arm2_pole.xml"))
    rate = derive.control_rate(arm).value
    ref = derive.closed_loop_reference(arm, derive.excitation_signals(arm, rate).value).value
    sp, sv, sa = bem_slopes(arm)
    t = np.linspace(0.0, 60.0, 60001)
    A, f = np.array(ref["amplitudes"]), 2 * np.pi * np.array(ref["frequencies_hz"])
    q = (A[:, None] * np.sin(f[:, None] * t)).sum(0)
    qd = (A[:, None] * f[:, None] * np.cos(f[:, None] * t)).sum(0)
    qdd = -(A[:, None] * f[:, None] ** 2 * np.sin(f[:, None] * t)).sum(0)
    bem = sp.sum() * q + sv.sum() * qd + sa.sum() * qdd
    d = derive.design_region(arm).value
    assert 0.35 * d <= np.abs(bem).max() <= 0.55 * d, (np.abs(bem).max(), d)


def test_eic_gains_are_searched_in_mujoco_when_joint_friction_leaves_a_limit_cycle():
    """Dry friction on the arm's joints (frictionloss 0.1 / 0.02 N·m on tests/robots/arm2_pole.xml): the fastest-decaying
    pair of the friction-free linearisation circles in MuJoCo — over the last second of the recovery q_u swings far beyond
    the d/4 start error although its end sample lies within it (what the check read before) — so the derivation runs the
    grid's sampled-stable gains in MuJoCo and keeps one that settles: its own recovery stays within d/4 over the last
    second and its residual motion is a fraction of the first choice's."""
    from bemlearn.control.eic_linear import eic_fastest_gains
    from bemlearn.robots.scales import instability_rate

    xml = (ROBOTS / "arm2_pole.xml").read_text()
    xml = xml.replace('damping="0.5"/>', 'damping="0.5" frictionloss="0.1"/>').replace('damping="0.3"/>', 'damping="0.3" frictionloss="0.02"/>')
    assert xml.count("frictionloss") == 2
    arm = MujocoRobot.from_xml_string(xml, name="arm2_pole_friction")
    rate = derive.control_rate(arm).value
    e0 = derive.design_region(arm).value / 4
    wc = derive.closed_loop_sensor(arm, rate).value["velocity_cutoff"]
    lam = instability_rate(arm)
    w_u, w_a, _ = eic_fastest_gains(arm, lam, 2 * math.pi * rate.rate_hz / 20)
    ok, how, tail = derive._recovery_run(arm, derive._loop_gains(w_u, w_u / w_a), rate, qu0=e0, velocity_cutoff=wc)
    end = float(how.split("(ends ")[1].split(")")[0])
    assert not ok and end <= e0 < 2 * e0 < tail, how
    chosen = derive.eic_gains(arm, rate)
    assert "the first choice" in chosen.note and "bring the robot back in MuJoCo" in chosen.note, chosen.note
    ok2, how2, tail2 = derive._recovery_run(arm, chosen.value, rate, qu0=e0, velocity_cutoff=wc)
    assert ok2 and tail2 < 0.25 * tail, (how2, tail)


def test_prior_mean_is_derived_from_how_the_excitation_moves_the_actuated_directions():
    """``train.mean``: ``zero`` (eq. 11) for the paper's excitation, ``auto`` (eq. L2) where the excitation moves
    each actuated direction on its own (``collect.excursion`` non-empty); a given value is kept."""
    from bemlearn.pipeline.derived_defaults import DERIVED_KEYS, PRIOR_MEAN_NOTE
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    xml = str(ROBOTS / "cartpole.xml")
    plain = resolve_pipeline_config({"robot": xml})
    assert plain.config.train.mean == "zero" and plain.origins["train.mean"] == "derived"
    assert plain.notes["train.mean"] == PRIOR_MEAN_NOTE["zero"] and "train.mean" in DERIVED_KEYS
    directions = resolve_pipeline_config({"robot": xml, "collect": {"excursion": [0.2, 3.0]}})
    assert directions.config.train.mean == "auto" and directions.notes["train.mean"] == PRIOR_MEAN_NOTE["auto"]
    given = resolve_pipeline_config({"robot": xml, "collect": {"excursion": [0.2, 3.0]}, "train": {"mean": "linear"}})
    assert given.config.train.mean == "linear" and given.origins["train.mean"] == "given"
