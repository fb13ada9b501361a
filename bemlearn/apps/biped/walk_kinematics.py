"""Foot kinematics of the planar 5-link biped: batched pytorch-kinematics foot positions.

The walker's MuJoCo model (``assets/biped_planar.xml``) carries three joints (x, z, q1) on
its torso; :func:`_kinematic_chain` re-roots it as a one-joint-per-body tree so that
:func:`foot_positions` can locate both foot sites for a whole log of states at once
(used by :func:`bemlearn.apps.biped.walk_metrics.walk_metrics` for step lengths and clearance).
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import torch

from bemlearn.errors import ArgumentError

__all__ = ["foot_positions"]

_FOOT_SITES = ("foot1", "foot2")


def _planar_model() -> mujoco.MjModel:
    """The floating planar walker (``assets/biped_planar.xml``), as simulated by :mod:`bemlearn.apps.biped.walker`."""
    from bemlearn.apps.biped.assets import PLANAR_XML

    return mujoco.MjModel.from_xml_path(str(PLANAR_XML))


@functools.lru_cache(maxsize=1)
def _kinematic_chain():
    """The planar walker re-rooted as a one-joint-per-body tree (x slide → z slide → torso), and its chain.

    :func:`bemlearn.robots.kinematics.chain_from_model` needs at most one joint per body;
    the walker's torso carries three (x, z, q1), so they are split into nested bodies with
    the same joint order and a negligible inertia (kinematics only).
    """
    from bemlearn.apps.biped.assets import PLANAR_XML
    from bemlearn.robots.kinematics import chain_from_model

    root = ET.fromstring(PLANAR_XML.read_text())
    world = root.find("worldbody")
    torso = world.find("body[@name='torso']")
    joints = {j.get("name"): j for j in torso.findall("joint")}
    inertial = dict(pos="0 0 0", mass="1e-6", diaginertia="1e-9 1e-9 1e-9")
    base_x = ET.Element("body", name="base_x", pos=torso.get("pos", "0 0 0"))
    base_z = ET.SubElement(base_x, "body", name="base_z")
    for body, name in ((base_x, "x"), (base_z, "z")):
        torso.remove(joints[name])
        body.insert(0, joints[name])
        ET.SubElement(body, "inertial", **inertial)
    torso.set("pos", "0 0 0")
    world.remove(torso)
    base_z.append(torso)
    world.append(base_x)
    model = mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))
    return model, chain_from_model(model)


def foot_positions(qpos: np.ndarray) -> np.ndarray:
    """World positions of both foot sites, ``qpos (T, 7)`` [x, z, q1..q5] → ``(T, 2, 3)`` m.

    Batched forward kinematics with pytorch-kinematics (float64) on the re-rooted tree of
    :func:`_kinematic_chain`.
    """
    from bemlearn.robots.kinematics import frame_positions

    model, chain = _kinematic_chain()
    qpos = np.asarray(qpos, dtype=np.float64)
    if qpos.ndim != 2 or qpos.shape[1] != model.nq:
        raise ArgumentError(f"foot_positions: qpos must have shape (T, {model.nq}), got {qpos.shape}")
    fk = frame_positions(chain, model, torch.from_numpy(qpos), _FOOT_SITES)
    return np.stack([fk[n].numpy() for n in _FOOT_SITES], 1)

