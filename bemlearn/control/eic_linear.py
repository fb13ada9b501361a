"""The EIC closed loop (eq. 3, 8) with the model BEM, linearised at upright (m = 1).

With a zero reference, exact model and ideal sensing, the EIC gives q̈_u = v_u and
q̈_a = v_a exactly, where (linearised, x = [q_u, q_a, q̇_u, q̇_a] about upright)

    v_ext = −k_d,a q̇_a − k_p,a q_a
    q_u^e = s_p q_a + s_v q̇_a + s_a v_ext                       (linearised BEM, eq. 9)
    v_u   = −k_d,u q̇_u − k_p,u (q_u − q_u^e)
    v_a   = −(D_uu v_u + H_q x) / D_ua                           (eq. 8, unactuated row)

H_q = ∂h_u/∂[q, q̇] (h = C q̇ + G − τ_p).  The spectral abscissa max Re λ(A) < 0 is
necessary for the EIC to balance the robot near upright.  A positive s_p (the BEM moves
with the actuated *position*, as for an acrobot whose elbow shifts the centre of mass)
multiplies the actuated dynamics by 1 + D_uu s_p / D_ua, which can make this loop
unstable for every gain (see :func:`eic_linear_abscissa`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from bemlearn.errors import RobotModelError
from bemlearn.robots.protocol import ControlRobot

if TYPE_CHECKING:
    from bemlearn.robots.mujoco_robot import MujocoRobot

__all__ = ["eic_linear_matrix", "eic_linear_abscissa", "EICTickLoop", "eic_controller_jacobian", "eic_tick_loop"]


def _model_terms(robot: ControlRobot, eps: float = 1e-6) -> tuple[float, float, np.ndarray, np.ndarray]:
    from bemlearn.robots.scales import bem_slopes

    n, iu, ia = robot.n, robot.unactuated_index, robot.actuated_index[0]
    q0 = np.zeros(n)
    q0[iu] = robot.qu_nominal
    z = np.zeros(n)
    D = robot.terms(q0, z)[0]
    Hq = np.zeros(4)
    for k, (col, vel) in enumerate(((iu, False), (ia, False), (iu, True), (ia, True))):
        e = np.zeros(n)
        e[col] = eps
        if vel:
            hp, hm = robot.terms(q0, e)[1], robot.terms(q0, -e)[1]
        else:
            hp, hm = robot.terms(q0 + e, z)[1], robot.terms(q0 - e, z)[1]
        Hq[k] = float(hp[iu] - hm[iu]) / (2 * eps)
    return D[iu, iu], D[iu, ia], Hq, bem_slopes(robot)[:, 0]


def eic_linear_matrix(robot: ControlRobot, gains, *, terms: tuple[float, float, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The ``(4, 4)`` matrix A of ẋ = A x (module docstring) for a robot with m = 1 (1/s, 1/s²)."""
    if robot.m != 1:
        raise RobotModelError(f"eic_linear_matrix: needs one actuated joint, robot {robot.name!r} has {robot.m}")
    Duu, Dua, Hq, (sp, sv, sa) = terms if terms is not None else _model_terms(robot)
    g = gains
    vext = np.array([0.0, -g.kp_a, 0.0, -g.kd_a])
    que = np.array([0.0, sp, 0.0, sv]) + sa * vext
    vu = -g.kd_u * np.array([0.0, 0.0, 1.0, 0.0]) - g.kp_u * (np.array([1.0, 0.0, 0.0, 0.0]) - que)
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2] = vu
    A[3] = -(Duu * vu + Hq) / Dua
    return A


def eic_linear_abscissa(robot: ControlRobot, gains) -> float:
    """max Re λ of :func:`eic_linear_matrix` (1/s): < 0 is needed for the EIC to balance."""
    return float(np.max(np.linalg.eigvals(eic_linear_matrix(robot, gains)).real))


@dataclass(frozen=True)
class EICTickLoop:
    """The EIC loop as it runs, linearised at upright over one control tick (:func:`eic_tick_loop`).

    State z = [δq, δq̇ (the plant, robot coordinates), v (the velocity estimate), y_prev (the last
    measurement)], ``(4n,)``; ``z_{k+1} = M z_k + N w_k`` with w_k the encoder's quantisation error
    ``(n,)`` (rad or m), and the command ``u_k = K z_k + L w_k`` (``ctrl``).

    Attributes:
        M: ``(4n, 4n)``.  N: ``(4n, n)``.  K: ``(nu, 4n)``.  L: ``(nu, n)``.
        spectral_radius: max |eig(M)| (< 1: the sampled loop is stable).
        rate_hz: the control rate.  cutoff: ω_c of the velocity filter, rad/s.
    """

    M: np.ndarray
    N: np.ndarray
    K: np.ndarray
    L: np.ndarray
    spectral_radius: float
    rate_hz: float
    cutoff: float

    @property
    def decay_rate(self) -> float:
        """−ln(spectral radius) × rate, 1/s: the slowest mode's decay rate (< 0: it grows)."""
        return float(-math.log(max(self.spectral_radius, 1e-300)) * self.rate_hz)


def eic_controller_jacobian(robot: MujocoRobot, gains, *, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """∂u/∂y and ∂u/∂v ``(nu, n)`` each, of the EIC controller (:class:`~bemlearn.control.eic.EICController`
    with the model BEM of ``robot`` and a reference at rest) at upright, by central differences of the
    controller itself (``ctrl`` per rad or m, per rad/s or m/s)."""
    from bemlearn.control.actuator_inverse import MujocoActuatorInverse
    from bemlearn.control.bem_sources import ModelBEM
    from bemlearn.control.eic import EICController
    from bemlearn.robots.reference import CompositeSinusoid

    n, m = robot.n, robot.m
    ref = CompositeSinusoid(((0.0,),) * m, ((0.0,),) * m, ((0.0,),) * m, (0.0,) * m)
    ctrl = EICController(robot, ModelBEM(robot), ref, MujocoActuatorInverse(robot), gains)
    y0 = np.zeros(n)
    y0[robot.unactuated_index] = robot.qu_nominal
    v0 = np.zeros(n)
    Ky = np.zeros((robot.model.nu, n))
    Kv = np.zeros((robot.model.nu, n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = eps
        Ky[:, i] = (ctrl(0.0, y0 + e, v0)[0] - ctrl(0.0, y0 - e, v0)[0]) / (2 * eps)
        Kv[:, i] = (ctrl(0.0, y0, v0 + e)[0] - ctrl(0.0, y0, v0 - e)[0]) / (2 * eps)
    return Ky, Kv


def eic_tick_loop(robot: MujocoRobot, gains, *, rate_hz: float, velocity_cutoff: float, timestep: float | None = None,
                  plant: tuple[np.ndarray, np.ndarray] | None = None) -> EICTickLoop:
    """The EIC loop as the closed-loop simulation runs it, linearised at upright (:class:`EICTickLoop`).

    Per tick k: y_k = q_k + w_k (encoder), v_k = a v_{k−1} + b (y_k − y_{k−1}) (the Tustin velocity filter of
    :class:`~bemlearn.data.sensors.FilteredDifferentiator`, a = (2 − ω_c Δt)/(2 + ω_c Δt), b = 2ω_c/(2 + ω_c Δt)),
    u_k = K_y δy_k + K_v v_k (:func:`eic_controller_jacobian`), held over the tick:
    δx_{k+1} = A δx_k + B u_k (MuJoCo's tick map, :func:`~bemlearn.control.lqr.linearize`).  Unlike
    :func:`eic_linear_matrix` (continuous time, exact state), this includes the sampling, the hold and the
    lag of the velocity estimate, which destabilise stiff internal loops (k_d,u large against ω_c).

    Args:
        gains: :class:`~bemlearn.control.eic.EICGains`.
        rate_hz: control rate, Hz.  velocity_cutoff: ω_c, rad/s.  timestep: physics step override, s.
        plant: ``(A (2n, 2n), B (2n, nu))`` when already linearised.
    """
    from bemlearn.control.lqr import linearize

    n = robot.n
    A, B = plant if plant is not None else linearize(robot, rate_hz=rate_hz, timestep=timestep)[:2]
    Ky, Kv = eic_controller_jacobian(robot, gains)
    dt = 1.0 / rate_hz
    a = (2 - velocity_cutoff * dt) / (2 + velocity_cutoff * dt)
    b = 2 * velocity_cutoff / (2 + velocity_cutoff * dt)
    C = np.hstack([np.eye(n), np.zeros((n, n))])            # y = q (the plant state's positions)
    Z = np.zeros((n, n))
    # v_k = a v_{k-1} + b (C x_k + w_k − y_prev)
    Vz = np.hstack([b * C, a * np.eye(n), -b * np.eye(n)])  # (n, 4n)
    Vw = b * np.eye(n)
    Kz = Ky @ np.hstack([C, Z, Z]) + Kv @ Vz                # u_k = Kz z + Lw w
    Lw = Ky + Kv @ Vw
    nx = 2 * n
    M = np.zeros((4 * n, 4 * n))
    M[:nx, :nx] = A
    M[:nx] += B @ Kz
    M[nx : nx + n] = Vz
    M[nx + n :, :nx] = C
    Nw = np.zeros((4 * n, n))
    Nw[:nx] = B @ Lw
    Nw[nx : nx + n] = Vw
    Nw[nx + n :] = np.eye(n)
    rho = float(np.max(np.abs(np.linalg.eigvals(M))))
    return EICTickLoop(M, Nw, Kz, Lw, rho, float(rate_hz), float(velocity_cutoff))
