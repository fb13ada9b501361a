"""``bemlearn excite``: a reference schedule that lets a rig's own balancing loop resolve the BEM.

Under a balancing controller the unactuated acceleration follows the actuated one (q̈_u ≈ b q̈_a,
docs/verdict.md "Joint support"), so the data never reach the BEM's queries q̈_u = 0 at large
|q̈_a|.  A passive joint's response ratio b(ω) = q̈_u/q̈_a depends on the frequency of the actuated
motion, so sines at several frequencies on the actuated *reference* during balance give samples
off any one line.  Per actuated joint j the schedule is

    q_t,j(t) = Σ_k A_jk sin(2π f_k t + φ_jk),   k = 1..K (K = 4),                           (E1)

* frequencies f_k log-spaced over [f_hi / 10, f_hi]: f_hi = 1.5 λ / 2π from the upright's
  instability rate λ = √(Γ_q / D_uu) (the model's, or the data's 1/slope of (S2) when resolved),
  else 2 × the frequency below which 75 % of the data's q_a motion power lies (periodograms of 10 s
  pieces, without the mean; the top quarter is left out because an encoder's quantization noise is white);
* equal acceleration amplitudes A_jk (2π f_k)² = a_j / K with a_j = 1.3 d / |s_a,j| (the model's
  BEM slope in q̈_a, as the design region's box (D1)) or, from data, 4 × the data's std of q̈_a,j
  (the new motion then dominates the old line);
* each A_jk clipped to Q_j / K so that the position offset stays within Q_j: half the joint's
  range and d / |s_p,j| (the BEM it moves stays in the design region; s_p,j the model's BEM
  slope in q_a, or the data's least-squares slope);
* all amplitudes scaled down together until the input they add — the peak acceleration Σ A ω²
  times std(u) / std(q̈_a) of the data (the input moves with the acceleration as it does in the
  logs; a regression of u on the state would return the loop's feedback gains, not the plant's
  inertia), or D_aa / gear from the model — is at most half the actuator's headroom (a quarter of
  the ctrl range; from data, half the largest logged |u|);
* phases φ_jk drawn per trial (seeded);
* the unactuated joint's reference moves with the offsets by the BEM's static slope,
  q_u,t = Σ_j s_p,j q_t,j (the model's s_p, or the data's least-squares slope of q_u in q_a): where
  the passive joint rests for that actuated position (a pendubot's lower link stays vertical,
  s_p = −1; a Furuta's s_p = 0), so that a loop with no integral action is not asked to hold a
  pose that is not an equilibrium.

It says how long to log: trials of max(20 s, 10 / f_lo) and as many trials as the data had (at
least 12).  d is the design bound (0.2 rad, or m).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from bemlearn.errors import ConfigError

__all__ = ["excitation_schedule", "schedule_table", "N_SINES"]

N_SINES = 4
DESIGN_BOUND = 0.2


def _data_scales(config) -> dict[str, Any]:
    """The data's own scales (module docstring): per actuated joint std(q̈_a), the least-squares slope of q_u
    in q_a, the input regression, the q_a spectrum's 75 % frequency, and (S2)."""
    from bemlearn.data import build_datasets, read_trajectory
    from bemlearn.pipeline.support import extrapolation_leverage

    traj = read_trajectory(config.data)
    ds = build_datasets(traj, config.dataset)
    x, y = ds.train.x.numpy(), ds.train.y.numpy()
    names = tuple(ds.train.input_names)
    meta = traj.meta
    m = len(meta.actuated_names)
    lev = extrapolation_leverage(x, y, names)
    beta = np.linalg.lstsq(np.c_[np.ones(len(x)), x], y, rcond=None)[0][1:]
    fs = meta.sample_rate_hz
    f75 = []
    for joint in meta.actuated_names:
        col = meta.joint_names.index(joint)
        psd, freqs = None, None
        for s in traj.trial_slices():       # periodograms of 10 s pieces (Welch without overlap), summed
            q = traj.q[s.rows, col]
            n = min(len(q), int(fs * 10))
            if n < 16:
                continue
            for k in range(len(q) // n):
                piece = q[k * n:(k + 1) * n]
                p = np.abs(np.fft.rfft((piece - piece.mean()) * np.hanning(n))) ** 2
                if psd is None or len(psd) == len(p):
                    psd = p if psd is None else psd + p
                    freqs = np.fft.rfftfreq(n, 1.0 / fs)
        if psd is None or freqs is None or not psd[1:].sum() > 0:
            raise ConfigError(f"bemlearn excite: {config.data}: {joint} does not move in the data; no time scale to excite at")
        c = np.cumsum(psd[1:]) / psd[1:].sum()
        f75.append(float(freqs[1 + min(int(np.searchsorted(c, 0.75)), len(c) - 1)]))
    u_per_acc, u_max = None, math.nan
    if traj.u is not None and traj.u.size:
        # the input moves with the actuated acceleration as it does in the data: std(u) / std(q̈_a), the
        # largest over the inputs (a regression of u on the state would return the loop's feedback gains)
        u_std = traj.u[ds.train.row.numpy()].std(0)
        u_per_acc = float(u_std.max()) / np.maximum(x[:, :m].std(0), 1e-300)
        u_max = float(np.abs(traj.u).max())
    return {"qdd_std": x[:, :m].std(0), "s_p": beta[2 * m:3 * m], "unactuated": meta.unactuated,
            "unactuated_kind": meta.kind_of(meta.unactuated), "f75": np.array(f75), "leverage": lev, "u_per_acc": u_per_acc,
            "u_max": u_max, "names": tuple(meta.actuated_names), "kinds": [meta.kind_of(j) for j in meta.actuated_names],
            "n_trials": len(traj.trial_ids), "rate_hz": fs}


def excitation_schedule(config, *, n_sines: int = N_SINES, seed: int = 0) -> dict[str, Any]:
    """The schedule (E1) for a resolved :class:`~bemlearn.pipeline.config.PipelineConfig` (module docstring).

    Returns:
        ``{"source", "rate_hz", "trials", "log_seconds_per_trial", "frequency_basis", "joints": {name: {"unit",
        "sines": [{"amplitude", "frequency_hz", "phase"}], "peak", "peak_acceleration", "limited_by"}},
        "phases": [{name: [φ_k]}] per trial, "why"}``.
    """
    from bemlearn.robots import MujocoRobot, load
    from bemlearn.units import joint_unit

    robot: MujocoRobot | None = None
    if config.robot:
        loaded = load(config.robot, coordinates=config.coordinates)
        if not isinstance(loaded, MujocoRobot):
            raise ConfigError(f"bemlearn excite: robot {config.robot!r} has no MuJoCo model (its actuator limits are needed)")
        robot = loaded
    data = _data_scales(config) if config.data else None
    if robot is None and data is None:
        raise ConfigError("bemlearn excite: the config names neither robot: nor data:")
    d = DESIGN_BOUND
    if robot is not None:
        from bemlearn.pipeline.feasibility import equilibrium_stiffness
        from bemlearn.robots.scales import bem_slopes, qa_half_ranges

        eq = equilibrium_stiffness(robot)
        if eq["stable_without_control"]:
            raise ConfigError(f"bemlearn excite: {config.robot}: the equilibrium {eq['joint']} = {eq['qu']:.4g} is stable without "
                              "control (gravity stiffness < 0); declare the upright (bemlearn_qu_nominal) first")
        lam = math.sqrt(eq["gravity_stiffness"] / eq["d_uu"])
        f_hi = np.full(robot.m, 1.5 * lam / (2 * math.pi))
        basis = f"1.5 × the model's instability rate λ = {lam:.3g} 1/s"
        s = bem_slopes(robot)
        a_tot = np.where(np.abs(s[2]) > 0, 1.3 * d / np.maximum(np.abs(s[2]), 1e-300), np.inf)
        q_cap = np.minimum(0.5 * qa_half_ranges(robot), np.where(np.abs(s[0]) > 1e-9, d / np.maximum(np.abs(s[0]), 1e-300), np.inf))
        names = tuple(robot.actuated_names)
        kinds = [robot.coordinate_kinds[j] for j in robot.actuated_index]
        s_p = s[0]
        qu_name, qu_kind = robot.unactuated_name, robot.coordinate_kinds[robot.unactuated_index]
        model = robot.model
        lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
        q0 = np.zeros(robot.n)
        q0[robot.unactuated_index] = robot.qu_nominal
        D = robot.terms(q0, np.zeros(robot.n))[0]
        groups = robot.actuation   # one command per actuated coordinate, ctrl = W u (bemlearn.robots.actuation)
        if groups.grouped:   # a group's command reaches its coordinate through every member
            per_command = np.abs(robot.input_matrix_np[list(robot.actuated_index)] * groups.W.T).sum(axis=1)   # (m,) τ_c per unit u_c
            u_room = 0.5 * groups.command_limits(np.where(model.actuator_ctrllimited.astype(bool), 0.5 * (hi - lo), np.inf))
        else:   # one actuator per coordinate: its gear
            per_command = np.abs(model.actuator_gear[:robot.m, 0])
            u_room = np.where(model.actuator_ctrllimited[:robot.m].astype(bool), 0.25 * (hi - lo)[:robot.m], np.inf)
        u_per_acc = np.array([D[j, j] for j in robot.actuated_index]) / np.maximum(per_command, 1e-300)
        trials, rate = 12, float(config.collect.rate_hz or 500.0)
        if data is not None:
            a_tot = np.where(np.isfinite(a_tot), a_tot, 4.0 * data["qdd_std"])
    else:
        assert data is not None                            # checked above: robot or data
        names, kinds = data["names"], data["kinds"]
        lev = data["leverage"]
        if lev and lev["t"] >= 5.0 and lev["lambda2"] > 0:
            lam = math.sqrt(lev["lambda2"])
            f_hi = np.full(len(names), 1.5 * lam / (2 * math.pi))
            basis = f"1.5 × the data's instability rate λ = {lam:.3g} 1/s ((S2): 1/slope of q_u in q̈_u)"
        else:
            f_hi = 2.0 * data["f75"]
            basis = "2 × the frequency below which 75 % of the data's q_a motion power lies (the data do not resolve λ)"
        a_tot = 4.0 * data["qdd_std"]
        s_p = data["s_p"]
        qu_name, qu_kind = data["unactuated"], data["unactuated_kind"]
        sp = np.abs(s_p)
        q_cap = np.where(sp > 1e-9, d / np.maximum(sp, 1e-300), np.inf)
        trials, rate = max(12, data["n_trials"]), data["rate_hz"]
    rng = np.random.default_rng(seed)
    joints: dict[str, Any] = {}
    for j, name in enumerate(names):
        f = np.geomspace(f_hi[j] / 10.0, f_hi[j], n_sines)
        w = 2 * math.pi * f
        acc = np.full(n_sines, a_tot[j] / n_sines)
        A = acc / w**2
        limited = []
        if np.isfinite(q_cap[j]) and np.any(q_cap[j] / n_sines < A):
            A = np.minimum(A, q_cap[j] / n_sines)
            limited.append(f"position: Σ A ≤ {q_cap[j]:.3g}")
        # the input the sines add (module docstring): scale down to half the headroom
        if robot is not None:
            du = float(np.sum(A * w**2)) * u_per_acc[j]
            room = u_room[j]
        else:
            assert data is not None
            g = data["u_per_acc"]
            du = float(np.sum(A * w**2)) * float(g[j]) if g is not None else 0.0
            room = 0.5 * data["u_max"] if math.isfinite(data["u_max"]) else math.inf
        if du > room > 0:
            A = A * room / du
            limited.append(f"input: adds ≤ {room:.3g} (half the headroom)")
        kind = kinds[j]
        joints[name] = {"unit": joint_unit(kind), "sines": [{"amplitude": float(a), "frequency_hz": float(fk), "phase": 0.0}
                                                            for a, fk in zip(A, f)],
                        "peak": float(A.sum()), "peak_acceleration": float(np.sum(A * w**2)), "limited_by": limited or ["—"]}
    phases = [{name: [float(p) for p in rng.uniform(0, 2 * math.pi, n_sines)] for name in names} for _ in range(trials)]
    for name in names:
        for c, p in zip(joints[name]["sines"], phases[0][name]):
            c["phase"] = p
    f_lo = min(c["frequency_hz"] for jn in joints.values() for c in jn["sines"])
    seconds = float(max(20.0, math.ceil(10.0 / f_lo)))
    return {"source": f"robot {config.robot}" if robot is not None and data is None else f"data {config.data}",
            "rate_hz": rate, "trials": trials, "log_seconds_per_trial": seconds, "frequency_basis": basis, "joints": joints,
            "unactuated": {"name": qu_name, "unit": joint_unit(qu_kind),
                           "static_slope": {name: float(s_p[j]) for j, name in enumerate(names)}},
            "phases": phases,
            "why": "add these offsets to the actuated reference of the rig's balancing controller (its own gains, during "
                   "balance), and Σ_j static_slope_j × offset_j to the unactuated joint's reference (where it rests for that "
                   "actuated position), and log every trial: sines at several frequencies change the ratio of the passive joint's "
                   "acceleration to the actuated one, so the data reach q̈_u = 0 at large |q̈_a| (docs/verdict.md)"}


def schedule_table(schedule: dict[str, Any]) -> np.ndarray:
    """The schedule as rows ``[trial, t, q_t offset per actuated joint…, q_u,t offset, q̇_t offsets…, q̇_u,t offset]``
    at its rate (the CSV); q_u,t = Σ_j s_p,j q_t,j (the unactuated joint's rest position for those offsets)."""
    names = list(schedule["joints"])
    t = np.arange(int(round(schedule["log_seconds_per_trial"] * schedule["rate_hz"]))) / schedule["rate_hz"]
    rows = []
    for i, ph in enumerate(schedule["phases"]):
        q = np.zeros((len(t), len(names)))
        qd = np.zeros_like(q)
        for j, name in enumerate(names):
            for c, p in zip(schedule["joints"][name]["sines"], ph[name]):
                w = 2 * math.pi * c["frequency_hz"]
                q[:, j] += c["amplitude"] * np.sin(w * t + p)
                qd[:, j] += c["amplitude"] * w * np.cos(w * t + p)
        sp = np.array([schedule["unactuated"]["static_slope"][n] for n in names])
        rows.append(np.c_[np.full(len(t), i), t, q, q @ sp, qd, qd @ sp])
    return np.concatenate(rows)


def write_schedule(schedule: dict[str, Any], path: str | Path) -> Path:
    """Write ``schedule`` as YAML (``.yaml``/``.yml``) or CSV (``.csv``: :func:`schedule_table`), atomically."""
    import yaml

    from bemlearn.files import atomic_write_text

    path = Path(path)
    if path.suffix.lower() == ".csv":
        names = list(schedule["joints"])
        qu = schedule["unactuated"]["name"]
        header = ",".join(["trial", "t", *names, qu, *(f"{n}_rate" for n in names), f"{qu}_rate"])
        rows = schedule_table(schedule)
        text = header + "\n" + "\n".join(",".join(f"{v:.9g}" for v in r) for r in rows) + "\n"
    elif path.suffix.lower() in (".yaml", ".yml"):
        text = "# bemlearn excite: reference offsets for the rig's balancing controller (docs/verdict.md)\n" + \
            yaml.safe_dump(schedule, sort_keys=False, allow_unicode=True)
    else:
        raise ConfigError(f"bemlearn excite: --out {path}: expected a .yaml, .yml or .csv file")
    atomic_write_text(path, text)
    return path
