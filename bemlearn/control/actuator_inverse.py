"""The inverse of MuJoCo's actuator model, read from the MjModel: τ_a (eq. 3) → ``ctrl``.

For a joint-transmission actuator i with gear g_i on joint j(i) (``general``/``motor``/
``position``/``velocity`` with ``dyntype="none"``), MuJoCo applies

    f_i = gain_i · ctrl_i + b0_i + b1_i · l_i + b2_i · l̇_i,   l_i = g_i q_j,  l̇_i = g_i q̇_j
    gain_i = a0_i + a1_i · l_i + a2_i · l̇_i          (gaintype fixed: a1 = a2 = 0)

and the generalized force Σ_i B_{:,i} f_i, B = T⁻ᵀ B_j (:attr:`MujocoRobot.input_matrix`).
Given the actuated generalized force τ_a (m,) the actuator forces are f = B_a⁺ τ_a (the least-norm split when
several actuators drive one coordinate, :mod:`bemlearn.robots.actuation`) and

    ctrl_i = (f_i − b0_i − b1_i l_i − b2_i l̇_i) / gain_i,

clipped to ``ctrlrange`` where ``ctrllimited``.  When the command is held over a tick of ``hold_s`` seconds, a
servo with velocity feedback relaxes within the tick (eq. A3 of :mod:`bemlearn.robots.actuation`): its force
tends to the steady load f_L = B_a⁺ h_a (h = C q̇ + G − τ_p of eq. 1 now) and the rest decays, so the first
instant's force that gives the mean f over the tick is

    f_0 = f_L + φ_i (f − f_L)                                                                        (A4)

(φ_i = 1, f_0 = f, for an actuator without velocity feedback).  The Quanser motor of the shipped Furuta
(gain k_u, b2 = −b_emf) gives ctrl = (τ + b_emf θ̇)/k_u, the Quanser motor law (``bemlearn.apps.furuta.motor``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np

from bemlearn.errors import RobotModelError

if TYPE_CHECKING:
    from bemlearn.robots.mujoco_robot import MujocoRobot

__all__ = ["MujocoActuatorInverse"]

_GAIN_OK = (int(mujoco.mjtGain.mjGAIN_FIXED), int(mujoco.mjtGain.mjGAIN_AFFINE))
_BIAS_OK = (int(mujoco.mjtBias.mjBIAS_NONE), int(mujoco.mjtBias.mjBIAS_AFFINE))


class MujocoActuatorInverse:
    """``command(tau_a (m,), q (n,), qd (n,)) -> ctrl (nu,)`` for a MujocoRobot (module docstring).

    Args:
        robot: a :class:`~bemlearn.robots.MujocoRobot` (its model, coordinate map and B).
        hold_s: the control tick, s, when the command is held over it: f is then the tick's mean force, and an
            actuator with velocity feedback (a velocity servo, back-EMF) that settles within the tick (φ ≥ 2, eq. A5
            of :mod:`bemlearn.robots.actuation`) starts at φ f (A3); the others keep f now.  ``None``: f is the force now.

    Raises:
        ValueError: an actuator with dynamics (``dyntype`` ≠ none) or a gain/bias type
            other than fixed/affine, naming the actuator.
    """

    def __init__(self, robot: MujocoRobot, *, hold_s: float | None = None) -> None:
        model = robot.model
        for i in range(model.nu):
            name = model.actuator(i).name or f"#{i}"
            if int(model.actuator_dyntype[i]) != int(mujoco.mjtDyn.mjDYN_NONE):
                raise RobotModelError(f"{robot.source}: actuator {name!r} has activation dynamics; the EIC needs dyntype='none'")
            if int(model.actuator_gaintype[i]) not in _GAIN_OK or int(model.actuator_biastype[i]) not in _BIAS_OK:
                raise RobotModelError(f"{robot.source}: actuator {name!r} needs gaintype fixed/affine and biastype none/affine")
        self.Tinv = robot.Tinv_np
        self.identity = bool(robot.identity_coordinates)   # T = I: the map would only multiply by ones
        self.B_pinv = robot.actuation.force_split  # (nu, m) B_a⁺: the least-norm split over a coordinate's actuators
        self.gear = model.actuator_gear[:, 0].copy()
        self.joint_dof = np.array([int(model.jnt_dofadr[model.actuator_trnid[i, 0]]) for i in range(model.nu)], dtype=np.int64)
        self.dof_col = {int(a): k for k, a in enumerate(robot._dadr)}
        self.cols = np.array([self.dof_col[int(d)] for d in self.joint_dof], dtype=np.int64)
        self.gainprm = model.actuator_gainprm[:, :3].copy()
        self.affine_gain = model.actuator_gaintype == int(mujoco.mjtGain.mjGAIN_AFFINE)
        self.biasprm = np.where((model.actuator_biastype == int(mujoco.mjtBias.mjBIAS_AFFINE))[:, None], model.actuator_biasprm[:, :3], 0.0)
        self.lo, self.hi = model.actuator_ctrlrange[:, 0].copy(), model.actuator_ctrlrange[:, 1].copy()
        self.limited = model.actuator_ctrllimited.astype(bool)
        self.limit = np.where(self.limited, np.maximum(np.abs(self.lo), np.abs(self.hi)), np.inf)
        self.hold = np.ones(model.nu)
        if hold_s is not None:   # the command is held over a tick: a fast servo's first-instant force φ × the mean (A3, A5)
            from bemlearn.robots.actuation import held_servo_factors

            if (phi := held_servo_factors(robot, hold_s)) is not None:
                self.hold = phi
        self._robot = robot if bool(np.any(self.hold != 1.0)) else None
        self._ia = list(robot.actuated_index)

    def command(self, tau_a: np.ndarray, q: np.ndarray, qd: np.ndarray, *, clip: bool = True) -> np.ndarray:
        """``tau_a (m,)`` generalized forces (N·m or N), ``q, qd (n,)`` → ``ctrl (nu,)``, clipped to the
        ``ctrlrange`` unless ``clip=False``."""
        qj, qdj = (q, qd) if self.identity else (self.Tinv @ q, self.Tinv @ qd)
        length = self.gear * qj[self.cols]
        velocity = self.gear * qdj[self.cols]
        f = self.B_pinv @ tau_a
        if self._robot is not None:   # held servo: the load h_a is steady over the tick, the rest decays (A4)
            load = self.B_pinv @ self._robot.terms(q, qd)[1][self._ia]
            f = load + self.hold * (f - load)
        gain = self.gainprm[:, 0] + np.where(self.affine_gain, self.gainprm[:, 1] * length + self.gainprm[:, 2] * velocity, 0.0)
        bias = self.biasprm[:, 0] + self.biasprm[:, 1] * length + self.biasprm[:, 2] * velocity
        ctrl = (f - bias) / gain
        return np.where(self.limited, np.clip(ctrl, self.lo, self.hi), ctrl) if clip else ctrl
