"""Batched forward kinematics of MuJoCo models through pytorch-kinematics.

pytorch-kinematics' own MJCF loader (``build_chain_from_mjcf``, 0.10) fails on current
MuJoCo releases (it indexes its joint-type map with numpy integers), so bemlearn builds
the :class:`pytorch_kinematics.chain.Chain` from the *compiled* ``MjModel`` through
pytorch-kinematics' public ``Frame``/``Link``/``Joint`` classes.  This works for any
MuJoCo version bemlearn supports and uses the compiled (resolved) body poses.

A MuJoCo body frame is ``T_parent · (pos, quat) · Tr(p) · J(θ) · Tr(−p)`` for a joint at
``p`` in the body frame.  pytorch-kinematics composes ``link offset · joint offset · J(θ)``
per frame, so a joint with ``p ≠ 0`` (or a body with several joints, composed in order)
gets pivot frames (``<body>__pivot<i>``) and the body frame is the last one's fixed child
with offset ``Tr(−p)``.  Sites are fixed child frames.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytorch_kinematics as pk
import pytorch_kinematics.transforms as tf
import torch
from pytorch_kinematics import frame as pkframe

from bemlearn.errors import ArgumentError, RobotModelError

__all__ = ["chain_from_model", "frame_positions"]

_DT = torch.float64


def _tf(pos, quat=None) -> tf.Transform3d:
    pos = torch.as_tensor(np.asarray(pos, dtype=np.float64), dtype=_DT)
    rot = None if quat is None else torch.as_tensor(np.asarray(quat, dtype=np.float64), dtype=_DT)
    return tf.Transform3d(pos=pos, rot=rot, dtype=_DT)


def _frame(name: str, offset: tf.Transform3d, joint: pkframe.Joint, children: list | None = None) -> pkframe.Frame:
    # pytorch-kinematics 0.10's Frame.__init__ ignores a non-None ``children`` argument,
    # so children are attached after construction.
    f = pkframe.Frame(name, link=pkframe.Link(name, offset=offset), joint=joint)
    f.children = list(children or [])
    return f


def _site_frames(model: mujoco.MjModel, body_id: int) -> list:
    out = []
    for s in range(model.nsite):
        if int(model.site_bodyid[s]) == body_id:
            site = model.site(s)
            out.append(_frame(site.name, _tf(site.pos, site.quat), pkframe.Joint(site.name + "__fixed", dtype=_DT)))
    return out


def _body_frame(model: mujoco.MjModel, body_id: int) -> pkframe.Frame:
    body = model.body(body_id)
    children = [_body_frame(model, c) for c in range(model.nbody) if c != body_id and int(model.body_parentid[c]) == body_id]
    children += _site_frames(model, body_id)
    njnt = int(model.body_jntnum[body_id])
    offset = _tf(body.pos, body.quat)
    if njnt == 0:
        return _frame(body.name, offset, pkframe.Joint(body.name + "__fixed", dtype=_DT), children)
    joints = []
    for j in range(int(model.body_jntadr[body_id]), int(model.body_jntadr[body_id]) + njnt):
        jtype = {int(mujoco.mjtJoint.mjJNT_HINGE): "revolute", int(mujoco.mjtJoint.mjJNT_SLIDE): "prismatic"}.get(int(model.jnt_type[j]))
        if jtype is None:
            raise RobotModelError(f"joint {model.joint(j).name!r} is not a hinge or slide")
        axis = torch.as_tensor(np.asarray(model.jnt_axis[j], dtype=np.float64), dtype=_DT)
        joints.append((pkframe.Joint(model.joint(j).name, offset=None, joint_type=jtype, axis=axis, dtype=_DT), np.asarray(model.jnt_pos[j], dtype=np.float64)))
    if njnt == 1 and not np.any(joints[0][1]):
        return _frame(body.name, offset, joints[0][0], children)
    # Several joints, or one away from the body origin: MuJoCo composes J_k = Tr(p_k) R_k Tr(−p_k)
    # in order; each joint gets a pivot frame, the body frame is the last pivot's child at Tr(−p).
    frame = _frame(body.name, _tf(-joints[-1][1]), pkframe.Joint(body.name + "__fixed", dtype=_DT), children)
    for i in range(njnt - 1, -1, -1):
        p_i = joints[i][1]
        link = offset.compose(_tf(p_i)) if i == 0 else _tf(p_i - joints[i - 1][1])
        frame = _frame(f"{body.name}__pivot{i}", link, joints[i][0], [frame])
    return frame


def chain_from_model(model: mujoco.MjModel) -> pk.Chain:
    """A float64 pytorch-kinematics chain rooted at the world body of ``model``."""
    root = _body_frame(model, 0)
    return pk.Chain(root, dtype=_DT)


def frame_positions(chain: pk.Chain, model: mujoco.MjModel, qj: torch.Tensor, frames) -> dict[str, torch.Tensor]:
    """World positions ``{name: (B, 3)}`` (m) of bodies/sites for joint values ``qj (B, njnt)``."""
    order = chain.get_joint_parameter_names()
    index = {model.joint(i).name: i for i in range(model.njnt)}
    missing = [n for n in order if n not in index]
    if missing:
        raise RobotModelError(f"forward_kinematics: chain joints {missing} not found in the model (unnamed joints?)")
    th = qj[:, [index[n] for n in order]].to(_DT)
    names = set(chain.get_frame_names(exclude_fixed=False))
    unknown = [f for f in frames if f not in names]
    if unknown:
        raise ArgumentError(f"forward_kinematics: unknown frame(s) {unknown}; known bodies/sites: {sorted(names)}")
    fk = chain.forward_kinematics(th)
    return {f: fk[f].get_matrix()[:, :3, 3] for f in frames}
