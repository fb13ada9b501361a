"""The model BEM of a free body on two driven wheels against the full model's hard-no-slip dynamics.

    python scripts/measure_floating.py ROBOT.xml

For the reduction of :mod:`bemlearn.robots.floating` prints, over wheel accelerations θ̈ ∈ [−20, 20] rad/s²
(41 points, θ̇ = 0 and 10 rad/s, φ̇ = 0):

* max |φ_e,model − φ_e,KKT|: the reference solves the full model's hard-constraint dynamics (every dof,
  the contacts' no-slip and normal rows with J̇ q̇, ``kkt_acceleration(normal=True)``) with equal wheel
  torques chosen to give θ̈, and finds the pitch with φ̈ = 0 by root finding;
* max |φ_e,model − φ_e,P| with the planar closed form (P) of tests/test_floating.py,
  m_b g l sin φ = a (m_b (r + l cos φ) + Σ m_w r + Σ I_w / r), a = r θ̈, its masses, l and the wheels'
  inertia about the axle read from the model at pitch 0, with r = r_eff and with the geometric radius;
* MuJoCo's soft contact: the travel per wheel-angle-plus-pitch over 0.3 s of equal wheel commands from
  rest (1/20 of the ctrlrange, or ctrl 1 where unlimited), beside r_eff.

The figures are quoted in docs/wheeled.md.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import mujoco
import numpy as np
from scipy.optimize import brentq

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # this checkout's bemlearn

from bemlearn.robots import MujocoRobot, load
from bemlearn.robots.rolling import kkt_acceleration, wheel_geoms


def kkt_pitch_accel(robot: MujocoRobot, q: np.ndarray, qd: np.ndarray, alpha: float) -> float:
    m = robot.model
    d = mujoco.MjData(m)
    qpos, qvel = robot.state_to_mujoco(q, qd)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    wheels = wheel_geoms(m, d)
    dofs = [int(m.jnt_dofadr[m.actuator_trnid[i, 0]]) for i in range(m.nu)]
    acc = []
    for tau in (0.0, 1.0):
        f = np.zeros(m.nv)
        f[dofs] = tau * robot.floating.signs
        acc.append(robot.T_np @ kkt_acceleration(m, d, qpos, qvel, f, wheels, normal=True)[0])
    tau = (alpha - acc[0][0]) / (acc[1][0] - acc[0][0])
    return float(acc[0][1] + tau * (acc[1][1] - acc[0][1]))


def planar_parameters(robot: MujocoRobot) -> tuple[float, float, float, float]:
    """(m_b, l, Σ m_w, Σ I_w) at pitch 0 from MuJoCo's bodies (l: the body's centre of mass above the axle)."""
    m, fl = robot.model, robot.floating
    d = mujoco.MjData(m)
    d.qpos[:] = robot.state_to_mujoco(np.zeros(2))[0]
    mujoco.mj_kinematics(m, d)
    body = m.body(fl.body).id
    axle = d.xanchor[fl.wheels[0]]
    up = -m.opt.gravity / np.linalg.norm(m.opt.gravity)
    rel = d.xipos[body] - axle
    travel = np.cross(fl.axle, up)
    if abs(rel @ travel) > 1e-9:
        raise SystemExit("the body's centre of mass is not above the axle at pitch 0: the closed form here assumes it")
    mw = iw = 0.0
    for j in fl.wheels:
        b = int(m.jnt_bodyid[j])
        R = d.ximat[b].reshape(3, 3)
        iw += float(fl.axle @ (R @ np.diag(m.body_inertia[b]) @ R.T) @ fl.axle)
        mw += float(m.body_mass[b])
    return float(m.body_mass[body]), float(rel @ up), mw, iw


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("robot")
    args = p.parse_args()
    robot = load(args.robot)
    if not isinstance(robot, MujocoRobot) or robot.floating is None:
        raise SystemExit(f"{args.robot}: not a free body on wheels")
    fl, model = robot.floating, robot.model
    print(f"rolling: {fl.describe(model)}")
    r_eff = float(np.mean([c.radius for c in fl.contacts]))
    r_geo = float(np.mean([c.geometric_radius for c in fl.contacts]))
    mb, l, mw, iw = planar_parameters(robot)
    g = float(np.linalg.norm(model.opt.gravity))
    print(f"planar parameters: m_b {mb:g} kg, l {l:g} m, wheels {mw:g} kg, {iw:g} kg·m² about the axle")

    def closed(alpha: float, r: float) -> float:
        a = r * alpha
        return brentq(lambda f: mb * g * l * math.sin(f) - a * (mb * (r + l * math.cos(f)) + mw * r + iw / r), -1.5, 1.5, xtol=1e-15)

    alpha = np.linspace(-20.0, 20.0, 41)
    worst_kkt = worst_p = worst_geo = 0.0
    top = 0.0
    for rate in (0.0, 10.0):
        res = robot.bem(np.zeros((alpha.size, 1)), np.full((alpha.size, 1), rate), alpha[:, None])
        qu = res.qu.numpy()
        top = max(top, float(np.abs(qu).max()))
        for a, phi in zip(alpha, qu):
            ref = brentq(lambda f, a=a, rate=rate: kkt_pitch_accel(robot, np.array([0.0, f]), np.array([rate, 0.0]), a),
                         -1.2, 1.2, xtol=1e-14)
            worst_kkt = max(worst_kkt, abs(phi - ref))
            worst_p = max(worst_p, abs(phi - closed(a, r_eff)))
            worst_geo = max(worst_geo, abs(phi - closed(a, r_geo)))
    print(f"model BEM over θ̈ ∈ [−20, 20] rad/s² (|φ_e| up to {top:.4f} rad): vs the full model's hard-no-slip KKT "
          f"max {math.degrees(worst_kkt):.3e}°, vs the closed form with r_eff max {math.degrees(worst_p):.3e}°, "
          f"with the geometric radius {r_geo:g} m max {math.degrees(worst_geo):.3g}°")
    d = mujoco.MjData(model)
    d.qpos[:] = robot.state_to_mujoco(np.zeros(2))[0]
    hi = model.actuator_ctrlrange[:, 1]
    u = np.where(model.actuator_ctrllimited.astype(bool), hi / 20.0, 1.0) * fl.signs
    d.ctrl[:] = u
    steps = int(round(0.3 / model.opt.timestep))
    for _ in range(steps):
        mujoco.mj_step(model, d)
    q = robot.coordinates_of(d.qpos)
    travel = float(fl.displacement(model, d.qpos)[:3] @ np.cross(fl.axle, -model.opt.gravity / g))
    print(f"soft contact, {steps} steps of {model.opt.timestep:g} s from rest, ctrl {u}: travel/(θ + φ) = "
          f"{travel / (q[0] + q[1]):.6f} m (r_eff {r_eff:.6f}; θ = {q[0]:.3f} rad, φ = {q[1]:.3f} rad)")


if __name__ == "__main__":
    main()
