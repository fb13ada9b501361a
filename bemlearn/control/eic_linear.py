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

import numpy as np

from bemlearn.robots.protocol import ControlRobot

__all__ = ["eic_linear_matrix", "eic_linear_abscissa", "eic_fastest_gains"]


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
