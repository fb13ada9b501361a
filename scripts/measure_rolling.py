"""The model BEM of a wheeled inverted pendulum against the hard-no-slip balance, and MuJoCo's soft contact.

    python scripts/measure_rolling.py ROBOT.xml [--com-offset RAD]

For a pendulum hinged on a chassis that rolls on a wheel (x = r_eff θ) the balance at φ̇ = φ̈ = 0 is
φ_e = atan(r_eff θ̈ / g) − β, β the angle of the pendulum's centre of mass from its upright axis
(tests/test_rolling.py derives it).  Prints, for the robot's recognised rolling map:

* r_eff (MuJoCo's contact point) beside the geom's radius;
* max |φ_e,model − φ_e,reference| over θ̈ ∈ [−20, 20] rad/s² (81 points, θ̇ = 0 and 10 rad/s), degrees;
* the same with the geometric radius in the reference instead (the bias the effective radius removes);
* ẍ/θ̈ of MuJoCo's soft contact: from one ``mj_forward`` at rest with the actuator at 1/3 of its range,
  and as x/θ after 1 s of that drive from rest (the model's own step; stopped earlier where x reaches half
  its joint range), beside r_eff.

The figures are quoted in docs/wheeled.md.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # this checkout's bemlearn

from bemlearn.robots import MujocoRobot, load


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("robot")
    p.add_argument("--com-offset", type=float, default=0.0, help="β, rad: the pendulum's centre of mass from its axis")
    args = p.parse_args()
    robot = load(args.robot)
    if not isinstance(robot, MujocoRobot) or robot.rolling is None:
        raise SystemExit(f"{args.robot}: no rolling freedom recognised")
    model = robot.model
    r_eff = float(np.mean([c.radius for c in robot.rolling.contacts]))
    r_geo = float(np.mean([c.geometric_radius for c in robot.rolling.contacts]))
    print(f"rolling: {robot.rolling.describe(model)}")
    g = float(-model.opt.gravity[2])
    alpha = np.linspace(-20.0, 20.0, 81)
    worst = worst_geo = 0.0
    for rate in (0.0, 10.0):
        res = robot.bem(np.zeros((alpha.size, 1)), np.full((alpha.size, 1), rate), alpha[:, None])
        qu = res.qu.numpy()
        worst = max(worst, float(np.max(np.abs(qu - (np.arctan(r_eff * alpha / g) - args.com_offset)))))
        worst_geo = max(worst_geo, float(np.max(np.abs(qu - (np.arctan(r_geo * alpha / g) - args.com_offset)))))
    print(f"model BEM vs atan(r_eff θ̈/g) − β over θ̈ ∈ [−20, 20] rad/s²: max {math.degrees(worst):.3e}°")
    print(f"model BEM vs the same with the geometric radius {r_geo:g} m: max {math.degrees(worst_geo):.3g}°")
    a = model.actuator(0)
    data = mujoco.MjData(model)
    data.qpos[:] = robot.Tinv_np @ np.array([0.0 if i != robot.unactuated_index else robot.qu_nominal for i in range(robot.n)])
    u = (model.actuator_ctrlrange[0, 1] / 3.0) if model.actuator_ctrllimited[0] else 1.0
    data.ctrl[:] = u
    mujoco.mj_forward(model, data)
    (dep,) = robot.rolling.dependent
    wheel = robot.rolling.independent[robot.actuated_index[0]]
    ratio = data.qacc[model.jnt_dofadr[dep]] / data.qacc[model.jnt_dofadr[wheel]]
    print(f"soft contact, one mj_forward at rest, ctrl {a.name} = {u:g}: ẍ/θ̈ = {ratio:.5f} (r_eff {r_eff:.5f})")
    reach = 0.5 * float(np.min(np.abs(model.jnt_range[dep]))) if model.jnt_limited[dep] else math.inf
    steps = 0
    while steps < int(round(1.0 / model.opt.timestep)) and abs(data.qpos[model.jnt_qposadr[dep]]) < reach:
        mujoco.mj_step(model, data)
        steps += 1
    x, theta = data.qpos[model.jnt_qposadr[dep]], data.qpos[model.jnt_qposadr[wheel]]
    print(f"soft contact, {steps} steps of {model.opt.timestep:g} s from rest (at most 1 s, |x| below half its range): "
          f"x/θ = {x / theta:.5f} (θ = {theta:.3f} rad)")


if __name__ == "__main__":
    main()
