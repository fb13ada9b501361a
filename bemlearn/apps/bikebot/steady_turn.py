"""The bikebot's steady turn from Newton–Euler about the ground line: an independent reference.

Nothing here uses MuJoCo: the geometry, the kinematics and the balance are written from the
parameters of :class:`~bemlearn.apps.bikebot.model.BikeParameters`.

**Pose.**  Yaw 0, the rear frame B turned by R_B = R_x(φ) R_y(θ) (roll φ about the forward axis, then
pitch θ), its origin (the rear hub) at (0, 0, z_0); the fork H turned about the steer axis by δ,
R_H = R_B Rot(s, δ).  A wheel (centre C, unit axle a, radius r, half-width h: a cylinder) touches the
ground at the lowest point of its rims,

    P = C + r d − h sgn(a_z) a,      d = −(ẑ − a_z a) / |ẑ − a_z a|                         (G1)

(d: down within the wheel's plane; of the two rims the one on the lower side).  Both wheels on the
ground, P_R,z = P_F,z = 0, fix z_0 and θ (Newton's method).

**Steady turn.**  Rolling at constant speed, steer and roll, the frame and the fork turn together
about a vertical axis through O with yaw rate Ω (angular velocity Ω ẑ), and each wheel spins on its
axle at ω_w relative to its body: angular velocity Ω ẑ + ω_w a.  No slip at P:

    Ω ẑ × (P − O) + ω_w a × (P − C) = 0.                                                    (K1)

a × (P − C) = r a × d is horizontal and along the wheel's heading f = a × ẑ / |a × ẑ|, so Ω ẑ × (P − O)
must be too: O lies on the horizontal lines through P_R and P_F normal to f_R and f_F (their
intersection).  With n = ẑ × f and O = P_R + ρ n_R, (K1) gives Ω = v / ρ for the rear contact's
speed v along f_R, and ω_R = v / r_R: the forward speed is r_R times the rear wheel's rate.

**Balance.**  Every body i (mass m_i, centre of mass c_i, inertia I_i about it, angular velocity ω_i)
moves rigidly with the turn: its centre of mass on a horizontal circle, a_i = −Ω² (c_i − O)_⊥ (the part
normal to ẑ), and its angular momentum H_i = I_i ω_i is constant in the frame turning with Ω ẑ (the
wheels are symmetric about their axles, so their spin does not change I_i), dH_i/dt = Ω ẑ × H_i.  The
ground's forces act at P_R and P_F; the motors' torques are internal.  Their moment about the ground
line e = (P_F − P_R)/|P_F − P_R| vanishes, so the steady turn needs

    Σ_i [ (c_i − P_R) × m_i (g − a_i) − Ω ẑ × (I_i ω_i) ] · e = 0,     g = (0, 0, −g)          (N1)

(gravity, the centrifugal "forces" −m_i a_i, and the gyroscopic moments of the frame, the fork and the
spinning wheels, the trail entering through P_F and O).  The roll of the steady turn is the root φ of
(N1) at given (v, δ).

**The naive formula** φ = atan(v² tan δ / (g w)) is a point mass on a knife-edge bicycle with no head
angle, no trail, no gyroscopic moments: :func:`naive_roll`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from bemlearn.apps.bikebot.model import BikeParameters
from bemlearn.errors import ArgumentError, NumericalError

__all__ = ["BikePose", "bike_pose", "steady_turn_residual", "steady_turn_roll", "naive_roll"]

_Z = np.array([0.0, 0.0, 1.0])


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    """``(3, 3)`` rotation by ``angle`` (rad) about the unit ``axis`` (Rodrigues)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def _contact(centre: np.ndarray, axle: np.ndarray, radius: float, half_width: float) -> np.ndarray:
    """(G1): the lowest point ``(3,)`` of a cylinder's rims, m."""
    up_in_plane = _Z - axle[2] * axle
    d = -up_in_plane / np.linalg.norm(up_in_plane)
    return centre + radius * d - half_width * math.copysign(1.0, axle[2]) * axle


@dataclass(frozen=True)
class BikePose:
    """The bikebot on the ground at roll φ and steer δ (world axes x forward, y left, z up; m, rad).

    Attributes:
        phi, delta: roll and steer, rad.
        pitch: the rear frame's pitch θ, rad.
        height: the rear hub's height z_0, m.
        R_frame, R_fork: ``(3, 3)`` rotations of the rear frame and the fork.
        rear_hub, front_hub: ``(3,)`` wheel centres, m.
        frame_com, fork_com: ``(3,)`` centres of mass of B and H, m.
        rear_contact, front_contact: ``(3,)`` ground contact points (G1), m.
    """

    phi: float
    delta: float
    pitch: float
    height: float
    R_frame: np.ndarray
    R_fork: np.ndarray
    rear_hub: np.ndarray
    front_hub: np.ndarray
    frame_com: np.ndarray
    fork_com: np.ndarray
    rear_contact: np.ndarray
    front_contact: np.ndarray


def _pose(p: BikeParameters, phi: float, delta: float, pitch: float, height: float) -> BikePose:
    R_B = _rot(np.array([1.0, 0.0, 0.0]), phi) @ _rot(np.array([0.0, 1.0, 0.0]), pitch)
    R_H = R_B @ _rot(p.steer_axis, delta)
    origin = np.array([0.0, 0.0, height])
    rear_hub_up = np.array([0.0, 0.0, p.rear_radius])            # upright ground-frame position of the frame origin
    fork_origin = origin + R_B @ (p.steer_ground_point - rear_hub_up)

    def on_fork(x: np.ndarray) -> np.ndarray:
        return fork_origin + R_H @ (x - p.steer_ground_point)

    front_hub = on_fork(np.array([p.wheelbase, 0.0, p.front_radius]))
    y = np.array([0.0, 1.0, 0.0])
    return BikePose(phi=phi, delta=delta, pitch=pitch, height=height, R_frame=R_B, R_fork=R_H,
                    rear_hub=origin, front_hub=front_hub,
                    frame_com=origin + R_B @ (np.array([p.frame_com[0], 0.0, p.frame_com[1]]) - rear_hub_up),
                    fork_com=on_fork(np.array([p.fork_com[0], 0.0, p.fork_com[1]])),
                    rear_contact=_contact(origin, R_B @ y, p.rear_radius, p.wheel_half_width),
                    front_contact=_contact(front_hub, R_H @ y, p.front_radius, p.wheel_half_width))


def bike_pose(p: BikeParameters, phi: float, delta: float, *, tol: float = 1e-13) -> BikePose:
    """The pose with both wheels on the ground (contact heights 0 by Newton's method on (z_0, θ)).

    Args:
        p: the parameters.
        phi: roll, rad (not 0: an upright cylinder touches along a line).
        delta: steer, rad.
        tol: contact height tolerance, m.

    Raises:
        NumericalError: no convergence in 50 steps.
    """
    x = np.array([0.0, p.rear_radius])                        # pitch, height

    def heights(x: np.ndarray) -> np.ndarray:
        q = _pose(p, phi, delta, float(x[0]), float(x[1]))
        return np.array([q.rear_contact[2], q.front_contact[2]])

    for _ in range(50):
        r = heights(x)
        if np.max(np.abs(r)) < tol:
            return _pose(p, phi, delta, float(x[0]), float(x[1]))
        eps = 1e-7
        J = np.column_stack([(heights(x + eps * e) - heights(x - eps * e)) / (2 * eps) for e in np.eye(2)])
        x = x - np.linalg.solve(J, r)
    raise NumericalError(f"bike_pose: the wheels did not reach the ground at roll {phi:g}, steer {delta:g}")


def _turn(p: BikeParameters, q: BikePose, v: float) -> tuple[np.ndarray, float, float, float]:
    """(K1): the turn's centre O ``(3,)`` (m), yaw rate Ω (rad/s) and the wheels' spins ω_R, ω_F (rad/s)."""
    y = np.array([0.0, 1.0, 0.0])
    a_R, a_F = q.R_frame @ y, q.R_fork @ y
    f_R, f_F = (np.cross(a, _Z) / np.linalg.norm(np.cross(a, _Z)) for a in (a_R, a_F))
    n_R, n_F = np.cross(_Z, f_R), np.cross(_Z, f_F)
    # P_R + ρ n_R = P_F + σ n_F in the ground plane
    A = np.column_stack([n_R[:2], -n_F[:2]])
    rho, _ = np.linalg.solve(A, (q.front_contact - q.rear_contact)[:2])
    O = q.rear_contact + rho * n_R
    omega = v / rho
    spins = []
    for a, P, C in ((a_R, q.rear_contact, q.rear_hub), (a_F, q.front_contact, q.front_hub)):
        lhs, rhs = np.cross(a, P - C), -np.cross(omega * _Z, P - O)
        w = float(lhs @ rhs / (lhs @ lhs))
        if np.linalg.norm(w * lhs - rhs) > 1e-9 * max(1.0, float(np.linalg.norm(rhs))):
            raise NumericalError("steady turn: the wheels cannot roll without slip about one vertical axis")
        spins.append(w)
    return O, omega, spins[0], spins[1]


def steady_turn_residual(p: BikeParameters, phi: float, v: float, delta: float) -> float:
    """The left side of (N1), N·m: the moment about the ground line that the steady turn lacks.

    Args:
        p: the parameters.
        phi: roll, rad.
        v: forward speed r_R ω_R (the rear contact's speed), m/s.
        delta: steer, rad (not 0: a straight line has no centre).
    """
    q = bike_pose(p, phi, delta)
    O, omega, w_R, w_F = _turn(p, q, v)
    y = np.array([0.0, 1.0, 0.0])
    gvec = np.array([0.0, 0.0, -p.gravity])
    bodies = (
        (p.frame_mass, q.frame_com, q.R_frame @ p.inertia("frame") @ q.R_frame.T, omega * _Z),
        (p.fork_mass, q.fork_com, q.R_fork @ p.inertia("fork") @ q.R_fork.T, omega * _Z),
        (p.rear_mass, q.rear_hub, q.R_frame @ p.inertia("rear_wheel") @ q.R_frame.T, omega * _Z + w_R * (q.R_frame @ y)),
        (p.front_mass, q.front_hub, q.R_fork @ p.inertia("front_wheel") @ q.R_fork.T, omega * _Z + w_F * (q.R_fork @ y)),
    )
    line = q.front_contact - q.rear_contact
    e = line / np.linalg.norm(line)
    total = np.zeros(3)
    for m, c, inertia, w in bodies:
        rel = c - O
        accel = -omega**2 * (rel - rel[2] * _Z)
        total += np.cross(c - q.rear_contact, m * (gvec - accel)) - np.cross(omega * _Z, inertia @ w)
    return float(total @ e)


def naive_roll(p: BikeParameters, v: float, delta: float) -> float:
    """φ = atan(v² tan δ / (g w)), rad: the point-mass steady turn."""
    return math.atan(v**2 * math.tan(delta) / (p.gravity * p.wheelbase))


def steady_turn_roll(p: BikeParameters, v: float, delta: float, *, xtol: float = 1e-14) -> float:
    """The roll φ (rad) of the steady turn at speed ``v`` (m/s) and steer ``delta`` (rad): the root of (N1).

    Bracketed on the side of the naive roll's sign (φ and δ have the same sign; φ = 0 is excluded, module
    docstring), between a third of the naive roll and 1.5 rad.

    Raises:
        ArgumentError: δ = 0 or v = 0 (no turn).
        NumericalError: (N1) does not change sign in the bracket.
    """
    if delta == 0.0 or v == 0.0:
        raise ArgumentError(f"steady_turn_roll: a turn needs δ ≠ 0 and v ≠ 0 (got δ = {delta:g} rad, v = {v:g} m/s)")
    phi0 = naive_roll(p, v, delta)
    lo, hi = phi0 / 3.0, math.copysign(1.5, phi0)
    f = lambda phi: steady_turn_residual(p, phi, v, delta)  # noqa: E731
    if f(lo) * f(hi) > 0:
        raise NumericalError(f"steady_turn_roll: no root of the ground-line balance in [{lo:g}, {hi:g}] rad "
                             f"at v = {v:g} m/s, δ = {delta:g} rad")
    return float(brentq(f, lo, hi, xtol=xtol, rtol=4 * np.finfo(float).eps))
