"""A pole on an x-y cart's turntable (issue 28, ``xy_cart`` with a yaw hinge): the oracle's BEM at a yaw rate, the speed
at which the yaw rate doubles the upright's stiffness (the oracle's and the pipeline's, each against a closed form
from the body data), the BEM slopes at a yaw angle, and the excitation's extents derived from them."""

import math

import mujoco
import numpy as np
import pytest

from bemlearn.bench.family.generator import generate_robot
from bemlearn.bench.family.oracle import Oracle
from bemlearn.pipeline import derive
from bemlearn.robots import load
from bemlearn.robots.scales import bem_slopes, instability_rate, velocity_stiffening_speed

G = 9.81
TURNTABLES = (5, 11)  # family seed 0: an unlimited and a limited yaw


def _pole_terms(xml: str, truth: dict) -> tuple[float, float]:
    """(m l, J) of the pole from its body data at the upright: m l the mass times the centre's height over the hinge,
    J = I_xx + m l² − I_zz about the centre in world axes (tilt about y; the centrifugal potential −½ ψ̇² I_z(θ),
    I_z(θ) = I_zz cos²θ + (I_xx + m l²) sin²θ)."""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    o = Oracle(xml, truth["qu_upright"])
    d.qpos[:] = o.qa0_full()
    mujoco.mj_kinematics(m, d)
    b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "pole")
    j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "pole")
    mass = float(m.body_mass[b])
    r = d.xipos[b] - d.xanchor[j]
    assert abs(r[0]) < 1e-12 and abs(r[1]) < 1e-12 and r[2] > 0
    R = d.ximat[b].reshape(3, 3)
    inertia = R @ np.diag(m.body_inertia[b]) @ R.T
    return mass * float(r[2]), float(inertia[0, 0] + mass * r[2] ** 2 - inertia[2, 2])


def _closed_form_bem(a_e: np.ndarray, yaw_rate: np.ndarray, ml: float, J: float) -> np.ndarray:
    """θ with tan θ · (m l g + ψ̇² J cos θ) = m l a_e (Newton), a_e = ẍ cos ψ + ÿ sin ψ."""
    th = np.arctan(a_e / G)
    for _ in range(60):
        c, s = np.cos(th), np.sin(th)
        f = s * (ml * G + yaw_rate**2 * J * c) - ml * a_e * c
        df = c * (ml * G + yaw_rate**2 * J * c) - s * yaw_rate**2 * J * s + ml * a_e * s
        th = th - f / df
    return th


@pytest.mark.parametrize("index", TURNTABLES)
def test_oracle_bem_on_a_spinning_turntable_matches_the_closed_form(index):
    xml, truth = generate_robot(0, index, hold_check=False)
    o = Oracle(xml, truth["qu_upright"])
    ml, J = _pole_terms(xml, truth)
    rng = np.random.default_rng(index)
    n = 30
    qa = o.qa0 + rng.uniform(-1, 1, (n, 3)) * np.array([0.2, 0.2, 1.5])
    qd = rng.uniform(-1, 1, (n, 3)) * np.array([0.5, 0.5, 8.0])
    qdd = rng.uniform(-1, 1, (n, 3)) * np.array([2.0, 2.0, 50.0])  # ψ̈ drops out (the pole's tilt axis is a principal one)
    a_e = qdd[:, 0] * np.cos(qa[:, 2]) + qdd[:, 1] * np.sin(qa[:, 2])
    want = truth["qu_upright"] + _closed_form_bem(a_e, qd[:, 2], ml, J)
    np.testing.assert_allclose(o.bem(qa, qd, qdd), want, atol=1e-8)


@pytest.mark.parametrize("index", TURNTABLES)
def test_yaw_rate_that_doubles_the_upright_stiffness_oracle_and_pipeline(index, tmp_path):
    """ψ̇² J = m g l: the oracle (mj_inverse) and the pipeline (Γ_0) each against the closed form; slides never."""
    xml, truth = generate_robot(0, index, hold_check=False)
    ml, J = _pole_terms(xml, truth)
    want = math.sqrt(ml * G / J)
    o = Oracle(xml, truth["qu_upright"])
    assert o.stiffening_speed(2) == pytest.approx(want, rel=1e-6)
    assert math.isinf(o.stiffening_speed(0)) and math.isinf(o.stiffening_speed(1))
    # the oracle's box: no yaw rate beyond it (before: π ω_u ≈ 17 rad/s on an unlimited turntable)
    sc = o.scales()
    assert sc["vel"][2] <= want * (1 + 1e-6)
    # the y slide, flat at ψ = 0, moves the BEM at the yaw poses k/4 of the way to the span's ends: a_y = g tan 0.2 / max|sin ψ|
    # (before: ω_u² × its half span, 11–21 m/s², where the learned BEM was asked about ÿ the data never held)
    ends = sc["pos"][2]
    s_max = max(abs(math.sin(k / 4 * end)) for k in range(1, 5) for end in ends)
    assert sc["acc"][1] == pytest.approx(G * math.tan(0.2) / s_max, rel=1e-6)
    path = tmp_path / "robot.xml"
    path.write_text(xml)
    robot = load(str(path))
    v = velocity_stiffening_speed(robot)
    assert v[2] == pytest.approx(want, rel=1e-4) and np.all(np.isinf(v[:2]))


def test_bem_slopes_at_a_yaw_angle_and_the_excitation_extents(tmp_path):
    """s_a of the slides at yaw ψ is (cos ψ, sin ψ)/g; the excitation bounds the y slide's acceleration by where the
    yaw turns it into the swing plane (1.3 d g / max|sin ψ| over ψ's extent), sweeps an unlimited yaw over ±π, and
    keeps each component's yaw rate √(a P) within the stiffening speed."""
    xml, _ = generate_robot(0, 5, hold_check=False)  # unlimited yaw
    path = tmp_path / "robot.xml"
    path.write_text(xml)
    robot = load(str(path))
    for psi in (0.0, 0.4, 1.2, -2.5):
        at = np.zeros((3, 3))
        at[0, 2] = psi
        s = bem_slopes(robot, at=at)
        np.testing.assert_allclose(s[2, :2], np.array([math.cos(psi), math.sin(psi)]) / G, atol=1e-6)
        assert abs(s[2, 2]) < 1e-9 and np.all(np.abs(s[0]) < 1e-9)
    rate = derive.control_rate(robot).value
    sig = derive.excitation_signals(robot, rate).value
    ext = np.asarray(derive.excitation_directions(robot, rate, sig).value["excursion"])
    P, a = ext[:3], ext[3:]
    d = derive.design_region(robot).value
    assert P[2] == pytest.approx(math.pi, rel=1e-5)
    assert a[1] <= 1.3 * d * G * (1 + 1e-4)  # before: P_y ω_hi² (17 m/s² here), s_a,y = 0 at ψ = 0
    v = velocity_stiffening_speed(robot)[2]
    assert math.sqrt(a[2] * P[2]) <= v * (1 + 1e-4)


def test_eic_gains_with_three_actuated_joints_decay_in_the_loop_as_it_runs(tmp_path):
    """fam0_035: the critically damped gains fastest in the continuous linearisation grew at 0.31 1/s sampled at
    238 Hz with the velocity filter; the derived gains' sampled loop decays."""
    from bemlearn.control.eic_linear import eic_tick_loop
    from bemlearn.control.lqr import linearize

    xml, _ = generate_robot(0, 35, hold_check=False)
    path = tmp_path / "robot.xml"
    path.write_text(xml)
    robot = load(str(path))
    rate = derive.control_rate(robot).value
    g = derive.eic_gains(robot, rate).value
    wc = derive.closed_loop_sensor(robot, rate).value["velocity_cutoff"]
    plant = linearize(robot, rate_hz=rate.rate_hz, timestep=rate.timestep)[:2]
    assert eic_tick_loop(robot, g, rate_hz=rate.rate_hz, velocity_cutoff=wc, plant=plant).spectral_radius < 1.0


def test_excitation_target_takes_the_slopes_at_the_reference_pose(tmp_path):
    """With the turntable turned to ψ ≈ 1 rad (a near-static yaw component) and small slide sines, the q_u target with
    the slopes at the reference's pose leaves the unactuated row (D q̈ + h)_u as small as the constant-slope target
    does at ψ = 0 (a few % of its terms on this robot); the slopes at rest (s_a = (1/g, 0)) leave most of it (the
    slides' effect at ψ is (cos ψ, sin ψ)/g)."""
    from bemlearn.robots.scales import instability_rate
    from bemlearn.sim.collect import _pose_slopes, _reference_state, _trajectory_reference

    xml, _ = generate_robot(0, 5, hold_check=False)
    path = tmp_path / "robot.xml"
    path.write_text(xml)
    robot = load(str(path))
    ia, iu, n = list(robot.actuated_index), robot.unactuated_index, robot.n
    lam = instability_rate(robot)
    S = (*bem_slopes(robot).ravel(), lam)
    pose = _pose_slopes(robot, np.array([0.3, 0.3, math.pi]), lam)
    assert pose is not None
    A = 1e-3

    def worst_row(psi: float, table) -> float:
        comps = [(np.array([A]), np.array([2.0]), np.array([0.3])), (np.array([0.7 * A]), np.array([4.5]), np.array([2.0])),
                 (np.array([psi]), np.array([1e-4]), np.array([math.pi / 2]))]
        traj = _trajectory_reference(S, comps, robot.m)
        out = 0.0
        for t in np.linspace(0.0, 2.0, 9):
            q, qd, qdd = _reference_state(float(t), comps, traj, ia, iu, n, robot.qu_nominal, table)
            assert abs(q[ia[2]] - psi) < 1e-3
            D, h = robot.terms(q, qd)
            scale = abs(D[iu, iu] * qdd[iu]) + np.abs(D[iu, ia[:2]] * qdd[ia[:2]]).sum()
            out = max(out, abs(D[iu] @ qdd + h[iu]) / scale)
        return out

    at_zero = worst_row(0.0, None)
    assert worst_row(0.0, pose) == pytest.approx(at_zero, rel=1e-6)
    assert worst_row(1.0, pose) < 1.6 * at_zero < 0.1 < worst_row(1.0, None)
    # a cart whose slopes do not change with its pose keeps the constant-slope target (no table)
    xml2, _ = generate_robot(0, 23, hold_check=False)
    path2 = tmp_path / "cart.xml"
    path2.write_text(xml2)
    cart = load(str(path2))
    assert _pose_slopes(cart, np.array([0.3, 0.3]), instability_rate(cart)) is None


def test_design_grid_reaches_the_collection_extents(tmp_path):
    """The design-region check covers what the excitation moved (``collect.excursion``): a turntable's yaw to ±π, its
    rate to the stiffening speed v_tip (the swept hinge's whole region), the slides' accelerations to a; without the
    extents the box is the held-out references' own (|q| ≤ Σ|A| on every coordinate) and misses most yaw angles."""
    from bemlearn.pipeline.design_evaluation import design_grid
    from bemlearn.pipeline.evaluation import EvaluationConfig

    xml, _ = generate_robot(0, 5, hold_check=False)
    path = tmp_path / "robot.xml"
    path.write_text(xml)
    robot = load(str(path))
    ecfg = EvaluationConfig(amplitude_max=0.064, frequency_hz=(0.08, 0.86), n_sines=(2, 3), amplitude_min=0.032)
    P, a = np.array([0.34, 0.34, math.pi]), np.array([2.55, 2.55, 9.97])
    narrow = design_grid(robot, ecfg, n_points=256, seed=0)
    wide = design_grid(robot, ecfg, n_points=256, seed=0, excursion=(*P, *a))
    assert narrow.box["yaw"]["q"] == pytest.approx(0.064)
    assert wide.box["yaw"]["q"] == pytest.approx(math.pi)
    assert wide.box["yaw"]["qd"] == pytest.approx(velocity_stiffening_speed(robot)[2], rel=1e-9)
    assert wide.box["y"]["qdd"] >= a[1] and wide.box["x"]["q"] == pytest.approx(0.34)
    # the swept yaw's accelerations reach λ·v_tip (a motion on the balance's time scale up to the stiffening speed;
    # the yaw rate at which the thin pole's stiffness doubles is ≈ λ), beyond the excitation's own 9.97 rad/s²
    lam, v_tip = instability_rate(robot), velocity_stiffening_speed(robot)[2]
    assert v_tip == pytest.approx(lam, rel=0.05)
    assert wide.box["yaw"]["qdd"] == pytest.approx(lam * v_tip) and wide.box["yaw"]["qdd"] > 2 * a[2]
    x = wide.x.numpy()  # [q̈_a, q̇_a, q_a, 0, 0], m = 3
    yaw, yaw_rate = x[:, 8], x[:, 5]
    assert np.abs(yaw).max() > 2.5
    # at ψ̇ ≈ 0 the kept points' model BEM is the static closed form at their yaw
    still = np.abs(yaw_rate) < 0.05
    assert still.sum() > 0
    want = robot.qu_nominal + np.arctan((x[:, 0] * np.cos(yaw) + x[:, 1] * np.sin(yaw)) / G)
    np.testing.assert_allclose(wide.qu[still], want[still], atol=1e-4)
