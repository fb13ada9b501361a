"""Riding the bikebot in the soft-contact simulation: ``python -m bemlearn.apps.bikebot.ride_bench``.

1. A 60 s ride at 3 m/s (speed 3 ± 0.3 m/s at 0.05 Hz, steer reference 0.1 sin(2π · 0.1 t) rad): stayed up,
   largest roll, roll − lean reference RMS and the speed error over t ≥ 5 s.
2. Steady turns (a constant steer reference δ_r ramped in over 5 s, 15 s, the last second averaged): the
   simulation's roll against the model roll BEM of the simulation's own steer and speed, for MuJoCo's elliptic and
   pyramidal friction cones.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

#: (v m/s, δ_r rad) of the steady turns: the lean from 0.015 to 0.66 rad.
TURNS = ((2.0, 0.01), (2.0, 0.05), (3.0, 0.1), (4.0, 0.15), (5.0, 0.2), (6.0, 0.2), (6.0, 0.23))


def steady_turn(v: float, steer: float, *, cone: str = "elliptic", tyre_friction: float | None = None,
                bem=None) -> dict:
    """{v, delta, roll, model, fell, wobble} of one steady turn (module docstring, 2): m/s and rad."""
    from bemlearn.apps.bikebot.bem import BikebotBem
    from bemlearn.apps.bikebot.ride import RideReference, simulate_ride

    log = simulate_ride(RideReference(speed=v, steer_sines=((steer, 0.0, math.pi / 2),), ramp_s=5.0), 15.0,
                        cone=cone, tyre_friction=tyre_friction)
    if log.fell:
        return {"v": v, "delta": math.nan, "roll": math.nan, "model": math.nan, "fell": True, "wobble": math.nan}
    last = log.t >= 14.0
    phi, delta, speed = (float(np.mean(a[last])) for a in (log.q_true[:, 2], log.q_true[:, 0], log.speed))
    return {"v": speed, "delta": delta, "roll": phi, "model": (bem or BikebotBem()).roll(delta, speed), "fell": False,
            "wobble": float(np.ptp(log.q_true[last, 2]))}


def main(argv: list[str] | None = None) -> int:
    from bemlearn.apps.bikebot.bem import BikebotBem
    from bemlearn.apps.bikebot.ride import RideReference, simulate_ride

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--skip-pyramidal", action="store_true", help="only the elliptic cone's steady turns")
    args = p.parse_args(argv)
    log = simulate_ride(RideReference(speed=3.0, speed_sines=((0.3, 0.05, 0.0),), steer_sines=((0.1, 0.1, 0.0),)), 60.0)
    a = log.t >= 5.0
    phi = log.q_true[:, 2]
    print(f"60 s at 3 m/s: stayed up {not log.fell}; max |φ| {np.abs(phi).max():.4f} rad; φ − φ_ref RMS "
          f"{np.sqrt(np.mean((phi[a] - log.roll_ref[a]) ** 2)):.4f} rad; max |v − v_ref| "
          f"{np.abs(log.speed[a] - log.v_ref[a]).max():.4f} m/s; max |δ| {np.abs(log.q_true[:, 0]).max():.4f} rad")
    print()
    print("| cone | v (m/s) | δ (rad) | φ simulation (rad) | φ model BEM (rad) | simulation − model (rad) |")
    print("|---|---|---|---|---|---|")
    bem = BikebotBem()
    for cone in ("elliptic",) + (() if args.skip_pyramidal else ("pyramidal",)):
        for v, d in TURNS:
            r = steady_turn(v, d, cone=cone, bem=bem)
            if r["fell"]:
                print(f"| {cone} | {v:g} | (δ_r {d:g}) | fell | — | — |")
            else:
                print(f"| {cone} | {r['v']:.3f} | {r['delta']:+.4f} | {r['roll']:+.5f} | {r['model']:+.5f} | "
                      f"{r['roll'] - r['model']:+.5f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
