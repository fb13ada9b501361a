"""``bemlearn robot``: inspect robots, their model-based BEM and Lemma 1."""

from __future__ import annotations

__all__ = ["add_parser"]


def add_parser(sub) -> None:
    p = sub.add_parser("robot", help="inspect a robot: partition, BEM, Lemma 1", description="Inspect shipped or user MJCF robots.")
    rs = p.add_subparsers(dest="robot_command", metavar="ACTION", required=True)
    ls = rs.add_parser("list", help="the registered robot names (from the installed applications)")
    ls.set_defaults(func=_list)
    info = rs.add_parser("info", help="joints, partition and admissible BEM range of a robot")
    info.add_argument("robot", help="registry name, MJCF path, or a run config (.yaml: its robot and coordinates block)")
    info.set_defaults(func=_info)
    bem = rs.add_parser("bem", help="model-based BEM q_u^e for given actuated q_a, q̇_a, q̈_a (eq. 6–9)")
    bem.add_argument("robot", help="registry name, MJCF path, or a run config (.yaml: its robot and coordinates block)")
    bem.add_argument("--qa", type=float, nargs="+", required=True, help="actuated coordinates, in their joints' units (rad for a hinge, m for a slide)")
    bem.add_argument("--qad", type=float, nargs="+", required=True, help="actuated rates (rad/s or m/s)")
    bem.add_argument("--qadd", type=float, nargs="+", required=True, help="actuated accelerations (rad/s² or m/s²)")
    bem.set_defaults(func=_bem)
    lem = rs.add_parser("lemma1", help="Lemma 1 on any robot: ΔΓ vs Ḣ_u and max |q_u^d − q_u^e| for composite sinusoids")
    lem.add_argument("robot", help="registry name, MJCF path, or a run config (.yaml: its robot and coordinates block)")
    lem.add_argument("--rtol", type=float, default=1e-6,
                     help="fail (exit 1) when max|ΔΓ − Ḣ_u − b_u q̇_u^e| / max|ΔΓ| exceeds this (default 1e-6)")
    lem.add_argument("--fixed-references", action="store_true",
                     help="four fixed references (amplitudes 0.1–0.5, in the actuated joints' unit) instead of references scaled to the robot")
    lem.set_defaults(func=_lemma1)
    lqr = rs.add_parser("lqr", help="discrete LQR excitation gains of MuJoCo's linearisation at upright (u = K e)")
    lqr.add_argument("robot", help="registry name, MJCF path, or a run config (.yaml: its robot and coordinates block)")
    lqr.add_argument("--rate", type=float, default=None, help="control rate, Hz (default: derived, ≥ 100 Hz, whole physics steps)")
    lqr.set_defaults(func=_lqr)
    from bemlearn.applications import applications

    for app in applications().values():
        if app.add_robot_commands is not None:
            app.add_robot_commands(rs)


def _list(args) -> int:
    from bemlearn.applications import applications

    for app in applications().values():
        for name in app.robots:
            print(f"{name:<18} {app.name} application: {app.description}")
    print("any MJCF file of this class by path (hinge/slide joints, exactly one not driven by an actuator "
          "besides those that only roll with a wheel)")
    return 0


def _resolve(arg: str):
    """``(robot, ref)`` of a registry name, an MJCF path, or a run config (``.yaml``: its ``robot:`` or ``model:``
    with its ``coordinates:`` block)."""
    from pathlib import Path

    from bemlearn.robots import resolve_robot

    path = Path(arg)
    if path.suffix.lower() in (".yaml", ".yml"):
        from bemlearn.config import config_folder, load_yaml, rebase_paths
        from bemlearn.errors import ConfigError
        from bemlearn.pipeline.config import PATH_KEYS

        raw = rebase_paths(load_yaml(path), PATH_KEYS, config_folder(path))   # relative to the config's folder
        name = raw.get("robot") or raw.get("model")
        if not isinstance(name, str) or not name:
            raise ConfigError(f"{path}: expected 'robot:' (or 'model:') naming a robot, got {name!r}")
        return resolve_robot(name, coordinates=raw.get("coordinates"))
    return resolve_robot(arg)


def _info(args) -> int:
    from bemlearn.units import joint_unit

    r, ref = _resolve(args.robot)
    kinds = dict(zip(r.joint_names, r.coordinate_kinds))
    show = lambda names: ", ".join(f"{n} ({kinds[n]}, {joint_unit(kinds[n])})" for n in names)  # noqa: E731
    unit = joint_unit(kinds[r.unactuated_name])
    print(f"robot      {r.name}  ({type(r).__name__})")
    print(f"model      {ref.mjcf or 'no MJCF file'}" + (f"  (registry name {ref.registry})" if ref.registry else ""))
    print(f"joints     {show(r.joint_names)}")
    print(f"actuated   {show(r.actuated_names)}  (q_a, m = {r.m})")
    print(f"unactuated {show([r.unactuated_name])}  (q_u), BEM searched in [{r.qu_range[0]:.4f}, {r.qu_range[1]:.4f}] {unit}, nominal {r.qu_nominal:g} {unit}")
    note = getattr(r, "qu_nominal_note", None)
    if note:
        print(f"upright    {note}")
    from bemlearn.robots import MujocoRobot

    if isinstance(r, MujocoRobot) and r.rolling is not None:
        print(f"rolling    {r.rolling.describe(r.model)}")
    if isinstance(r, MujocoRobot) and r.floating is not None:
        print(f"rolling    {r.floating.describe(r.model)}")
    from bemlearn.robots.cyclic import cyclic_coordinates, unbounded_cyclic

    flags = cyclic_coordinates(r)
    cyclic = [name for name, c in zip(r.joint_names, flags) if c]
    if cyclic:
        left = unbounded_cyclic(r, flags)
        print(f"cyclic     {', '.join(cyclic)}: the dynamics (D, h of eq. 1) do not depend on {'its' if len(cyclic) == 1 else 'their'} position"
              + (f"; {', '.join(left)} without a joint range: left out of the GP inputs (dataset.cyclic)" if left else ""))
    from bemlearn.robots.scales import upright_stiffness

    stiffness = upright_stiffness(r)[0]
    if not stiffness > 0:
        print(f"warning    the nominal pose is stable without control (Γ_q = {stiffness:.4g} ≤ 0): it is not a pose to balance")
    return 0


def _bem(args) -> int:
    import torch


    r = _resolve(args.robot)[0]
    t = lambda v: torch.tensor([v], dtype=torch.float64)  # noqa: E731
    res = r.bem(t(args.qa), t(args.qad), t(args.qadd))
    if not bool(res.valid[0]):
        print(f"no BEM in [{r.qu_range[0]:.4f}, {r.qu_range[1]:.4f}] for these inputs")
        return 1
    from bemlearn.units import generalized_force_unit, joint_unit

    kind = r.coordinate_kinds[r.unactuated_index]
    print(f"q_u^e = {float(res.qu[0]):.12f} {joint_unit(kind)}  (|Γ_0| = {float(res.residual[0]):.2e} {generalized_force_unit(kind)})")
    return 0


def _lemma1(args) -> int:
    import numpy as np

    from bemlearn.robots.reference import CompositeSinusoid
    from bemlearn.robots.zero_dynamics import lemma1, lemma1_relative_gap, scaled_references

    robot = _resolve(args.robot)[0]
    if args.fixed_references:
        refs = {
            "0.3 sin(π t) + 0.2 sin(2π t + 0.7)": CompositeSinusoid.single([0.3, 0.2], [0.5, 1.0], [0.0, 0.7]),
            "0.4 sin(π/2 t + 0.3) + 0.1 sin(3π/2 t + 1.1)": CompositeSinusoid.single([0.4, 0.1], [0.25, 0.75], [0.3, 1.1]),
            "0.2/0.15/0.1 at 0.2/0.6/1.0 Hz": CompositeSinusoid.single([0.2, 0.15, 0.1], [0.2, 0.6, 1.0], [0.0, 0.5, 2.0]),
            "0.5 sin(2π t)": CompositeSinusoid.single([0.5], [1.0]),
        }
        if robot.m != 1:
            refs = {k: CompositeSinusoid(v.amplitudes * robot.m, v.frequencies * robot.m, v.phases * robot.m, v.offsets * robot.m) for k, v in refs.items()}
    else:
        refs = scaled_references(robot)
    units = _units(robot)
    print(f"Lemma 1 on {robot.name}: q_a^d in {units[0]}, ΔΓ in {units[1]}, q_u in {units[2]}; pass when relative gap ≤ {args.rtol:g}")
    width = max(46, max(len(k) for k in refs) + 2)
    print(f"{'reference q_a^d(t)':<{width}}{'max|ΔΓ|':>10}{'max|ΔΓ−Ḣ_u−b_u q̇_u^e|':>24}{'relative':>10}{'max|Γ(q_u^d)|':>15}{'max|q_u^d−q_u^e|':>18}")
    worst = 0.0
    for label, ref in refs.items():
        L = lemma1(robot, ref, n_nodes=256)
        rel = lemma1_relative_gap(L)
        worst = max(worst, rel)
        print(f"{label:<{width}}{np.abs(L.delta_gamma).max():>10.3e}{np.abs(L.gap).max():>24.2e}{rel:>10.1e}"
              f"{np.abs(L.zero_dynamics.residual).max():>15.2e}{L.max_distance:>18.4f}")
    ok = worst <= args.rtol
    print(f"{'PASS' if ok else 'FAIL'}: worst relative gap {worst:.2e} (tolerance {args.rtol:g})")
    return 0 if ok else 1


def _units(robot) -> tuple[str, str, str]:
    """Units of q_a, of the unactuated row's generalized force, and of q_u (by joint kind)."""

    kinds = robot.coordinate_kinds if getattr(robot, "coordinate_joints", None) is not None else None
    if kinds is None:
        return "rad", "N·m", "rad"
    ka = {kinds[i] for i in robot.actuated_index}
    qa = "rad" if ka == {"hinge"} else "m" if ka == {"slide"} else "rad or m"
    ku = kinds[robot.unactuated_index]
    return qa, "N·m" if ku == "hinge" else "N", "rad" if ku == "hinge" else "m"


def _lqr(args) -> int:

    from bemlearn.control.lqr import discrete_lqr
    from bemlearn.errors import RobotModelError
    from bemlearn.pipeline.derive import control_rate, design_region, initial_ranges, input_units
    from bemlearn.robots import MujocoRobot

    robot = _resolve(args.robot)[0]
    if not isinstance(robot, MujocoRobot):
        raise RobotModelError(f"robot lqr: {args.robot!r} has no MuJoCo model to linearize; give an MJCF robot")
    if (why := robot.actuator_mismatch()) is not None:
        raise RobotModelError(f"robot lqr: {why}")
    rate = control_rate(robot)
    if args.rate is None:
        hz, h = rate.value.rate_hz, rate.value.timestep
        print(f"rate       {rate.note}")
    else:
        hz, h = args.rate, (rate.value.timestep if rate.value.timestep_changed else None)
    d = design_region(robot).value
    res = discrete_lqr(robot, rate_hz=hz, timestep=h, design_qu=d, qu0=0.25 * d, qa0=initial_ranges(robot).value["initial_qa"][1])
    unit = input_units(robot).value
    pos = ["rad" if k == "hinge" else "m" for k in robot.coordinate_kinds]
    if robot.coordinate_joints is None:
        pos = ["rad"] * robot.n
    cols = [f"{nm} [{unit}/{u}]" for nm, u in zip(robot.joint_names, pos)] + [f"d{nm} [{unit}/({u}/s)]" for nm, u in zip(robot.joint_names, pos)]
    print(f"robot      {robot.name}: u = K e, e = [q − q_t, q̇ − q̇_t]; {hz:g} Hz, {res.substeps} × {res.timestep:g} s physics steps")
    print(f"weights    Bryson (|q_u| ≤ {d:g}, joint ranges, ctrlrange, forcerange){'' if res.r_scale == 1 else f', R × {res.r_scale:g} to stay within them'}")
    for note in res.notes:
        print(f"note       {note}")
    width = max(len(c) for c in cols) + 2
    names = list(robot.actuation.names)
    if (grouping := robot.actuation.describe(tuple(robot.actuated_names))):
        print(f"commands   {grouping}")
    lw = max(12, *(len(nm) + 2 for nm in names))
    print(f"{'':<{lw}}" + "".join(f"{c:>{width}}" for c in cols))
    for name, row in zip(names, res.K):
        print(f"{name:<{lw}}" + "".join(f"{v:>{width}.6g}" for v in row))
    print(f"closed-loop spectral radius {res.spectral_radius:.6f}; peak effort (|ctrl|/ctrlrange, |force|/forcerange) "
          f"for a {0.25 * d:g} q_u error: {res.u_peak:.2f}")
    return 0
