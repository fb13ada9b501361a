"""Model scales of a balance robot at upright, from which defaults are derived.

* Instability rate of the unactuated row with the actuated joints held (eq. 5 linearised):
      D_uu δq̈_u = Γ_q δq_u,   Γ_q = −∂Γ_0/∂q_u,   λ = √(Γ_q / D_uu)   (1/s)
* Linearised BEM (eq. 9) about upright, per actuated coordinate j:
      q_u^e ≈ q_u,nominal + s_p,j q_a,j + s_v,j q̇_a,j + s_a,j q̈_a,j
  so a reference component A sin ωt on joint j moves the BEM by A |s_p,j − s_a,j ω²| (and
  s_v,j ω in quadrature).
* Half ranges of the coordinates (joint ``range`` when limited, else a default).

Units follow the joint (rad or m).
"""

from __future__ import annotations

import math

import numpy as np

from bemlearn.errors import RobotModelError
from bemlearn.robots.bem import find_roots
from bemlearn.robots.mujoco_robot import MujocoRobot
from bemlearn.robots.protocol import BalanceRobot, ControlRobot

__all__ = ["upright_stiffness", "instability_rate", "bem_slopes", "velocity_stiffening_speed", "qu_half_range", "qa_half_ranges", "qa_limited", "bem_gain", "design_bound", "UNLIMITED_HALF_RANGE", "DESIGN_QU"]

UNLIMITED_HALF_RANGE = 0.5
"""Half range assumed for an unlimited actuated coordinate, rad or m."""

DESIGN_QU = 0.2
"""The BEM range the data must cover, |q_u^e − nominal| ≤ 0.2 in q_u's unit (rad for a hinge, m for a slide)."""


def design_bound(robot: BalanceRobot) -> float:
    """d = min(:data:`DESIGN_QU`, q_u half range): the half width of the BEM design region, q_u's unit."""
    return float(min(DESIGN_QU, qu_half_range(robot)))


def upright_stiffness(robot: ControlRobot, *, step: float = 1e-5) -> tuple[float, float]:
    """``(Γ_q, D_uu)`` at q_u,nominal with the actuated coordinates at rest at 0: Γ_q = −∂Γ_0/∂q_u by a central
    difference of ``step`` (N·m/rad or N/m; > 0 where the pose falls without control) and D_uu (kg·m² or kg)."""
    n, iu = robot.n, robot.unactuated_index
    z = np.zeros(robot.m)
    gq = -(robot.gamma0_scalar(robot.qu_nominal + step, z, z, z) - robot.gamma0_scalar(robot.qu_nominal - step, z, z, z)) / (2 * step)
    q0 = np.zeros(n)
    q0[iu] = robot.qu_nominal
    return float(gq), float(robot.terms(q0, np.zeros(n))[0][iu, iu])


def instability_rate(robot: ControlRobot, *, step: float = 1e-5) -> float:
    """λ = √(Γ_q / D_uu) at upright (1/s); see the module docstring.

    Raises:
        RobotModelError: Γ_q ≤ 0: the nominal pose is stable without control (a hanging pendulum),
            so there is nothing to balance there and no instability rate.
    """
    gq, duu = upright_stiffness(robot, step=step)
    if not gq > 0:
        raise RobotModelError(
            f"robot {robot.name!r}: q_u = {robot.qu_nominal:g} is a stable pose without control (Γ_q = −∂Γ_0/∂q_u = "
            f"{gq:.4g} ≤ 0: gravity pulls it back), not an upright to balance; {getattr(robot, 'qu_nominal_note', '')}".rstrip("; "))
    return math.sqrt(gq / duu)


def bem_slopes(robot: ControlRobot, *, step: float = 1e-4, at: np.ndarray | None = None) -> np.ndarray:
    """``(3, m)`` rows (s_p, s_v, s_a): ∂q_u^e/∂q_a, ∂/∂q̇_a, ∂/∂q̈_a at upright (module docstring).

    Central differences of the model BEM (eq. 9: the root of Γ_0 nearest q_u,nominal in
    :attr:`qu_range`, :func:`~bemlearn.robots.bem.find_roots`) at ±``step`` on each input.

    Args:
        at: ``(3, m)`` the actuated motion (q_a, q̇_a, q̈_a) about which to differentiate (joint units; default
            rest at q_a = 0).  A turntable's yaw ψ turns the direction a pole balances: there s_a of the two slides
            is (cos ψ, sin ψ)/g, which the slopes at rest (ψ = 0) do not show.
    """
    m = robot.m
    rows = np.zeros((6 * m, 3, m))
    if at is not None:
        rows += np.asarray(at, dtype=np.float64).reshape(1, 3, m)
    for k in range(3):
        for j in range(m):
            rows[(2 * k) * m + j, k, j] = step
            rows[(2 * k + 1) * m + j, k, j] = -step

    def gamma0(x: np.ndarray, problems: np.ndarray) -> np.ndarray:  # (R, K) candidate q_u -> Γ_0 (R, K)
        return np.array([[robot.gamma0_scalar(float(qu), *rows[p]) for qu in row] for row, p in zip(x, problems)])

    lo, hi = robot.qu_range
    qu = find_roots(gamma0, len(rows), lo=lo, hi=hi, nominal=robot.qu_nominal)[0]
    if not np.all(np.isfinite(qu)):
        raise RobotModelError(f"bem_slopes: robot {robot.name!r} has no BEM near upright")
    out = np.empty((3, m))
    for k in range(3):
        for j in range(m):
            out[k, j] = (qu[(2 * k) * m + j] - qu[(2 * k + 1) * m + j]) / (2 * step)
    return out


def velocity_stiffening_speed(robot: ControlRobot, *, step: float = 1e-5) -> np.ndarray:
    """``(m,)`` per actuated coordinate j the speed v_j at which its velocity alone (others at rest at 0, q_u at
    nominal) doubles the upright's stiffness Γ_q = −∂Γ_0/∂q_u: the velocity's forces then tip the pole as hard as
    gravity does, the upright diverges at √2 λ and the BEM's response to the accelerations is halved (a pole on a
    turntable spinning at ψ̇: Γ_q(ψ̇) = Γ_q(0) + ψ̇² (I_⊥ + m l² − I_∥), so v = √(m g l / (I_⊥ + m l² − I_∥)) ≈ λ
    for a thin rod).  Velocity forces are quadratic in the velocities (eq. 1: C(q, q̇) q̇; damping does not
    depend on q_u), so Γ_q(v e_j) = Γ_q(0) + c_j v², c_j from one evaluation at unit speed:

        v_j = √(Γ_q(0) / |c_j|)     (∞ where c_j = 0: the velocity does not change the balance, e.g. a slide)
    """
    m, z = robot.m, np.zeros(robot.m)
    qn = robot.qu_nominal

    def gq(qad: np.ndarray) -> float:
        return -(robot.gamma0_scalar(qn + step, z, qad, z) - robot.gamma0_scalar(qn - step, z, qad, z)) / (2 * step)

    g0 = gq(z)
    out = np.full(m, math.inf)
    for j in range(m):
        e = np.zeros(m)
        e[j] = 1.0
        c = gq(e) - g0
        if abs(c) > 1e-9 * max(abs(g0), 1e-300) and g0 > 0:
            out[j] = math.sqrt(g0 / abs(c))
    return out


def bem_gain(slopes: np.ndarray, omega: float | np.ndarray) -> np.ndarray:
    """|Δq_u^e| per unit amplitude of a sine at ω (rad/s) on each actuated joint, ``(m,)`` or ``(m, K)``."""
    w = np.asarray(omega, dtype=np.float64)
    sp, sv, sa = (s.reshape(s.shape + (1,) * w.ndim) for s in slopes)
    return np.hypot(sp - sa * w**2, sv * w)


def qu_half_range(robot: BalanceRobot) -> float:
    """Distance from q_u,nominal to the nearer end of the admissible q_u range (rad or m)."""
    lo, hi = robot.qu_range
    return float(min(hi - robot.qu_nominal, robot.qu_nominal - lo))


def qa_half_ranges(robot: BalanceRobot) -> np.ndarray:
    """``(m,)`` half ranges of the actuated coordinates: min(|lo|, |hi|) of a limited coordinate of a
    :class:`~bemlearn.robots.MujocoRobot` (its joint's range, narrowed by a freedom that rolls with it:
    :attr:`~bemlearn.robots.MujocoRobot.coordinate_limits`), else :data:`UNLIMITED_HALF_RANGE` (also when
    the model declares a coordinate map, and for a robot without a MuJoCo model)."""
    out = np.full(robot.m, UNLIMITED_HALF_RANGE)
    if not isinstance(robot, MujocoRobot):
        return out
    limits = robot.coordinate_limits
    for k, j in enumerate(robot.actuated_index):
        if (lim := limits[j]) is not None:
            out[k] = float(min(abs(lim[0]), abs(lim[1])))
    return out


def qa_limited(robot: MujocoRobot) -> np.ndarray:
    """``(m,)`` bool: which actuated coordinates have limits (all, when the model declares a coordinate map:
    their ranges are unknown and treated as limited; a free body's wheel angle is its wheels' hinge angle)."""
    if robot.coordinate_joints is None and getattr(robot, "floating", None) is None:   # a free body's wheel angle is a hinge's angle
        return np.ones(robot.m, dtype=bool)
    limits = robot.coordinate_limits
    return np.array([limits[j] is not None for j in robot.actuated_index], dtype=bool)
