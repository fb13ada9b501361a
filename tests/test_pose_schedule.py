"""The excitation balance scheduled over the actuated pose (issue 28, the turntable carts): the scheduled LQR gains of a
rotation-symmetric x-y turntable equal the ψ = 0 gains rotated (closed form: the slide inputs and positions turn with
ψ), robots whose fixed gains hold at every pose stay unscheduled, the yaw sweep, (S2) with a BEM that turns with the
pose, and the Gaussian σ bounded by a turning pose's rate."""

import math

import numpy as np
import pytest

from bemlearn.control.lqr import discrete_lqr, linearize, pose_gain_schedule
from bemlearn.robots import load

# x and y slides with equal moving masses (the carriage under the y slide is nearly massless), equal ranges and motors,
# an unlimited yaw, a pole tilting in the turntable's x-z plane with an axisymmetric inertia: the robot at yaw ψ is the
# robot at 0 with the slide coordinates and forces turned by ψ.
TURNTABLE = """<mujoco model="tt_sym">
<option timestep="0.002" gravity="0 0 -9.81"/>
<worldbody>
<body name="carriage">
<joint name="x" type="slide" axis="1 0 0" range="-0.5 0.5"/>
<inertial pos="0 0 0" mass="1e-7" diaginertia="1e-9 1e-9 1e-9"/>
<body name="cart">
<joint name="y" type="slide" axis="0 1 0" range="-0.5 0.5"/>
<inertial pos="0 0 0" mass="1.0" diaginertia="0.002 0.002 0.002"/>
<body name="turntable" pos="0 0 0.03">
<joint name="yaw" type="hinge" axis="0 0 1"/>
<inertial pos="0 0 0" mass="0.2" diaginertia="1e-4 1e-4 2e-4"/>
<body name="pole" pos="0 0 0.03">
<joint name="pole" type="hinge" axis="0 1 0" range="-90 90"/>
<inertial pos="0 0 0.25" mass="0.2" diaginertia="0.004 0.004 1e-5"/>
</body>
</body>
</body>
</body>
</worldbody>
<actuator>
<motor name="x_act" joint="x" ctrlrange="-20 20"/>
<motor name="y_act" joint="y" ctrlrange="-20 20"/>
<motor name="yaw_act" joint="yaw" ctrlrange="-2 2"/>
</actuator>
</mujoco>"""

RATE = 250.0


@pytest.fixture(scope="module")
def turntable(tmp_path_factory):
    path = tmp_path_factory.mktemp("tt") / "turntable.xml"
    path.write_text(TURNTABLE)
    return load(str(path))


def _turned(K0: np.ndarray, psi: float, ix: list[int], n: int) -> np.ndarray:
    """K(ψ) = T_u(ψ) K0 T_x(−ψ): the slide forces turn by ψ, the slide errors by −ψ (positions and velocities)."""
    c, s = math.cos(psi), math.sin(psi)
    R = np.array([[c, -s], [s, c]])
    Tu = np.eye(K0.shape[0])
    Tu[:2, :2] = R
    Tx = np.eye(2 * n)
    for off in (0, n):
        Tx[np.ix_([off + i for i in ix], [off + i for i in ix])] = R.T
    return Tu @ K0 @ Tx


def test_scheduled_gains_are_the_rest_gains_turned_with_the_yaw(turntable):
    robot = turntable
    assert list(robot.joint_names) == ["x", "y", "yaw", "pole"]
    res = discrete_lqr(robot, rate_hz=RATE, design_qu=0.2, qu0=0.05, qa0=0.05)
    K0 = res.K
    sched = pose_gain_schedule(robot, K0, rate_hz=RATE, timestep=None, extents=np.array([0.3, 0.3, math.pi]),
                               design_qu=0.2, qu0=0.05, qa0=0.05)
    assert sched is not None and sched.coords == (2,) and sched.periodic == (True,)   # the yaw alone, over a full turn
    assert sched.rho_fixed[0] > 1.0 > sched.rho_scheduled[0]   # the rest gains lose the pole at ψ = π/2; the schedule holds it
    grid = sched.grids[0]
    scale = np.abs(K0).max()
    for psi in (grid[12], grid[24], grid[36], grid[0], grid[5]):   # −π/2, 0, π/2, −π, and an off-axis pose
        qa = np.array([0.0, 0.0, psi])
        want = _turned(K0, psi, [0, 1], robot.n)
        np.testing.assert_allclose(K0 + sched.delta(qa), want, atol=2e-4 * scale)
    # periodic: a pose one turn on reads the same gains
    np.testing.assert_allclose(sched.delta(np.array([0.0, 0.0, grid[5] + 2 * math.pi])), sched.delta(np.array([0.0, 0.0, grid[5]])),
                               atol=1e-9 * scale)


def test_linearisation_at_a_yaw_is_the_rest_one_turned(turntable):
    """The tick map at ψ, in coordinates turned by −ψ, is the map at rest (to the finite differences' accuracy)."""
    robot = turntable
    A0, B0, _, _ = linearize(robot, rate_hz=RATE)
    psi = 1.1
    A, B, _, _ = linearize(robot, rate_hz=RATE, at=np.array([0.0, 0.0, psi]))
    c, s = math.cos(psi), math.sin(psi)
    R = np.array([[c, -s], [s, c]])
    P = np.eye(2 * robot.n)
    for off in (0, robot.n):
        P[off:off + 2, off:off + 2] = R
    Tu = np.eye(3)
    Tu[:2, :2] = R
    np.testing.assert_allclose(P.T @ A @ P, A0, atol=1e-6)
    np.testing.assert_allclose(P.T @ B @ Tu, B0, atol=1e-7)


@pytest.mark.parametrize("name", ["cartpole", "pendubot", "arm2_pole"])
def test_robots_whose_fixed_gains_hold_at_every_pose_are_not_scheduled(name):
    """A cart's linearisation does not change with its slide; a pendubot's shoulder and an arm's joints move within
    extents where the rest gains still hold: none is scheduled, so their trials are the ones they always were
    (``simulate_trial`` uses K unchanged when the schedule is ``None``)."""
    from bemlearn.pipeline import derive
    from bemlearn.sim.collect import CollectConfig, _gain_schedule

    robot = load(f"tests/robots/{name}.xml")
    rate = derive.control_rate(robot).value
    gains = derive.excitation_gains(robot, rate).value["gains"]
    sig = derive.excitation_signals(robot, rate).value
    dirs = derive.excitation_directions(robot, rate, sig).value
    cfg = CollectConfig(rate_hz=rate.rate_hz, physics_timestep=rate.timestep if rate.timestep_changed else None, gains=gains,
                        n_sines=sig["n_sines"], amplitude=dirs["amplitude"], initial_qa=derive.initial_ranges(robot).value["initial_qa"],
                        excursion=dirs["excursion"], reference_bem=dirs["reference_bem"])
    assert _gain_schedule(robot, cfg, np.asarray(gains).reshape(robot.m, 2 * robot.n)) is None


def test_sweep_only_where_the_pose_turns_the_slopes_over_a_wide_extent(turntable):
    from bemlearn.sim.collect import CollectConfig, _pose_slopes, _sweep_components

    ext = (0.3, 0.3, math.pi, 2.0, 2.0, 9.0)
    pose = _pose_slopes(turntable, np.array(ext[:3]), 6.0)
    assert pose is not None   # the yaw turns the slides' s_a
    sw = _sweep_components(turntable, CollectConfig(excursion=ext), np.random.default_rng(0), pose)
    assert sw is not None and sw[0] == (0.0, 0.0, 0.0, 1.0) and sw[1] == (0.0, 0.0, 0.0, 1.0)   # slides: no sweep
    A, w, _, keep = sw[2]
    # the peak rate reaches SWEEP_REACH × the stiffening speed v = √(m g l / (I_⊥ + m l² − I_∥)) (pole: 0.2 kg at 0.25 m,
    # I_⊥ = 0.004, I_∥ = 1e-5): the design region's rates reach v
    from bemlearn.sim.collect import SWEEP_REACH

    v = math.sqrt(0.2 * 9.81 * 0.25 / (0.004 + 0.2 * 0.25**2 - 1e-5))
    top = SWEEP_REACH * v
    assert pytest.approx(math.pi) == A and keep == 1.0 and 0.5 * top <= A * w <= top * (1 + 1e-6)   # unlimited yaw: in [Ω_top/2, Ω_top]
    rng = np.random.default_rng(0)
    before = rng.bit_generator.state
    narrow = (0.3, 0.3, 0.8, 2.0, 2.0, 9.0)   # a yaw extent below a radian: the sines visit it
    assert _sweep_components(turntable, CollectConfig(excursion=narrow), rng, _pose_slopes(turntable, np.array(narrow[:3]), 6.0)) is None
    assert _sweep_components(turntable, CollectConfig(excursion=ext), rng, None) is None   # no pose table (a cart)
    assert rng.bit_generator.state == before   # no draw: a robot without a sweep keeps its trials


def test_s2_with_a_bem_that_turns_with_the_pose():
    """q_u = atan((ẍ cos ψ + ÿ sin ψ)/g) + q̈_u/λ²: the fit linear in the actuated inputs does not describe it; with the
    learned BEM (here the exact one) as a regressor the slope 1/λ² is recovered and resolved.  A linear BEM's fit is
    unchanged by the argument."""
    from bemlearn.pipeline.support import LINEAR_R2, extrapolation_leverage

    rng = np.random.default_rng(1)
    N, g, lam2 = 600, 9.81, 40.0
    qdd_a = rng.normal(0, 1.5, (N, 3))
    qd_a = rng.normal(0, 0.5, (N, 3))
    q_a = np.c_[rng.normal(0, 0.2, (N, 2)), rng.uniform(-math.pi, math.pi, N)]
    qdd_u = rng.normal(0, 2.0, N)
    qd_u = rng.normal(0, 0.3, N)
    bem = np.arctan((qdd_a[:, 0] * np.cos(q_a[:, 2]) + qdd_a[:, 1] * np.sin(q_a[:, 2])) / g)
    y = bem + qdd_u / lam2 + rng.normal(0, 1e-3, N)
    x = np.c_[qdd_a, qd_a, q_a, qdd_u, qd_u]
    names = ("qdd_x", "qdd_y", "qdd_yaw", "qd_x", "qd_y", "qd_yaw", "q_x", "q_y", "q_yaw", "qdd_pole", "qd_pole")
    plain = extrapolation_leverage(x, y, names)
    assert plain["r2"] < LINEAR_R2 and not plain["with_bem"]
    out = extrapolation_leverage(x, y, names, bem=bem)
    assert out["with_bem"] and out["r2"] > 0.99
    assert out["slope"] == pytest.approx(1 / lam2, rel=0.02) and out["t"] > 50
    wrong = extrapolation_leverage(x, y, names, bem=rng.normal(0, 0.1, N))   # a "learned BEM" that describes nothing
    assert wrong["with_bem"] and wrong["r2"] < LINEAR_R2 and wrong["t"] is None   # S2 then says nothing either way
    lin = 0.1 * qdd_a[:, 0] + 0.02 * qdd_a[:, 1] + qdd_u / lam2 + rng.normal(0, 1e-3, N)
    a, b = extrapolation_leverage(x, lin, names), extrapolation_leverage(x, lin, names, bem=np.zeros(N))
    assert a == b and not b["with_bem"]


def _turntable_log(yaw_rate: float, *, with_products: bool):
    """Two trials at 250 Hz: slides x, y with sines, a yaw turning at ``yaw_rate`` (rad/s) with a sine, and a pole
    that follows atan((ẍ cos ψ + ÿ sin ψ)/g) (``with_products``) or ẍ/g alone."""
    from bemlearn.data.trajectory import Trajectory, TrajectoryMeta

    rate, T = 250.0, 5000
    t = np.arange(T) / rate
    rows = []
    for k in range(2):
        ph = 0.7 * k
        x = 0.05 * np.sin(2 * math.pi * 1.1 * t + ph) + 0.03 * np.sin(2 * math.pi * 0.37 * t)
        y = 0.05 * np.sin(2 * math.pi * 0.9 * t + 2 * ph) + 0.03 * np.sin(2 * math.pi * 0.53 * t + 1.0)
        psi = yaw_rate * t * (-1) ** k + 0.5 * np.sin(2 * math.pi * 0.2 * t)
        ax = -0.05 * (2 * math.pi * 1.1) ** 2 * np.sin(2 * math.pi * 1.1 * t + ph) - 0.03 * (2 * math.pi * 0.37) ** 2 * np.sin(2 * math.pi * 0.37 * t)
        ay = -0.05 * (2 * math.pi * 0.9) ** 2 * np.sin(2 * math.pi * 0.9 * t + 2 * ph) - 0.03 * (2 * math.pi * 0.53) ** 2 * np.sin(2 * math.pi * 0.53 * t + 1.0)
        pole = np.arctan((ax * np.cos(psi) + ay * np.sin(psi)) / 9.81) if with_products else np.arctan(ax / 9.81)
        rows.append((t + 100 * k, np.full(T, k), np.c_[x, y, psi, pole]))
    meta = TrajectoryMeta(robot="synthetic", joint_names=("x", "y", "yaw", "pole"), unactuated="pole",
                          actuator_names=("x_act", "y_act", "yaw_act"), sample_rate_hz=rate, trial_failed={0: False, 1: False},
                          joint_kinds=("slide", "slide", "hinge", "hinge"))
    q = np.concatenate([r[2] for r in rows])
    return Trajectory(t=np.concatenate([r[0] for r in rows]), trial=np.concatenate([r[1] for r in rows]).astype(np.int64),
                      q=q, u=np.zeros((len(q), 3)), meta=meta)


def test_sigma_bounded_by_a_turning_pose_only_where_its_products_carry_the_label():
    from bemlearn.data.derivative_choice import TURNING_KEPT, choose_sigma

    turning = choose_sigma(_turntable_log(4.0, with_products=True), qu_window=None)
    bound = math.sqrt(-2 * math.log(TURNING_KEPT)) / 4.0      # the yaw's rate is 4 ± 0.63 rad/s
    assert "yaw turns through" in turning.note
    assert 0.8 * bound <= turning.sigma_s <= bound
    plain = choose_sigma(_turntable_log(4.0, with_products=False), qu_window=None)   # the yaw turns, the label ignores it
    assert "yaw" not in plain.note and plain.sigma_s > 1.5 * turning.sigma_s


# The same turntable with position servos on the slides (the family's turntables with weak yaw servos, fam0_017, 029,
# 035, have them): turning steadily, the balance scheduled over the pose at rest loses the slides beyond a rate.
SERVO_SLIDES = (TURNTABLE.replace('<motor name="x_act" joint="x" ctrlrange="-20 20"/>', '<position name="x_act" joint="x" kp="200" ctrlrange="-1 1"/>')
                .replace('<motor name="y_act" joint="y" ctrlrange="-20 20"/>', '<position name="y_act" joint="y" kp="200" ctrlrange="-1 1"/>'))


@pytest.fixture(scope="module")
def servo_turntable(tmp_path_factory):
    path = tmp_path_factory.mktemp("tt") / "servo_turntable.xml"
    path.write_text(SERVO_SLIDES)
    robot = load(str(path))
    K0 = discrete_lqr(robot, rate_hz=RATE, design_qu=0.2, qu0=0.05, qa0=0.05).K
    sched = pose_gain_schedule(robot, K0, rate_hz=RATE, timestep=None, extents=np.array([0.3, 0.3, math.pi]),
                               design_qu=0.2, qu0=0.05, qa0=0.05)
    assert sched is not None and sched.coords == (2,) and sched.periodic == (True,)
    return robot, K0, sched


def _spin(robot, K0: np.ndarray, sched, rate: float, seconds: float, tilt: float = 0.02) -> float:
    """:func:`_follow` with the yaw commanded to turn steadily at ``rate`` and the pose-scheduled gains
    u = (K0 + ΔK(ψ)) e (the model's inverse along the turn: its bias alone, q̈_t = 0)."""
    ia = list(robot.actuated_index)
    return _follow(robot, lambda k, q: K0 + sched.delta(q[ia]), lambda t: (rate * t, rate, 0.0), seconds, tilt)


def test_turning_rate_the_pose_schedule_holds_is_where_steady_turning_grows_in_mujoco(servo_turntable):
    """turning_rate_limit (the Floquet exponent of the linearised loop over a turn) against MuJoCo itself: turning at
    0.6 × Ω_hold the tilt and the slides settle; at 1.6 × Ω_hold they grow (the robot falls or ends far off)."""
    from bemlearn.control.lqr import turning_rate_limit

    robot, K0, sched = servo_turntable
    hold, growth = turning_rate_limit(robot, K0, 2, sched.grids[0], sched.deltas[0], 5.0, rate_hz=RATE, timestep=None,
                                      horizon_s=20.0, levels=4, refine=3)
    assert 1.0 < hold < 5.0 and growth > 1.0 / 20.0   # measured: 2.49 rad/s, 0.34 1/s at 5 rad/s (12 levels)
    assert _spin(robot, K0, sched, 0.6 * hold, 12.0) < 0.02 / 4
    assert _spin(robot, K0, sched, 1.6 * hold, 20.0) > 0.02 * 5


def test_sweep_peak_rate_within_the_rate_the_balance_holds_turning(turntable, servo_turntable):
    """Where a schedule's Ω_hold bounds it (no LQR along the reference: several swept hinges), the yaw sweep's peak rate
    A ω ~ U(0.5, 1) min(Ω_top, Ω_hold) (beyond the rate at which the pose-scheduled balance holds turning fam0_029 lost
    17 of 24 trials), drawn the same way (the same draws from the trial's generator), and unchanged where the balance
    holds turning at Ω_top."""
    import dataclasses

    from bemlearn.sim.collect import CollectConfig, _pose_slopes, _sweep_components, sweep_top

    _, _, sched = servo_turntable
    ext = (0.3, 0.3, math.pi, 2.0, 2.0, 9.0)
    v = float(sweep_top(turntable, CollectConfig(excursion=ext))[2])
    pose = _pose_slopes(turntable, np.array(ext[:3]), 6.0)
    held = dataclasses.replace(sched, turn_rate=(1.2,), growth=(0.3,))
    free = dataclasses.replace(sched, turn_rate=(v,), growth=(-0.5,))
    for seed in range(20):
        rng_a, rng_b, rng_c = (np.random.default_rng(seed) for _ in range(3))
        A, w, ph, keep = _sweep_components(turntable, CollectConfig(excursion=ext), rng_a, pose, held)[2]
        A0, w0, ph0, _ = _sweep_components(turntable, CollectConfig(excursion=ext), rng_b, pose)[2]
        assert pytest.approx(math.pi) == A and 0.6 <= A * w <= 1.2 * (1 + 1e-12) and ph == ph0   # bounded by Ω_hold
        assert A * w == pytest.approx(A0 * w0 * 1.2 / v, rel=1e-12)   # the same draw, scaled to the bound
        assert _sweep_components(turntable, CollectConfig(excursion=ext), rng_c, pose, free)[2] == (A0, w0, ph0, keep)
        assert rng_a.bit_generator.state == rng_b.bit_generator.state == rng_c.bit_generator.state


def test_a_pose_where_scipys_riccati_solver_fails_gets_the_recursions_gains(turntable, monkeypatch):
    """SciPy's solve_discrete_are can fail ("very ill-conditioned") at a well-posed pose (fam0_035 at ψ = −2π/3); the
    schedule then took the gains at rest there, which push the pole the wrong way two thirds of a turn on (its trials
    fell at ψ ≈ −2.1).  Now the Riccati recursion's gains: the rest gains turned with the yaw (closed form, as above)."""
    import scipy.linalg

    robot = turntable
    K0 = discrete_lqr(robot, rate_hz=RATE, design_qu=0.2, qu0=0.05, qa0=0.05).K
    grid = np.linspace(-math.pi, math.pi, 49)
    bad = float(grid[8])   # −2π/3
    real = scipy.linalg.solve_discrete_are
    iu = robot.unactuated_index
    seen = []

    def failing(A, B, Q, R, *args, **kwargs):
        # the pole's row of B turns with the yaw: −(cos ψ, sin ψ) × the slide force's effect at rest
        psi = math.atan2(-B[robot.n + iu, 1], -B[robot.n + iu, 0])
        if abs(psi - bad) < 1e-3:
            seen.append(psi)
            raise ValueError("Reordering of (A, B) failed because the transformed matrix pair (A, B) would be too far "
                             "from generalized Schur form; the problem is very ill-conditioned.")
        return real(A, B, Q, R, *args, **kwargs)

    monkeypatch.setattr(scipy.linalg, "solve_discrete_are", failing)
    # (a y extent of its own: not the schedule cached by the test above)
    sched = pose_gain_schedule(robot, K0, rate_hz=RATE, timestep=None, extents=np.array([0.3, 0.31, math.pi]),
                               design_qu=0.2, qu0=0.05, qa0=0.05)
    assert seen, "the failing pose was designed"
    assert sched is not None and sched.rho_scheduled[0] < 1.0
    scale = np.abs(K0).max()
    np.testing.assert_allclose(K0 + sched.delta(np.array([0.0, 0.0, bad])), _turned(K0, bad, [0, 1], robot.n), atol=2e-4 * scale)
    # the recursion against SciPy where SciPy succeeds
    from bemlearn.control.lqr import riccati_iteration

    A, B, _, _ = linearize(robot, rate_hz=RATE, at=np.array([0.0, 0.0, 0.4]))
    Q, R = np.diag(np.linspace(1.0, 3.0, A.shape[0])), np.diag([0.5, 0.7, 2.0])
    P = riccati_iteration(A, B, Q, R)
    assert P is not None
    np.testing.assert_allclose(P, real(A, B, Q, R), rtol=1e-7, atol=1e-9 * np.abs(P).max())


def _fixed_maps(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, S: np.ndarray | None, *, by_rate: np.ndarray | None = None):
    """TurningMaps whose tick map is (A, B) at every pose, plus ``by_rate`` × the rate (linear in it) where given."""
    from bemlearn.control.lqr import TurningMaps

    poses, rates = np.linspace(-math.pi, math.pi, 5), np.array([-2.0, -0.5, 1.0, 3.0])
    As = np.broadcast_to(A, (5, 4, *A.shape)).copy()
    if by_rate is not None:
        As += rates[None, :, None, None] * by_rate
    Bs = np.broadcast_to(B, (5, 4, *B.shape)).copy()
    return TurningMaps(2, poses, rates, As, Bs, True, Q, R, S, np.zeros(B.shape[::-1]), 1.0)


def test_tracking_gains_are_the_finite_horizon_lqr(turntable):
    """tracking_gains along a motion whose tick map does not change is the finite-horizon LQR of a fixed system (closed
    forms): at the last tick (P = Q) K = −(R + BᵀQB)⁻¹(BᵀQA + Sᵀ); far from it the stationary gains of SciPy's DARE; and
    with a map linear in the rate, held at a rate between the grid's, the DARE of that rate's map (the interpolation is
    exact there)."""
    import scipy.linalg

    from bemlearn.control.lqr import tracking_gains

    A, B, _, _ = linearize(turntable, rate_hz=RATE, at=np.array([0.0, 0.0, 0.4]))
    nx = A.shape[0]
    Q, R = np.diag(np.linspace(1.0, 3.0, nx)), np.diag([0.5, 0.7, 2.0])
    S = 0.01 * np.ones((nx, 3))
    T = 4000   # 16 s at 250 Hz: the recursion forgets its start within a few of the loop's settling times
    psi = np.linspace(-4.0, 4.0, T)   # wraps at ±π
    G = tracking_gains(_fixed_maps(A, B, Q, R, S), psi, np.full(T, 0.7))
    K_last = -np.linalg.solve(R + B.T @ Q @ B, B.T @ Q @ A + S.T)
    np.testing.assert_allclose(G[-1], K_last, rtol=1e-12, atol=1e-12 * np.abs(K_last).max())
    P = scipy.linalg.solve_discrete_are(A, B, Q, R, s=S)
    K_inf = -np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A + S.T)
    np.testing.assert_allclose(G[0], K_inf, rtol=1e-8, atol=1e-9 * np.abs(K_inf).max())
    E = np.zeros_like(A)
    E[0, 4], E[4, 1] = 1e-3, -2e-3   # a coupling of the slides that grows with the rate (the Coriolis terms' form)
    r = 1.7
    G = tracking_gains(_fixed_maps(A, B, Q, R, S, by_rate=E), psi, np.full(T, r))
    Ar = A + r * E
    P = scipy.linalg.solve_discrete_are(Ar, B, Q, R, s=S)
    np.testing.assert_allclose(G[0], -np.linalg.solve(R + B.T @ P @ B, B.T @ P @ Ar + S.T), rtol=1e-8, atol=1e-9 * np.abs(K_inf).max())


def _follow(robot, gains, ref, seconds: float, tilt: float = 0.02) -> float:
    """MuJoCo itself: the yaw commanded along ``ref(t) -> (ψ_t, ψ̇_t, ψ̈_t)`` with the pole upright, u = gains(k, q) e + the
    model's inverse along it, from a ``tilt`` off upright and the reference's rate; the largest |x|, |y|, |ψ − ψ_t|,
    |q_u − q_u*| over the last second (1 where it passed 1 on the way)."""
    import mujoco

    from bemlearn.control.actuator_inverse import MujocoActuatorInverse

    model, data = robot.model, mujoco.MjData(robot.model)
    inverse = MujocoActuatorInverse(robot)
    iu, ia, n = robot.unactuated_index, list(robot.actuated_index), robot.n
    q = np.zeros(n)
    q[iu] = robot.qu_nominal + tilt
    qd = np.zeros(n)
    q[ia[2]], qd[ia[2]], _ = ref(0.0)
    data.qpos[:], data.qvel[:] = robot.state_to_mujoco(q, qd)
    mujoco.mj_forward(model, data)
    steps = int(round(1.0 / (RATE * model.opt.timestep)))
    ticks = int(seconds * RATE)
    last = 0.0
    for k in range(ticks):
        q_ref, qd_ref, qdd_ref = np.zeros(n), np.zeros(n), np.zeros(n)
        q_ref[iu] = robot.qu_nominal
        q_ref[ia[2]], qd_ref[ia[2]], qdd_ref[ia[2]] = ref(k / RATE)
        q = robot.coordinates_of(data.qpos)
        qd = robot.T_np @ data.qvel
        dev = float(np.max(np.abs(np.r_[q[ia[:2]], q[ia[2]] - q_ref[ia[2]], q[iu] - robot.qu_nominal])))
        if dev > 1.0:
            return 1.0
        if k >= ticks - int(RATE):
            last = max(last, dev)
        D, h = robot.terms(q_ref, qd_ref)
        u = gains(k, q) @ np.concatenate([q - q_ref, qd - qd_ref])
        data.ctrl[:] = u + inverse.command((D @ qdd_ref + h)[ia], q_ref, qd_ref, clip=False)
        for _ in range(steps):
            mujoco.mj_step(model, data)
    return last


def test_lqr_along_a_known_turn_holds_where_the_pose_schedule_loses_it(servo_turntable):
    """The position-servo turntable turning steadily at 1.6 × the rate to which the balance scheduled over the pose at
    rest holds turning (Ω_hold ≈ 2.5 rad/s, above): with that schedule the slides and the tilt grow (the robot falls or
    ends far off, as above); with the LQR along the known turn (tick maps at its pose *and* rate, turning_maps /
    tracking_gains) the tilt and the slides settle (MuJoCo, nonlinear)."""
    from bemlearn.control.lqr import tracking_gains, turning_maps

    robot, K0, sched = servo_turntable
    rate, seconds = 4.0, 20.0   # 1.6 × 2.49 (Ω_hold, measured with 12 levels)
    maps = turning_maps(robot, j=2, extent=math.pi, rate_max=5.0, rate_hz=RATE, timestep=None, design_qu=0.2, qu0=0.05,
                        qa0=0.05, points=25, levels=4)
    np.testing.assert_allclose(maps.K_rest, K0, rtol=1e-6, atol=1e-9 * np.abs(K0).max())   # the rest design's gains
    t = np.arange(int(seconds * RATE) + int(math.ceil(5 * maps.settle_s * RATE))) / RATE
    G = tracking_gains(maps, rate * t, np.full(t.size, rate))

    def spin(t: float) -> tuple[float, float, float]:
        return rate * t, rate, 0.0

    ia = list(robot.actuated_index)
    assert _follow(robot, lambda k, q: K0 + G[k] - maps.K_rest, spin, seconds) < 0.02 / 4
    assert _follow(robot, lambda k, q: K0 + sched.delta(q[ia]), spin, seconds) > 0.02 * 5


def test_a_hinge_with_rounding_size_slopes_gets_the_half_turn_scale(tmp_path):
    """Family robot (0, 41), a turntable with a motor yaw: at rest its yaw's slope is of rounding size (s_a ≈ 1e-12 rad per
    rad/s², its BEM gain at λ ≈ 3.5e-11, above the 1e-12 that marked a yaw idle): its Bryson scale was d/gain ≈ 6e9 rad,
    its LQR gains ≈ 1e-9 and the yaw ran off its reference by tens of turns (7 of 8 replayed trials fell).  Slopes
    ≤ 1e-9 per unit are no motion of the BEM (as in the excitation's extents): the half-turn scale of a yaw, and gains
    that hold it."""
    from bemlearn.bench.family.generator import generate_robot
    from bemlearn.control.lqr import bryson_scales
    from bemlearn.robots.scales import bem_gain, bem_slopes, instability_rate

    xml, _ = generate_robot(0, 41, hold_check=False)
    path = tmp_path / "fam0_041.xml"
    path.write_text(xml)
    robot = load(str(path))
    j = list(robot.actuated_names).index("yaw")
    slopes = bem_slopes(robot)
    gain = bem_gain(slopes, instability_rate(robot))
    assert np.max(np.abs(slopes[:, j])) <= 1e-9 and gain[j] > 1e-12   # the case: rounding-size, not exactly 0
    xmax, _, _ = bryson_scales(robot, design_qu=0.2)
    assert xmax[robot.actuated_index[j]] == pytest.approx(math.pi)
    K = discrete_lqr(robot, rate_hz=100.0, design_qu=0.2, qu0=0.05, qa0=0.04).K
    assert abs(K[j, robot.actuated_index[j]]) > 1e-2 and abs(K[j, robot.n + robot.actuated_index[j]]) > 1e-3


def test_poses_without_a_design_take_their_neighbours_change_on_a_limited_and_a_full_turn_grid():
    """fill_between_poses: linear interpolation from the poses that have a design, on a limited joint's grid (where a
    run of fam1_021 crashed: the grid's poses against the good poses' values) and across ±2π on a full turn."""
    from bemlearn.control.lqr import fill_between_poses

    grid = np.linspace(-1.0, 1.0, 9)
    d = np.stack([grid, 2 * grid], axis=1)[:, None, :]          # (9, 1, 2): a change linear in the pose
    ok = np.ones(9, dtype=bool)
    ok[[0, 3, 4]] = False
    got = fill_between_poses(grid, np.where(ok[:, None, None], d, np.nan), ok, periodic=False)
    want = d.copy()
    want[0] = d[1]                                               # before the first good pose: its value
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    turn = np.linspace(-math.pi, math.pi, 8, endpoint=False)
    dt = np.cos(turn)[:, None, None] * np.ones((1, 1, 2))
    okt = np.ones(8, dtype=bool)
    okt[0] = False                                               # −π: between 3π/4 (one turn back) and −3π/4
    gt = fill_between_poses(turn, np.where(okt[:, None, None], dt, np.nan), okt, periodic=True)
    np.testing.assert_allclose(gt[0], 0.5 * (dt[1] + dt[7]), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(gt[1:], dt[1:])


def test_tracking_gains_tail_is_at_most_the_trial_when_the_rest_loop_is_slower_than_it(turntable, monkeypatch):
    """The backward recursion of collect._tracking_gains runs 5 × the rest loop's slowest time constant past the trial,
    at most the trial's length (collect.tail_ticks): a rest design with a 10⁴ s mode would otherwise ask for 10⁷ ticks
    (the maps interpolated at each: gigabytes); the gains returned are one per tick of the trial."""
    import dataclasses

    import bemlearn.control.lqr as lqr_mod
    from bemlearn.sim import collect as col
    from bemlearn.sim.collect import CollectConfig, tail_ticks

    assert tail_ticks(0.9, 200.0, 4000) == 900 and tail_ticks(1400.0, 208.0, 4160) == 4160
    n = turntable.n
    A, B = np.eye(2 * n), np.zeros((2 * n, turntable.m))
    maps = dataclasses.replace(_fixed_maps(A, B, np.eye(2 * n), np.eye(turntable.m), None), settle_s=1.0e4)
    lengths = []

    def fake_tracking(m, q, qd):
        lengths.append(len(q))
        return np.zeros((len(q), turntable.m, 2 * n))

    monkeypatch.setattr(lqr_mod, "turning_maps", lambda *a, **k: maps)
    monkeypatch.setattr(lqr_mod, "tracking_gains", fake_tracking)
    cfg = CollectConfig(rate_hz=RATE, duration_s=2.0, n_sines=(2, 3), amplitude=(0.1, 0.5), initial_qa=(0.0, 0.05),
                        excursion=(0.3, 0.3, math.pi, 2.0, 2.0, 8.0))
    comps = (np.array([1.0, 0.5]), np.array([1.0, 3.0]), np.array([0.0, 0.3]))
    G = col._tracking_gains(turntable, cfg, 2, comps)
    n_ticks = int(round(cfg.duration_s * RATE))
    assert lengths == [2 * n_ticks] and G.shape == (n_ticks, turntable.m, 2 * n)
