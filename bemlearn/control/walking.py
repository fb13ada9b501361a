"""Walking controller: gait tracking with the torso balanced by an EIC internal loop (eq. 3, 8, 9).

Each control tick (115 Hz in the paper) works in the stance-relative coordinates of the
pinned model (:func:`bemlearn.control.gait.stance_frame`: leg 1 = stance, legs swapped
when the walker stands on leg 2), with D, h = C q̇ + G − τ_p of the *nominal* pinned
model (``terms(q, q̇)``; single support, stance foot fixed):

1. Phase s, ṡ of the gait (ϑ = cᵀq) and the reference q_a^d = h(s), q̇_a^d = h'ṡ,
   q̈_a^d = h''ṡ² (the phase is taken to move at its current rate, s̈ = 0).
2. BEM of the desired gait (eq. 9, queried as in eq. 14): q1^e = BEM(x^d),
   x^d = [q̈_a^d, q̇_a^d, q_a^d] (B = 1, 3m = 12 columns) from any BEM source
   (:mod:`bemlearn.control.bem_sources`: the model-based BEM of the pinned model, a
   learned predictor, or zero).  Where the source has no root the last valid value is held.
3. Internal loop on the unactuated torso: v_u = −k_d,u q̇1 − k_p,u (q1 − q1^e).
4. External loop: the knees track h relative to the thigh, the hips track h in the world
   frame (thigh pitch q1 + q_hip against q1* + h_hip, q1* the gait's design torso), so the
   swing leg lands where designed whatever the torso does:
       e = q_a + S (q1 − q1*) − q_a^d,  ė = q̇_a + S q̇1 − q̇_a^d,
       v_ext = q̈_a^d − k_d ė − k_p e − S v_u,            S = [1, 0, 1, 0]ᵀ.
5. EIC combination (eq. 8 with the external loop in the null space of D_ua):
       v_a = −D_ua⁺ (D_uu v_u + h_u) + (I − D_ua⁺ D_ua) v_ext,
   and the torques of eq. (3): τ_a = D_aa v_a + D_au v_u + h_a, clipped to the limits and
   mapped back to the walker's actuators [q2, q3, q4, q5].

D_ua⁺ points almost along the stance leg (hip and half the knee): the internal loop
turns the torso with the stance hip while the body vaults over the foot under gravity
(the zero dynamics); the swing leg and the knee posture are tracked in the null space.

Deviation from :mod:`bemlearn.control.eic`: the BEM's rates along the reference
(q̇_u^e, q̈_u^e) are not fed forward.  The reference here is parametrized by the state
(the phase), not by time, and finite differences of the BEM along s amplified the
impact transients in simulation; the internal loop is a PD on q1 − q1^e.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from bemlearn.control.gait import BezierGait, stance_frame

__all__ = ["WalkingGains", "WalkingController"]

log = logging.getLogger(__name__)

_S = np.array([1.0, 0.0, 1.0, 0.0])


@dataclass(frozen=True)
class WalkingGains:
    """Gains of the walking controller (module docstring).

    Attributes:
        kp, kd: external loop, 1/s², 1/s (every actuated joint).
        kp_u, kd_u: internal loop on the torso q1, 1/s², 1/s.
        torque_limit: actuator saturation, N·m.
    """

    kp: float = 150.0
    kd: float = 25.0
    kp_u: float = 400.0
    kd_u: float = 40.0
    torque_limit: float = 20.0

    def __post_init__(self) -> None:
        for name in ("kp", "kd", "kp_u", "kd_u", "torque_limit"):
            if getattr(self, name) < 0:
                raise ValueError(f"gains.{name} must be >= 0, got {getattr(self, name)}")


class WalkingController:
    """Gait tracking with an EIC internal loop on the torso (module docstring).

    Args:
        nominal: the pinned biped (``bemlearn.robots.load("biped")``): ``terms(q, qd)`` and
            the partition (q1 unactuated).
        bem: a BEM source, ``x (B, 12) -> q1^e (B,)`` with x = [q̈_a, q̇_a, q_a] in stance-relative order.
        gait: the virtual constraints.
        gains: :class:`WalkingGains`.
    """

    def __init__(self, nominal, bem, gait: BezierGait, *, gains: WalkingGains = WalkingGains()) -> None:
        if nominal.n != 5 or nominal.unactuated_index != 0:
            raise ValueError(f"WalkingController: needs the 5-link biped with q1 unactuated, got {nominal!r}")
        self.nominal, self.bem, self.gait, self.gains = nominal, bem, gait, gains
        self.qu_e = gait.torso
        self.bem_invalid = 0
        self._x = np.empty((1, 12))

    def __call__(self, q: np.ndarray, qd: np.ndarray, stance_leg: int) -> tuple[np.ndarray, dict]:
        """Actuator torques ``u (4,)`` N·m for [q2, q3, q4, q5] of the walker, and internals.

        Args:
            q: ``(5,)`` walker coordinates [q1..q5], rad (measured).
            qd: ``(5,)`` rates, rad/s (estimated).
            stance_leg: 1 or 2.

        Returns:
            ``u`` and a dict with ``s``, ``sd`` (phase, 1/s), ``qu_e`` (rad), ``v_u``,
            ``bem_x (12,)`` (the BEM query), ``tau`` (stance-relative torques, N·m).
        """
        g, gait = self.gains, self.gait
        qs, qds = stance_frame(q, stance_leg), stance_frame(qd, stance_leg)
        s, sd = gait.phase(qs, qds)
        qa_d, qad_d, qadd_d = gait.reference(s, sd)
        x = self._x
        x[0, :4], x[0, 4:8], x[0, 8:] = qadd_d, qad_d, qa_d
        qu_e = float(np.asarray(self.bem(x)).reshape(-1)[0])
        if np.isfinite(qu_e):
            self.qu_e = qu_e
        else:
            self.bem_invalid += 1
            log.debug("BEM source returned %r at s = %.3f; holding %.4f rad", qu_e, s, self.qu_e)
        v_u = -g.kd_u * qds[0] - g.kp_u * (qs[0] - self.qu_e)
        e = qs[1:] + _S * (qs[0] - gait.torso) - qa_d
        ed = qds[1:] + _S * qds[0] - qad_d
        v_ext = qadd_d - g.kd * ed - g.kp * e - _S * v_u
        D, h = self.nominal.terms(qs, qds)
        D_ua = D[0, 1:]
        pinv = D_ua / (D_ua @ D_ua)
        v_a = -pinv * (D[0, 0] * v_u + h[0]) + v_ext - pinv * (D_ua @ v_ext)
        tau = np.clip(D[1:, 1:] @ v_a + D[1:, 0] * v_u + h[1:], -g.torque_limit, g.torque_limit)
        u = stance_frame(np.r_[0.0, tau], stance_leg)[1:]
        return u, {"s": s, "sd": sd, "qu_e": self.qu_e, "v_u": float(v_u), "bem_x": x[0].copy(), "tau": tau}
