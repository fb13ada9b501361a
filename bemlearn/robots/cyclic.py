"""Cyclic coordinates: positions the dynamics do not depend on.

A coordinate q_i is *cyclic* when neither the mass matrix nor the other terms of eq. (1) change
with it:

    ∂D/∂q_i = 0,   ∂h/∂q_i = 0,   h = C(q, q̇) q̇ + G(q) − τ_p(q, q̇)

(a wheel's angle, a cart's position on a level rail without springs).  Then Γ_0 and the model-based
BEM (eq. 6–9) do not depend on q_i either: a BEM learned over x = [q̈_a, q̇_a, q_a, q̈_u, q̇_u]
(eq. 11) need not take a cyclic q_a as an input.  :func:`cyclic_coordinates` tests the definition
at a few seeded states (central differences of D and h in q_i, relative to their size).

:func:`unbounded_cyclic` names the actuated ones the learned BEM leaves out of its inputs (``dataset.cyclic``):
cyclic *and* without a joint range.  A bounded cyclic coordinate (a cart on its rail) stays within the range the
data visit; an unbounded one (a wheel's angle, a free turntable's or arm's turn) runs on without bound while the
robot is used, and as an input it would put every query beyond the training data after a few turns.
"""

from __future__ import annotations

import numpy as np

from bemlearn.robots.protocol import ControlRobot

__all__ = ["cyclic_coordinates", "unbounded_cyclic"]


def cyclic_coordinates(robot: ControlRobot, *, n_states: int = 4, step: float = 0.37, rtol: float = 1e-9,
                       seed: int = 0) -> tuple[bool, ...]:
    """Per coordinate, whether D and h of eq. (1) are the same when only that coordinate moves.

    Args:
        robot: the robot (its single-state ``terms``).
        n_states: seeded random states (q within ±0.5 of the nominal pose, q̇ within ±2) at which it is tested.
        step: the shift of the coordinate, rad (m for a slide).
        rtol: tolerance relative to max(|D|, |h|) at the state.
        seed: seed of the states.

    Returns:
        ``(n,)`` booleans in coordinate order.
    """
    rng = np.random.default_rng(seed)
    n = robot.n
    nominal = np.zeros(n)
    nominal[robot.unactuated_index] = robot.qu_nominal
    cyclic = np.ones(n, dtype=bool)
    for _ in range(n_states):
        q = nominal + rng.uniform(-0.5, 0.5, n)
        qd = rng.uniform(-2.0, 2.0, n)
        D0, h0 = robot.terms(q, qd)
        scale = max(float(np.abs(D0).max()), float(np.abs(h0).max()), 1e-300)
        for i in np.flatnonzero(cyclic):
            shifted = q.copy()
            shifted[i] += step
            D1, h1 = robot.terms(shifted, qd)
            if max(float(np.abs(D1 - D0).max()), float(np.abs(h1 - h0).max())) > rtol * scale:
                cyclic[i] = False
    return tuple(bool(c) for c in cyclic)


def unbounded_cyclic(robot: ControlRobot, cyclic: tuple[bool, ...] | None = None) -> tuple[str, ...]:
    """The actuated coordinates that are cyclic (:func:`cyclic_coordinates`) and have no joint range, by name.

    Only a :class:`~bemlearn.robots.MujocoRobot` declares ranges; any other robot gives ``()`` (nothing is known
    to be unbounded).  ``cyclic``: :func:`cyclic_coordinates` ``(robot)`` when the caller has it already.
    """
    from bemlearn.robots.mujoco_robot import MujocoRobot
    from bemlearn.robots.scales import qa_limited

    if not isinstance(robot, MujocoRobot):
        return ()
    cyclic = cyclic_coordinates(robot) if cyclic is None else cyclic
    limited = qa_limited(robot)
    return tuple(robot.joint_names[i] for j, i in enumerate(robot.actuated_index) if cyclic[i] and not limited[j])
