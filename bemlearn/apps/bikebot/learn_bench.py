"""The learned roll BEM against the model roll BEM: ``bemlearn bench bikebot-learned``.

Rides (:func:`~bemlearn.apps.bikebot.learn.excitation_rides`) → pairs (:func:`~bemlearn.apps.bikebot.learn.ride_gp_data`)
→ GP (:func:`~bemlearn.apps.bikebot.learn.fit_roll_gp`) → the learned BEM at φ̇ = φ̈ = 0, δ̇ = δ̈ = v̇ = 0 against
:class:`~bemlearn.apps.bikebot.bem.BikebotBem` on v ∈ {2 … 6} m/s, δ ∈ ±{0.05, 0.1, 0.15, 0.2} rad: a table,
the RMSE, the largest error and the gain, against the target RMSE ≤ 0.01 rad.

Also runnable as ``python -m bemlearn.apps.bikebot.learn_bench``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

#: The target on the learned-vs-model roll BEM RMSE over the grid, rad.
TARGET_RMSE = 0.01


def learned_bem_bench(*, trials: int = 8, duration: float = 60.0, n_points: int = 10_000, kind: str = "sgpr",
                      inducing: int = 256, derivative: str = "savgol", truth: bool = False, cone: str = "elliptic",
                      tyre_friction: float | None = None, seed: int = 0):
    """(score, report, gp): the rides, the pairs, the GP and its score (module docstring); the defaults are the
    bench's."""
    from bemlearn.apps.bikebot.learn import excitation_rides, fit_roll_gp, ride_gp_data, score_learned_bem
    from bemlearn.fitting.gp_config import GPConfig

    t0 = time.perf_counter()
    rides = excitation_rides(trials, duration, seed=seed, cone=cone, tyre_friction=tyre_friction)
    t1 = time.perf_counter()
    X, y, rep = ride_gp_data(rides, derivative=derivative, n_points=n_points, truth=truth, seed=seed)
    cfg = GPConfig(kind=kind, n_inducing=inducing, seed=seed)       # type: ignore[arg-type]
    gp = fit_roll_gp(X, y, rear_radius=rides[0].extra["rear_radius"], config=cfg)
    t2 = time.perf_counter()
    rep.update(rides_s=t1 - t0, fit_s=t2 - t1, rate_hz=rides[0].sample_rate_hz, tyre_friction=rides[0].extra["tyre_friction"],
               noise_std_rad=gp.fit["noise_std_rad"], n_inducing=gp.state.n_support if gp.state.sparse else None)
    return score_learned_bem(gp), rep, gp


def run(args: argparse.Namespace) -> int:
    sc, rep, _ = learned_bem_bench(trials=args.trials, duration=args.duration, n_points=args.n_points, kind=args.kind,
                                inducing=args.inducing, derivative=args.derivative, truth=args.truth, cone=args.cone,
                                tyre_friction=args.tyre_friction, seed=args.seed)
    print(f"rides: {rep['rides']} × {args.duration:g} s at {rep['rate_hz']:g} Hz, {args.cone} cone, tyre friction "
          f"{rep['tyre_friction']:g}, fell {rep['fell']}; pool {rep['pool']}, N = {rep['n_train']} "
          f"({'exact states' if args.truth else rep['estimator']}); {args.kind} GP"
          + (f" (M = {rep['n_inducing']})" if rep.get("n_inducing") else "")
          + f"; rides {rep['rides_s']:.0f} s, fit {rep['fit_s']:.0f} s; σ_0 = {rep['noise_std_rad']:.2e} rad")
    print()
    print("| v (m/s) | δ (rad) | φ model BEM (rad) | φ learned (rad) | learned − model (rad) |")
    print("|---|---|---|---|---|")
    for v, d, m, ll in zip(sc.speeds, sc.steers, sc.model, sc.learned):
        print(f"| {v:g} | {d:+.2f} | {m:+.4f} | {ll:+.4f} | {ll - m:+.4f} |")
    print()
    ok = sc.rmse <= TARGET_RMSE
    print(f"grid of {len(sc.model)}: RMSE {sc.rmse:.4f} rad ({math.degrees(sc.rmse):.2f}°), max |error| "
          f"{sc.max_abs:.4f} rad, gain {sc.gain:.4f}; target RMSE ≤ {TARGET_RMSE} rad: {'met' if ok else 'MISSED'}")
    return 0


def _arguments(b: argparse.ArgumentParser) -> None:
    b.add_argument("--trials", type=int, default=8, help="excitation rides")
    b.add_argument("--duration", type=float, default=60.0, help="seconds per ride")
    b.add_argument("--n-points", type=int, default=10_000, help="GP training pairs drawn from the pool")
    b.add_argument("--kind", choices=("exact", "sgpr"), default="sgpr", help="GP kind")
    b.add_argument("--inducing", type=int, default=256, help="inducing points (sgpr)")
    b.add_argument("--derivative", default="savgol", help="derivative estimator (bemlearn.data)")
    b.add_argument("--truth", action="store_true", help="train on the simulator's exact states (oracle)")
    b.add_argument("--cone", choices=("elliptic", "pyramidal"), default="elliptic", help="MuJoCo's friction cone in the rides")
    b.add_argument("--tyre-friction", type=float, default=None, help="tyres' friction coefficient in the rides (default the MJCF's, 1)")
    b.add_argument("--seed", type=int, default=0, help="seed of the excitation, the sensors, the draw and the GP")


def add_learned_bench(sub) -> None:
    """Register ``bemlearn bench bikebot-learned``."""
    b = sub.add_parser("bikebot-learned", help="bikebot: learned roll BEM (soft-contact rides, GP) vs the model BEM",
                       description=__doc__.split("\n\n")[0])
    _arguments(b)
    b.set_defaults(func=run)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    _arguments(parser)
    sys.exit(run(parser.parse_args()))
