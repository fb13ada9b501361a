"""EIC with the learned, the model and the zero roll BEM: ``bemlearn bench bikebot-eic``.

Fits the learned roll BEM as ``bemlearn bench bikebot-learned`` does (its defaults), evaluated every tick
(:class:`~bemlearn.apps.bikebot.eic.LearnedBem`), tabulates the model roll BEM on a (v, δ) grid
(:class:`~bemlearn.apps.bikebot.eic.BemTable`), then follows a 10 m circle and an S-curve (curvature
sin(2π s / 60 m) / 10 m) at 3 m/s for 60 s with each BEM in (P2) of :mod:`bemlearn.apps.bikebot.eic`, and prints
the roll error against the BEM used and against the model BEM, and the path error, over t ≥ 10 s.

Also runnable as ``python -m bemlearn.apps.bikebot.eic_bench``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable

#: The model BEM table's steers, rad (mirrored; 0 by symmetry) and speeds, m/s.
TABLE_STEERS = (0.005, 0.01, 0.02, 0.03, 0.05, 0.075, 0.1, 0.15, 0.2, 0.25, 0.3)


def eic_bench(*, speed: float = 3.0, duration: float = 60.0, radius: float = 10.0, s_period: float = 60.0,
              learned=None, progress=print) -> list[dict]:
    """Rows {path, bem, fell, roll_error_rms, roll_vs_model_rms, path_error_rms, path_error_max} (module docstring).

    Args:
        learned: a fitted :class:`~bemlearn.apps.bikebot.learn.RollGP` (default: fitted with the learned bench's
            defaults).
    """
    import numpy as np

    from bemlearn.apps.bikebot.eic import BemTable, LearnedBem, circle_path, ride_eic, s_curve_path
    from bemlearn.apps.bikebot.learn_bench import learned_bem_bench

    t0 = time.perf_counter()
    if learned is None:
        sc, _, learned = learned_bem_bench()
        progress(f"learned BEM: grid RMSE {sc.rmse:.4f} rad ({time.perf_counter() - t0:.0f} s)")
    st = np.array(TABLE_STEERS)
    speeds, steers = [speed - 0.5, speed, speed + 0.5], np.concatenate([-st[::-1], [0.0], st])
    table = BemTable.model(speeds, steers)
    bems: dict[str, Callable[[float, float], float]] = {"learned": LearnedBem(learned),
                                                        "model": table, "zero": lambda d, v: 0.0}
    length = speed * duration + 20.0
    paths = {f"circle R = {radius:g} m": circle_path(radius, length),
             f"S-curve (R ≥ {radius:g} m, period {s_period:g} m)": s_curve_path(radius, s_period, length)}
    rows = []
    for pname, path in paths.items():
        for bname, bem in bems.items():
            r = ride_eic(path, bem, duration, speed=speed, model_bem=table)
            rows.append({"path": pname, "bem": bname, "fell": r.log.fell, "t_end": float(r.log.t[-1]),
                         "roll_error_rms": r.roll_error_rms, "roll_vs_model_rms": r.roll_vs_model_rms,
                         "path_error_rms": r.path_error_rms, "path_error_max": r.path_error_max,
                         "max_roll": float(np.abs(r.log.q_true[:, 2]).max())})
    return rows


def format_eic_bench(rows: list[dict], speed: float = 3.0, duration: float = 60.0) -> str:
    out = [f"| path ({speed:g} m/s, {duration:g} s) | BEM | stayed up | roll − BEM used, RMS (rad) | "
           "roll − model BEM, RMS (rad) | path error RMS (m) | path error max (m) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        up = "yes" if not r["fell"] else f"fell at {r['t_end']:.1f} s"
        cells = [_f(r[k], 4) for k in ("roll_error_rms", "roll_vs_model_rms")] + [_f(r[k], 3) for k in
                                                                                   ("path_error_rms", "path_error_max")]
        out.append(f"| {r['path']} | {r['bem']} | {up} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def _f(x: float, digits: int) -> str:
    return "—" if math.isnan(x) else f"{x:.{digits}f}"


def run(args: argparse.Namespace) -> int:
    rows = eic_bench(speed=args.speed, duration=args.duration)
    print(format_eic_bench(rows, args.speed, args.duration))
    return 0


def _arguments(b: argparse.ArgumentParser) -> None:
    b.add_argument("--speed", type=float, default=3.0, help="v^d, m/s")
    b.add_argument("--duration", type=float, default=60.0, help="seconds per ride")


def add_eic_bench(sub) -> None:
    """Register ``bemlearn bench bikebot-eic``."""
    b = sub.add_parser("bikebot-eic", help="bikebot: EIC on a circle and an S-curve with the learned, model and zero BEM",
                       description=__doc__.split("\n\n")[0])
    _arguments(b)
    b.set_defaults(func=run)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    _arguments(parser)
    sys.exit(run(parser.parse_args()))
