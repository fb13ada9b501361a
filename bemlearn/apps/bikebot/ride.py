"""Riding the bikebot in MuJoCo's soft-contact simulation: sensors, a steer-into-the-fall balance law, a speed loop.

**Coordinates read from the simulator.**  The frame's roll φ, pitch θ and yaw ψ are its Euler angles
R = R_z(ψ) R_x(φ) R_y(θ) from the free joint's quaternion; the rates (ψ̇, φ̇, θ̇) solve (E1) of
:mod:`bemlearn.apps.bikebot.bem` with the free joint's angular velocity; the steer δ and the rear wheel's
angle θ_R are their hinges; the speed is v = r_R θ̇_R.

**Sensors (a rig's).**  At the control rate f_c the controller reads δ and θ_R from encoders and φ from an
attitude estimate, each quantised to 2π / 4096 rad (:class:`~bemlearn.data.sensors.Encoder`), and their rates
from the Tustin differentiator ω_c s / (s + ω_c) (:class:`~bemlearn.data.sensors.FilteredDifferentiator`,
ω_c = 50 rad/s).  The logged data are the quantised angles; the simulator's exact values are logged beside
them as the ground truth.

**Balance (steer into the fall).**  A lean pendulum on a bicycle of wheelbase w, its centre of mass at height
h and a distance b ahead of the rear contact, steering δ at speed v (the point-mass bicycle: no trail, no
gyroscopic moments):

    h φ̈ ≈ g φ − (v² / w) δ − (v b / w) δ̇.                                                       (C2)

Steering

    δ_cmd = δ_ff + k_φ (φ − φ_ref) + k_φ̇ φ̇,   δ_ff = atan(g w tan φ_ref / v²)                    (C1)

with (k_φ, k_φ̇) of :func:`lean_gains` puts the poles of (C2) at ω_n with damping ζ and holds the lean reference φ_ref with the steer of the
naive steady turn (the feedback removes the rest: the true steady turn's lean differs from the naive one,
docs/bikebot.md); v is floored at ``min_speed`` in the gains.  The steering motor is a PD servo on δ_cmd,
τ_δ = k_p (δ_cmd − δ) − k_d δ̇, and the rear motor a P loop on the speed, τ_R = k_v (v_ref − v); both
saturate at the MJCF's ±20 N·m.

**The reference.**  :class:`RideReference`: the speed v_ref(t) is a mean plus sines; the lean reference is
the naive steady-turn lean of a steer reference δ_r(t) (sum of sines) at v_ref(t),
φ_ref = atan(v_ref² tan δ_r / (g w)), so that a steer amplitude asks for the same steer at every speed.
Both are ramped in over ``ramp_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from bemlearn.apps.bikebot.bem import _euler, _euler_axes
from bemlearn.data.sensors import Encoder, FilteredDifferentiator, SensorConfig
from bemlearn.errors import ArgumentError

__all__ = ["RideGains", "RideReference", "RideLog", "BikeReading", "read_coordinates", "simulate_ride",
           "JOINT_NAMES", "lean_gains"]

#: The logged coordinates' order (the data's columns): steer δ, rear wheel θ_R, roll φ (rad).
JOINT_NAMES = ("steer", "rear_wheel", "roll")


@dataclass(frozen=True)
class BikeReading:
    """The bikebot's coordinates from MuJoCo's state (exact).

    Attributes:
        roll, roll_rate: φ (rad), φ̇ (rad/s).
        yaw, pitch: ψ, θ (rad).
        steer, steer_rate: δ (rad), δ̇ (rad/s).
        wheel, wheel_rate: θ_R (rad), θ̇_R (rad/s).
        hub: ``(3,)`` the rear hub's position, m.
    """

    roll: float
    roll_rate: float
    yaw: float
    pitch: float
    steer: float
    steer_rate: float
    wheel: float
    wheel_rate: float
    hub: np.ndarray


def read_coordinates(model: mujoco.MjModel, data: mujoco.MjData) -> BikeReading:
    """The coordinates of the module docstring from ``data`` (after ``mj_forward`` or ``mj_step``)."""
    R = data.xmat[model.body("frame").id].reshape(3, 3)
    psi, phi, theta = _euler(R)
    rates = np.linalg.solve(_euler_axes(psi, phi), R @ data.qvel[3:6])
    js, jr = model.joint("steer"), model.joint("rear_wheel")
    return BikeReading(roll=phi, roll_rate=float(rates[1]), yaw=psi, pitch=theta,
                       steer=float(data.qpos[js.qposadr[0]]), steer_rate=float(data.qvel[js.dofadr[0]]),
                       wheel=float(data.qpos[jr.qposadr[0]]), wheel_rate=float(data.qvel[jr.dofadr[0]]),
                       hub=data.xpos[model.body("frame").id].copy())


@dataclass(frozen=True)
class RideGains:
    """Gains of (C1) and the motors' loops (module docstring).

    Attributes:
        lean_frequency: ω_n, rad/s.
        lean_damping: ζ.
        steer_kp, steer_kd: k_p (N·m/rad), k_d (N·m·s/rad) of the steering servo.
        speed_kp: k_v, N·m per m/s.
        max_steer: |δ_cmd| bound, rad.
        min_speed: the speed floor in the gains, m/s.
    """

    lean_frequency: float = 4.0
    lean_damping: float = 0.8
    steer_kp: float = 100.0
    steer_kd: float = 10.0
    speed_kp: float = 30.0
    max_steer: float = 0.5
    min_speed: float = 1.0


@dataclass(frozen=True)
class RideReference:
    """Speed and lean references (module docstring).

    Attributes:
        speed: v_ref's mean, m/s.
        speed_sines: ((amplitude m/s, frequency Hz, phase rad), ...) added to the mean.
        steer_sines: ((amplitude rad, frequency Hz, phase rad), ...) of the steer reference δ_r.
        ramp_s: the sines ramp in linearly over this time, s.
    """

    speed: float = 3.0
    speed_sines: tuple[tuple[float, float, float], ...] = ()
    steer_sines: tuple[tuple[float, float, float], ...] = ()
    ramp_s: float = 3.0

    def _ramp(self, t: float) -> float:
        return min(1.0, t / self.ramp_s) if self.ramp_s > 0 else 1.0

    def velocity(self, t: float) -> float:
        """v_ref(t), m/s."""
        r = self._ramp(t)
        return self.speed + r * sum(a * math.sin(2 * math.pi * f * t + p) for a, f, p in self.speed_sines)

    def steer(self, t: float) -> float:
        """δ_r(t), rad."""
        r = self._ramp(t)
        return r * sum(a * math.sin(2 * math.pi * f * t + p) for a, f, p in self.steer_sines)


@dataclass
class RideLog:
    """One ride, sampled at the control rate (T samples).

    Attributes:
        t: ``(T,)`` s.
        q: ``(T, 3)`` the sensors' quantised (δ, θ_R, φ), rad (columns :data:`JOINT_NAMES`).
        q_true, qd_true: ``(T, 3)`` the simulator's (δ, θ_R, φ) and their rates, rad, rad/s.
        hub: ``(T, 3)`` the rear hub's position, m.
        yaw: ``(T,)`` ψ, rad.
        u: ``(T, 2)`` motor torques (τ_δ, τ_R) applied over the next period, N·m.
        v_ref, roll_ref: ``(T,)`` the references, m/s and rad.
        fell: the ride ended with |φ| above ``max_roll``.
        sample_rate_hz: f_c, Hz.
    """

    t: np.ndarray
    q: np.ndarray
    q_true: np.ndarray
    qd_true: np.ndarray
    hub: np.ndarray
    yaw: np.ndarray
    u: np.ndarray
    v_ref: np.ndarray
    roll_ref: np.ndarray
    fell: bool
    sample_rate_hz: float
    extra: dict = field(default_factory=dict)

    @property
    def speed(self) -> np.ndarray:
        """``(T,)`` the true speed r_R θ̇_R, m/s (r_R from ``extra['rear_radius']``)."""
        return self.extra["rear_radius"] * self.qd_true[:, 1]


def lean_gains(v: float, wn: float, zeta: float, *, h: float, b: float, w: float, g: float) -> tuple[float, float]:
    """(k_φ, k_φ̇) of (C1) that place the poles of (C2) at ω_n = ``wn`` (rad/s), damping ``zeta``, at speed v (m/s).

    (C2) with δ = k_φ φ + k_φ̇ φ̇ reads (h + v b k_φ̇ / w) φ̈ + (v² k_φ̇ + v b k_φ) / w φ̇ + (v² k_φ / w − g) φ = 0;
    matching it to φ̈ + 2 ζ ω_n φ̇ + ω_n² φ = 0 is linear in (k_φ, k_φ̇).
    """
    A = np.array([[v**2 / w, -wn**2 * v * b / w], [v * b / w, v**2 / w - 2 * zeta * wn * v * b / w]])
    k = np.linalg.solve(A, np.array([g + wn**2 * h, 2 * zeta * wn * h]))
    return float(k[0]), float(k[1])


def _geometry(model: mujoco.MjModel) -> tuple[float, float, float, float, float]:
    """(r_R, w, h, b, g): rear radius, wheelbase (hub to hub), the whole bicycle's centre of mass height and
    its distance ahead of the rear hub, gravity."""
    d = mujoco.MjData(model)
    mujoco.mj_forward(model, d)
    rr = float(model.geom_size[model.geom("rear_tyre").id, 0])
    hubs = [d.xpos[model.body(b).id] for b in ("rear_wheel", "front_wheel")]
    w = float(np.linalg.norm(hubs[1] - hubs[0]))
    com = d.subtree_com[model.body("frame").id]
    b = float(com[0] - d.xpos[model.body("rear_wheel").id, 0])
    return rr, w, float(com[2]), b, float(np.linalg.norm(model.opt.gravity))


def simulate_ride(reference: RideReference, duration_s: float, *, gains: RideGains = RideGains(),
                  control_rate_hz: float = 200.0, sensors: SensorConfig | None = None, seed: int = 0,
                  max_roll: float = 1.2, xml: str | Path | None = None, cone: str = "elliptic",
                  tyre_friction: float | None = None, steer_command=None) -> RideLog:
    """Ride the bikebot for ``duration_s`` with (C1) and the speed loop (module docstring).

    Starts upright on the floor at MuJoCo's ``qpos0`` rolling at v_ref(0).

    Args:
        reference: the speed and lean references.
        duration_s: s.
        gains: :class:`RideGains`.
        control_rate_hz: f_c (a multiple of 1 / the MJCF's time step), Hz.
        sensors: encoder resolution (also the roll's), noise and the differentiator's cutoff (default
            :class:`~bemlearn.data.sensors.SensorConfig`: 4096 counts/rev, no noise, 50 rad/s).
        seed: the sensors' noise seed.
        max_roll: the ride ends (fell) when |φ| exceeds it, rad.
        xml: the MJCF (default the shipped one).
        cone: MuJoCo's friction cone in the simulation, ``"elliptic"`` (default: the friction circle |f_t| ≤ μ f_n)
            or ``"pyramidal"`` (the MJCF's, MuJoCo's default: its soft pyramid lets the tyres slide sideways
            before the circle's limit — the bikebot falls at about 0.68 rad of lean (0.8 g) at μ = 1 and leans
            0.006 rad less than the hard model at 0.6 rad even at μ = 2; docs/bikebot.md).
        tyre_friction: the tyres' sliding friction coefficient in the simulation (``None``: the MJCF's, 1; MuJoCo
            takes the larger of the two geoms' coefficients, the floor's is 1).
        steer_command: optional ``f(t, reading_dict) -> δ_cmd`` replacing (C1) (the EIC); the dict holds the
            sensed ``roll, roll_rate, steer, steer_rate, wheel, speed``, the simulator's rear hub ``x, y`` and
            ``yaw`` (a rig's localisation is not modelled) and ``geometry`` (w, h, b, g, rear_radius).
    """
    if xml is None:
        from bemlearn.apps.bikebot.assets import BIKEBOT_XML

        xml = BIKEBOT_XML
    model = mujoco.MjModel.from_xml_path(str(xml))
    if cone not in ("elliptic", "pyramidal"):
        raise ArgumentError(f"simulate_ride: cone must be 'elliptic' or 'pyramidal', got {cone!r}")
    model.opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC if cone == "elliptic" else mujoco.mjtCone.mjCONE_PYRAMIDAL
    if tyre_friction is not None:
        for tyre in ("rear_tyre", "front_tyre"):
            model.geom_friction[model.geom(tyre).id, 0] = tyre_friction
    data = mujoco.MjData(model)
    nsub = round(1.0 / (control_rate_hz * model.opt.timestep))
    if nsub < 1 or abs(nsub * model.opt.timestep * control_rate_hz - 1.0) > 1e-9:
        raise ArgumentError(f"simulate_ride: control rate {control_rate_hz:g} Hz is not a divisor of the simulator's "
                            f"{1.0 / model.opt.timestep:g} Hz")
    dt = nsub * model.opt.timestep
    rr, w, h, b, g = _geometry(model)
    geometry = {"w": w, "h": h, "b": b, "g": g, "rear_radius": rr}
    rf = float(model.geom_size[model.geom("front_tyre").id, 0])
    v0 = reference.velocity(0.0)
    data.qpos[:] = model.qpos0
    data.qvel[0] = v0
    data.qvel[model.joint("rear_wheel").dofadr[0]] = v0 / rr
    data.qvel[model.joint("front_wheel").dofadr[0]] = v0 / rf
    mujoco.mj_forward(model, data)
    sensors = sensors or SensorConfig()
    enc = Encoder(sensors, np.random.default_rng(seed))
    diff = FilteredDifferentiator(3, cutoff=sensors.velocity_cutoff, dt=dt)
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    n = int(round(duration_s / dt))
    cols: dict[str, list] = {k: [] for k in ("t", "q", "q_true", "qd_true", "hub", "yaw", "u", "v_ref", "roll_ref")}
    fell = False
    for k in range(n + 1):
        t = k * dt
        r = read_coordinates(model, data)
        q_true = np.array([r.steer, r.wheel, r.roll])
        y = enc(q_true)
        yd = diff(y)
        if k == 0:     # the differentiator starts at rest: seed it with the initial rates
            diff.v = np.array([r.steer_rate, r.wheel_rate, r.roll_rate])
            yd = diff.v.copy()
        v_ref = reference.velocity(t)
        sensed = {"roll": y[2], "roll_rate": yd[2], "steer": y[0], "steer_rate": yd[0], "wheel": y[1],
                  "speed": rr * yd[1], "x": r.hub[0], "y": r.hub[1], "yaw": r.yaw, "geometry": geometry}
        vs = max(sensed["speed"], gains.min_speed)
        roll_ref = math.atan(v_ref**2 * math.tan(reference.steer(t)) / (g * w))
        if steer_command is None:
            k_phi, k_rate = lean_gains(vs, gains.lean_frequency, gains.lean_damping, h=h, b=b, w=w, g=g)
            d_cmd = (math.atan(g * w * math.tan(roll_ref) / vs**2) + k_phi * (sensed["roll"] - roll_ref)
                     + k_rate * sensed["roll_rate"])
        else:
            d_cmd = float(steer_command(t, sensed))
        d_cmd = float(np.clip(d_cmd, -gains.max_steer, gains.max_steer))
        u = np.clip([gains.steer_kp * (d_cmd - sensed["steer"]) - gains.steer_kd * sensed["steer_rate"],
                     gains.speed_kp * (v_ref - sensed["speed"])], lo, hi)
        for key, val in (("t", t), ("q", y), ("q_true", q_true),
                         ("qd_true", [r.steer_rate, r.wheel_rate, r.roll_rate]), ("hub", r.hub), ("yaw", r.yaw),
                         ("u", u), ("v_ref", v_ref), ("roll_ref", roll_ref)):
            cols[key].append(val)
        if abs(r.roll) > max_roll:
            fell = True
            break
        if k == n:
            break
        data.ctrl[:] = u
        for _ in range(nsub):
            mujoco.mj_step(model, data)
    arr = {k: np.asarray(v, dtype=np.float64) for k, v in cols.items()}
    return RideLog(**arr, fell=fell, sample_rate_hz=1.0 / dt,
                   extra={"rear_radius": rr, "wheelbase": w, "com_height": h, "gravity": g, "seed": seed,
                          "tyre_friction": float(model.geom_friction[model.geom("rear_tyre").id, 0]), "cone": cone})
