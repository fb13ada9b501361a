"""Simulated excitation data collection in MuJoCo (paper Section IV-A).

Each trial runs the paper's excitation controller

    u = kᵀ e,   e = [q − q_t, q̂̇ − q̇_t]   (joint order, q_t = [q_a,t, q_u,nominal])

(u: one command per actuated coordinate, reaching the actuators as ctrl = W u, :mod:`bemlearn.robots.actuation`;
the log holds u, each coordinate's command as its first actuator received it)

around a reference q_a,t(t) that is a random sum of sines, at the control rate (400 Hz
for the Furuta) with the input held between ticks and clipped to the actuator range
(±10 V).  The controller sees only what a rig sees: quantized encoder angles and a
filtered velocity estimate (:mod:`bemlearn.data.sensors`).  Gains, sine amplitudes,
frequencies, phases and initial states are drawn per trial from configured ranges; a
trial ends when |q_u − q_u,nominal| leaves ``fall_window`` (it *fell*: kept up to the
fall and marked failed) or at ``duration_s``.

Only what a rig would log goes into the data file (time, quantized angles, commanded
inputs, trial id and outcome); the simulator's true q, q̇, q̈ go into a separate
ground-truth file (``<stem>.truth<suffix>``) for evaluation.

Trials are seeded from ``numpy.random.SeedSequence(seed).spawn(n_trials)``, so the result
does not depend on the number of worker processes.

Where the fixed gains do not hold the linearisation at a pose the reference reaches (a turntable's yaw turns the
pole's plane away from the slide that balanced it at 0), the gains are scheduled over that coordinate
(:func:`_gain_schedule`, :func:`~bemlearn.control.lqr.pose_gain_schedule`: u = (K + ΔK(q̂_a)) ∘ scale, the measured
pose in the tick); a hinge whose extent reaches :data:`SWEEP_SPAN` also sweeps it (:func:`_sweep_components`) to
rates beyond the stiffening speed, its own sines to the accelerations λ·√(a P) (:func:`_component_extent`), and the
balance along that known motion is the finite-horizon LQR of the tick maps at the reference's pose *and rate*
(:func:`_tracking_gains`, :func:`~bemlearn.control.lqr.tracking_gains`).  Every other robot's trials are unchanged,
draw for draw.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
from collections.abc import Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np
from tqdm.auto import tqdm

from bemlearn._version import __version__
from bemlearn.config import to_dict
from bemlearn.data.sensors import SensorConfig
from bemlearn.data.trajectory import Trajectory, TrajectoryMeta
from bemlearn.errors import ConfigError, DataError, RobotModelError
from bemlearn.robots.coordinates import CoordinatesConfig, coordinates_mapping
from bemlearn.units import q_unit_label
from bemlearn.warnings import DataWarning, warn

if TYPE_CHECKING:
    from bemlearn.robots.mujoco_robot import MujocoRobot

__all__ = ["CollectConfig", "TrialResult", "collect", "simulate_trial"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CollectConfig:
    """Excitation collection options (``collect:`` section of a pipeline config).

    Attributes:
        n_trials: number of trials.
        duration_s: time limit of a trial, s.
        rate_hz: control and logging rate, Hz (the physics steps ``1/(rate·timestep)`` times per tick) (``null``: derived from the model, see ``bemlearn config show``).
        fall_window: a trial falls when |q_u − nominal| exceeds this, in q_u's unit (``null``: derived from the model, see ``bemlearn config show``).
        gains: nominal k, row-major ``(m, 2n)`` for e = [q − q_t, q̇ − q̇_t] in joint order (``null``: derived from the model, see ``bemlearn config show``): a
            discrete LQR of MuJoCo's linearisation (``bemlearn robot lqr``).
        gain_scale: each gain is multiplied by U(lo, hi) per trial (``null``: derived from the model, see ``bemlearn config show``).
        n_sines: (min, max) number of sine components per actuated joint (``null``: derived from the model, see ``bemlearn config show``).
        amplitude: (min, max) amplitude of each component, in the actuated joints' units (``null``: derived from the model, see ``bemlearn config show``).
        frequency_hz: (min, max) frequency of each component, Hz (``null``: derived from the model, see ``bemlearn config show``).
        initial_qa, initial_qu: (min, max) initial actuated / unactuated coordinates, in their units (``null``: derived from the model, see ``bemlearn config show``).
        input_units: unit of the logged inputs, e.g. ``V`` for a motor driven in volts (``null``: derived from the model, see ``bemlearn config show``).
        reference_bem: ``[]``: the paper's excitation (q_u target at nominal).  Else the linearised BEM (eq. 9) at upright,
            s_p, s_v, s_a per actuated coordinate, then λ (1/s): the q_u target is the periodic motion of q_u the actuated
            sines drive (:func:`_trajectory_reference`; with ``excursion``, the slopes' change with the pose from the
            model added, :func:`_pose_slopes`), and the command carries the model's inverse dynamics along that
            reference, u = u_ff(q_t, q̇_t, q̈_t) + kᵀe, so that each actuated direction follows its own sines instead of
            the LQR cancelling one joint's reference with another's (``null``: derived from the model, see ``bemlearn config show``).
        excursion: ``[]``: every component's amplitude is drawn from ``amplitude`` (rad or m, shared by the actuated
            coordinates).  Else per actuated coordinate j its position extent P_j, then its acceleration extent a_j
            (2m values, its units): a component at ω on coordinate j has amplitude U(amplitude) · min(P_j, a_j/ω²),
            ``amplitude`` then a dimensionless fraction, so that each direction moves within its own scales whatever
            the frequency; two of them become a slow and a fast anchor that bring q_a,j and q̈_a,j to their extents
            together (:func:`_two_band`) (``null``: derived from the model, see ``bemlearn config show``).
        seed: master seed.
        workers: processes (0 = one per core, 1 = in-process).
        sensor: the encoder and velocity-filter model.
        physics_timestep: physics step, s (``null``: the model file's; derived finer when the file's step is
            coarser than the control rate needs).
    """

    n_trials: int = 24
    duration_s: float = 20.0
    rate_hz: float | None = None
    fall_window: float | None = None
    gains: tuple[float, ...] | None = None
    gain_scale: tuple[float, float] | None = None
    n_sines: tuple[int, int] | None = None
    amplitude: tuple[float, float] | None = None
    frequency_hz: tuple[float, float] | None = None
    initial_qa: tuple[float, float] | None = None
    initial_qu: tuple[float, float] | None = None
    input_units: str | None = None
    reference_bem: tuple[float, ...] | None = None
    excursion: tuple[float, ...] | None = None
    seed: int = 0
    workers: int = 0
    sensor: SensorConfig = field(default_factory=SensorConfig)
    physics_timestep: float | None = None

    def __post_init__(self) -> None:
        if self.n_trials < 1:
            raise ConfigError(f"collect.n_trials must be ≥ 1, got {self.n_trials}")
        if self.duration_s <= 0 or (self.rate_hz is not None and self.rate_hz <= 0) or (self.fall_window is not None and self.fall_window <= 0):
            raise ConfigError("collect.duration_s, rate_hz and fall_window must be > 0")
        for name in ("gain_scale", "n_sines", "amplitude", "frequency_hz", "initial_qa", "initial_qu"):
            if getattr(self, name) is None:
                continue
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ConfigError(f"collect.{name}: expected (min, max) with min ≤ max, got {(lo, hi)}")
        if self.n_sines is not None and self.n_sines[0] < 1:
            raise ConfigError(f"collect.n_sines: need at least one sine, got {self.n_sines}")


@dataclass(frozen=True)
class TrialResult:
    """One simulated trial: logged and true signals, all ``(T, ·)`` float64."""

    trial_id: int
    failed: bool
    t: np.ndarray
    q_meas: np.ndarray
    u: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray


def _robot_and_model(robot_name: str, coordinates: Mapping[str, Any] | None = None):
    from bemlearn.robots import MujocoRobot, load

    robot = load(robot_name, coordinates=coordinates)
    if not isinstance(robot, MujocoRobot):
        raise RobotModelError(f"collect: robot {robot_name!r} has no MuJoCo model to simulate; give an MJCF robot (a registry name or a path to an .xml file)")
    return robot


def simulate_trial(robot: MujocoRobot, config: CollectConfig, trial_id: int, seed_seq: np.random.SeedSequence) -> TrialResult:
    """Run one excitation trial (module docstring) and return its logged and true signals."""
    from bemlearn.sim.plant import SensedPlant  # here: the plant loads torch

    rng = np.random.default_rng(seed_seq)
    # every field is set (collect() checks it; complete_section derives them)
    assert config.rate_hz is not None and config.fall_window is not None and config.gains is not None
    assert config.gain_scale is not None and config.n_sines is not None and config.amplitude is not None
    assert config.frequency_hz is not None and config.initial_qa is not None and config.initial_qu is not None
    model, n, m = robot.model, robot.n, robot.m
    plant = SensedPlant(robot, rate_hz=config.rate_hz, sensor=config.sensor, rng=rng, where="collect", timestep=config.physics_timestep)
    dt = plant.dt
    K = np.asarray(config.gains, dtype=np.float64)
    if K.size != m * 2 * n:
        raise ConfigError(f"collect.gains: expected m·2n = {m * 2 * n} values for robot {robot.name!r}, got {K.size}")
    K0 = K.reshape(m, 2 * n)
    K_scale = rng.uniform(*config.gain_scale, size=(m, 2 * n))
    K = K0 * K_scale
    # reference: per actuated joint a random sum of sines
    comps = _draw_sines(config, m, rng)
    if config.excursion:
        ext = np.asarray(config.excursion, dtype=np.float64)
        if ext.size != 2 * m or not np.all(ext > 0):
            raise ConfigError(f"collect.excursion: expected 2·m = {2 * m} positive extents (positions, then accelerations) or [], got {list(ext)}")
    ia, iu = list(robot.actuated_index), robot.unactuated_index
    pose = None
    if config.reference_bem and config.excursion:
        pose = _pose_slopes(robot, np.asarray(config.excursion, dtype=np.float64)[:m], float(config.reference_bem[-1]))
    if config.excursion:
        swept_j = _swept(robot, config, pose)
        comps = [(A * _component_extent(config, j, w, swept), w, ph) for j, ((A, w, ph), swept) in enumerate(zip(comps, swept_j))]
        comps = [c if swept else _two_band(config, j, c, rng) for j, (c, swept) in enumerate(zip(comps, swept_j))]
    # the balance: scheduled over the pose where the fixed gains fail there; a swept hinge's known motion gets the
    # LQR along it (_tracking_gains), else the sweep's rate is bounded by the turning rate the schedule holds
    schedule = _gain_schedule(robot, config, K0, turning=False)
    tracked = _tracked_hinge(robot, config, pose, schedule)
    if tracked is None and schedule is not None:
        schedule = _gain_schedule(robot, config, K0)
    sweep = _sweep_components(robot, config, rng, pose, schedule)
    stiff_v = None
    if sweep is not None:
        from bemlearn.robots.scales import velocity_stiffening_speed

        comps = [(np.append(A * keep, a_s), np.append(w, w_s), np.append(ph, p_s)) if a_s > 0 else (A, w, ph)
                 for (A, w, ph), (a_s, w_s, p_s, keep) in zip(comps, sweep)]
        stiff_v = velocity_stiffening_speed(robot)
    traj = _trajectory_reference(config.reference_bem, comps, m)
    along = None if tracked is None or sweep is None else _tracking_gains(robot, config, tracked, comps[tracked])
    if traj is None:
        pose = None
    inverse = None
    if traj is not None:
        from bemlearn.control.actuator_inverse import MujocoActuatorInverse  # the model's feedforward along the reference

        inverse = MujocoActuatorInverse(robot)
    q0 = np.zeros(n)
    q0[ia] = rng.uniform(*config.initial_qa, size=m)
    q0[iu] = robot.qu_nominal + rng.uniform(*config.initial_qu)
    qd0 = None
    if traj is not None:  # start on the reference (its initial state plus the drawn offsets)
        r0 = _reference_state(0.0, comps, traj, ia, iu, n, robot.qu_nominal, pose, stiff_v)
        q0 += r0[0] - np.where(np.arange(n) == iu, robot.qu_nominal, 0.0)
        qd0 = r0[1]
    plant.reset(q0, qd0)
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    limited = model.actuator_ctrllimited.astype(bool)
    groups = robot.actuation   # one command per actuated coordinate: ctrl = W u
    n_ticks = int(round(config.duration_s * config.rate_hz))
    rec = {k: np.empty((n_ticks, w)) for k, w in (("q_meas", n), ("u", m), ("q", n), ("qd", n), ("qdd", n))}
    failed = False
    k = n_ticks
    for tick in range(n_ticks):
        t = tick * dt
        q_true = plant.true_q()
        if not abs(q_true[iu] - robot.qu_nominal) <= config.fall_window:  # also catches NaN
            failed, k = True, tick
            break
        y, v = plant.measure(q_true)
        q_ref, qd_ref, qdd_ref = _reference_state(t, comps, traj, ia, iu, n, robot.qu_nominal, pose, stiff_v)
        if along is not None:
            Kt = (K0 + along[tick]) * K_scale
        else:
            Kt = K if schedule is None else (K0 + schedule.delta(y[ia])) * K_scale
        ctrl = groups.ctrl(Kt @ np.concatenate([y - q_ref, v - qd_ref]))
        if inverse is not None:
            D, h = robot.terms(q_ref, qd_ref)
            ctrl = ctrl + inverse.command((D @ qdd_ref + h)[ia], q_ref, qd_ref, clip=False)
        ctrl = np.where(limited, np.clip(ctrl, lo, hi), ctrl)
        if not np.all(np.isfinite(ctrl)):  # diverged state: never hand MuJoCo a non-finite ctrl
            failed, k = True, tick
            break
        u = groups.command_of(ctrl)   # the logged input: each coordinate's command (its first actuator's ctrl)
        qd, qdd = plant.apply(ctrl)
        rec["q_meas"][tick], rec["u"][tick], rec["q"][tick], rec["qd"][tick], rec["qdd"][tick] = y, u, q_true, qd, qdd
    times = np.arange(k) * dt
    return TrialResult(trial_id, failed, times, *(rec[name][:k] for name in ("q_meas", "u", "q", "qd", "qdd")))


def _draw_sines(config: CollectConfig, m: int, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per actuated coordinate its reference's sines ``(A, ω, φ)`` (``(k,)`` each): k ~ U{``n_sines``}, A ~ U(``amplitude``),
    ω = 2π U(``frequency_hz``), φ ~ U(0, 2π); the counts of all m coordinates are drawn first."""
    assert config.n_sines is not None and config.amplitude is not None and config.frequency_hz is not None
    n_sines = rng.integers(config.n_sines[0], config.n_sines[1] + 1, size=m)
    return [(rng.uniform(*config.amplitude, size=k), 2 * math.pi * rng.uniform(*config.frequency_hz, size=k), rng.uniform(0, 2 * math.pi, size=k))
            for k in n_sines]


def _gain_schedule(robot: MujocoRobot, config: CollectConfig, K: np.ndarray, *, turning: bool = True):
    """The excitation balance scheduled over the actuated pose (:func:`~bemlearn.control.lqr.pose_gain_schedule`), or
    ``None`` where the fixed gains ``K (m, 2n)`` stabilise the linearisation at every pose the reference reaches (each
    coordinate's ``excursion`` extent, or with the paper's excitation n_max × the top amplitude).  The design is the
    derived one's: |q_u| ≤ d (:func:`~bemlearn.robots.scales.design_bound`), a d/4 q_u start, the ``initial_qa`` start.
    With ``excursion`` and ``turning``, an unlimited hinge's rates to √(a_j P_j) are checked too: the schedule's
    ``turn_rate``, the rate to which it holds turning steadily (a trial's ``duration_s`` the horizon), bounds the sweep
    (:func:`_sweep_components`) where no LQR along the sweep holds it (:func:`_tracked_hinge`)."""
    from bemlearn.control.lqr import pose_gain_schedule
    from bemlearn.robots.scales import design_bound

    assert config.rate_hz is not None and config.n_sines is not None and config.amplitude is not None and config.initial_qa is not None
    m = robot.m
    rates = None
    if config.excursion:
        ext = np.asarray(config.excursion, dtype=np.float64)
        extents = ext[:m]
        if turning:
            rates = np.sqrt(ext[:m] * ext[m:2 * m])   # the components' and a sweep's speed bound √(a P)
    else:
        extents = np.full(m, config.n_sines[1] * config.amplitude[1])
    d = design_bound(robot)
    qa0 = float(config.initial_qa[1]) or None
    return pose_gain_schedule(robot, K, rate_hz=config.rate_hz, timestep=config.physics_timestep, extents=extents,
                              design_qu=d, qu0=d / 4, qa0=qa0, rates=rates, horizon_s=config.duration_s)


def _component_extent(config: CollectConfig, j: int, w: np.ndarray, swept: bool) -> np.ndarray:
    """``(k,)`` the extent a sine at ω (``w (k,)``, rad/s) on actuated coordinate j multiplies its drawn amplitude by
    (``collect.excursion``: P_j, then a_j):

        min(P_j, a_j/ω²)                     its position and acceleration extents, or on a swept hinge (:func:`_swept`)
        min(P_j, λ V_j/ω², V_j/ω)            V_j = √(a_j P_j), λ = ``reference_bem``'s instability rate

    a_j of a hinge that does not move the BEM at rest (a turntable's yaw) keeps its speed √(a_j P_j) within the
    stiffening speed; as an acceleration bound it leaves the yaw's own sines at a_j ≪ λ v_j, the accelerations the design
    region asks for (:func:`~bemlearn.pipeline.design_evaluation.design_grid`).  The GP then curved away beyond the data:
    ``fam0_017`` (yaw accelerations to 9.5 rad/s² (95 %) of the box's 29) had errors of 0.034 rad RMSE at |ψ̈| = 30–50
    against 0.0065 at |ψ̈| < 5, where the BEM does not depend on ψ̈ at all.  The swept hinge's own sines then reach the
    accelerations λ V_j at the speeds V_j."""
    ext = np.asarray(config.excursion, dtype=np.float64)
    m = ext.size // 2
    P, a = float(ext[j]), float(ext[m + j])
    if not swept or not config.reference_bem:
        return np.minimum(P, a / w**2)
    V, lam = math.sqrt(a * P), float(config.reference_bem[-1])
    return np.minimum(np.minimum(P, lam * V / w**2), V / w)


#: The two anchor components of a coordinate's sines (:func:`_two_band`) take U(lo, hi) of its extent at the derived
#: level (the level check's factor scales them with ``collect.amplitude``).
ANCHOR_FRACTION = (0.6, 0.9)


def _two_band(config: CollectConfig, j: int, comp: tuple, rng: np.random.Generator) -> tuple:
    """Actuated coordinate j's sines ``comp = (A, ω, φ)`` (``(k,)`` each, after :func:`_component_extent`) with a slow
    and a fast anchor, so that its position and acceleration reach their extents *together* (``collect.excursion``: P_j,
    a_j; ω_lo, ω_hi from ``frequency_hz``):

        ω₀ = ω_lo (ω_c/ω_lo)^(u/2),   A₀ = f₀ P_j                 (a slow sine: q to f₀ P_j, q̈ ≪ a_j)
        ω₁ = ω_hi (ω_c/ω_hi)^(u'/2),  A₁ = f₁ a_j/ω₁²             (a fast sine: q̈ to f₁ a_j, q ≪ P_j)
        ω_c = √(a_j/P_j),  f₀, f₁ ~ κ U(:data:`ANCHOR_FRACTION`),  κ = √n_max × ``amplitude``'s top,  u, u' ~ U(0, 1)

    and the other components at half their drawn amplitude.  One sine has q̈ = −ω² q: it never puts position and
    acceleration at their extents with the same sign, and a sum of k sines of similar fractions (U(0.2, 1)/√n_max
    each) rarely puts either at its extent; but the design region's worst points lie where every actuated input is
    at its edge at once (docs/family.md: on a two-link arm, 1–2 % of the samples had |q| and |q̈| beyond half their
    extents with the same sign, and the design queries' nearest samples lay about 2 box half-widths away).  Two sines far
    apart in frequency put (q, q̈) on nearly the product of their ranges: the slow anchor's acceleration is at most
    (ω₀/ω_c)² ≤ ω_lo/ω_c of a_j and the fast one's excursion at most (ω_c/ω₁)² ≤ ω_c/ω_hi of P_j (on a two-link arm
    of the robot family about 0.15 and 0.4: the band ω_hi/ω_lo is 15, the balance's own).  κ = 1 at the derived
    level; the excitation level check's halvings of ``amplitude`` halve it too.  A coordinate whose crossover ω_c lies
    outside (ω_lo, ω_hi), or with a single component, keeps its sines."""
    assert config.n_sines is not None and config.amplitude is not None and config.frequency_hz is not None
    A, w, ph = (np.array(x, dtype=np.float64) for x in comp)
    ext = np.asarray(config.excursion, dtype=np.float64)
    m = ext.size // 2
    P, a = float(ext[j]), float(ext[m + j])
    w_lo, w_hi = 2 * math.pi * float(config.frequency_hz[0]), 2 * math.pi * float(config.frequency_hz[1])
    w_c = math.sqrt(a / P)
    if A.size < 2 or not w_lo < w_c < w_hi:
        return comp
    kappa = math.sqrt(config.n_sines[1]) * float(config.amplitude[1])
    u = rng.uniform(size=2)
    f = kappa * rng.uniform(*ANCHOR_FRACTION, size=2)
    w[0] = w_lo * (w_c / w_lo) ** (0.5 * u[0])
    w[1] = w_hi * (w_c / w_hi) ** (0.5 * u[1])
    A[2:] *= 0.5
    A[0] = f[0] * P
    A[1] = f[1] * a / w[1] ** 2
    return (A, w, ph)


def _trajectory_reference(reference_bem: tuple[float, ...] | None, comps: list, m: int) -> list | None:
    """Per actuated coordinate j and sine component k the complex gain of the q_u target (``collect.reference_bem``):

        G_jk = (s_p,j + i ω_k s_v,j − s_a,j ω_k²) / (1 + ω_k²/λ²)

    the periodic solution of the unactuated row linearised at upright (D_uu q̈_u − Γ_q δq_u = −Γ_q × the BEM's
    linear part, λ² = Γ_q/D_uu) driven by q_a,j = A sin(ω_k t + φ): the reference is then a motion the robot
    can follow, and the feedforward (:func:`simulate_trial`) realises it.  ``None``: the paper's excitation."""
    if not reference_bem:
        return None
    S = np.asarray(reference_bem, dtype=np.float64)
    if S.size != 3 * m + 1 or not np.all(np.isfinite(S)) or not S[-1] > 0:
        raise ConfigError(f"collect.reference_bem: expected 3·m + 1 = {3 * m + 1} finite values (s_p, s_v, s_a per actuated "
                          f"coordinate, then λ > 0 in 1/s) or [], got {list(S)}")
    sp, sv, sa, lam = S[:m], S[m:2 * m], S[2 * m:3 * m], float(S[-1])
    return [(sp[j] + 1j * w * sv[j] - sa[j] * w**2) / (1 + (w / lam) ** 2) for j, (_, w, _) in enumerate(comps)]


def _reference_state(t: float, comps: list, traj: list | None, ia: list[int], iu: int, n: int,
                     qu_nominal: float, pose: tuple | None = None, stiff_v: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(q_t, q̇_t, q̈_t)`` (n,) each: the actuated sines and the q_u target (nominal, or on the periodic BEM motion).

    ``stiff_v`` ``(m,)`` (with a sweep, :func:`_sweep_components`): the speeds that double the upright's stiffness
    (:func:`~bemlearn.robots.scales.velocity_stiffening_speed`); the target's offset from nominal is divided by
    Γ_q(q̇_t)/Γ_q(0) = 1 + Σ_j (q̇_t,j/v_j)² (a turntable turning at ψ̇: tan θ (m l g + ψ̇² J) ≈ m l a), the
    reference's rate varying slowly against the target's components.

    ``pose`` (:func:`_pose_slopes`): the BEM slopes change with the actuated pose; the target's gains
    (:func:`_trajectory_reference`) then take the slopes at the reference's own pose q_a,t (a turntable at ψ: the
    slides' s_a = (cos ψ, sin ψ)/g), the pose varying slowly against the components."""
    out = np.zeros((3, n))
    out[0, iu] = qu_nominal
    for j, (A, w, ph) in zip(ia, comps):
        s_ = np.sin(w * t + ph)
        out[:, j] = (np.sum(A * s_), np.sum(A * w * np.cos(w * t + ph)), -np.sum(A * w**2 * s_))
    if traj is not None:
        gains = traj
        if pose is not None:
            grids, deltas, lam = pose
            ds = np.zeros(deltas[0].shape[1])  # (3m,) the slopes' change at q_a,t: s_p, s_v, s_a per coordinate
            for i, j in enumerate(ia):
                ds += np.array([np.interp(out[0, j], grids[i], deltas[i][:, r]) for r in range(ds.size)])
            m = len(ia)
            gains = [G + (ds[k] + 1j * w * ds[m + k] - ds[2 * m + k] * w**2) / (1 + (w / lam) ** 2)
                     for k, (G, (_, w, _)) in enumerate(zip(traj, comps))]
        for (A, w, ph), G in zip(comps, gains):
            e = G * A * np.exp(1j * (w * t + ph))
            out[:, iu] += (np.sum(e.imag), np.sum((1j * w * e).imag), np.sum((-(w**2) * e).imag))
        if stiff_v is not None:
            rate = out[1, ia] / stiff_v
            out[:, iu] = np.array([qu_nominal, 0.0, 0.0]) + (out[:, iu] - np.array([qu_nominal, 0.0, 0.0])) / (1.0 + float(np.sum(rate**2)))
    return out[0], out[1], out[2]


def _sweep_components(robot: MujocoRobot, config: CollectConfig, rng: np.random.Generator, pose: tuple | None,
                      schedule=None) -> list | None:
    """Per actuated coordinate ``(A_s, ω_s, φ_s, keep)``: one more sine for a hinge whose pose turns the BEM's slopes
    (``pose``, :func:`_pose_slopes`: a turntable's yaw) over an ``excursion`` extent P_j ≥ :data:`SWEEP_SPAN`
    (A_s = 0 elsewhere): A_s = P_j (0.75 P_j on a limited joint, whose own sines are then halved, ``keep`` = 0.5, to
    stay off its stops) at ω_s = Ω/A_s, Ω ~ U(0.5, 1) Ω_top, φ_s ~ U(0, 2π).  Ω_top = :data:`SWEEP_REACH` × v_j, v_j the
    speed that doubles the upright's stiffness (:func:`~bemlearn.robots.scales.velocity_stiffening_speed`), which the
    design region's rates reach (:func:`~bemlearn.pipeline.design_evaluation.design_grid`): a sine's rate dwells at its
    peak, and the data then cover the region to its edge (``fam0_029``, Ω_top = √(a P) = 5.7 rad/s of v = 6.8: errors
    to 0.068 rad at |ψ̇| = 6–6.8); √(a_j A_s) where v_j is infinite.  The sines shared among n components (each ≤
    P_j/√n_max) keep such a coordinate near its start — a turntable's yaw within ±1.9 rad and its rate below 3.3 rad/s of
    the ±π and 5.6 rad/s its design region spans (measured on ``fam0_005``); the sweep visits the whole extent at rates
    up to that speed.  ``None`` (no draw from ``rng``) where no coordinate sweeps: every other robot's trials are
    unchanged.

    The balance that holds these turns is the LQR along the trial's known reference (:func:`_tracking_gains`).  Where
    there is none (several swept hinges) and the excitation's gain ``schedule`` (:func:`_gain_schedule`) gives one, the
    peak rate is also bounded by the largest steady rate at which the balance, scheduled over the pose at rest, still
    holds turning (:func:`~bemlearn.control.lqr.turning_rate_limit`, ``GainSchedule.turn_rate``): Ω ~ U(0.5, 1)
    min(Ω_top, Ω_hold).  Turning at ψ̇ turns the pole's plane under the slides' loop; on ``fam0_029`` (Ω_hold 1.73 rad/s)
    17 of 24 trials fell at 5.7 rad/s with that schedule, with the slides running off their references while the weak
    yaw servo followed its own."""
    turns = _swept(robot, config, pose)
    if not any(turns):
        return None
    from bemlearn.robots.scales import qa_limited

    m = robot.m
    ext = np.asarray(config.excursion, dtype=np.float64)
    limited = qa_limited(robot)
    amp = np.where(limited, 0.75, 1.0) * ext[:m]
    top = sweep_top(robot, config)
    if schedule is not None and schedule.turn_rate is not None:
        for i, hold in zip(schedule.coords, schedule.turn_rate):
            if hold is not None:
                top[i] = min(top[i], hold)
    rate = rng.uniform(0.5, 1.0, size=m) * top
    phase = rng.uniform(0.0, 2 * math.pi, size=m)
    return [(float(amp[j]), float(rate[j] / amp[j]), float(phase[j]), 0.5 if limited[j] else 1.0) if turns[j]
            else (0.0, 0.0, 0.0, 1.0) for j in range(m)]


def _swept(robot: MujocoRobot, config: CollectConfig, pose: tuple | None) -> list[bool]:
    """Per actuated coordinate whether the excitation sweeps it (:func:`_sweep_components`): a hinge whose pose turns
    the BEM's slopes (``pose``, :func:`_pose_slopes`; by more than 10⁻³ of the largest change) over an ``excursion``
    extent P_j ≥ :data:`SWEEP_SPAN`.  All ``False`` without ``excursion`` or ``pose``."""
    m = robot.m
    if not config.excursion or pose is None:
        return [False] * m
    ext = np.asarray(config.excursion, dtype=np.float64)
    kinds = tuple(getattr(robot, "coordinate_kinds", ()))
    deltas = pose[1]
    scale = max(float(np.max(np.abs(d))) for d in deltas) or 1.0
    return [len(kinds) == robot.n and kinds[robot.actuated_index[j]] == "hinge" and bool(ext[j] >= SWEEP_SPAN)
            and float(np.max(np.abs(deltas[j]))) > 1e-3 * scale for j in range(m)]


def _tracked_hinge(robot: MujocoRobot, config: CollectConfig, pose: tuple | None, schedule) -> int | None:
    """The swept hinge (:func:`_swept`) whose balance is the LQR along its known motion (:func:`_tracking_gains`): the
    one swept coordinate, where the gain ``schedule`` (:func:`_gain_schedule`) holds it (its pose changes the
    linearisation); ``None`` otherwise (no sweep, or several: the schedule over the pose and the sweep's rate bounded
    by the turning rate it holds)."""
    swept = [j for j, s in enumerate(_swept(robot, config, pose)) if s]
    if len(swept) != 1 or schedule is None or swept[0] not in schedule.coords:
        return None
    return swept[0]


def _tracking_gains(robot: MujocoRobot, config: CollectConfig, j: int, comps_j: tuple) -> np.ndarray:
    """ΔK ``(T, m, 2n)`` per tick of a trial (T = ``duration_s`` × ``rate_hz``, collect's convention): the balance along the
    swept hinge j's reference q_t,j(t) = Σ_k A_k sin(ω_k t + φ_k) (``comps_j``, the sweep included), the finite-horizon
    LQR of the tick maps linearised at that reference's pose *and rate* (:func:`~bemlearn.control.lqr.tracking_gains`,
    the rest design's weights) less the rest design's gains.

    Turning at ψ̇ turns the pole's plane under the slides' loop, and the gains of a steady turn differ strongly between
    +ψ̇ and −ψ̇ (the slides' slow position modes anticipate the turn); the sweep reverses.  The LQR along the known
    reference anticipates exactly the turns it will make: on ``fam0_029`` (weak yaw servo, position-servo slides) 0 of
    24 trials fell with the sweep at its full rate (√(a P) = 5.7 rad/s), 17 with the pose schedule.  The recursion starts
    at P = Q a tail of 5 × the rest loop's slowest time constant after the trial's end (:class:`~bemlearn.control.lqr
    .TurningMaps` ``settle_s``; it forgets its start at twice that rate), at most the trial's length
    (:func:`tail_ticks`).  The maps' rates reach the reference's bound: the sweep's Ω_top (:func:`sweep_top`) and n_max × the top amplitude × √(a_j P_j) of the joint's own sines
    (:func:`_component_extent`)."""
    from bemlearn.control.lqr import tracking_gains, turning_maps
    from bemlearn.robots.scales import design_bound

    assert config.rate_hz is not None and config.initial_qa is not None and config.n_sines is not None and config.amplitude is not None
    m = robot.m
    ext = np.asarray(config.excursion, dtype=np.float64)
    own = config.n_sines[1] * config.amplitude[1] * math.sqrt(ext[j] * ext[m + j])
    d = design_bound(robot)
    qa0 = float(config.initial_qa[1]) or None
    maps = turning_maps(robot, j=j, extent=float(ext[j]), rate_max=float(sweep_top(robot, config)[j]) + own, rate_hz=config.rate_hz,
                        timestep=config.physics_timestep, design_qu=d, qu0=d / 4, qa0=qa0)
    n_ticks = int(round(config.duration_s * config.rate_hz))
    t = np.arange(n_ticks + tail_ticks(maps.settle_s, config.rate_hz, n_ticks)) / config.rate_hz
    A, w, ph = comps_j
    arg = w[None, :] * t[:, None] + ph[None, :]
    G = tracking_gains(maps, np.sin(arg) @ A, np.cos(arg) @ (A * w))
    return G[:n_ticks] - maps.K_rest


def tail_ticks(settle_s: float, rate_hz: float, n_ticks: int) -> int:
    """The ticks :func:`_tracking_gains`' backward recursion runs past a trial of ``n_ticks`` ticks: 5 × the rest loop's
    slowest time constant ``settle_s`` (s) at ``rate_hz``, at most the trial's own length.  On the robot family the
    time constants were 0.5–0.9 s (tails of 2.5–4.5 s against trials of 20 s, never capped); a rest design whose R
    was raised far to stay within the actuator limits can have a mode slower than the trial itself (one generated
    turntable: 1400 s, a tail of 7.3 M ticks whose interpolated maps took 3.5 GB each, and two collection workers were
    killed for memory).  There the gains along the trial depend on the recursion's start whatever the tail, and a
    tail as long as the trial keeps the cost bounded."""
    return min(int(math.ceil(5 * settle_s * rate_hz)), int(n_ticks))


def sweep_top(robot: MujocoRobot, config: CollectConfig) -> np.ndarray:
    """``(m,)`` the sweep's top peak rate Ω_top per actuated coordinate (:func:`_sweep_components`; its unit per s):
    :data:`SWEEP_REACH` × the stiffening speed v_j where that is finite, else √(a_j A_s) (A_s = P_j, 0.75 P_j on a
    limited joint; ``collect.excursion``)."""
    from bemlearn.robots.scales import qa_limited, velocity_stiffening_speed

    m = robot.m
    ext = np.asarray(config.excursion, dtype=np.float64)
    amp = np.where(qa_limited(robot), 0.75, 1.0) * ext[:m]
    v = velocity_stiffening_speed(robot)
    return np.where(np.isfinite(v), SWEEP_REACH * np.where(np.isfinite(v), v, 0.0), np.sqrt(amp * ext[m:2 * m]))


#: The sweep's peak rate reaches this × the stiffening speed v_j (:func:`sweep_top`): the design region's rates reach
#: v_j, and the data reach a little beyond its edge.
SWEEP_REACH = 1.1

#: A hinge whose pose turns the BEM's slopes sweeps its extent when that is at least this (rad): beyond it cos and sin
#: of the pose are far from linear, and sines shared among components leave most of the extent unvisited.
SWEEP_SPAN = 1.0


_POSE_SLOPES: dict = {}


def _pose_slopes(robot: MujocoRobot, extents: np.ndarray, lam: float, *, points: int = 49) -> tuple | None:
    """How the BEM slopes (eq. 9 linearised, :func:`~bemlearn.robots.scales.bem_slopes`) change with the actuated pose:
    per actuated coordinate i alone on a grid over ±1.5 P_i (``extents``), Δs_i(q) = s(q e_i) − s(0), ``(points, 3m)``;
    the slopes at a pose are s(0) + Σ_i Δs_i(q_a,i).  ``None`` where no slope changes by more than 10⁻⁶ of the largest
    (a cart's: the q_u target is then exactly the one of constant slopes).  Cached per robot and extents.

    Returns ``(grids, deltas, λ)``: ``grids`` m arrays (points,), ``deltas`` m arrays (points, 3m)."""
    from bemlearn.robots.scales import bem_slopes

    key = (robot.name, robot.model.nq, tuple(float(x) for x in extents), float(lam), points)
    if key in _POSE_SLOPES:
        return _POSE_SLOPES[key]
    m = robot.m
    s0 = bem_slopes(robot)
    grids, deltas = [], []
    for i in range(m):
        g = np.linspace(-1.5 * extents[i], 1.5 * extents[i], points)
        rows = np.zeros((points, 3 * m))
        for k, q in enumerate(g):
            at = np.zeros((3, m))
            at[0, i] = q
            try:
                rows[k] = (bem_slopes(robot, at=at) - s0).ravel()
            except RobotModelError:  # no BEM near upright at that pose: keep the slopes at rest there
                rows[k] = 0.0
        grids.append(g)
        deltas.append(rows)
    scale = float(np.max(np.abs(s0))) or 1.0
    out = (grids, deltas, lam) if max(float(np.max(np.abs(d))) for d in deltas) > 1e-6 * scale else None
    _POSE_SLOPES[key] = out
    return out


_WORKER_ROBOT = None


def _worker_init(robot_name: str, parent_pid: int, coordinates: Mapping[str, Any] | None = None) -> None:
    global _WORKER_ROBOT
    from bemlearn.child_processes import die_with_parent

    die_with_parent(parent_pid)  # ends with the parent whatever ends it (SIGTERM, kill -9); ignores Ctrl-C
    _WORKER_ROBOT = _robot_and_model(robot_name, coordinates)


def _worker_run(args) -> TrialResult:
    config, trial_id, seq = args
    assert _WORKER_ROBOT is not None, "the pool's initializer loads the robot"
    return simulate_trial(_WORKER_ROBOT, config, trial_id, seq)


def collect(robot_name: str, config: CollectConfig, *, progress: bool = True,
            coordinates: CoordinatesConfig | Mapping[str, Any] | None = None) -> tuple[Trajectory, Trajectory]:
    """Run all trials; return ``(data, ground_truth)`` trajectories.

    ``robot_name``: a registry name or MJCF path; ``coordinates``: the config's ``coordinates:`` block for an
    MJCF path (:mod:`bemlearn.robots.coordinates`).

    ``data`` holds what a rig logs (quantized angles, inputs, trial outcome); ``ground_truth``
    the same rows with the simulator's true q, q̇, q̈.  Trials shorter than 10 samples
    (a fall right at the start) are dropped and counted in the log and in
    ``meta.extra["dropped_trials"]``.
    """
    coords = coordinates_mapping(coordinates)
    robot = _robot_and_model(robot_name, coords)
    unset = [f.name for f in dataclasses.fields(config) if getattr(config, f.name) is None and f.name != "physics_timestep"]
    if unset:
        raise ConfigError(f"collect: {unset} not set; derive them from the model with "
                         "bemlearn.pipeline.complete_section(robot, 'collect', config) (as every pipeline command does) or give them")
    assert config.rate_hz is not None and config.input_units is not None  # checked just above
    seqs = np.random.SeedSequence(config.seed).spawn(config.n_trials)
    jobs = [(config, i, s) for i, s in enumerate(seqs)]
    workers = config.workers or (os.cpu_count() or 1)
    workers = max(1, min(workers, config.n_trials))
    bar = tqdm(total=config.n_trials, desc="collect trials", unit="trial", disable=not progress)
    results: list[TrialResult] = []
    if workers == 1:
        for job in jobs:
            results.append(simulate_trial(robot, *job))
            bar.update()
    else:
        import multiprocessing as mp

        ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
        pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_worker_init, initargs=(robot_name, os.getpid(), coords))
        try:
            for res in pool.map(_worker_run, jobs, chunksize=1):
                results.append(res)
                bar.update()
        except BaseException:  # Ctrl-C or a failed trial: do not wait for the queued trials
            for proc in list(getattr(pool, "_processes", {}).values()):
                proc.terminate()
            pool.shutdown(wait=False, cancel_futures=True)
            bar.close()
            raise
        pool.shutdown()
    bar.close()
    kept = [r for r in results if r.t.size >= 10]
    dropped = [r.trial_id for r in results if r.t.size < 10]
    if dropped:
        warn(DataWarning, log, "collect: dropped %d trial(s) that fell within 10 samples: %s", len(dropped), dropped)
    if not kept:
        raise DataError("collect: every trial fell immediately; check the gains and initial ranges")
    n_failed = sum(r.failed for r in kept)
    log.info("collect: %d trials, %d fell, %d samples", len(kept), n_failed, sum(r.t.size for r in kept))
    cat = lambda name: np.concatenate([getattr(r, name) for r in kept])  # noqa: E731
    trial = np.concatenate([np.full(r.t.size, r.trial_id, dtype=np.int64) for r in kept])
    meta = TrajectoryMeta(
        robot=robot.name,
        joint_names=robot.joint_names,
        unactuated=robot.unactuated_name,
        actuator_names=robot.actuation.names,
        sample_rate_hz=config.rate_hz,
        trial_failed={r.trial_id: r.failed for r in kept},
        units={"t": "s", "q": q_unit_label(robot.coordinate_kinds), "u": config.input_units},
        joint_kinds=robot.coordinate_kinds,
        qu_upright=robot.qu_nominal,
        extra={
            "generator": f"bemlearn {__version__} collect",
            "collect_config": to_dict(config),
            "dropped_trials": dropped,
            "mujoco_version": mujoco.__version__,
        },
    )
    data = Trajectory(t=cat("t"), trial=trial, q=cat("q_meas"), u=cat("u"), meta=meta)
    truth = Trajectory(t=cat("t"), trial=trial, q=cat("q"), u=cat("u"), meta=meta, qd=cat("qd"), qdd=cat("qdd"))
    return data, truth
