"""A torque logged on the unactuated joint, weighed against gravity (issue 28).

The BEM is the q_u-row of the dynamics with Γ_u = 0 (eq. 2, 6–9): Γ_0(q_u^e, q_a, q̇_a, q̈_a) = 0.
A torque τ_u on q_u (a friction compensation, an applied perturbation) moves the equilibrium to
Γ_0(q_u^e + Δ, …) = τ_u, so to first order

    Δ = τ_u / k_g,   k_g = ∂Γ_0/∂q_u at the upright   (N·m/rad; N/m for a slide),

and a map learned from such data mixes τ_u in.  With a model (``robot:`` or ``model:``)
:func:`unactuated_torque_metrics` converts the logged τ_u's rms into that equilibrium shift;
:func:`bemlearn.pipeline.verdict.judge_run` calls the run degraded when the shift exceeds the
BEM accuracy target (RMSE ≤ 0.05 d, d the design bound): the gravity torque that holds q_u at
d is k_g·d, so this is τ_u,rms > 0.05 · k_g · d.  Without a model the torque is reported only.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["gravity_stiffness", "unactuated_torque_metrics"]


def gravity_stiffness(robot, *, step: float = 1e-5) -> float:
    """k_g = |∂Γ_0/∂q_u| at the upright (q_a = q̇_a = q̈_a = 0, q_u = ``robot.qu_nominal``), N·m/rad (N/m for a slide);
    central difference of ``robot.gamma0_scalar`` over ±``step``."""
    z = np.zeros(robot.m)
    g_plus = robot.gamma0_scalar(robot.qu_nominal + step, z, z, z)
    g_minus = robot.gamma0_scalar(robot.qu_nominal - step, z, z, z)
    return abs(float(g_plus - g_minus)) / (2 * step)


def unactuated_torque_metrics(traj, robot=None, *, bound: float | None = None) -> dict[str, Any] | None:
    """The torque logged on q_u (``traj.tau``), weighed against gravity when ``robot`` is given.

    Args:
        traj: the training :class:`~bemlearn.data.Trajectory`.
        robot: the model (``None``: model-free; the torque is reported only).
        bound: the design bound d (rad or m); with ``robot`` the accuracy target is 0.05 d.

    Returns:
        ``None`` when no torque on q_u was logged, else ``{"joint", "unit", "rms", "mean", "max_abs"}``
        and, with a model, ``"stiffness"`` (k_g), ``"shift_rms"`` (τ_rms / k_g, q_u's unit),
        ``"target"`` (0.05 d) and ``"gravity_scale"`` (k_g · d, the torque's unit).
    """
    from bemlearn.pipeline.verdict import RMSE_OF_BOUND

    joint = traj.meta.unactuated
    if joint not in traj.meta.torque_joints:
        return None
    tau = traj.torque(joint)
    slide = traj.meta.kind_of(joint) == "slide"
    out: dict[str, Any] = {"joint": joint, "unit": "N" if slide else "N·m", "rms": float(np.sqrt(np.mean(tau**2))),
                           "mean": float(np.mean(tau)), "max_abs": float(np.max(np.abs(tau)))}
    if robot is not None and bound is not None:
        k = gravity_stiffness(robot)
        out.update(stiffness=k, stiffness_unit="N/m" if slide else "N·m/rad", bound=bound, target=RMSE_OF_BOUND * bound,
                   gravity_scale=k * bound, shift_rms=out["rms"] / k if k > 0 else math.inf)
    return out
