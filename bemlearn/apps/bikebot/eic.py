"""EIC path following with a roll BEM: the learned, the model or the zero BEM, in the soft-contact simulation.

**External loop** (eq. 3: the actuated motion tracks its reference).  The path is a polyline with heading ψ_p
and curvature κ (positive to the left); the rear hub's signed lateral offset e_y (positive left of the path)
and heading error e_ψ = ψ − ψ_p give the desired steer

    δ^d = −atan(w κ) + k_y e_y + k_ψ e_ψ + k_i ∫ e_y dt                                           (P1)

(positive δ steers right; atan(w κ) is the kinematic bicycle's steer for the curvature, and the integral
takes up what it misses — the steer axis's tilt, the lean, the tyres; the gains put the three poles of
ė_y = v e_ψ, ė_ψ = −(v / w) Δδ with the integral at −ω_p: k_ψ = 3 ω_p w / v, k_y = 3 ω_p² w / v²,
k_i = ω_p³ w / v²).  The speed loop holds v^d.

**Internal loop** (eq. 8: the roll tracks its BEM through the steering).  The roll's BEM φ_e = BEM(δ^d, v^d)
of the actuated reference (steady turn: δ̇ = δ̈ = v̇ = 0 and φ̇ = φ̈ = 0 in the BEM's query), and

    δ_cmd = δ^d + k_φ (φ − φ_e) + k_φ̇ φ̇                                                         (P2)

with (k_φ, k_φ̇) of :func:`~bemlearn.apps.bikebot.ride.lean_gains`: the inversion of (8) with the point-mass
lean model (C2) of :mod:`~bemlearn.apps.bikebot.ride` standing in for D_uu, D_ua, G_u.  When the roll sits on
a correct BEM, δ_cmd = δ^d and the bicycle turns as the path asks; a wrong BEM leaves the steering to fight
the lean and the external loop to make up for it (path error).

**The BEMs**: ``"learned"``: a :class:`~bemlearn.apps.bikebot.learn.RollGP`'s mean at x_e, evaluated every tick
(:class:`LearnedBem`: the frozen posterior's kernel row, about 0.2 ms); ``"model"``:
:class:`~bemlearn.apps.bikebot.bem.BikebotBem` tabulated on a (v, δ) grid and interpolated bilinearly (:class:`BemTable`:
one root costs 0.2 s, too slow for a 200 Hz loop; φ_e(0) = 0 by the bicycle's mirror symmetry); ``"zero"``: φ_e = 0.

The position and heading are the simulator's (a rig's localisation is not modelled); δ, φ and the speed are the
rig's quantised sensors of :func:`~bemlearn.apps.bikebot.ride.simulate_ride`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from bemlearn.apps.bikebot.ride import RideLog, RideReference, lean_gains, simulate_ride

__all__ = ["Path2D", "circle_path", "s_curve_path", "BemTable", "LearnedBem", "EicResult", "ride_eic"]


@dataclass(frozen=True)
class Path2D:
    """A dense polyline: ``(K,)`` x, y (m), heading ψ (rad) and curvature κ (1/m, positive to the left)."""

    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    curvature: np.ndarray


def _integrate(kappa: Callable[[np.ndarray], np.ndarray], length: float, ds: float = 0.01) -> Path2D:
    s = np.arange(0.0, length + ds, ds)
    k = kappa(s)
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (k[1:] + k[:-1]) * ds)])
    x = np.concatenate([[0.0], np.cumsum(0.5 * (np.cos(psi[1:]) + np.cos(psi[:-1])) * ds)])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (np.sin(psi[1:]) + np.sin(psi[:-1])) * ds)])
    return Path2D(x=x, y=y, heading=psi, curvature=k)


def circle_path(radius: float, length: float) -> Path2D:
    """A left circle of ``radius`` (m) from the origin heading +x, ``length`` m of it."""
    return _integrate(lambda s: np.full_like(s, 1.0 / radius), length)


def s_curve_path(radius: float, period: float, length: float) -> Path2D:
    """κ(s) = sin(2π s / ``period``) / ``radius``: alternating left and right bends down to ``radius`` (m)."""
    return _integrate(lambda s: np.sin(2 * math.pi * s / period) / radius, length)


class BemTable:
    """A roll BEM tabulated on a (v, δ) grid, bilinear in between and held at the edges (module docstring).

    Args:
        speeds: ``(A,)`` m/s, increasing.
        steers: ``(B,)`` rad, increasing.
        table: ``(A, B)`` φ_e, rad.
    """

    def __init__(self, speeds, steers, table) -> None:
        from scipy.interpolate import RegularGridInterpolator

        self.speeds, self.steers = np.asarray(speeds, float), np.asarray(steers, float)
        self.table = np.asarray(table, float)
        self._interp = RegularGridInterpolator((self.speeds, self.steers), self.table)

    @classmethod
    def model(cls, speeds, steers, bem=None) -> BemTable:
        """The model roll BEM of :class:`~bemlearn.apps.bikebot.bem.BikebotBem` (steady turn); ``steers`` contain 0
        (φ_e = 0 there by the bicycle's mirror symmetry) and are symmetric: positive steers are solved, negative
        ones mirrored (φ_e(−δ) = −φ_e(δ))."""
        from bemlearn.apps.bikebot.bem import BikebotBem

        bem = bem or BikebotBem()
        steers = np.asarray(steers, float)
        roots = {}
        table = np.zeros((len(speeds), len(steers)))
        for i, v in enumerate(speeds):
            for j, d in enumerate(steers):
                if d != 0.0:
                    key = (float(v), abs(float(d)))
                    if key not in roots:
                        roots[key] = bem.roll(key[1], key[0])
                    table[i, j] = math.copysign(roots[key], d)
        return cls(speeds, steers, table)

    @classmethod
    def learned(cls, gp, speeds, steers) -> BemTable:
        """The learned roll BEM (a :class:`~bemlearn.apps.bikebot.learn.RollGP`'s mean at x_e) at every grid point
        (no symmetry imposed)."""
        V, D = np.meshgrid(np.asarray(speeds, float), np.asarray(steers, float), indexing="ij")
        return cls(speeds, steers, gp.bem(D, V))

    def __call__(self, delta: float, v: float) -> float:
        v = min(max(v, self.speeds[0]), self.speeds[-1])
        delta = min(max(delta, self.steers[0]), self.steers[-1])
        return float(self._interp([[v, delta]])[0])


class LearnedBem:
    """The learned roll BEM evaluated at every tick: a :class:`~bemlearn.apps.bikebot.learn.RollGP`'s frozen posterior
    mean at x_e = [0, 0, 0, v/r_R, δ, 0, 0] (steady turn, φ̇ = φ̈ = 0),

        φ_e = y_mean + y_std k_Z(x̃_e)ᵀ α,   x̃_e = (x_e − x_mean)/x_std     (eq. 11, 12)

    one kernel row of M support points (:meth:`~bemlearn.models.predictor_state.PredictorState.kernel_row`; about
    0.2 ms on one torch thread, which :func:`ride_eic` sets).  ``delta`` rad, ``v`` m/s → rad.
    """

    def __init__(self, gp) -> None:
        self.gp = gp
        self.rear_radius = float(gp.rear_radius)
        self._x = torch.zeros(1, gp.state.dim, dtype=torch.float64)

    def __call__(self, delta: float, v: float) -> float:
        x = self._x
        x[0, 3], x[0, 4] = v / self.rear_radius, delta
        return float(self.gp.mean_of(x)[0])


@dataclass
class EicResult:
    """One EIC ride.

    Attributes:
        log: the ride (:class:`~bemlearn.apps.bikebot.ride.RideLog`).
        roll_bem: ``(T,)`` φ_e used, rad.
        lateral: ``(T,)`` e_y, m.
        roll_error_rms, path_error_rms, path_error_max: over t ≥ ``settle_s``, rad and m (``nan`` if it fell).
        roll_vs_model_rms: RMS of φ − φ_e^model (the model BEM of the same δ^d, v^d), rad.
    """

    log: RideLog
    roll_bem: np.ndarray
    lateral: np.ndarray
    roll_error_rms: float
    path_error_rms: float
    path_error_max: float
    roll_vs_model_rms: float


def ride_eic(path: Path2D, bem: Callable[[float, float], float], duration_s: float, *, speed: float = 3.0,
             path_frequency: float = 0.4, settle_s: float = 10.0,
             model_bem: Callable[[float, float], float] | None = None, **ride_kwargs) -> EicResult:
    """Follow ``path`` at ``speed`` (m/s) for ``duration_s`` with (P1)–(P2) and the roll BEM ``bem(δ, v)`` (rad).

    Args:
        path: the path, starting at the origin heading +x.
        bem: φ_e(δ^d, v^d), rad.
        duration_s: s.
        speed: v^d, m/s.
        path_frequency: ω_p of (P1), rad/s (well below the lean loop's ω_n: the path loop of 1 rad/s at
            3 m/s with ω_n = 4 rad/s rocks the bicycle in a limit cycle of ±0.4 m).
        settle_s: the errors are taken over t ≥ settle_s.
        model_bem: the model BEM for ``roll_vs_model_rms`` (default ``bem``).
        ride_kwargs: to :func:`~bemlearn.apps.bikebot.ride.simulate_ride` (gains, sensors, cone …).
    """
    from bemlearn.apps.bikebot.ride import RideGains

    gains: RideGains = ride_kwargs.get("gains", RideGains())
    geo: dict = {}
    idx = [0]
    state = {"integral": 0.0, "t": 0.0}
    trace: dict[str, list] = {"bem": [], "model": [], "ey": []}
    pts = np.column_stack([path.x, path.y])

    def steer(t: float, s: dict) -> float:
        if not geo:
            geo.update(s["geometry"])
        w, h, b, g = geo["w"], geo["h"], geo["b"], geo["g"]
        p = np.array([s["x"], s["y"]])
        i0 = idx[0]
        window = pts[max(0, i0 - 100): i0 + 2000]
        i = max(0, i0 - 100) + int(np.argmin(np.sum((window - p) ** 2, axis=1)))
        idx[0] = i
        n_left = np.array([-math.sin(path.heading[i]), math.cos(path.heading[i])])
        e_y = float((p - pts[i]) @ n_left)
        e_psi = math.remainder(s["yaw"] - path.heading[i], 2 * math.pi)
        wp = path_frequency
        k_y, k_psi, k_i = 3 * wp**2 * w / speed**2, 3 * wp * w / speed, wp**3 * w / speed**2
        state["integral"] += e_y * (t - state["t"])
        state["t"] = t
        d_des = -math.atan(w * path.curvature[i]) + k_y * e_y + k_psi * e_psi + k_i * state["integral"]
        phi_e = bem(d_des, speed)
        k_phi, k_rate = lean_gains(max(s["speed"], gains.min_speed), gains.lean_frequency, gains.lean_damping,
                                   h=h, b=b, w=w, g=g)
        trace["bem"].append(phi_e)
        trace["model"].append(phi_e if model_bem is None else model_bem(d_des, speed))
        trace["ey"].append(e_y)
        return d_des + k_phi * (s["roll"] - phi_e) + k_rate * s["roll_rate"]

    from bemlearn.threads import torch_threads

    with torch_threads(1):   # one BEM query per tick: a thread pool only waits (as bemlearn.sim.closed_loop does)
        log = simulate_ride(RideReference(speed=speed), duration_s, steer_command=steer, **ride_kwargs)
    n = len(log.t)
    phi_e, phi_m, ey = (np.asarray(trace[k][:n]) for k in ("bem", "model", "ey"))
    keep = log.t >= settle_s
    phi = log.q_true[:, 2]
    if log.fell or not keep.any():
        nan = math.nan
        return EicResult(log=log, roll_bem=phi_e, lateral=ey, roll_error_rms=nan, path_error_rms=nan,
                         path_error_max=nan, roll_vs_model_rms=nan)
    return EicResult(log=log, roll_bem=phi_e, lateral=ey,
                     roll_error_rms=float(np.sqrt(np.mean((phi[keep] - phi_e[keep]) ** 2))),
                     path_error_rms=float(np.sqrt(np.mean(ey[keep] ** 2))), path_error_max=float(np.abs(ey[keep]).max()),
                     roll_vs_model_rms=float(np.sqrt(np.mean((phi[keep] - phi_m[keep]) ** 2))))
