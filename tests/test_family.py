"""The robot family of issue 28 (bemlearn/bench/family): generator determinism, every file compiles, and the
oracle checked against closed forms and independent computations."""

import math

import mujoco
import numpy as np
import pytest

from bemlearn.bench.family.generator import TOPOLOGIES, generate_robot
from bemlearn.bench.family.oracle import Oracle, wrap_angle


def test_same_seed_same_bytes():
    for i in (0, 5, 10):
        a = generate_robot(3, i, hold_check=False)
        b = generate_robot(3, i, hold_check=False)
        assert a[0] == b[0] and a[1] == b[1]
    assert generate_robot(3, 0, hold_check=False)[0] != generate_robot(4, 0, hold_check=False)[0]


@pytest.mark.parametrize("index", range(12))
def test_every_file_compiles_and_its_upright_is_an_unstable_equilibrium(index):
    xml, truth = generate_robot(0, index, hold_check=False)
    m = mujoco.MjModel.from_xml_string(xml)
    assert m.nu == truth["m"] and m.nv == truth["m"] + 1
    assert truth["topology"] == TOPOLOGIES[index % len(TOPOLOGIES)]
    up = truth["upright_check"]
    assert up["ok"] and up["unstable"] and up["energy_max"] and abs(up["residual"]) < 1e-9
    # the upright by construction is the potential energy's maximum found without being told
    assert abs(float(wrap_angle(Oracle(xml).qu_star - truth["qu_upright"]))) < 1e-9
    # the pole's centre of mass is straight above its hinge there
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    d.qpos[Oracle(xml).u] = truth["qu_upright"]
    mujoco.mj_kinematics(m, d)
    pole = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "pole")
    jnt = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "pole")
    r = d.xipos[pole] - d.xanchor[jnt]
    assert r[2] > 0 and math.hypot(r[0], r[1]) < 1e-9 * max(1.0, r[2]) + 1e-12
