"""The bikebot's model roll BEM against the steady-turn balance over a grid: ``bemlearn bench bikebot-bem``.

For each speed v and steer δ of the grid (δ̇ = δ̈ = v̇ = 0) :func:`run_bikebot_bem_bench` computes

* φ_model: the model roll BEM of :class:`~bemlearn.apps.bikebot.bem.BikebotBem` (MuJoCo's M, bias and
  contact Jacobians, hard no-slip and normal rows with J̇ q̇, KKT);
* φ_ref: the root of the Newton–Euler balance about the ground line (N1) of
  :mod:`bemlearn.apps.bikebot.steady_turn` (no MuJoCo);
* φ_naive = atan(v² tan δ / (g w));
* φ_nodrift: the same KKT root without the J̇ q̇ term (what a constraint without its drift term gives:
  the rolling's curvature, hence the centripetal acceleration, is lost), searched over 1e-3 ≤ |φ| ≤ 1.5 rad
  on the side of sgn δ;
* φ_soft (``soft_contact``): the root of the roll acceleration read from one soft-contact ``mj_forward`` per roll
  (:mod:`bemlearn.apps.bikebot.soft_contact`).

Also runnable as ``python -m bemlearn.apps.bikebot.bench``.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from dataclasses import dataclass

from bemlearn.errors import NumericalError

__all__ = ["BikebotBemRow", "run_bikebot_bem_bench", "format_bikebot_bem_bench", "add_bench",
           "SPEEDS", "STEERS"]

#: The grid of the issue's target: v ∈ [2, 6] m/s, |δ| ≤ 0.2 rad.
SPEEDS = (2.0, 3.0, 4.0, 5.0, 6.0)
STEERS = (-0.2, -0.1, 0.05, 0.1, 0.2)


@dataclass(frozen=True)
class BikebotBemRow:
    """One grid point (angles in rad).

    Attributes:
        v: forward speed, m/s.
        delta: steer, rad.
        model, reference, naive: φ_model, φ_ref, φ_naive, rad.
        no_drift: φ_nodrift, rad (``nan`` where no root is bracketed).
        soft: φ_soft, rad (``nan`` where not asked or not found).
    """

    v: float
    delta: float
    model: float
    reference: float
    naive: float
    no_drift: float
    soft: float = math.nan


def run_bikebot_bem_bench(speeds=SPEEDS, steers=STEERS, *, no_drift: bool = True,
                          soft_contact: bool = False) -> list[BikebotBemRow]:
    """The grid's rows (module docstring); about 0.2 s per point, twice that with ``no_drift``, 0.5 s more
    with ``soft_contact``."""
    from bemlearn.apps.bikebot.bem import BikebotBem
    from bemlearn.apps.bikebot.model import BikeParameters
    from bemlearn.apps.bikebot.soft_contact import soft_contact_roll
    from bemlearn.apps.bikebot.steady_turn import naive_roll, steady_turn_roll

    p, bem = BikeParameters(), BikebotBem()
    rows = []
    for v in speeds:
        for delta in steers:
            nd = soft = math.nan
            if no_drift:
                with contextlib.suppress(NumericalError):
                    nd = bem.roll(delta, v, drift=False, bracket=(math.copysign(1e-3, delta), math.copysign(1.5, delta)))
            if soft_contact:
                with contextlib.suppress(NumericalError):
                    soft = soft_contact_roll(bem, delta, v)
            rows.append(BikebotBemRow(v=v, delta=delta, model=bem.roll(delta, v), reference=steady_turn_roll(p, v, delta),
                                      naive=naive_roll(p, v, delta), no_drift=nd, soft=soft))
    return rows


def format_bikebot_bem_bench(rows: list[BikebotBemRow]) -> str:
    """A Markdown table of the rows (degrees) and the grid's maxima."""
    deg = math.degrees
    out = ["| v (m/s) | δ (rad) | φ model BEM (°) | φ reference (°) | model − reference (°) | naive − reference (°) | "
           "without J̇q̇ (°) | one soft-contact `mj_forward` (°) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r.v:g} | {r.delta:g} | {deg(r.model):.6f} | {deg(r.reference):.6f} | "
                   f"{deg(r.model - r.reference):.1e} | {deg(r.naive - r.reference):+.3f} | {_cell(r.no_drift)} | {_cell(r.soft)} |")
    err = max(abs(deg(r.model - r.reference)) for r in rows)
    naive = [abs(deg(r.naive - r.reference)) for r in rows]
    nd = [abs(deg(r.no_drift - r.reference)) for r in rows if not math.isnan(r.no_drift)]
    out.append("")
    out.append(f"grid of {len(rows)}: max |model − reference| = {err:.2e}°; |naive − reference| from {min(naive):.3f}° "
               f"to {max(naive):.3f}°" + (f"; |without J̇q̇ − reference| from {min(nd):.3f}° to {max(nd):.3f}°" if nd else ""))
    return "\n".join(out)


def _cell(x: float) -> str:
    return "—" if math.isnan(x) else f"{math.degrees(x):.3f}"


def _bench(args: argparse.Namespace) -> int:
    print(format_bikebot_bem_bench(run_bikebot_bem_bench(tuple(args.speeds), tuple(args.steers),
                                                         no_drift=not args.skip_no_drift,
                                                         soft_contact=args.soft_contact)))
    return 0


def add_bench(sub) -> None:
    """Register ``bemlearn bench bikebot-bem``."""
    b = sub.add_parser("bikebot-bem", help="bikebot: model roll BEM (MuJoCo, hard rolling KKT) vs the steady-turn balance",
                       description=__doc__.split("\n\n")[0])
    _arguments(b)
    b.set_defaults(func=_bench)


def _arguments(b: argparse.ArgumentParser) -> None:
    b.add_argument("--speeds", type=float, nargs="+", default=list(SPEEDS), metavar="V", help="speeds, m/s")
    b.add_argument("--steers", type=float, nargs="+", default=list(STEERS), metavar="DELTA",
                   help="steering angles, rad (not 0)")
    b.add_argument("--skip-no-drift", action="store_true", help="leave out the root without J̇q̇")
    b.add_argument("--soft-contact", action="store_true",
                   help="add the root read from one soft-contact mj_forward per roll (about 0.5 s per point)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    _arguments(parser)
    sys.exit(_bench(parser.parse_args()))
