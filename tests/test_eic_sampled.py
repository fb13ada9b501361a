"""The EIC loop as it runs (sampled, command held, rates from the velocity filter): its linearisation
(:func:`bemlearn.control.eic_linear.eic_tick_loop`) against the closed-loop simulation, the gain search of
:func:`bemlearn.pipeline.derive.eic_gains`, and the model check ``eic_recovery`` on the acrobot."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bemlearn.control.eic import EICGains
from bemlearn.control.eic_linear import eic_linear_abscissa, eic_tick_loop
from bemlearn.data.sensors import SensorConfig
from bemlearn.pipeline import derive
from bemlearn.robots import MujocoRobot
from bemlearn.robots.scales import instability_rate
from bemlearn.sim.closed_loop import ReferenceConfig, SimulateConfig, simulate

ROBOTS = Path(__file__).parent / "robots"


def _family_robot(tmp_path: Path, seed: int, index: int) -> tuple[MujocoRobot, Path]:
    """Robot ``index`` of the generated family ``seed`` (``bemlearn.bench.family``), written to ``tmp_path`` and loaded."""
    from bemlearn.bench.family.generator import generate_robot

    xml, _ = generate_robot(seed, index, hold_check=False)
    path = tmp_path / f"fam{seed}_{index:03d}.xml"
    path.write_text(xml)
    return MujocoRobot.from_xml(path), path


AT_REST = ReferenceConfig((0.0,), (0.0,), (0.0,), 0.0)


def _sim(robot, gains, rate, *, qu0: float, cutoff: float, counts: int, seconds: float):
    cfg = SimulateConfig(duration_s=seconds, rate_hz=rate.rate_hz, bem_source="model", reference=AT_REST, gains=gains,
                         sensor=SensorConfig(counts_per_rev=counts, velocity_cutoff=cutoff), initial_qu=qu0, fall_window=0.6,
                         warmup_s=0.0, physics_timestep=rate.timestep if rate.timestep_changed else None)
    return simulate(robot, cfg, progress=False)


@pytest.mark.parametrize("name", ["cartpole", "reaction_wheel", "pendubot"])
def test_tick_loop_predicts_the_closed_loop_simulation(name):
    """From a 1e-5 error of q_u (ideal encoder: no quantisation), z_{k+1} = M z_k reproduces the simulated
    coordinates (MuJoCo, the EIC with the model BEM, the Tustin filter) over 400 ticks within 5 % of their range."""
    robot = MujocoRobot.from_xml(ROBOTS / f"{name}.xml")
    rate = derive.control_rate(robot).value
    gains = derive.eic_gains(robot, rate).value
    wc = derive.closed_loop_sensor(robot, rate).value["velocity_cutoff"]
    loop = eic_tick_loop(robot, gains, rate_hz=rate.rate_hz, velocity_cutoff=wc, timestep=rate.timestep)
    e, ticks = 1e-5, 400
    res = _sim(robot, gains, rate, qu0=e, cutoff=wc, counts=0, seconds=ticks / rate.rate_hz)
    n, iu = robot.n, robot.unactuated_index
    z = np.zeros(4 * n)
    z[iu] = e
    z[3 * n + iu] = e          # the filter's first sample: v_0 = 0 (no previous measurement)
    pred = np.empty((ticks, n))
    for k in range(ticks):
        pred[k] = z[:n]
        z = loop.M @ z
    q = res.q.copy()
    q[:, iu] -= robot.qu_nominal
    assert q.shape == pred.shape
    assert np.max(np.abs(pred - q)) <= 0.05 * np.max(np.abs(q))
    assert loop.spectral_radius < 1


def test_velocity_filter_lag_destabilises_a_pendubot_the_continuous_model_calls_stable(tmp_path):
    """Family robot (0, 33), a pendubot with a velocity servo: with the rule's gains the continuous linearisation
    is stable but the sampled loop with its velocity filter grows, and the closed loop falls in MuJoCo; the derived
    gains (the search) make the sampled loop decay and the robot recover from a d/4 error.  (With the
    family's 4096-count encoder the rule's loop falls in the pipeline's closed loop at 1.3 s, docs/family.md.)"""
    robot, _ = _family_robot(tmp_path, 0, 33)
    rate = derive.control_rate(robot).value
    wc = derive.closed_loop_sensor(robot, rate).value["velocity_cutoff"]
    w_u = 2.2 * instability_rate(robot)
    rule = EICGains(kp_a=(w_u / 7) ** 2, kd_a=2 * w_u / 7, kp_u=w_u**2, kd_u=2 * w_u)
    assert eic_linear_abscissa(robot, rule) < -1.0
    assert eic_tick_loop(robot, rule, rate_hz=rate.rate_hz, velocity_cutoff=wc).spectral_radius > 1.0
    res = _sim(robot, rule, rate, qu0=0.01, cutoff=wc, counts=0, seconds=5.0)
    last = np.abs(res.q[res.t > 4.0, robot.unactuated_index] - robot.qu_nominal)
    assert res.fell or np.max(last) > 3 * 0.01     # grows (e^{0.49·5} ≈ 11 in the linearisation)
    derived = derive.eic_gains(robot, rate)
    assert derived.value.kp_u != pytest.approx(rule.kp_u)
    assert eic_tick_loop(robot, derived.value, rate_hz=rate.rate_hz, velocity_cutoff=wc).spectral_radius < 1.0
    ok, how = derive.eic_recovery(robot, derived.value, rate, qu0=0.05, velocity_cutoff=wc)
    assert ok, how


def test_acrobot_eic_basin_is_smaller_than_the_design_errors():
    """The acrobot's searched gains make the sampled loop decay (from 0.001 rad it is held, after a transient
    about ten times the start), yet from the d/4 =
    0.05 rad start the elbow swings beyond 2 rad and the robot falls: the model check says why it is unusable."""
    robot = MujocoRobot.from_xml(ROBOTS / "acrobot.xml")
    rate = derive.control_rate(robot).value
    wc = derive.closed_loop_sensor(robot, rate).value["velocity_cutoff"]
    gains = derive.eic_gains(robot, rate).value
    assert eic_tick_loop(robot, gains, rate_hz=rate.rate_hz, velocity_cutoff=wc).spectral_radius < 1.0
    small = _sim(robot, gains, rate, qu0=0.001, cutoff=wc, counts=0, seconds=5.0)
    peak = np.max(np.abs(small.q[:, robot.unactuated_index]))
    assert not small.fell and 0.001 < peak < 0.02   # held, after a transient ~10× the start (0.05 would not stay linear)
    ok, how = derive.eic_recovery(robot, gains, rate, qu0=0.05, velocity_cutoff=wc)
    assert not ok and "falls" in how and "elbow" in how
    big = _sim(robot, gains, rate, qu0=0.05, cutoff=wc, counts=4096, seconds=3.0)
    assert big.fell and np.max(np.abs(big.q[:, robot.actuated_index[0]])) > 2.0


@pytest.mark.slow
def test_effort_capped_excitation_is_halved_until_its_trials_stay_up(tmp_path):
    """Family robot (0, 27), a pendubot on a position servo whose forcerange binds far inside its ctrlrange: at the
    amplitude the actuator limits allow most excitation trials fall; the checked amplitude is smaller, and on
    trials the check never ran (other seeds) fewer fall."""
    import dataclasses

    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.sim.collect import simulate_trial

    robot, path = _family_robot(tmp_path, 0, 27)
    rate = derive.control_rate(robot).value
    sig = derive.excitation_signals(robot, rate).value
    assert sig["effort_capped"]
    collect = resolve_pipeline_config({"robot": str(path)}).config.collect
    assert collect.amplitude[1] < sig["amplitude"][1]
    seqs = np.random.SeedSequence([collect.seed, 7]).spawn(8)
    full = dataclasses.replace(collect, amplitude=sig["amplitude"], duration_s=10.0)
    checked = dataclasses.replace(collect, duration_s=10.0)
    fell_full = sum(simulate_trial(robot, full, i, s).failed for i, s in enumerate(seqs))
    fell_checked = sum(simulate_trial(robot, checked, i, s).failed for i, s in enumerate(seqs))
    assert fell_full > 4 and fell_checked <= 2, (fell_full, fell_checked)
    assert math.isfinite(collect.amplitude[1])


def test_excitation_amplitude_set_by_the_bem_budget_is_checked_by_trials_too(tmp_path):
    """Family robot (1, 15), a pendubot on a velocity servo at 192 Hz: the BEM budget, not the actuator limits, sets the
    amplitude (0.063 rad), yet 11 of 12 five-second trials fell there (none without sines); the trials decide, and
    the derived amplitude is halved."""
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    robot, path = _family_robot(tmp_path, 1, 15)
    sig = derive.excitation_signals(robot, derive.control_rate(robot).value).value
    assert not sig["effort_capped"]
    resolved = resolve_pipeline_config({"robot": str(path)})
    assert resolved.config.collect.amplitude[1] == pytest.approx(0.5 * sig["amplitude"][1], rel=1e-12)
    assert "fall at A × 0.5 and" in resolved.notes["collect.n_sines"] and "of 20 s trials: A × 0.5" in resolved.notes["collect.n_sines"]


def test_the_excitation_level_the_first_trials_choose_is_confirmed_by_independent_trials(tmp_path):
    """Family robot (1, 33), a pendubot on a position servo: at A × ½ the check's first 24 five-second trials had 4 falls
    and passed, yet the collection there lost 15 of 24 trials (ten other seeds' five-second batches: 6–13 falls).  The
    level is confirmed by 24 independent trials as long as the collection's (at most a third may fall); here they
    reject it, and the collection's own trials at the level chosen stay up."""
    import dataclasses

    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.sim.collect import simulate_trial

    robot, path = _family_robot(tmp_path, 1, 33)
    sig = derive.excitation_signals(robot, derive.control_rate(robot).value).value
    resolved = resolve_pipeline_config({"robot": str(path)})
    note = resolved.notes["collect.n_sines"]
    assert "4/24 fall at A × 0.5 and" in note and note.endswith(": A × 0.25"), note
    collect = resolved.config.collect
    assert collect.amplitude[1] == pytest.approx(0.25 * sig["amplitude"][1], rel=1e-12)
    # the collection's own seeds (not the check's), its whole 20 s: at the level chosen few fall, at the level the first
    # batch alone chose most do
    seqs = np.random.SeedSequence(collect.seed).spawn(collect.n_trials)
    fell = sum(simulate_trial(robot, collect, i, s).failed for i, s in enumerate(seqs))
    twice = dataclasses.replace(collect, amplitude=tuple(2 * a for a in collect.amplitude))
    fell_twice = sum(simulate_trial(robot, twice, i, s).failed for i, s in enumerate(seqs))
    assert fell <= collect.n_trials / 8 and fell_twice > collect.n_trials / 2, (fell, fell_twice)


def test_eic_gains_hold_the_closed_loop_reference_not_only_a_recovery(tmp_path):
    """Family robot (0, 58), a two-link arm with a pole on velocity servos: the fastest-decaying grid gains
    (ω_u = 5 λ, ω_u/ω_a = 30) bring the pole back from d/4 at rest, but with the 4096-count encoders the loop
    playing the derived closed-loop reference drifts along the joints' null direction and falls (at 4.7 s;
    with an ideal encoder it tracks within 0.02 rad)."""
    import dataclasses

    robot, _ = _family_robot(tmp_path, 0, 58)
    rate = derive.control_rate(robot).value
    sig = derive.excitation_signals(robot, rate).value
    ref = derive.closed_loop_reference(robot, sig).value
    wc = derive.closed_loop_sensor(robot, rate).value["velocity_cutoff"]
    lam = instability_rate(robot)
    w_u = 5 * lam
    fast = EICGains(kp_a=(w_u / 30) ** 2, kd_a=2 * w_u / 30, kp_u=w_u**2, kd_u=2 * w_u)
    e0 = derive.design_region(robot).value / 4
    assert derive.eic_recovery(robot, fast, rate, qu0=e0, velocity_cutoff=wc)[0]
    held, how, _ = derive._reference_run(robot, fast, rate, ref, velocity_cutoff=wc)
    assert not held and "falls" in how, how
    # the same loop with an ideal encoder holds: the encoder's counts, not the gains' linear loop, make it fall
    cfg = SimulateConfig(duration_s=10.0, rate_hz=rate.rate_hz, bem_source="model", reference=ReferenceConfig(**{
        k: tuple(v) if isinstance(v, (list, tuple)) else v for k, v in ref.items()}), gains=fast,
        sensor=dataclasses.replace(SensorConfig(velocity_cutoff=wc), counts_per_rev=0),
        fall_window=derive.fall_window(robot).value)
    assert not simulate(robot, cfg, progress=False).fell


@pytest.mark.slow
def test_eic_gains_derived_with_the_reference_hold_it(tmp_path):
    """Family robot (0, 58) (the test above): the gains :func:`derive.eic_gains` derives with the closed-loop
    reference hold that reference in MuJoCo (model BEM, encoders, limits) and track it within 0.05 rad RMS
    (measured 0.015); the gain search runs several MuJoCo loops (about 10 s on a quiet machine)."""
    robot, _ = _family_robot(tmp_path, 0, 58)
    rate = derive.control_rate(robot).value
    ref = derive.closed_loop_reference(robot, derive.excitation_signals(robot, rate).value).value
    wc = derive.closed_loop_sensor(robot, rate).value["velocity_cutoff"]
    g = derive.eic_gains(robot, rate, velocity_cutoff=wc, reference=ref).value
    held, how, rms = derive._reference_run(robot, g, rate, ref, velocity_cutoff=wc)
    assert held and rms < 0.05, how


def test_a_trial_derivation_is_reused_for_the_same_model_and_not_for_another(monkeypatch):
    """The derivations that play MuJoCo trials run once per process for the same compiled model and arguments
    (a sweep's full resolutions, a test's): the reused result equals a fresh computation, an edited model is
    computed again, and a computation that warned is not kept (its warning would not be replayed)."""
    import dataclasses

    from bemlearn.warnings import DesignWarning

    calls = []
    real = derive._eic_gains

    def counting(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(derive, "_TRIAL_RESULTS", {})
    monkeypatch.setattr(derive, "_eic_gains", counting)
    robot = MujocoRobot.from_xml(ROBOTS / "cartpole.xml")
    rate = derive.control_rate(robot).value
    first = derive.eic_gains(robot, rate)
    again = derive.eic_gains(MujocoRobot.from_xml(ROBOTS / "cartpole.xml"), rate)    # reloaded: the same bytes
    assert len(calls) == 1 and again == first
    derive._TRIAL_RESULTS.clear()
    assert derive.eic_gains(robot, rate) == first and len(calls) == 2     # computed again: the same numbers
    other = MujocoRobot.from_xml(ROBOTS / "cartpole.xml")
    other.model.body_mass[-1] *= 1.5                                       # another model
    derive.eic_gains(other, rate)
    assert len(calls) == 3
    slower = dataclasses.replace(rate, rate_hz=rate.rate_hz / 2)          # other arguments
    derive.eic_gains(robot, slower)
    assert len(calls) == 4
    acrobot = MujocoRobot.from_xml(ROBOTS / "acrobot.xml")                 # no sampled-stable gains: it warns
    arate = derive.control_rate(acrobot).value
    for k in (5, 6):
        with pytest.warns(DesignWarning, match="no sampled-stable EIC gains"):
            derive.eic_gains(acrobot, arate)
        assert len(calls) == k                                            # each time: the warning is issued again


def _arm_with_friction(friction: float) -> MujocoRobot:
    """A two-link arm (motors) with a passive pole on top, upright at 0; ``friction``: the arm joints' ``frictionloss``, N·m."""
    xml = f"""<mujoco model="arm_pole_friction">
<compiler angle="radian"/>
<option timestep="0.001" gravity="0 0 -9.81"/>
<default><geom contype="0" conaffinity="0"/>
<default class="drive"><joint damping="0.04" frictionloss="{friction}" armature="0.01"/></default></default>
<worldbody>
<body name="upper"><joint name="shoulder" type="hinge" axis="0 1 0" class="drive" range="-1.4 1.4"/>
<geom type="capsule" fromto="0 0 0 0 0 0.2" size="0.015" mass="0.4"/>
<body name="fore" pos="0 0 0.2"><joint name="elbow" type="hinge" axis="0 1 0" class="drive" range="-1.1 1.1"/>
<geom type="capsule" fromto="0 0 0 0 0 0.18" size="0.012" mass="0.5"/>
<body name="pole" pos="0 0 0.18"><joint name="pole" type="hinge" axis="0 1 0" damping="0.001"/>
<geom type="capsule" fromto="0 0 0 0 0 0.6" size="0.01" mass="0.12"/></body></body></body>
</worldbody>
<actuator><motor name="shoulder_act" joint="shoulder" ctrlrange="-2 2"/><motor name="elbow_act" joint="elbow" ctrlrange="-1.5 1.5"/></actuator>
</mujoco>"""
    return MujocoRobot.from_xml_string(xml, name=f"arm_pole_friction_{friction:g}")


def test_dry_friction_stick_slip_around_a_balanced_pole_is_held_not_a_failed_recovery():
    """A two-link arm with a pole whose BEM moves with both joint angles (s_p = −1, −1) and 0.08 N·m of dry
    friction on both arm joints: the EIC (no friction term, eq. 3) leaves a stick-slip cycle, the arm stuck off
    rest with the pole upright over it, so q_u (relative to the forearm) stays off nominal by about the arm's
    offset.  No gain the search tries brings q_u back within d/4 of nominal; the derived gains must hold it in
    that cycle and the model check ``eic_recovery`` must pass them (before: it failed them and the run stopped
    as if the robot could not be balanced).  Checked independently: the pole's absolute angle
    (shoulder + elbow + pole, parallel axes) stays within 0.01 rad of upright over the last second while q_u and
    the shoulder are ≈ 0.09 off, and the same gains without the friction bring q_u back within d/4."""
    robot = _arm_with_friction(0.08)
    rate = derive.control_rate(robot).value
    d = derive.design_region(robot).value
    wc = derive.closed_loop_sensor(robot, rate).value["velocity_cutoff"]
    np.testing.assert_allclose(derive.bem_slopes(robot)[0], [-1.0, -1.0], atol=1e-6)
    gains = derive.eic_gains(robot, rate)
    assert "stick-slip" in gains.note
    ok, how = derive.eic_recovery(robot, gains.value, rate, qu0=d / 4, velocity_cutoff=wc)
    assert ok, how
    nominal_ok, _, tail = derive._recovery_run(robot, gains.value, rate, qu0=d / 4, velocity_cutoff=wc)
    assert not nominal_ok and d / 4 < tail <= d
    res = derive._recovery_sim(robot, gains.value, rate, qu0=d / 4, velocity_cutoff=wc, duration_s=3.0)
    last = res.t >= res.t[-1] - 1.0
    assert not res.fell
    assert np.max(np.abs(res.q[last].sum(axis=1))) < 0.01        # the pole's absolute angle: upright
    assert np.max(np.abs(res.q[last, 0])) > d / 4                # the shoulder stuck off rest
    smooth = _arm_with_friction(0.0)
    ok0, how0, tail0 = derive._recovery_run(smooth, gains.value, rate, qu0=d / 4, velocity_cutoff=wc)
    assert ok0 and tail0 <= d / 4, how0


def test_a_loop_off_its_bem_with_dry_friction_is_not_held():
    """The same arm and friction with the fastest continuous gains (ω_u ≈ 3.2 λ, ω_u/ω_a ≈ 12): q_u ends off
    nominal *and* off its BEM (the pole is not balanced over a stuck arm), so the friction does not excuse it."""
    from bemlearn.control.eic_linear import eic_fastest_gains

    robot = _arm_with_friction(0.08)
    rate = derive.control_rate(robot).value
    d = derive.design_region(robot).value
    wc = derive.closed_loop_sensor(robot, rate).value["velocity_cutoff"]
    lam = instability_rate(robot)
    w_u, w_a, _ = eic_fastest_gains(robot, lam, 2 * math.pi * rate.rate_hz / 20)
    gains = EICGains(kp_a=w_a**2, kd_a=2 * w_a, kp_u=w_u**2, kd_u=2 * w_u)
    ok, how = derive.eic_recovery(robot, gains, rate, qu0=d / 4, velocity_cutoff=wc)
    assert not ok and "no stick-slip cycle" in how, how


def test_the_confirming_trials_last_the_collection_trials_within_a_cap(monkeypatch):
    """The confirming batch of the excitation check plays the collection's trial length, at most CONFIRM_LENGTHS times the
    first batch's: a config asking for 100 000 s trials does not make the derivation play them."""
    import dataclasses

    @dataclasses.dataclass(frozen=True)
    class Collect:   # the two fields of CollectConfig the check reads and replaces
        amplitude: tuple[float, float]
        duration_s: float

    played = []

    def fell(robot, cfg, seqs):   # one of each batch falls: the first batch passes, the second confirms
        played.append(cfg.duration_s)
        return [True] + [False] * (len(seqs) - 1)

    monkeypatch.setattr(derive, "_trials_fell", fell)
    collect = Collect(amplitude=(0.01, 0.1), duration_s=100000.0)
    out = derive._excitation_amplitude_trials(None, collect, trials=4, duration_s=5.0, halvings=1)
    assert out.value == 1.0 and played == [5.0, derive.CONFIRM_LENGTHS * 5.0]
    assert "1/4 fall at A × 1 and 1/4 of 20 s trials" in out.note
    played.clear()
    short = Collect(amplitude=(0.01, 0.1), duration_s=8.0)
    derive._excitation_amplitude_trials(None, short, trials=4, duration_s=5.0, halvings=1)
    assert played == [5.0, 8.0]
    # a level at which none of the first batch fell is not confirmed (its 5 s fall rate is below 12 % at 95 %)
    played.clear()
    monkeypatch.setattr(derive, "_trials_fell", lambda robot, cfg, seqs: played.append(cfg.duration_s) or [False] * len(seqs))
    out = derive._excitation_amplitude_trials(None, collect, trials=4, duration_s=5.0, halvings=1)
    assert out.value == 1.0 and played == [5.0] and out.note.endswith("0/4 fall at A × 1")


def test_eic_gains_search_damping_ratios_where_no_critically_damped_pair_brings_the_robot_back(tmp_path):
    """Family robot (4, 9), a pendubot on a velocity servo at 294 Hz: two critically damped pairs of the grid make the
    sampled loop stable (decaying at 0.28 and 0.36 1/s) and neither brings the pole back from d/4 in MuJoCo; the
    second grid, with damping ratios (derive._damped_search), finds gains that do, k_d = 2 ζ ω with ζ ≠ 1."""
    from bemlearn.control.lqr import linearize

    robot, _ = _family_robot(tmp_path, 4, 9)
    rate = derive.control_rate(robot).value
    wc = derive.closed_loop_sensor(robot, rate).value["velocity_cutoff"]
    e0 = derive.design_region(robot).value / 4
    lam = instability_rate(robot)
    plant = linearize(robot, rate_hz=rate.rate_hz, timestep=rate.timestep)[:2]
    critical = [derive._loop_gains(wl * lam, r) for wl in derive.EIC_GRID_OMEGA_U for r in derive.EIC_GRID_RATIO
                if wl * lam <= 2 * math.pi * rate.rate_hz / 10]
    stable = [g for g in critical if eic_tick_loop(robot, g, rate_hz=rate.rate_hz, velocity_cutoff=wc, plant=plant).spectral_radius < 1]
    assert 0 < len(stable) <= derive.EIC_SEARCH_TRIES
    assert not any(derive.eic_recovery(robot, g, rate, qu0=e0, velocity_cutoff=wc)[0] for g in stable)
    got = derive.eic_gains(robot, rate)
    g = got.value
    w_u, w_a = math.sqrt(g.kp_u), math.sqrt(g.kp_a)
    zeta_u, zeta_a = g.kd_u / (2 * w_u), g.kd_a / (2 * w_a)
    assert (zeta_u, zeta_a) != pytest.approx((1.0, 1.0)) and "ζ_u" in got.note
    assert min(abs(zeta_u - z) for z in derive.EIC_GRID_DAMPING) < 1e-12
    assert eic_tick_loop(robot, g, rate_hz=rate.rate_hz, velocity_cutoff=wc, plant=plant).spectral_radius < 1
    assert derive.eic_recovery(robot, g, rate, qu0=e0, velocity_cutoff=wc)[0]
