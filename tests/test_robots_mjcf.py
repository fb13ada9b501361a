"""Robots from user MJCF files: a cart-pole against its closed form, and clear errors."""

from __future__ import annotations

import math

import mujoco
import pytest
import torch

from bemlearn.apps.biped.assets import PLANAR_XML
from bemlearn.robots import RobotModelError, load
from tests.test_robots_contract import CARTPOLE

M, MP, L, J = 1.3, 0.2, 0.25, 0.004  # cart mass, pole mass, pole COM distance, pole inertia (see CARTPOLE)


@pytest.fixture(scope="module")
def cartpole(tmp_path_factory):
    path = tmp_path_factory.mktemp("mjcf") / "cartpole.xml"
    path.write_text(CARTPOLE)
    return load(path)


def test_cartpole_partition(cartpole):
    assert cartpole.joint_names == ("x", "phi") and cartpole.unactuated_name == "phi"
    assert cartpole.qu_range == (-math.pi / 2, math.pi / 2)


def test_cartpole_dynamics_closed_form(cartpole):
    g = torch.Generator().manual_seed(0)
    q = torch.rand(50, 2, generator=g, dtype=torch.float64) * 2 - 1
    qd = torch.rand(50, 2, generator=g, dtype=torch.float64) * 4 - 2
    c, s = torch.cos(q[:, 1]), torch.sin(q[:, 1])
    D = torch.stack([torch.stack([torch.full_like(c, M + MP), MP * L * c], -1), torch.stack([MP * L * c, torch.full_like(c, MP * L**2 + J)], -1)], -2)
    bias = torch.stack([-MP * L * s * qd[:, 1] ** 2, -MP * 9.81 * L * s], -1)
    torch.testing.assert_close(cartpole.mass_matrix(q), D, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(cartpole.bias(q, qd), bias, rtol=1e-10, atol=1e-12)


def test_cartpole_bem_closed_form(cartpole):
    """m l cos φ ẍ − m g l sin φ = 0  ⇒  tan φ = ẍ / g."""
    xdd = torch.linspace(-15, 15, 31, dtype=torch.float64)[:, None]
    res = cartpole.bem(torch.zeros_like(xdd), torch.zeros_like(xdd), xdd)
    torch.testing.assert_close(res.qu, torch.atan(xdd[:, 0] / 9.81), rtol=0, atol=1e-12)


def test_forward_kinematics_matches_mujoco_sites(cartpole):
    q = torch.tensor([[0.3, 0.2], [-1.0, -0.7]], dtype=torch.float64)
    tip = cartpole.forward_kinematics(q, ["tip"])["tip"]
    d = mujoco.MjData(cartpole.model)
    for i in range(2):
        d.qpos[:] = q[i].numpy()
        mujoco.mj_kinematics(cartpole.model, d)
        torch.testing.assert_close(tip[i], torch.as_tensor(d.site_xpos[0].copy()), rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="unknown frame"):
        cartpole.forward_kinematics(q, ["nope"])


def _write(tmp_path, body):
    path = tmp_path / "m.xml"
    path.write_text(f'<mujoco><worldbody>{body}</worldbody></mujoco>' if "<actuator>" not in body else body)
    return path


def test_two_unactuated_joints_rejected(tmp_path):
    xml = CARTPOLE.replace('<actuator><motor joint="x"/></actuator>', "")
    p = tmp_path / "a.xml"
    p.write_text(xml)
    with pytest.raises(RobotModelError, match=r"exactly one unactuated.*found 2"):
        load(p)


def test_fully_actuated_rejected(tmp_path):
    xml = CARTPOLE.replace('<motor joint="x"/>', '<motor joint="x"/><motor joint="phi"/>')
    p = tmp_path / "b.xml"
    p.write_text(xml)
    with pytest.raises(RobotModelError, match="found no"):
        load(p)


def test_free_joint_rejected(tmp_path):
    p = tmp_path / "c.xml"
    p.write_text('<mujoco><worldbody><body><freejoint/><geom size="0.1"/></body></worldbody></mujoco>')
    with pytest.raises(RobotModelError, match="ball/free"):
        load(p)


def test_unknown_name_and_missing_file(tmp_path):
    with pytest.raises(ValueError, match=r"unknown robot 'furuto'.*\['biped'"):
        load("furuto")
    with pytest.raises(FileNotFoundError, match="not found"):
        load(tmp_path / "missing.xml")
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body>")
    with pytest.raises(RobotModelError, match="could not load"):
        load(bad)


def test_planar_walker_is_not_a_balance_robot():
    with pytest.raises(RobotModelError, match="exactly one unactuated"):
        load(PLANAR_XML)


def test_kinematics_of_bodies_with_several_joints_and_offset_pivots():
    """The planar walker's torso has x, z slides and a hinge; a user model puts a hinge off the body origin."""
    from bemlearn.robots.kinematics import chain_from_model, frame_positions

    models = [mujoco.MjModel.from_xml_path(str(PLANAR_XML)), mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="b" pos="0.1 0 0.2"><joint name="s" type="slide" axis="1 0 0" pos="0.3 0 0"/>'
        '<joint name="h" type="hinge" axis="0 1 0" pos="0 0 0.4"/><geom size="0.1"/><site name="tip" pos="0.2 0 -0.5"/>'
        '</body></worldbody></mujoco>')]
    g = torch.Generator().manual_seed(0)
    for m in models:
        chain = chain_from_model(m)
        sites = [m.site(i).name for i in range(m.nsite)]
        qj = (torch.rand(8, m.njnt, generator=g, dtype=torch.float64) - 0.5) * 1.5
        fk = frame_positions(chain, m, qj, sites)
        d = mujoco.MjData(m)
        for i in range(qj.shape[0]):
            d.qpos[:] = qj[i].numpy()
            mujoco.mj_kinematics(m, d)
            for k, name in enumerate(sites):
                torch.testing.assert_close(fk[name][i], torch.as_tensor(d.site_xpos[k].copy()), rtol=0, atol=1e-12)
