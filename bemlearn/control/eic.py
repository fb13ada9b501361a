"""The external/internal convertible (EIC) controller with a BEM in the loop (eq. 3, 8).

Per control tick, with the measured q, estimated q̇ and the desired q_a^d(t):

1. External (tracking) loop:  v_a^ext = q̈_a^d − k_d,a (q̇_a − q̇_a^d) − k_p,a (q_a − q_a^d).
2. BEM: q_u^e = BEM(v_a^ext, q̇_a, q_a) from a pluggable source (learned predictor, model,
   zero) — the instantaneous equilibrium of the unactuated row under v_a^ext (eq. 6, 14).
   With ``momentum_correction`` (default) the source's full map (eq. 11) is evaluated at
   the BEM's own rates instead: q_u^* = f(v_a^ext, q̇_a, q_a, q̈_u^e, q̇_u^e).  Why: with the
   plain BEM, perfect balance gives v_a^int − v_a^ext = −ΔΓ/D_ua (Lemma 1, eq. 10), i.e. the
   rate of momentum Ḣ_u leaks into the actuated acceleration; linearized about upright
   this is θ̈ ≈ v_ext − (D_uu / Γ_q) v̈_ext, a (1 + D_uu ω²/Γ_q) gain at frequency ω.  One
   correction step removes the first-order term; iterating it would converge only for
   ω² < Γ_q/D_uu (≈ (6.6 rad/s)² for the Furuta), so references well below ~1 Hz are
   tracked best (measured: `bemlearn bench sim`).
3. Internal (balance) loop:  v_u = q̈_u^e − k_d,u (q̇_u − q̇_u^e) − k_p,u (q_u − q_u^e).
   The BEM's time derivatives are taken *along the reference*: the same source is
   evaluated at x^d(t ± h) = [q̈_a^d, q̇_a^d, q_a^d](t ± h) and differenced centrally
   (q̇_u^e ≈ (b₊ − b₋)/2h, q̈_u^e ≈ (b₊ − 2b₀ + b₋)/h²).  The reference is known
   analytically, so this is free of sensor noise; with a known control rate these
   reference-only rows are evaluated for ``chunk`` ticks ahead in one batched call, and the
   source is called every tick for the measured state.
4. Actuated acceleration (eq. 8, with the external loop in the null space of D_ua):
       v_a = −D_ua⁺ (D_uu v_u + h_u) + (I − D_ua⁺ D_ua) v_a^ext
   (for m = 1 the projector vanishes and v_a = v_a^int).
5. Torque (eq. 3) with q̈_u = v_u:  τ_a = D_aa v_a + D_au v_u + h_a, h = C q̇ + G − τ_p,
   mapped to the actuator (volts for the Furuta motor, with saturation).

D, h come from a *nominal* robot (``terms(q, q̇)``), which may differ from the simulated one.

Guards.  A BEM value that is NaN, infinite or outside ``qu_limits`` (default: the nominal
robot's admissible q_u range) never reaches the actuator: the last valid value is held
and :attr:`EICController.bem_rejected` counts the ticks where that happened (the BEM
rates along the reference are held the same way).  A non-finite command is replaced by
the last finite one (zero at the start) and counted in :attr:`EICController.command_rejected`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from bemlearn.config import Limit, config_limits
from bemlearn.control.bem_sources import BEMSource
from bemlearn.errors import ArgumentError, ConfigError
from bemlearn.robots.protocol import ControlRobot
from bemlearn.robots.reference import CompositeSinusoid

__all__ = ["EICGains", "EICController", "Actuator"]


class Actuator(Protocol):
    """Maps the actuated generalized forces to commands (e.g. :class:`~bemlearn.control.MujocoActuatorInverse`)."""

    def command(self, tau_a: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """``tau_a (m,)`` N·m or N, ``q, qd (n,)`` → commands ``(nu,)`` (e.g. V)."""
        ...


@dataclass(frozen=True)
class EICGains:
    """Gains of the EIC law (module docstring).

    Attributes:
        kp_a: external loop, proportional, 1/s² (same for every actuated joint; ``null``: derived from the
            model, ``bemlearn.pipeline.derive.eic_gains``).
        kd_a: external loop, derivative, 1/s (same for every actuated joint; ``null``: derived from the model).
        kp_u: internal loop on q_u, proportional, 1/s² (``null``: derived from the model).
        kd_u: internal loop on q_u, derivative, 1/s (``null``: derived from the model).
        deriv_step: h of the BEM derivatives along the reference, s.
        momentum_correction: evaluate the BEM source's full map (eq. 11) at the BEM's own
            rates, q_u^* = f(v_a^ext, q̇_a, q_a, q̈_u^e, q̇_u^e), instead of at q̇_u = q̈_u = 0
            (eq. 14).  By Lemma 1 the plain BEM leaves v_a^int − v_a^ext = −ΔΓ/D_ua = −Ḣ_u/D_ua
            (plus damping), which drives a tracking error; the correction removes it.
    """

    kp_a: float | None = None
    kd_a: float | None = None
    kp_u: float | None = None
    kd_u: float | None = None
    deriv_step: float = 0.01
    momentum_correction: bool = True


config_limits(EICGains, kp_a=Limit(ge=0, unit="1/s^2"), kd_a=Limit(ge=0, unit="1/s"), kp_u=Limit(ge=0, unit="1/s^2"),
              kd_u=Limit(ge=0, unit="1/s"), deriv_step=Limit(gt=0, le=1, unit="s"))


class EICController:
    """EIC control law (module docstring).

    Args:
        nominal: the controller's model, with ``terms(q, qd) -> (D (n,n), h (n,))`` and the partition.
        bem: a BEM source, ``x (B, 3m) -> (B,)`` and its ``full`` map.
        reference: q_a^d(t).
        actuator: maps τ_a to commands.
        gains: :class:`EICGains` with all four loop gains set (derived from the model by
            ``bemlearn.pipeline.complete_section(robot, "simulate", config)``, or given).

    Raises:
        ValueError: a gain of ``gains`` is unset, or the reference's m is not the robot's.
    """

    def __init__(self, nominal: ControlRobot, bem: BEMSource, reference: CompositeSinusoid, actuator: Actuator, gains: EICGains, *,
                 rate_hz: float | None = None, chunk: int = 400, qu_limits: tuple[float, float] | None = None) -> None:
        if reference.m != nominal.m:
            raise ArgumentError(f"EICController: reference has {reference.m} actuated joints, robot {nominal.name!r} has {nominal.m}")
        unset = [n for n in ("kp_a", "kd_a", "kp_u", "kd_u") if getattr(gains, n) is None]
        if unset:
            raise ConfigError(f"EICController: gains {unset} not set; derive them from the model "
                             "(bemlearn.pipeline.derive.eic_gains) or give them")
        self.nominal, self.bem, self.reference, self.actuator, self.gains = nominal, bem, reference, actuator, gains
        self.ia = np.array(nominal.actuated_index)
        self._aa = np.ix_(self.ia, self.ia)
        self.iu = nominal.unactuated_index
        self.m = nominal.m
        self._x = np.empty((1, 3 * nominal.m))
        self._xf = np.empty((1, 3 * nominal.m + 2))
        # with a known control rate, the reference-only quantities (q_a^d and the BEM along it at
        # t and t ± h) are evaluated ``chunk`` ticks at a time in one batched call
        self.rate_hz, self.chunk = rate_hz, chunk
        self._cache_k0: int | None = None
        self.qu_limits = tuple(qu_limits) if qu_limits is not None else tuple(nominal.qu_range)
        self.bem_rejected = 0
        self.command_rejected = 0
        self._qu_last = float(nominal.qu_nominal)
        self._rates_last = (0.0, 0.0)
        self._u_last: np.ndarray | None = None

    def _valid(self, v) -> bool:
        """Every value of ``v`` (a float or an array) finite and inside :attr:`qu_limits`."""
        lo, hi = self.qu_limits
        values = (v,) if isinstance(v, float) else np.asarray(v, dtype=np.float64).ravel().tolist()
        return all(math.isfinite(x) and lo <= x <= hi for x in values)

    def _reference_terms(self, t: float):
        """q_a^d, q̇_a^d, q̈_a^d at t and the BEM along the reference at (t − h, t, t + h)."""
        g = self.gains
        h = g.deriv_step
        if self.rate_hz is None:
            ts = np.array([t - h, t, t + h])
            qa_d, qad_d, qadd_d = self.reference.evaluate(ts)
            x = np.concatenate([qadd_d, qad_d, qa_d], axis=1)
            return qa_d[1], qad_d[1], qadd_d[1], self.bem(x)
        k = int(round(t * self.rate_hz))
        k0 = self._cache_k0
        if k0 is None or not (k0 <= k < k0 + self.chunk):
            ks = np.arange(k, k + self.chunk)
            tk = ks / self.rate_hz
            ts = np.concatenate([tk - h, tk, tk + h])
            qa_d, qad_d, qadd_d = self.reference.evaluate(ts)
            b = self.bem(np.ascontiguousarray(np.concatenate([qadd_d, qad_d, qa_d], axis=1))).reshape(3, self.chunk)
            n = self.chunk
            self._cache = (qa_d[n : 2 * n], qad_d[n : 2 * n], qadd_d[n : 2 * n], b)
            self._cache_k0 = k0 = k
        i = k - k0
        qa_d, qad_d, qadd_d, b = self._cache
        return qa_d[i], qad_d[i], qadd_d[i], b[:, i]

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, dict[str, float | np.ndarray]]:
        """Commands ``u (nu,)`` and a dict of internals for logging.

        Args:
            t: time, s.
            q: ``(n,)`` measured coordinates, rad (m for slides).
            qd: ``(n,)`` estimated rates, rad/s (m/s for slides).
        """
        g, m, ia, iu = self.gains, self.m, self.ia, self.iu
        h = g.deriv_step
        qa_d, qad_d, qadd_d, b = self._reference_terms(t)
        qa, qad = q[ia], qd[ia]
        v_ext = qadd_d - g.kd_a * (qad - qad_d) - g.kp_a * (qa - qa_d)
        rejected = False
        if self._valid(b):
            qud_e = (b[2] - b[0]) / (2 * h)  # BEM rates along the reference
            qudd_e = (b[2] - 2 * b[1] + b[0]) / (h * h)
            self._rates_last = (qud_e, qudd_e)
        else:
            qud_e, qudd_e = self._rates_last
            rejected = True
        if g.momentum_correction:
            xf = self._xf
            xf[0, :m], xf[0, m : 2 * m], xf[0, 2 * m : 3 * m] = v_ext, qad, qa
            xf[0, 3 * m], xf[0, 3 * m + 1] = qudd_e, qud_e
            qu_e = float(self.bem.full(xf)[0])
        else:
            x = self._x
            x[0, :m], x[0, m : 2 * m], x[0, 2 * m :] = v_ext, qad, qa
            qu_e = float(self.bem(x)[0])
        if self._valid(qu_e):
            self._qu_last = qu_e
        else:
            qu_e = self._qu_last
            rejected = True
        self.bem_rejected += rejected
        v_u = qudd_e - g.kd_u * (qd[iu] - qud_e) - g.kp_u * (q[iu] - qu_e)
        D, hv = self.nominal.terms(q, qd)
        D_ua = D[iu, ia]  # (m,)
        pinv = D_ua / (D_ua @ D_ua)  # D_ua⁺ of the 1×m row, (m,)
        v_a = -pinv * (D[iu, iu] * v_u + hv[iu]) + v_ext - pinv * (D_ua @ v_ext)
        tau_a = D[self._aa] @ v_a + D[ia, iu] * v_u + hv[ia]
        u = self.actuator.command(tau_a, q, qd)
        if not np.all(np.isfinite(u)):
            self.command_rejected += 1
            u = self._u_last.copy() if self._u_last is not None else np.zeros_like(u, dtype=np.float64)
        self._u_last = u
        return u, {"qu_e": qu_e, "qud_e": float(qud_e), "qudd_e": float(qudd_e), "v_ext": v_ext, "v_u": float(v_u), "tau_a": tau_a}
