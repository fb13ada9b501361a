"""What one soft-contact ``mj_forward`` says of the bikebot's steady turn (why the model BEM solves the KKT).

At roll φ and steer δ the state has the velocities of the hard-constraint model
(:meth:`~bemlearn.apps.bikebot.bem.BikebotBem.state`: the rigid turn at speed v) and the tyres pressed into
the floor by the depths (d_R, d_F) at which MuJoCo's soft contacts hold the frame: its vertical and pitch
accelerations vanish (Newton's method on the depths).  The motor torques are those that give δ̈ = θ̈_R = 0
in that ``mj_forward`` (a few Newton steps: the soft contact is nearly linear in them).  The roll
acceleration φ̈ is read from that single ``mj_forward`` by (E2) and its root in φ found by Brent's method.

MuJoCo's soft contact asks each contact's tangential acceleration to relax its tangential velocity
(zero here), J q̈ ≈ 0, not J q̈ = −J̇ q̇: the rolling's curvature — the turn's centripetal acceleration —
is missing, and the root lies near the lean of a bicycle running straight.
"""

from __future__ import annotations

import mujoco
import numpy as np
from scipy.optimize import brentq

from bemlearn.apps.bikebot.bem import BikebotBem, BikeState
from bemlearn.errors import NumericalError

__all__ = ["soft_contact_roll_accel", "soft_contact_roll"]


def _forward(bem: BikebotBem, data: mujoco.MjData, qpos: np.ndarray, qvel: np.ndarray, u: np.ndarray) -> np.ndarray:
    data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, u
    mujoco.mj_forward(bem.model, data)
    return data.qacc.copy()


def soft_contact_roll_accel(bem: BikebotBem, phi: float, delta: float, v: float) -> tuple[float, np.ndarray]:
    """(φ̈ (rad/s²), depths (d_R, d_F) (m)) of one soft-contact ``mj_forward`` (module docstring).

    Raises:
        NumericalError: no depths hold the frame within 30 Newton steps.
    """
    m = bem.model
    data = mujoco.MjData(m)
    s = bem.state(phi, delta, v)
    idx = [bem.dof_steer, bem.dof_rear]

    def read(depths: np.ndarray) -> tuple[np.ndarray, float]:
        q = bem.pose(phi, delta, depths=(float(depths[0]), float(depths[1])))
        a0 = _forward(bem, data, q, s.qvel, np.zeros(2))
        U = np.column_stack([_forward(bem, data, q, s.qvel, e) - a0 for e in np.eye(2)])[idx]
        u = np.linalg.solve(U, -a0[idx])
        for _ in range(5):
            u = u - np.linalg.solve(U, _forward(bem, data, q, s.qvel, u)[idx])
        acc = _forward(bem, data, q, s.qvel, u)
        euler = bem.euler_accelerations(BikeState(qpos=q, qvel=s.qvel), acc)     # (ψ̈, φ̈, θ̈)
        return np.array([acc[2], euler[2]]), float(euler[1])

    x = np.array([1e-3, 1e-3])
    for _ in range(30):
        r, phi_dd = read(x)
        if np.max(np.abs(r)) < 1e-9:
            return phi_dd, x
        eps = 1e-8
        J = np.column_stack([(read(x + eps * e)[0] - read(x - eps * e)[0]) / (2 * eps) for e in np.eye(2)])
        x = np.maximum(x - np.linalg.solve(J, r), 0.1 * x)      # a tyre stays in contact
    raise NumericalError(f"soft_contact_roll_accel: no tyre depths hold the frame at roll {phi:g}, steer {delta:g}")


def soft_contact_roll(bem: BikebotBem, delta: float, v: float, *, bracket: tuple[float, float] | None = None) -> float:
    """The root φ (rad) of the soft-contact φ̈ at steer ``delta`` (rad) and speed ``v`` (m/s).

    Args:
        bracket: default from 1e-3 to 0.5 rad on the side of sgn δ (the soft contact's root is a lean of
                a few degrees at most: module docstring).

    Raises:
        NumericalError: φ̈ does not change sign over the bracket.
    """
    lo, hi = bracket if bracket is not None else (float(np.copysign(1e-3, delta)), float(np.copysign(0.5, delta)))
    f = lambda phi: soft_contact_roll_accel(bem, phi, delta, v)[0]  # noqa: E731
    if f(lo) * f(hi) > 0:
        raise NumericalError(f"soft_contact_roll: φ̈ does not change sign over [{lo:g}, {hi:g}] rad")
    return float(brentq(f, lo, hi, xtol=1e-10))
