"""The EIC closed loop (eq. 3, 8) with the model BEM, linearised at upright.

With a zero reference, exact model and ideal sensing, the EIC gives q̈_u = v_u and
q̈_a = v_a exactly, where (linearised, x = [q_u, q_a, q̇_u, q̇_a] about upright, q_a ∈ R^m)

    v_ext = −k_d,a q̇_a − k_p,a q_a
    q_u^e = s_pᵀ q_a + s_vᵀ q̇_a + s_aᵀ v_ext                    (linearised BEM, eq. 9)
    v_u   = −k_d,u q̇_u − k_p,u (q_u − q_u^e)
    v_a   = −D_ua⁺ (D_uu v_u + H_q x) + (I − D_ua⁺ D_ua) v_ext   (eq. 8, unactuated row; for m = 1 the
                                                                 projector vanishes: v_a = −(D_uu v_u + H_q x)/D_ua)

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

from bemlearn.robots.protocol import ControlRobot

if TYPE_CHECKING:
    from bemlearn.robots.mujoco_robot import MujocoRobot

__all__ = ["eic_linear_matrix", "eic_linear_abscissa", "EICTickLoop", "eic_controller_jacobian", "eic_tick_loop", "eic_fastest_gains"]


def _model_terms(robot: ControlRobot, eps: float = 1e-6) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """``(D_uu, D_ua (m,), H_q (2n,) over x = [q_u, q_a, q̇_u, q̇_a], slopes (3, m))`` at upright."""
    from bemlearn.robots.scales import bem_slopes

    n, iu, ia = robot.n, robot.unactuated_index, list(robot.actuated_index)
    q0 = np.zeros(n)
    q0[iu] = robot.qu_nominal
    z = np.zeros(n)
    D = robot.terms(q0, z)[0]
    order = [iu, *ia]
    Hq = np.zeros(2 * n)
    for k in range(2 * n):
        e = np.zeros(n)
        e[order[k % n]] = eps
        if k >= n:
            hp, hm = robot.terms(q0, e)[1], robot.terms(q0, -e)[1]
        else:
            hp, hm = robot.terms(q0 + e, z)[1], robot.terms(q0 - e, z)[1]
        Hq[k] = float(hp[iu] - hm[iu]) / (2 * eps)
    return float(D[iu, iu]), np.asarray(D[iu, ia], dtype=np.float64), Hq, bem_slopes(robot)


def eic_linear_matrix(robot: ControlRobot, gains, *, terms: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The ``(2n, 2n)`` matrix A of ẋ = A x (module docstring), x = [q_u, q_a, q̇_u, q̇_a] (1/s, 1/s²)."""
    Duu, Dua, Hq, (sp, sv, sa) = terms if terms is not None else _model_terms(robot)
    m = Dua.size
    n = m + 1
    g = gains
    Qa = np.zeros((m, 2 * n))
    Qa[:, 1:n] = np.eye(m)
    Qad = np.zeros((m, 2 * n))
    Qad[:, n + 1:] = np.eye(m)
    vext = -g.kd_a * Qad - g.kp_a * Qa                        # (m, 2n)
    que = sp @ Qa + sv @ Qad + sa @ vext                      # (2n,)
    eu = np.zeros(2 * n)
    eu[0] = 1.0
    edu = np.zeros(2 * n)
    edu[n] = 1.0
    vu = -g.kd_u * edu - g.kp_u * (eu - que)
    pinv = Dua / float(Dua @ Dua)
    va = -np.outer(pinv, Duu * vu + Hq) + vext - np.outer(pinv, Dua @ vext)
    A = np.zeros((2 * n, 2 * n))
    A[:n, n:] = np.eye(n)
    A[n] = vu
    A[n + 1:] = va
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


def eic_controller_jacobian(robot: MujocoRobot, gains, *, eps: float = 1e-6, rate_hz: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """∂u/∂y and ∂u/∂v ``(nu, n)`` each, of the EIC controller (:class:`~bemlearn.control.eic.EICController`
    with the model BEM of ``robot`` and a reference at rest) at upright, by central differences of the
    controller itself (``ctrl`` per rad or m, per rad/s or m/s)."""
    from bemlearn.control.actuator_inverse import MujocoActuatorInverse
    from bemlearn.control.bem_sources import ModelBEM
    from bemlearn.control.eic import EICController
    from bemlearn.robots.reference import CompositeSinusoid

    n, m = robot.n, robot.m
    ref = CompositeSinusoid(((0.0,),) * m, ((0.0,),) * m, ((0.0,),) * m, (0.0,) * m)
    inverse = MujocoActuatorInverse(robot, hold_s=None if rate_hz is None else 1.0 / rate_hz)   # held over the tick, as it runs
    ctrl = EICController(robot, ModelBEM(robot), ref, inverse, gains)
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
    Ky, Kv = eic_controller_jacobian(robot, gains, rate_hz=rate_hz)
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


def eic_fastest_gains(robot: ControlRobot, lam: float, w_max: float, *, lo: float = 1.2, hi: float = 6.0,
                      ratios: tuple[float, float] = (2.0, 60.0), grid: int = 31) -> tuple[float, float, float]:
    """``(ω_u, ω_a, max Re λ)``: the critically damped gains (k_p = ω², k_d = 2ω for each loop) whose linearised loop
    decays fastest, over ω_u ∈ [lo λ, min(hi λ, w_max)] and ω_u/ω_a ∈ ``ratios`` (log grids of ``grid`` points).
    With m ≥ 2 the stable gains of an arm whose BEM moves with the actuated positions lie on a narrow ridge
    (ω_u/ω_a growing like (ω_u/λ)²): a fixed ratio can miss it."""
    from types import SimpleNamespace

    terms = _model_terms(robot)
    best = (math.inf, lo * lam, lo * lam / 7.0)
    top = max(min(hi * lam, w_max), lo * lam)
    for wu in np.geomspace(lo * lam, top, grid):
        for r in np.geomspace(*ratios, grid):
            wa = wu / r
            g = SimpleNamespace(kp_a=wa**2, kd_a=2 * wa, kp_u=wu**2, kd_u=2 * wu)
            ab = float(np.max(np.linalg.eigvals(eic_linear_matrix(robot, g, terms=terms)).real))
            if ab < best[0]:
                best = (ab, float(wu), float(wa))
    return best[1], best[2], best[0]
