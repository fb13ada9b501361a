"""``bemlearn robot``: inspect robots, their model-based BEM and Lemma 1."""

from __future__ import annotations


__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser("robot", help="inspect a robot: partition, BEM, Lemma 1", description="Inspect shipped or user MJCF robots.")
    rs = p.add_subparsers(dest="robot_command", metavar="ACTION", required=True)
    info = rs.add_parser("info", help="joints, partition and admissible BEM range of a robot")
    info.add_argument("robot", help="shipped robot name or MJCF path")
    info.set_defaults(func=_info)
    bem = rs.add_parser("bem", help="model-based BEM q_u^e for given actuated q_a, q̇_a, q̈_a (eq. 6–9)")
    bem.add_argument("robot")
    bem.add_argument("--qa", type=float, nargs="+", required=True, help="actuated angles, rad")
    bem.add_argument("--qad", type=float, nargs="+", required=True, help="actuated rates, rad/s")
    bem.add_argument("--qadd", type=float, nargs="+", required=True, help="actuated accelerations, rad/s²")
    bem.set_defaults(func=_bem)
    lem = rs.add_parser("lemma1", help="Lemma 1 on the Furuta: ΔΓ vs Ḣ_u and max |q_u^d − q_u^e| for composite sinusoids")
    lem.add_argument("robot", nargs="?", default="furuta")
    lem.set_defaults(func=_lemma1)
    from bemlearn.applications import applications

    for app in applications().values():
        if app.add_robot_commands is not None:
            app.add_robot_commands(rs)


def _info(args) -> int:
    from bemlearn.robots import load

    r = load(args.robot)
    print(f"robot      {r.name}  ({type(r).__name__})")
    print(f"joints     {', '.join(r.joint_names)}")
    print(f"actuated   {', '.join(r.actuated_names)}  (q_a, m = {r.m})")
    print(f"unactuated {r.unactuated_name}  (q_u), BEM searched in [{r.qu_range[0]:.4f}, {r.qu_range[1]:.4f}], nominal {r.qu_nominal:g}")
    return 0


def _bem(args) -> int:
    import torch

    from bemlearn.robots import load

    r = load(args.robot)
    t = lambda v: torch.tensor([v], dtype=torch.float64)  # noqa: E731
    res = r.bem(t(args.qa), t(args.qad), t(args.qadd))
    if not bool(res.valid[0]):
        print(f"no BEM in [{r.qu_range[0]:.4f}, {r.qu_range[1]:.4f}] for these inputs")
        return 1
    print(f"q_u^e = {float(res.qu[0]):.12f} rad  (|Γ_0| = {float(res.residual[0]):.2e} N·m)")
    return 0


def _lemma1(args) -> int:
    import numpy as np

    from bemlearn.robots import load
    from bemlearn.robots.reference import CompositeSinusoid
    from bemlearn.robots.zero_dynamics import lemma1

    robot = load(args.robot)
    refs = {
        "0.3 sin(π t) + 0.2 sin(2π t + 0.7)": CompositeSinusoid.single([0.3, 0.2], [0.5, 1.0], [0.0, 0.7]),
        "0.4 sin(π/2 t + 0.3) + 0.1 sin(3π/2 t + 1.1)": CompositeSinusoid.single([0.4, 0.1], [0.25, 0.75], [0.3, 1.1]),
        "0.2/0.15/0.1 at 0.2/0.6/1.0 Hz": CompositeSinusoid.single([0.2, 0.15, 0.1], [0.2, 0.6, 1.0], [0.0, 0.5, 2.0]),
        "0.5 sin(2π t)": CompositeSinusoid.single([0.5], [1.0]),
    }
    print(f"{'reference q_a^d(t) (rad)':<46}{'max|ΔΓ|':>10}{'max|ΔΓ−Ḣ_u−b_u q̇_u^e|':>24}{'max|Γ(q_u^d)|':>15}{'max|q_u^d−q_u^e|':>18}")
    for label, ref in refs.items():
        L = lemma1(robot, ref, n_nodes=256)
        print(f"{label:<46}{np.abs(L.delta_gamma).max():>10.3e}{np.abs(L.gap).max():>24.2e}{np.abs(L.zero_dynamics.residual).max():>15.2e}{L.max_distance:>18.4f}")
    return 0
