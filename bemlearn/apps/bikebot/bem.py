"""The bikebot's model roll BEM: MuJoCo's dynamics with the hard rolling constraint.

**Coordinates.**  The bikebot has MuJoCo's free joint on the rear frame (qpos: hub position and
quaternion; qvel: the hub's velocity and the frame's angular velocity ω_b in the frame's axes), the
steering hinge δ and the two wheel hinges θ_R, θ_F (n_v = 9).  Its roll φ and pitch θ are the
frame's Euler angles with yaw ψ: R = R_z(ψ) R_x(φ) R_y(θ), so its world angular velocity is

    ω = R ω_b = ψ̇ ẑ + φ̇ e₁ + θ̇ e₂,     e₁ = R_z(ψ) x̂,   e₂ = R_z(ψ) R_x(φ) ŷ                   (E1)

and, differentiating (E1), its angular acceleration α = R ω̇_b (MuJoCo's q̈ of the rotation) is

    α = ψ̈ ẑ + φ̈ e₁ + θ̈ e₂ + φ̇ ψ̇ ẑ × e₁ + θ̇ (ψ̇ ẑ + φ̇ e₁) × e₂:                                (E2)

φ̈ is read from α through the 3 × 3 system [ẑ e₁ e₂].

**The state on the ground.**  At roll φ and steer δ (yaw 0, wheels at angle 0) the frame's height and
pitch are those at which both tyres touch the floor (``mj_geomDistance`` = −``depth``, a penetration
small enough to leave the geometry unchanged and large enough that MuJoCo reports the contact at
q ± ε q̇; Newton's method).  Velocities satisfy the constraint rows of both contacts (no slip, two per
contact, and no motion along the normal, one: ``rolling_rows``) and three more conditions: the rear
wheel's rate θ̇_R = v / r_R, the steering rate δ̇ and the roll rate φ̇ of (E1) — nine equations for the
nine velocities.  The forward speed v = r_R θ̇_R is the rear contact's speed in a steady turn
(:mod:`bemlearn.apps.bikebot.steady_turn`).

**The dynamics** are the hard-constraint KKT system (R3) of :mod:`bemlearn.robots.rolling`
(:func:`~bemlearn.robots.rolling.kkt_acceleration` with ``normal=True``): M q̈ − Jᵀ λ = B u − c,
J q̈ = −J̇ q̇ with MuJoCo's mass matrix, bias and passive forces and J̇ q̇ by central differences along
the motion.  It is linear in the two motor torques u = (τ_δ, τ_R), so three solves (u = 0 and each
unit torque) give q̈(u); u is chosen so that δ̈ and θ̈_R = v̇ / r_R take the values asked.

**The model roll BEM** is the root φ_e of φ̈(φ) = 0 at φ̇ = 0 (the paper's eq. 6–9 with q_u = φ and
q_a = (δ, θ_R)), found by Brent's method.  A single soft-contact ``mj_forward`` does not give these
accelerations: MuJoCo's contact holds the wheels by a spring-damper on the contact's velocity and
penetration, with no J̇ q̇ term, so it cannot hold the curved rolling of a turn at one instant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from scipy.optimize import brentq

from bemlearn.errors import ArgumentError, NumericalError
from bemlearn.robots.rolling import kkt_acceleration, rolling_rows, wheel_geoms

__all__ = ["BikeState", "BikebotBem"]

_Z = np.array([0.0, 0.0, 1.0])


def _quat_x(angle: float) -> np.ndarray:
    return np.array([math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0])


def _quat_y(angle: float) -> np.ndarray:
    return np.array([math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0])


def _euler(R: np.ndarray) -> tuple[float, float, float]:
    """(ψ, φ, θ) of R = R_z(ψ) R_x(φ) R_y(θ), rad."""
    phi = math.asin(float(np.clip(R[2, 1], -1.0, 1.0)))
    return math.atan2(-R[0, 1], R[1, 1]), phi, math.atan2(-R[2, 0], R[2, 2])


def _euler_axes(psi: float, phi: float) -> np.ndarray:
    """``(3, 3)`` columns [ẑ, e₁, e₂] of (E1)."""
    cz, sz, cx, sx = math.cos(psi), math.sin(psi), math.cos(phi), math.sin(phi)
    e1 = np.array([cz, sz, 0.0])
    e2 = np.array([-sz * cx, cz * cx, sx])
    return np.column_stack([_Z, e1, e2])


@dataclass(frozen=True)
class BikeState:
    """One state of the bikebot on the ground (MuJoCo's positions and velocities).

    Attributes:
        qpos: ``(n_q,)`` positions (m, quaternion, rad).
        qvel: ``(n_v,)`` velocities (m/s, rad/s), on the constraint.
    """

    qpos: np.ndarray
    qvel: np.ndarray


class BikebotBem:
    """The bikebot's roll BEM from MuJoCo's constrained dynamics (module docstring).

    Args:
        xml: the MJCF (default: the shipped ``bikebot.xml``).
        depth: the tyres' penetration of the floor in the states built, m.
        fd_step: ε of J̇ q̇'s central differences, s.
    """

    def __init__(self, xml: str | Path | None = None, *, depth: float = 1e-9, fd_step: float = 1e-6) -> None:
        if xml is None:
            from bemlearn.apps.bikebot.assets import BIKEBOT_XML

            xml = BIKEBOT_XML
        self.model = mujoco.MjModel.from_xml_path(str(xml))
        self.data = mujoco.MjData(self.model)
        self.depth, self.fd_step = depth, fd_step
        m = self.model
        self.floor = m.geom("floor").id
        self.tyres = (m.geom("rear_tyre").id, m.geom("front_tyre").id)
        self.rear_radius = float(m.geom_size[self.tyres[0], 0])
        self.dof_steer = int(m.jnt_dofadr[m.joint("steer").id])
        self.dof_rear = int(m.jnt_dofadr[m.joint("rear_wheel").id])
        self.qadr_steer = int(m.jnt_qposadr[m.joint("steer").id])
        mujoco.mj_kinematics(m, self.data)
        self.wheels = wheel_geoms(m, self.data)
        if set(self.wheels) != set(self.tyres):
            raise NumericalError(f"BikebotBem: expected the two tyres as wheel geoms, found {sorted(self.wheels)}")
        self.B = np.zeros((m.nv, 2))
        self.B[self.dof_steer, 0] = self.B[self.dof_rear, 1] = 1.0

    # -- positions -----------------------------------------------------------------------------------------

    def _qpos(self, phi: float, delta: float, pitch: float, height: float) -> np.ndarray:
        q = np.array(self.model.qpos0, dtype=np.float64)
        q[:3] = (0.0, 0.0, height)
        quat = np.zeros(4)
        mujoco.mju_mulQuat(quat, _quat_x(phi), _quat_y(pitch))
        q[3:7] = quat
        q[self.qadr_steer] = delta
        return q

    def _distances(self, qpos: np.ndarray) -> np.ndarray:
        d = self.data
        d.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, d)
        fromto = np.zeros(6)
        return np.array([mujoco.mj_geomDistance(self.model, d, self.floor, g, 1.0, fromto) for g in self.tyres])

    def pose(self, phi: float, delta: float, *, depths: tuple[float, float] | None = None,
             tol: float = 1e-13) -> np.ndarray:
        """``(n_q,)`` qpos at roll ``phi`` and steer ``delta`` (rad) with both tyres ``depth`` into the floor
        (or the rear and front tyre ``depths``, m).

        Raises:
            NumericalError: Newton's method on (pitch, height) does not converge in 50 steps.
        """
        x = np.array([0.0, self.rear_radius])
        target = -np.array(depths if depths is not None else (self.depth, self.depth))

        def resid(x: np.ndarray) -> np.ndarray:
            return self._distances(self._qpos(phi, delta, float(x[0]), float(x[1]))) - target

        for _ in range(50):
            r = resid(x)
            if np.max(np.abs(r)) < tol:
                return self._qpos(phi, delta, float(x[0]), float(x[1]))
            eps = 1e-7
            J = np.column_stack([(resid(x + eps * e) - resid(x - eps * e)) / (2 * eps) for e in np.eye(2)])
            x = x - np.linalg.solve(J, r)
        raise NumericalError(f"BikebotBem.pose: the tyres did not reach the floor at roll {phi:g}, steer {delta:g}")

    # -- velocities and accelerations -------------------------------------------------------------------------

    def frame_axes(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R ``(3, 3)``, [ẑ e₁ e₂] ``(3, 3)``) of the frame at ``qpos``."""
        flat = np.zeros(9)
        mujoco.mju_quat2Mat(flat, qpos[3:7])
        R = flat.reshape(3, 3)
        psi, phi, _ = _euler(R)
        return R, _euler_axes(psi, phi)

    def state(self, phi: float, delta: float, v: float, *, delta_rate: float = 0.0, phi_rate: float = 0.0) -> BikeState:
        """The state at roll ``phi``, steer ``delta`` (rad), speed ``v`` = r_R θ̇_R (m/s), δ̇ and φ̇ (rad/s)."""
        m, d = self.model, self.data
        qpos = self.pose(phi, delta)
        d.qpos[:], d.qvel[:] = qpos, 0.0
        mujoco.mj_fwdPosition(m, d)
        tangential, normal, found = rolling_rows(m, d, self.wheels)
        if len(found) != 2:
            raise NumericalError(f"BikebotBem.state: {len(found)} tyre contacts at roll {phi:g}, steer {delta:g} "
                                 "(expected one per tyre)")
        R, E = self.frame_axes(qpos)
        roll_row = np.zeros(m.nv)
        roll_row[3:6] = np.linalg.inv(E)[1] @ R
        rows = [tangential, normal, np.eye(m.nv)[[self.dof_rear, self.dof_steer]], roll_row[None]]
        rhs = np.concatenate([np.zeros(len(tangential) + len(normal)), [v / self.rear_radius, delta_rate, phi_rate]])
        A = np.vstack(rows)
        if A.shape != (m.nv, m.nv):
            raise NumericalError(f"BikebotBem.state: {A.shape[0]} velocity conditions for {m.nv} velocities")
        return BikeState(qpos=qpos, qvel=np.linalg.solve(A, rhs))

    def euler_accelerations(self, state: BikeState, qacc: np.ndarray) -> np.ndarray:
        """``(3,)`` (ψ̈, φ̈, θ̈) (rad/s²) of the frame from MuJoCo's ``qacc`` ``(n_v,)`` at ``state``, by (E2)."""
        R, E = self.frame_axes(state.qpos)
        psi_d, phi_d, theta_d = np.linalg.solve(E, R @ state.qvel[3:6])
        zhat, e1, e2 = E.T
        alpha = R @ qacc[3:6] - phi_d * psi_d * np.cross(zhat, e1) - theta_d * np.cross(psi_d * zhat + phi_d * e1, e2)
        return np.linalg.solve(E, alpha)

    def roll_acceleration(self, state: BikeState, qacc: np.ndarray) -> float:
        """φ̈ (rad/s²) from MuJoCo's ``qacc`` ``(n_v,)`` at ``state`` by (E2)."""
        return float(self.euler_accelerations(state, qacc)[1])

    def accelerations(self, state: BikeState, *, delta_acc: float = 0.0, v_dot: float = 0.0,
                      drift: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(q̈ ``(n_v,)``, u ``(2,)``): the hard-constraint accelerations with the motor torques u = (τ_δ, τ_R)
        (N·m) that give δ̈ = ``delta_acc`` (rad/s²) and θ̈_R = ``v_dot`` / r_R.

        Args:
            state: the state.
            delta_acc: δ̈, rad/s².
            v_dot: v̇, m/s².
            drift: include J̇ q̇ (``False``: what the constraint gives without it).
        """
        def qacc(force: np.ndarray) -> np.ndarray:
            return kkt_acceleration(self.model, self.data, state.qpos, state.qvel, force, self.wheels,
                                    fd_step=self.fd_step, drift=drift, normal=True)[0]

        base = qacc(np.zeros(self.model.nv))
        unit = np.column_stack([qacc(self.B[:, k]) - base for k in range(2)])
        idx = [self.dof_steer, self.dof_rear]
        u = np.linalg.solve(unit[idx], np.array([delta_acc, v_dot / self.rear_radius]) - base[idx])
        return base + unit @ u, u

    def roll_accel_at(self, phi: float, delta: float, v: float, *, delta_rate: float = 0.0, delta_acc: float = 0.0,
                      v_dot: float = 0.0, drift: bool = True) -> float:
        """φ̈ (rad/s²) at roll ``phi`` with φ̇ = 0, given the actuated state (δ, δ̇, δ̈ in rad, rad/s, rad/s²;
        v, v̇ in m/s, m/s²)."""
        s = self.state(phi, delta, v, delta_rate=delta_rate)
        qacc, _ = self.accelerations(s, delta_acc=delta_acc, v_dot=v_dot, drift=drift)
        return self.roll_acceleration(s, qacc)

    def roll(self, delta: float, v: float, *, delta_rate: float = 0.0, delta_acc: float = 0.0, v_dot: float = 0.0,
             bracket: tuple[float, float] | None = None, drift: bool = True, xtol: float = 1e-13) -> float:
        """The model roll BEM φ_e (rad): φ̈(φ_e) = 0 at φ̇ = 0 and the given actuated state.

        Args:
            delta, delta_rate, delta_acc: δ (rad), δ̇ (rad/s), δ̈ (rad/s²).
            v, v_dot: forward speed r_R θ̇_R (m/s) and its rate (m/s²).
            bracket: the roll interval searched, rad; default on the side of sgn δ (the turn leans into
                itself; φ = 0 is excluded, where an upright cylinder touches along a line): from
                0.1 |atan(v² tan δ / (g w))| to 1.5 rad, w the distance between the hubs.
            drift: include J̇ q̇ (``False``: the root a constraint without its drift term gives).
            xtol: tolerance on φ_e, rad.

        Raises:
            NumericalError: φ̈ does not change sign over the bracket.
            ArgumentError: δ = 0 without a bracket.
        """
        if bracket is None:
            if delta == 0.0:
                raise ArgumentError("BikebotBem.roll: δ = 0 (running straight) needs an explicit bracket")
            g = float(np.linalg.norm(self.model.opt.gravity))
            d = self.data
            d.qpos[:] = self.model.qpos0
            mujoco.mj_kinematics(self.model, d)
            w = float(np.linalg.norm(d.xpos[self.model.geom_bodyid[self.tyres[1]]] - d.xpos[self.model.geom_bodyid[self.tyres[0]]]))
            naive = abs(math.atan(v**2 * math.tan(delta) / (g * w)))
            sign = math.copysign(1.0, delta)
            bracket = (sign * 0.1 * naive, sign * 1.5)
        f = lambda phi: self.roll_accel_at(phi, delta, v, delta_rate=delta_rate, delta_acc=delta_acc, v_dot=v_dot,  # noqa: E731
                                             drift=drift)
        lo, hi = bracket
        flo, fhi = f(lo), f(hi)
        if flo * fhi > 0:
            raise NumericalError(f"BikebotBem.roll: φ̈ does not change sign over [{lo:g}, {hi:g}] rad "
                                 f"(v = {v:g} m/s, δ = {delta:g} rad)")
        return float(brentq(f, lo, hi, xtol=xtol, rtol=4 * np.finfo(float).eps))
