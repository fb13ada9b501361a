"""Discrete LQR of MuJoCo's own linearisation at the upright equilibrium.

The plant held over one control tick of N = ``substeps`` physics steps with a zero-order-hold
input is, linearised at x* = [q_a = 0, q_u = q_u,nominal, q̇ = 0], u = 0,

    δx_{k+1} = A_N δx_k + B_N u_k,   A_N = A^N,   B_N = Σ_{i<N} A^i B

where (A, B) is one physics step's Jacobian from ``mujoco.mjd_transitionFD`` (joint state
[q_j, q̇_j], inputs in actuator ``ctrl`` units; an RK4 model is linearised with its
integrator set to Euler, which ``mjd_transitionFD`` supports).  In the robot's coordinates q = T q_j the
state is S x_j, S = diag(T, T).  The gain minimises Σ δxᵀQδx + uᵀRu (``scipy.linalg.
solve_discrete_are``) with Bryson's rule

    Q = diag(1/x_max²),   R = diag(1/u_max²)

x_max from the design region (|q_u − nominal| ≤ 0.2 rad or less if the joint range is
smaller; actuated positions from their joint ranges, 0.5 rad / 0.5 m when unlimited;
rates from those times the instability rate), u_max = half the ``ctrlrange`` width.  If
the linear closed loop started at a typical error (q_u off by ``qu0``) needs more than the
``ctrlrange``, R is raised by 4× until it does not (at most 12 times).

Sign convention of collect: u = K e, e = [q − q_t, q̇ − q̇_t], so K = −K_lqr.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from bemlearn.errors import ArgumentError

if TYPE_CHECKING:
    from bemlearn.robots.mujoco_robot import MujocoRobot

__all__ = ["LQRResult", "linearize", "discrete_lqr"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LQRResult:
    """A discrete LQR design (module docstring).

    Attributes:
        K: ``(nu, 2n)`` gains for u = K e, e = [q − q_t, q̇ − q̇_t] in the robot's coordinates
            (ctrl units per rad or m, per rad/s or m/s).
        A: ``(2n, 2n)`` the tick map's state matrix in coordinates.
        B: ``(2n, nu)`` its input matrix.
        Q: the state weight used.
        R: the input weight used.
        rate_hz: control rate.
        substeps: physics steps per tick.
        timestep: physics step, s.
        spectral_radius: of A + B K (< 1 when stabilising).
        u_peak: max |u| / u_max of the linear closed loop from the check's initial error.
        r_scale: factor applied to Bryson's R to respect ctrlrange.
    """

    K: np.ndarray
    A: np.ndarray
    B: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    rate_hz: float
    substeps: int
    timestep: float
    spectral_radius: float
    u_peak: float
    r_scale: float


def linearize(robot: MujocoRobot, *, rate_hz: float, timestep: float | None = None, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray, int, float]:
    """Tick map (A_N, B_N) of ``robot`` (a MujocoRobot) in its coordinates at upright.

    Args:
        rate_hz: control rate, Hz; 1/rate must be a whole number of physics steps.
        timestep: physics step override, s (default: the model's).

    Returns:
        ``(A (2n, 2n), B (2n, nu), substeps, timestep)``.
    """
    model = _model_copy(robot.model, timestep)
    if int(model.opt.integrator) == int(mujoco.mjtIntegrator.mjINT_RK4):
        # mjd_transitionFD does not support RK4: linearise the same dynamics with Euler steps
        import copy

        model = copy.deepcopy(model)
        model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    h = float(model.opt.timestep)
    steps = 1.0 / (rate_hz * h)
    if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
        raise ArgumentError(f"linearize: 1/rate_hz = {1 / rate_hz} s is not a whole number of physics steps ({h} s)")
    N = int(round(steps))
    data = mujoco.MjData(model)
    n = robot.n
    q0 = np.zeros(n)
    q0[robot.unactuated_index] = robot.qu_nominal
    data.qpos[robot._qadr] = robot.Tinv_np @ q0
    mujoco.mj_forward(model, data)
    nx = 2 * model.nv + model.na
    A1 = np.zeros((nx, nx))
    B1 = np.zeros((nx, model.nu))
    mujoco.mjd_transitionFD(model, data, eps, True, A1, B1, None, None)
    A1, B1 = A1[: 2 * n, : 2 * n], B1[: 2 * n]
    AN, BN = np.eye(2 * n), np.zeros_like(B1)
    for _ in range(N):
        BN = A1 @ BN + B1
        AN = A1 @ AN
    T = robot.T_np
    S = np.block([[T, np.zeros((n, n))], [np.zeros((n, n)), T]])
    Sinv = np.linalg.inv(S)
    return S @ AN @ Sinv, S @ BN, N, h


def _model_copy(model: mujoco.MjModel, timestep: float | None) -> mujoco.MjModel:
    if timestep is None or timestep == model.opt.timestep:
        return model
    import copy

    out = copy.deepcopy(model)
    out.opt.timestep = timestep
    return out


def bryson_scales(robot: MujocoRobot, *, design_qu: float = 0.2) -> tuple[np.ndarray, np.ndarray, float]:
    """Bryson maxima ``(x_max (2n,), u_max (nu,), λ)`` (module docstring); λ = √(Γ_q/D_uu), 1/s.

    An unlimited actuated coordinate gets at least the amplitude a sine at λ needs to move the
    BEM by ``design_qu`` (a reaction wheel turns through many radians to balance).
    """
    from bemlearn.robots.scales import bem_gain, bem_slopes, instability_rate, qa_half_ranges, qu_half_range

    n, iu, ia = robot.n, robot.unactuated_index, list(robot.actuated_index)
    lam = instability_rate(robot)
    xmax = np.empty(2 * n)
    dq = min(design_qu, qu_half_range(robot))
    xmax[iu] = dq
    qa_max = qa_half_ranges(robot)
    need = dq / np.maximum(bem_gain(bem_slopes(robot), lam), 1e-12)
    limited = _limited_actuated(robot)
    xmax[ia] = np.where(limited, qa_max, np.maximum(qa_max, need))
    xmax[n:] = xmax[:n] * max(lam, 1.0)
    lo, hi = robot.model.actuator_ctrlrange[:, 0], robot.model.actuator_ctrlrange[:, 1]
    ulim = robot.model.actuator_ctrllimited.astype(bool)
    umax = np.where(ulim, 0.5 * (hi - lo), 1.0)
    return xmax, umax, lam


def _limited_actuated(robot: MujocoRobot) -> np.ndarray:
    if not robot.identity_coordinates:
        return np.ones(robot.m, dtype=bool)
    return np.array([bool(robot.model.jnt_limited[j]) for j in robot.actuated_index])


def discrete_lqr(
    robot: MujocoRobot,
    *,
    rate_hz: float,
    timestep: float | None = None,
    design_qu: float = 0.2,
    qu0: float = 0.05,
    check_s: float = 3.0,
) -> LQRResult:
    """Discrete LQR gains in collect's convention (module docstring).

    Args:
        robot: a MujocoRobot.
        rate_hz: control rate, Hz.  timestep: physics step override, s.
        design_qu: |q_u − nominal| design bound of Bryson's rule, rad (or m).
        qu0: initial q_u error of the ctrlrange check, rad (or m).
        check_s: duration of the check, s.
    """
    from scipy.linalg import solve_discrete_are

    A, B, N, h = linearize(robot, rate_hz=rate_hz, timestep=timestep)
    xmax, umax, _ = bryson_scales(robot, design_qu=design_qu)
    Q = np.diag(1.0 / xmax**2)
    R0 = np.diag(1.0 / umax**2)
    x0 = np.zeros(A.shape[0])
    x0[robot.unactuated_index] = qu0
    steps = int(math.ceil(check_s * rate_hz))
    scale = 1.0
    for _ in range(13):
        R = R0 * scale
        P = solve_discrete_are(A, B, Q, R)
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        Acl = A - B @ K
        x, peak = x0.copy(), 0.0
        for _ in range(steps):
            u = -K @ x
            peak = max(peak, float(np.max(np.abs(u) / umax)))
            x = Acl @ x
        if peak <= 1.0:
            break
        scale *= 4.0
    else:
        log.warning("discrete_lqr: %s needs %.2f× its ctrlrange for a %.3g initial q_u error even with R × %g", robot.name, peak, qu0, scale)
    rho = float(np.max(np.abs(np.linalg.eigvals(A - B @ K))))
    return LQRResult(-K, A, B, Q, R, float(rate_hz), N, h, rho, peak, scale)
