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

import numpy as np

from bemlearn.errors import RobotModelError
from bemlearn.robots.protocol import ControlRobot

__all__ = ["eic_linear_matrix", "eic_linear_abscissa"]


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
