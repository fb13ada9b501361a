"""Closed-loop defaults derived from the model: EIC gains (eq. 3, 8) and the closed-loop reference.

Part of :mod:`bemlearn.pipeline.derive` (which re-exports both functions); see there for the
model scales used.
"""

from __future__ import annotations

import math

import numpy as np

from bemlearn.pipeline.derive import Derived, RateChoice, _frequency_band, _limited_actuated, design_region, log
from bemlearn.robots.scales import bem_gain, bem_slopes, instability_rate, qa_half_ranges

__all__ = ["eic_gains", "closed_loop_reference"]


def eic_gains(robot, rate: RateChoice, *, qu_error: float | None = None) -> Derived:
    """EIC gains from the model (eq. 3, 8): critically damped loops

        internal: ω_u = min(2.2 λ, 2π·rate/20),  k_p,u = ω_u², k_d,u = 2 ω_u
        external: ω_a = ω_u / 7,                 k_p,a = ω_a², k_d,a = 2 ω_a

    (λ = √(Γ_q/D_uu)).  ω_u is lowered (down to 1.2 λ) while the linearised command for a
    q_u error of ``qu_error`` (default d/4) would exceed the ``ctrlrange``.

    Returns:
        ``Derived(EICGains, note)``.
    """
    from bemlearn.control.eic import EICGains

    lam = instability_rate(robot)
    d = design_region(robot).value
    e0 = d / 4 if qu_error is None else qu_error
    w_u = min(2.2 * lam, 2 * math.pi * rate.rate_hz / 20)
    peak = _eic_peak(robot, w_u, e0)
    while peak > 1.0 and w_u > 1.2 * lam:
        w_u = max(1.2 * lam, 0.9 * w_u)
        peak = _eic_peak(robot, w_u, e0)
    w_a = w_u / 7
    h = min(0.01, 0.02 / max(_frequency_band(robot, rate)[1], 1e-9))
    g = EICGains(kp_a=w_a**2, kd_a=2 * w_a, kp_u=w_u**2, kd_u=2 * w_u, deriv_step=h)
    note = (f"ω_u = {w_u:.3g} rad/s ({w_u / lam:.2g} λ, λ = {lam:.3g}), ω_a = ω_u/7, critically damped; "
            f"linearised command for a {e0:.3g} q_u error = {peak:.2f} × ctrlrange")
    if robot.m == 1:
        from bemlearn.control.eic_linear import eic_linear_abscissa

        ab = eic_linear_abscissa(robot, g)
        note += f"; linearised EIC loop max Re λ = {ab:.3g} 1/s"
        if ab >= 0:
            log.warning("%s: the EIC with the derived gains is unstable in its linearisation at upright (max Re λ = %.3g 1/s)", robot.name, ab)
    return Derived(g, note)


def _eic_peak(robot, w_u: float, e0: float) -> float:
    """|ctrl| / ctrl_max of the EIC's first tick for a q_u error e0 at rest at upright (linearised)."""
    import torch

    from bemlearn.control.actuator_inverse import MujocoActuatorInverse

    n, iu, ia = robot.n, robot.unactuated_index, list(robot.actuated_index)
    q = np.zeros(n)
    q[iu] = robot.qu_nominal
    D = robot.mass_matrix(torch.from_numpy(q[None]))[0].numpy()
    v_u = -(w_u**2) * e0
    D_ua = D[iu, ia]
    v_a = -D_ua / (D_ua @ D_ua) * (D[iu, iu] * v_u)
    tau = D[np.ix_(ia, ia)] @ v_a + D[ia, iu] * v_u
    inv = MujocoActuatorInverse(robot)
    raw = inv.B_pinv @ tau / inv.gainprm[:, 0]
    umax = np.where(inv.limited, inv.limit, np.inf)
    return float(np.max(np.abs(raw) / umax))


def closed_loop_reference(robot, signals: dict) -> Derived:
    """The closed-loop reference: two components at 0.2 and 0.4 × λ/2π (clipped to the
    excitation band) with amplitudes 3 : 2 scaled so that the linearised BEM peaks at d/2.

    Returns:
        ``Derived(dict of ReferenceConfig fields, note)``.
    """
    d = design_region(robot).value
    lam = instability_rate(robot)
    f_lo, f_hi = signals["frequency_hz"]
    f = np.clip(np.array([0.2, 0.4]) * lam / (2 * math.pi), f_lo, f_hi)
    g = np.max(bem_gain(bem_slopes(robot), 2 * math.pi * f), axis=0)
    w = np.array([0.6, 0.4])
    s = 0.5 * d / max(float(w @ g), 1e-12)
    limited = _limited_actuated(robot)
    cap = float(np.min(0.5 * qa_half_ranges(robot)[limited])) if limited.any() else math.inf
    s = min(s, cap, signals["n_sines"][1] * signals["amplitude"][1])
    A = tuple(float(f"{a:.4g}") for a in s * w)
    out = {"amplitudes": A, "frequencies_hz": tuple(float(f"{x:.4g}") for x in f), "phases": (0.0, 0.0), "offset": 0.0}
    return Derived(out, f"A = {A} at {tuple(round(float(x), 3) for x in f)} Hz: linearised BEM peak ≈ {s * float(w @ g):.3g}")
