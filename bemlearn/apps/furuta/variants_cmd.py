"""``bemlearn robot furuta-variants``: the rigid-body Furuta's BEM vs the paper's printed rows."""

from __future__ import annotations

__all__ = ["add_robot_commands"]


def add_robot_commands(rs) -> None:
    var = rs.add_parser("furuta-variants", help="BEM of the rigid-body Furuta vs the paper's printed rows over (θ̇, θ̈)")
    var.set_defaults(func=_variants)


def _variants(args) -> int:
    import torch

    from bemlearn.apps.furuta.model import AnalyticFuruta

    rigid, paper = AnalyticFuruta(variant="rigid"), AnalyticFuruta(variant="paper")
    rates = [0.0, 2.0, 5.0, 10.0]
    accs = [5.0, 10.0, 20.0, 30.0]
    t = lambda v: torch.tensor([[v]], dtype=torch.float64)  # noqa: E731
    print("max |α_rigid − α_paper| (rad) of the BEM; rows θ̇ (rad/s), columns θ̈ (rad/s²)")
    print("θ̇ \\ θ̈  " + "".join(f"{a:>10g}" for a in accs))
    for w in rates:
        row = [abs(float((rigid.bem(t(0.0), t(w), t(a)).qu - paper.bem(t(0.0), t(w), t(a)).qu)[0])) for a in accs]
        print(f"{w:>7g}  " + "".join(f"{v:>10.2e}" for v in row))
    return 0
