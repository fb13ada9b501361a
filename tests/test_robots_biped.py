"""Biped: coordinates (absolute torso angle), input matrix, kinematics vs MuJoCo."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from bemlearn.apps.biped.assets import PLANAR_XML
from bemlearn.apps.biped.model import BipedParameters
from bemlearn.robots import load


@pytest.fixture(scope="module")
def biped():
    return load("biped")


def test_partition_and_input_matrix(biped):
    assert biped.joint_names == ("q1", "q2", "q3", "q4", "q5")
    assert biped.unactuated_name == "q1"
    B = biped.input_matrix
    torch.testing.assert_close(B, torch.cat([torch.zeros(1, 4), torch.eye(4)]).double())


def _pitch(xmat):
    R = np.asarray(xmat).reshape(3, 3)
    return float(np.arctan2(R[0, 2], R[2, 2]))  # rotation about +y taking +z towards +x


def test_q1_is_absolute_torso_angle_and_links_follow_convention(biped):
    g = torch.Generator().manual_seed(0)
    q = (torch.rand(20, 5, generator=g, dtype=torch.float64) - 0.5) * 1.2
    qj = (q @ biped.Tinv.T).numpy()
    d = mujoco.MjData(biped.model)
    bid = lambda n: mujoco.mj_name2id(biped.model, mujoco.mjtObj.mjOBJ_BODY, n)  # noqa: E731
    for i in range(q.shape[0]):
        d.qpos[:] = qj[i]
        mujoco.mj_kinematics(biped.model, d)
        q1, q2, q3, q4, q5 = q[i].tolist()
        assert abs(_pitch(d.xmat[bid("torso")]) - q1) < 1e-12
        # stance leg bodies point up from the foot, swing leg bodies point down: same absolute angle convention
        assert abs(_pitch(d.xmat[bid("thigh1")]) - (q1 + q2)) < 1e-12
        assert abs(_pitch(d.xmat[bid("shank1")]) - (q1 + q2 + q3)) < 1e-12
        assert abs(_pitch(d.xmat[bid("thigh2")]) - (q1 + q4)) < 1e-12
        assert abs(_pitch(d.xmat[bid("shank2")]) - (q1 + q4 + q5)) < 1e-12


def test_batched_foot_positions_match_mujoco_sites(biped):
    g = torch.Generator().manual_seed(1)
    q = (torch.rand(16, 5, generator=g, dtype=torch.float64) - 0.5)
    fk = biped.forward_kinematics(q, ["foot1", "foot2", "hip"])
    qj = (q @ biped.Tinv.T).numpy()
    d = mujoco.MjData(biped.model)
    sid = lambda n: mujoco.mj_name2id(biped.model, mujoco.mjtObj.mjOBJ_SITE, n)  # noqa: E731
    for i in range(q.shape[0]):
        d.qpos[:] = qj[i]
        mujoco.mj_kinematics(biped.model, d)
        for name in ("foot1", "foot2", "hip"):
            np.testing.assert_allclose(fk[name][i].numpy(), d.site_xpos[sid(name)], rtol=0, atol=1e-12)


def test_straight_legs_geometry(biped):
    p = BipedParameters()
    fk = biped.forward_kinematics(torch.zeros(1, 5, dtype=torch.float64), ["hip", "foot2"])
    np.testing.assert_allclose(fk["hip"][0].numpy(), [0, 0, p.L_s + p.L_t], atol=1e-14)
    np.testing.assert_allclose(fk["foot2"][0].numpy(), [0, 0, 0], atol=1e-14)


def test_planar_walker_loads_with_paper_joint_names():
    m = mujoco.MjModel.from_xml_path(str(PLANAR_XML))
    names = [m.joint(i).name for i in range(m.njnt)]
    assert names == ["x", "z", "q1", "q2", "q3", "q4", "q5"]
    assert m.nu == 4
    total = sum(m.body_mass)
    p = BipedParameters()
    assert abs(total - (p.m_b + 2 * p.m_t + 2 * p.m_s)) < 1e-12


def test_planar_walker_foot_radius():
    """The feet are spheres of ``foot_radius`` at the shank ends (a near-point foot, as the
    pinned model assumes); a non-positive radius is refused by name."""
    from bemlearn.apps.biped.model import biped_planar_mjcf

    for r in (0.002, 0.01):
        m = mujoco.MjModel.from_xml_string(biped_planar_mjcf(foot_radius=r))
        for name in ("foot1", "foot2"):
            g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)
            assert m.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE and m.geom_size[g, 0] == pytest.approx(r, abs=1e-12)
            site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
            np.testing.assert_allclose(m.geom_pos[g], m.site_pos[site], atol=1e-12)
    shipped = mujoco.MjModel.from_xml_path(str(PLANAR_XML))
    assert shipped.geom_size[mujoco.mj_name2id(shipped, mujoco.mjtObj.mjOBJ_GEOM, "foot1"), 0] == pytest.approx(0.002)
    with pytest.raises(ValueError, match="foot_radius"):
        biped_planar_mjcf(foot_radius=0.0)
