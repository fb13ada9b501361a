"""The bikebot's learned roll BEM: excitation rides → GP of the roll → BEM at zero roll rate and acceleration.

1. **Rides** (:func:`excitation_rides`): :func:`~bemlearn.apps.bikebot.ride.simulate_ride` in MuJoCo's soft-contact
   simulation with the speed reference v_ref = v̄ + A_v sin(2π f_v t + p) sweeping [2, 6] m/s and a steer
   reference of two sines (the lean reference is its naive steady-turn lean), each trial its own
   frequencies and phases (seeded); logged at the control rate with the rig's quantised δ, θ_R, φ.
2. **Pairs** (:func:`ride_gp_data`): q̇, q̈ of the quantised (δ, θ_R, φ) by one of the project's estimators
   (:func:`bemlearn.data.make_estimator`, per trial, edge samples dropped), the paper's x = [q̈_a, q̇_a, q_a,
   q̈_u, q̇_u] of eq. (11) with q_a = (δ, θ_R), q_u = φ — **less the rear wheel's angle θ_R**, which is cyclic
   (the dynamics do not depend on it: the bicycle is the same after any turn of its wheel), so

       x = [δ̈, θ̈_R, δ̇, θ̇_R, δ, φ̈, φ̇] ∈ R⁷,   y = φ  (rad);

   the speed is r_R θ̇_R.  N pairs drawn at random from the pool.
3. **GP** (:func:`fit_roll_gp`): the core's float64 GP (:func:`bemlearn.fitting.train_gp`, exact by default)
   on the standardised pairs (:class:`bemlearn.data.Normalization`).
4. **Learned BEM** (:meth:`RollGP.bem`): the GP mean at x_e = [0, 0, 0, v / r_R, δ, 0, 0] (eq. 14: the
   steady turn δ̇ = δ̈ = v̇ = 0 at φ̇ = φ̈ = 0), scored by :func:`score_learned_bem` against the model roll BEM
   of :class:`~bemlearn.apps.bikebot.bem.BikebotBem` on a grid of (v, δ).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch

from bemlearn.apps.bikebot.ride import RideLog, RideReference, simulate_ride
from bemlearn.errors import ConfigError, DataError
from bemlearn.fitting.gp_config import GPConfig

__all__ = ["INPUT_NAMES", "excitation_references", "excitation_rides", "ride_gp_data", "RollGP", "fit_roll_gp",
           "score_learned_bem", "GRID_SPEEDS", "GRID_STEERS"]

#: The GP's input columns (units rad/s², rad/s², rad/s, rad/s, rad, rad/s², rad/s).
INPUT_NAMES = ("steer_acc", "wheel_acc", "steer_rate", "wheel_rate", "steer", "roll_acc", "roll_rate")

#: The target's grid: v ∈ [2, 6] m/s, |δ| ≤ 0.2 rad (δ = 0 left out: running straight, φ_e = 0 by symmetry).
GRID_SPEEDS = (2.0, 3.0, 4.0, 5.0, 6.0)
GRID_STEERS = (-0.2, -0.15, -0.1, -0.05, 0.05, 0.1, 0.15, 0.2)


def excitation_references(n_trials: int, *, seed: int = 0, speed_range: tuple[float, float] = (1.8, 6.2),
                          steer_amplitude: float = 0.26) -> list[RideReference]:
    """``n_trials`` references (module docstring, step 1): the speed sweeps ``speed_range`` (m/s) once per
    period of 30–60 s, the steer reference is two sines (0.04–0.1 Hz and 0.15–0.3 Hz, amplitudes 2/3 and 1/3 of
    ``steer_amplitude`` rad); frequencies and phases drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    lo, hi = speed_range
    out = []
    for _ in range(n_trials):
        fv, f1, f2 = rng.uniform(1 / 60, 1 / 30), rng.uniform(0.04, 0.1), rng.uniform(0.15, 0.3)
        pv, p1, p2 = rng.uniform(0, 2 * math.pi, 3)
        out.append(RideReference(speed=(lo + hi) / 2, speed_sines=(((hi - lo) / 2, fv, pv),),
                                 steer_sines=((2 * steer_amplitude / 3, f1, p1), (steer_amplitude / 3, f2, p2)),
                                 ramp_s=3.0))
    return out


def excitation_rides(n_trials: int, duration_s: float, *, seed: int = 0, control_rate_hz: float = 200.0,
                     cone: str = "elliptic", tyre_friction: float | None = None, **kwargs) -> list[RideLog]:
    """The rides of :func:`excitation_references` (``kwargs`` to it), sensor seeds ``seed + i``, MuJoCo's friction
    ``cone`` and ``tyre_friction`` as in :func:`~bemlearn.apps.bikebot.ride.simulate_ride` (the grid's corner
    v = 6 m/s, δ = 0.2 rad leans 0.70 rad, 0.84 g of lateral acceleration: the elliptic cone at the MJCF's μ = 1
    holds it, the pyramidal does not)."""
    return [simulate_ride(r, duration_s, control_rate_hz=control_rate_hz, seed=seed + i, cone=cone,
                          tyre_friction=tyre_friction)
            for i, r in enumerate(excitation_references(n_trials, seed=seed, **kwargs))]


def ride_gp_data(rides: list[RideLog], *, derivative: str = "savgol", options: dict | None = None,
                 n_points: int = 3000, skip_s: float = 3.0, truth: bool = False, seed: int = 0) -> tuple[np.ndarray, np.ndarray, dict]:
    """Training pairs (module docstring, step 2) from the rides.

    Args:
        rides: the rides (a ride that fell is left out).
        derivative, options: the estimator (:func:`bemlearn.data.make_estimator`; default Savitzky–Golay, 0.2 s).
        n_points: N drawn from the pool.
        skip_s: the first seconds of each ride (the ramp from the upright start) are left out, s.
        truth: use the simulator's exact angles and rates, with q̈ by central differences of the exact rates
            (the oracle's pairs: no sensor, no estimator).
        seed: the draw's seed.

    Returns:
        ``X (N, 7)`` (:data:`INPUT_NAMES`), ``y (N,)`` φ in rad, and a report of counts.
    """
    from bemlearn.data import make_estimator

    est = make_estimator(derivative, options or {}, where="bikebot derivative")
    Xs, ys, report = [], [], {"rides": len(rides), "fell": int(sum(r.fell for r in rides)), "estimator": repr(est)}
    for r in rides:
        if r.fell:
            continue
        fs = r.sample_rate_hz
        if truth:
            q, qd = r.q_true, r.qd_true
            qdd = np.gradient(qd, 1.0 / fs, axis=0)
            valid = np.ones(len(q), bool)
            valid[[0, -1]] = False
        else:
            q = r.q
            if len(q) < est.min_samples(fs):
                continue
            if getattr(est, "smooths", False):
                q, qd, qdd = est.filter(q, sample_rate_hz=fs)   # type: ignore[attr-defined]
            else:
                qd, qdd = est(q, sample_rate_hz=fs)
            e = est.edge_samples(fs)
            valid = np.ones(len(q), bool)
            if not getattr(est, "edges_valid", True) and e:
                valid[:e] = valid[-e:] = False
        valid &= r.t >= skip_s
        X = np.column_stack([qdd[:, 0], qdd[:, 1], qd[:, 0], qd[:, 1], q[:, 0], qdd[:, 2], qd[:, 2]])
        Xs.append(X[valid])
        ys.append(q[valid, 2])
    if not Xs:
        raise DataError("ride_gp_data: no ride left (all fell or were too short)")
    X, y = np.concatenate(Xs), np.concatenate(ys)
    report["pool"] = len(y)
    rng = np.random.default_rng(seed)
    if len(y) > n_points:
        idx = np.sort(rng.choice(len(y), n_points, replace=False))
        X, y = X[idx], y[idx]
    report["n_train"] = len(y)
    return X, y, report


@dataclass
class RollGP:
    """The fitted GP of the roll and its standardisation.

    Attributes:
        model, likelihood: the core's GP (normalised units).
        normalization: :class:`bemlearn.data.Normalization` of the pairs.
        rear_radius: r_R, m (θ̇_R = v / r_R in the BEM's query).
        fit: the fit's metrics.
    """

    model: torch.nn.Module
    likelihood: torch.nn.Module
    normalization: object
    rear_radius: float
    fit: dict

    def mean(self, X: np.ndarray) -> np.ndarray:
        """The GP mean of φ (rad) at ``X (B, 7)`` physical inputs, from the frozen posterior (:attr:`state`: one kernel
        row and a dot product per point, as the exported predictor computes it)."""
        return self.mean_of(torch.as_tensor(np.atleast_2d(np.asarray(X, dtype=np.float64)), dtype=torch.float64)).numpy()

    def mean_of(self, x: torch.Tensor) -> torch.Tensor:
        """μ = y_mean + y_std k_Z(x̃)ᵀ α (eq. 12's mean, the kernel row only): ``(B,)`` rad at ``x (B, 7)`` physical."""
        st = self.state
        with torch.no_grad():
            return st.y_mean + st.y_std * (st.kernel_row(x) @ st.alpha)

    @functools.cached_property
    def state(self):
        """The frozen float64 posterior (:func:`bemlearn.models.freeze.predictor_state`) in physical units."""
        from bemlearn.models.freeze import predictor_state

        nrm = self.normalization
        return predictor_state(self.model, self.likelihood, x_mean=nrm.x_mean, x_std=nrm.x_std,
                               y_mean=nrm.y_mean, y_std=nrm.y_std, input_names=INPUT_NAMES,
                               n_train=int(self.fit["n_train"]))

    def bem(self, delta: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The learned roll BEM (rad) at steer ``delta`` (rad) and speed ``v`` (m/s) (same shapes): the mean at
        x_e = [0, 0, 0, v / r_R, δ, 0, 0]."""
        d, s = np.broadcast_arrays(np.asarray(delta, float), np.asarray(v, float))
        z = np.zeros(d.size)
        X = np.column_stack([z, z, z, s.ravel() / self.rear_radius, d.ravel(), z, z])
        return self.mean(X).reshape(d.shape)


def fit_roll_gp(X: np.ndarray, y: np.ndarray, *, rear_radius: float, config: GPConfig | None = None,
                progress: bool = False) -> RollGP:
    """Fit the GP of φ on ``X (N, 7)``, ``y (N,)`` (float64) with :func:`bemlearn.fitting.train_gp`
    (``config`` default: an exact GP).

    Raises:
        ConfigError: ``config.mean`` other than ``"zero"`` (the roll GP has no plane).
    """
    from bemlearn.data import Normalization
    from bemlearn.fitting import train_gp

    if config is not None and config.mean != "zero":
        raise ConfigError(f"fit_roll_gp: train.mean {config.mean!r}: the roll GP is fitted with a zero prior mean (eq. 11); "
                          "set mean: zero")
    x, yt = torch.as_tensor(X, dtype=torch.float64), torch.as_tensor(y, dtype=torch.float64)
    nrm = Normalization.fit(x, yt, names=INPUT_NAMES)
    model, lik, res = train_gp(nrm.normalize_x(x), nrm.normalize_y(yt), config=config or GPConfig(), progress=progress)
    return RollGP(model=model, likelihood=lik, normalization=nrm, rear_radius=rear_radius,
                  fit={"loss": float(res.loss), "seconds": float(res.seconds), "stop_reason": res.stop_reason, "n_train": len(yt),
                       "noise_std_rad": float(nrm.y_std * lik.noise.detach().sqrt().reshape(()))})


@dataclass(frozen=True)
class BemScore:
    """Learned against model roll BEM on a grid.

    Attributes:
        speeds, steers: ``(K,)`` the grid points, m/s and rad.
        model, learned: ``(K,)`` φ_e, rad.
        rmse, max_abs: rad.
        gain: the least-squares slope of learned on model (1: no shrink).
    """

    speeds: np.ndarray
    steers: np.ndarray
    model: np.ndarray
    learned: np.ndarray
    rmse: float
    max_abs: float
    gain: float


def score_learned_bem(gp: RollGP, speeds=GRID_SPEEDS, steers=GRID_STEERS, *, bem=None) -> BemScore:
    """RMSE, max |error| and gain of the learned BEM against the model roll BEM on ``speeds × steers``."""
    from bemlearn.apps.bikebot.bem import BikebotBem

    bem = bem or BikebotBem()
    V, D = (a.ravel() for a in np.meshgrid(np.asarray(speeds, float), np.asarray(steers, float), indexing="ij"))
    model = np.array([bem.roll(float(d), float(v)) for v, d in zip(V, D)])
    learned = gp.bem(D, V)
    err = learned - model
    return BemScore(speeds=V, steers=D, model=model, learned=learned, rmse=float(np.sqrt(np.mean(err**2))),
                    max_abs=float(np.max(np.abs(err))), gain=float(learned @ model / (model @ model)))
