"""A :class:`~bemlearn.robots.robot.Robot` whose dynamics come from a MuJoCo model.

Any MJCF whose joints are hinges or slides and whose actuators drive joints directly
works: D(q) is MuJoCo's composite-rigid-body mass matrix, C q̇ + G its recursive
Newton–Euler bias (``mj_rne`` with zero acceleration), τ_p its passive forces
(``mj_passive``: joint damping, stiffness).  The unactuated coordinate is the one whose
row of the input matrix B is zero; exactly one is required.

Coordinates.  By default the coordinates are the MJCF joints in model order.  A model may
declare a constant linear change of coordinates q = T q_joint, which is how a planar
biped with a pinned stance foot (an ankle-rooted kinematic tree) exposes the absolute
torso angle as its unactuated coordinate:

.. code-block:: xml

    <custom>
      <numeric name="bemlearn_coordinates" data="..."/>       <!-- T, n×n row-major -->
      <text name="bemlearn_coordinate_names" data="q1 q2 ..."/>
      <numeric name="bemlearn_qu_range" data="-1.5708 1.5708"/> <!-- optional -->
      <numeric name="bemlearn_qu_nominal" data="0"/>            <!-- optional -->
      <text name="bemlearn_rolling_dependent" data="x"/>        <!-- optional, rolling below -->
    </custom>

A run's config may declare the same elements in a ``coordinates:`` block instead
(:mod:`bemlearn.robots.coordinates`), leaving the file as it is.

With q_j = T⁻¹ q, the dynamics transform as D = T⁻ᵀ D_j T⁻¹, C q̇ + G = T⁻ᵀ (C q̇ + G)_j,
τ_p = T⁻ᵀ τ_p,j and B = T⁻ᵀ B_j (T constant, so no extra velocity terms).

Rolling.  When more than one joint has no actuator and a wheel's rolling contact determines all
but one of them (a chassis slide that moves only because the wheel rolls), those joints are
dependent (:mod:`bemlearn.robots.rolling`): the coordinates are the other joints, q_j = S q with a
constant ``(n_j, n)`` map S (x = r_eff θ), and the dynamics transform with S in the place of T⁻¹:
D = Sᵀ D_j S, h = Sᵀ h_j, B = Sᵀ B_j (eq. R4 there: the hard no-slip constraint's KKT system with
the constraint force projected out).  T is then the ``(n, n_j)`` selection of the independent joints.
Where more than one choice of dependent joints fits, ``bemlearn_rolling_dependent`` names it.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from bemlearn._lazy import lazy_module
from bemlearn.errors import MissingFileError, RobotModelError
from bemlearn.robots._mujoco_compat import full_mass_matrix, make_mass_matrix
from bemlearn.robots.actuation import ActuatorGroups, actuator_groups
from bemlearn.robots.coordinates import declared_numeric, declared_text
from bemlearn.robots.floating import FloatingRolling, find_floating
from bemlearn.robots.robot import Robot, as_batch
from bemlearn.robots.rolling import RollingMap, find_rolling
from bemlearn.robots.upright import UprightSearch, find_upright
from bemlearn.warnings import RobotModelWarning, warn

if TYPE_CHECKING:
    import torch

    from bemlearn.robots.coordinates import CoordinatesConfig
else:
    torch = lazy_module("torch")

__all__ = ["MujocoRobot", "RobotModelError"]

log = logging.getLogger(__name__)

_JOINT_KIND = {
    int(mujoco.mjtJoint.mjJNT_HINGE): "hinge",
    int(mujoco.mjtJoint.mjJNT_SLIDE): "slide",
    int(mujoco.mjtJoint.mjJNT_BALL): "ball",
    int(mujoco.mjtJoint.mjJNT_FREE): "free",
}


#: MjModel arrays that must be finite, with the MJCF attribute they come from.
_FINITE_ARRAYS = (("body_mass", "body mass"), ("body_inertia", "body inertia"), ("body_pos", "body pos"),
                  ("body_quat", "body quat"), ("jnt_range", "joint range"), ("dof_damping", "joint damping"),
                  ("dof_armature", "joint armature"), ("dof_frictionloss", "joint frictionloss"),
                  ("jnt_stiffness", "joint stiffness"), ("actuator_gear", "actuator gear"),
                  ("actuator_ctrlrange", "actuator ctrlrange"), ("actuator_gainprm", "actuator gain"),
                  ("actuator_biasprm", "actuator bias"), ("geom_size", "geom size"))


def _unlimit_unbounded_joints(model: mujoco.MjModel, where: str) -> None:
    """A joint whose range is (−∞, +∞) (MJCF ``range="-inf inf"``, e.g. a wheel) has no limits: it is made
    unlimited in ``model`` (``jnt_limited = 0``, range 0 0; MuJoCo never activates an infinite limit, so the
    physics is the same).  Every other range must be finite.

    Raises:
        RobotModelError: a range with NaN or with one infinite end, naming the joint.
    """
    for j in np.flatnonzero(np.asarray(model.jnt_limited).astype(bool)):
        lo, hi = (float(v) for v in model.jnt_range[j])
        if np.isfinite(lo) and np.isfinite(hi):
            continue
        name = model.joint(int(j)).name or f"joint{j}"
        if lo == -math.inf and hi == math.inf:
            model.jnt_limited[j] = 0
            model.jnt_range[j] = 0.0
            continue
        raise RobotModelError(f"{where}: <joint name=\"{name}\" range=\"{lo:g} {hi:g}\">: expected a finite range, "
                              "or \"-inf inf\" for a joint without limits")


def _check_physics(model: mujoco.MjModel, where: str) -> None:
    """What the simulation divides by or integrates must make sense: a positive, finite physics step,
    finite gravity and parameters, non-negative masses and damping, ranges with lo < hi.

    Raises:
        RobotModelError: naming the MJCF option or attribute, what was expected and what was found.
    """
    h = float(model.opt.timestep)
    if not (np.isfinite(h) and 0.0 < h <= 1.0):
        raise RobotModelError(f"{where}: <option timestep=\"{h:g}\">: expected a positive, finite physics step of at most 1 s")
    if not np.all(np.isfinite(model.opt.gravity)):
        raise RobotModelError(f"{where}: <option gravity=\"{' '.join(f'{g:g}' for g in model.opt.gravity)}\">: expected finite values")
    for attr, label in _FINITE_ARRAYS:
        values = np.asarray(getattr(model, attr, np.zeros(0)))
        if values.size and not np.all(np.isfinite(values)):
            raise RobotModelError(f"{where}: a {label} is not finite (NaN or inf); expected finite numbers")
    for attr, label in (("body_mass", "body mass"), ("dof_damping", "joint damping"), ("dof_armature", "joint armature")):
        values = np.asarray(getattr(model, attr))
        if values.size and np.any(values < 0):
            raise RobotModelError(f"{where}: a {label} is negative ({values.min():g}); expected ≥ 0")
    for limited, ranges, label in ((model.jnt_limited, model.jnt_range, "joint range"),
                                   (model.actuator_ctrllimited, model.actuator_ctrlrange, "actuator ctrlrange")):
        for i in np.flatnonzero(np.asarray(limited).astype(bool)):
            lo, hi = ranges[i]
            if not lo < hi:
                raise RobotModelError(f"{where}: {label} \"{lo:g} {hi:g}\" of entry {i}: expected lo < hi")


class MujocoRobot(Robot):
    """A robot defined by an MJCF model (see module docstring).

    Args:
        model: a compiled ``mujoco.MjModel``.
        name: a name for the robot (default: the model name).
        source: where the model came from (path or registry name), for messages.

    Attributes:
        identity_coordinates: True when the coordinates are the MJCF joints themselves (T = I; see
            the module docstring), so joint ranges and kinds apply to the coordinates directly.
        coordinate_joints: the MJCF joint index of each coordinate when every coordinate is one joint
            (T = I, or the independent joints of a rolling robot), else ``None`` (a declared map).
        rolling: the :class:`~bemlearn.robots.rolling.RollingMap` when freedoms roll with a wheel, else ``None``.
        T_np: ``(n, n_j)`` the coordinate map q = T q_j as a NumPy array (:attr:`T` is the same numbers as a
            torch tensor); square unless the robot rolls.
        Tinv_np: ``(n_j, n)`` the map back, q_j = T⁻¹ q (the rolling map S when the robot rolls; :attr:`Tinv` in torch).
        input_matrix_np: ``(n, nu)`` B = T⁻ᵀ B_j as a NumPy array (:attr:`input_matrix` in torch).
    """

    def __init__(self, model: mujoco.MjModel, *, name: str | None = None, source: str | None = None,
                 coordinates: Mapping[str, Any] | None = None) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.source = source or "<MjModel>"
        #: the config's ``coordinates:`` block the model was compiled with (:meth:`from_xml`), as a mapping
        self.coordinates: dict[str, Any] | None = dict(coordinates) if coordinates else None
        self.name = name or model.names[: model.names.find(b"\0")].decode() or "robot"
        where = f"{self.source}"
        _unlimit_unbounded_joints(model, where)
        _check_physics(model, where)
        if model.njnt == 0:
            raise RobotModelError(f"{where}: the model has no joints")
        kinds = [_JOINT_KIND.get(int(t), str(t)) for t in model.jnt_type]
        names = [model.joint(i).name or f"joint{i}" for i in range(model.njnt)]
        # a free body on wheels (robots.floating): the coordinates are a wheel angle and the body's pitch
        self.floating: FloatingRolling | None = find_floating(model, where=where) if "free" in kinds else None
        bad = [(n, k) for n, k in zip(names, kinds) if k not in ("hinge", "slide")]
        if bad and self.floating is None:
            raise RobotModelError(
                f"{where}: joints {bad} are ball/free joints; bemlearn robots need hinge or slide joints "
                "only (one unactuated, the rest actuated)"
            )
        n = model.njnt if self.floating is None else model.nv
        self.joint_kinds = tuple(kinds)
        self.mjcf_joint_names = tuple(names)
        self._qadr = np.array(model.jnt_qposadr, dtype=np.int64)
        # "joint space": one entry per joint; MuJoCo's tangent space (qvel) for a free body on wheels
        self._dadr = np.array(model.jnt_dofadr, dtype=np.int64) if self.floating is None else np.arange(model.nv, dtype=np.int64)
        # MuJoCo's RNE leaves out the rotor inertia (armature) that its mass matrix holds: added to every q̈ term
        self._armature = np.array(model.dof_armature[self._dadr], dtype=np.float64)
        # input matrix in joint coordinates (nv x nu)
        Bj = np.zeros((n, model.nu))
        dof_to_joint = {int(a): k for k, a in enumerate(self._dadr)}   # dof address -> row of the joint space
        for i in range(model.nu):
            act = model.actuator(i)
            if int(model.actuator_trntype[i]) != int(mujoco.mjtTrn.mjTRN_JOINT):
                raise RobotModelError(
                    f"{where}: actuator {act.name or i!r} does not drive a joint directly "
                    "(bemlearn supports joint transmissions only)"
                )
            j = int(model.actuator_trnid[i, 0])
            Bj[dof_to_joint[int(model.jnt_dofadr[j])], i] = model.actuator_gear[i, 0]
        # coordinate map
        T = declared_numeric(model, "bemlearn_coordinates")
        self.rolling: RollingMap | None = None
        if self.floating is not None:
            T = self.floating.T
        elif T is None:
            T = np.eye(n)
            undriven = [j for j in range(n) if bool((np.abs(Bj[j]) < 1e-12).all())]
            if len(undriven) > 1:   # freedoms that only roll with a wheel are not coordinates (robots.rolling)
                self.rolling = find_rolling(model, undriven, where=where)
        elif T.size != n * n:
            raise RobotModelError(f"{where}: custom numeric 'bemlearn_coordinates' must have {n * n} entries (n×n), got {T.size}")
        else:
            T = T.reshape(n, n)
            if abs(np.linalg.det(T)) < 1e-12:
                raise RobotModelError(f"{where}: 'bemlearn_coordinates' matrix is singular")
        # numpy here, torch tensors on first use (T, Tinv, input_matrix): loading a robot does not load torch
        if self.floating is not None:
            self.T_np, self.Tinv_np = self.floating.T.copy(), self.floating.S.copy()
            self.coordinate_joints: tuple[int, ...] | None = None
        elif self.rolling is not None:
            self.T_np, self.Tinv_np = self.rolling.T.copy(), self.rolling.S.copy()
            self.coordinate_joints = self.rolling.independent
        else:
            self.T_np = np.array(T, dtype=np.float64)
            self.Tinv_np = np.linalg.inv(self.T_np)
            self.coordinate_joints = tuple(range(n)) if bool(np.allclose(self.T_np, np.eye(n))) else None
        nc = self.T_np.shape[0]
        coord_names = declared_text(model, "bemlearn_coordinate_names")
        if self.floating is not None:
            self.joint_names = (names[self.floating.wheels[0]], f"{self.floating.body}_pitch")
        elif coord_names:
            self.joint_names = tuple(coord_names.split())
        elif self.coordinate_joints is not None:
            self.joint_names = tuple(names[j] for j in self.coordinate_joints)
        else:
            self.joint_names = tuple(names)
        if len(self.joint_names) != nc:
            raise RobotModelError(f"{where}: 'bemlearn_coordinate_names' lists {len(self.joint_names)} names, expected {nc}")
        self.input_matrix_np = self.Tinv_np.T @ Bj  # (n, nu): generalized force = B @ actuator force
        self.identity_coordinates = self.rolling is None and self.coordinate_joints is not None
        zero_rows = [i for i in range(nc) if bool((np.abs(self.input_matrix_np[i]) < 1e-12).all())]
        if len(zero_rows) != 1:
            desc = "no" if not zero_rows else f"{len(zero_rows)} ({[self.joint_names[i] for i in zero_rows]})"
            raise RobotModelError(
                f"{where}: expected exactly one unactuated coordinate (a hinge/slide joint no actuator "
                f"drives), found {desc}; joints: {list(self.joint_names)}, actuators: {model.nu}"
            )
        self.unactuated_index = zero_rows[0]
        if self.floating is not None:
            self._coordinate_kinds: tuple[str, ...] = ("hinge", "hinge")   # a wheel angle and the body's pitch
        elif self.coordinate_joints is not None:
            self._coordinate_kinds = tuple(self.joint_kinds[j] for j in self.coordinate_joints)
        elif len(set(self.joint_kinds)) == 1:  # a linear map of like joints keeps their kind
            self._coordinate_kinds = (self.joint_kinds[0],) * n
        else:
            raise RobotModelError(f"{where}: 'bemlearn_coordinates' mixes hinge and slide joints; their units would not be defined")
        # admissible range and nominal value of q_u
        rng = declared_numeric(model, "bemlearn_qu_range")
        nom = declared_numeric(model, "bemlearn_qu_nominal")
        self._M = np.zeros((model.nv, model.nv))
        self._vec = np.zeros(model.nv)
        # hinge/slide joints only: nq = nv = n; in model order (the usual case) a row loads as a slice
        self._joint_order = bool(np.array_equal(self._qadr, np.arange(n)) and np.array_equal(self._dadr, np.arange(n)))
        self._ix_dd = np.ix_(self._dadr, self._dadr)
        self._ia = np.array([i for i in range(self.n) if i != self.unactuated_index], dtype=np.int64)   # coordinates
        self._chain = None
        self.upright_search = self._search_upright(rng)
        if nom is not None:
            self.qu_nominal = float(nom[0])
            self.qu_nominal_note = (f"{self.qu_nominal:g}: declared by the config (coordinates: qu_nominal)"
                                    if self.coordinates and "qu_nominal" in self.coordinates
                                    else f"{self.qu_nominal:g}: declared by the model (custom numeric bemlearn_qu_nominal)")
        elif self.upright_search.upright is not None:
            self.qu_nominal = float(self.upright_search.upright.qu)
            self.qu_nominal_note = self.upright_search.describe(self._qu_unit())
        else:
            self.qu_nominal = 0.0
            self.qu_nominal_note = "0: " + self.upright_search.describe(self._qu_unit())
            warn(RobotModelWarning, log, "%s: %s; q_u = 0 is taken as nominal", where, self.upright_search.describe(self._qu_unit()))
        limits = self.coordinate_limits
        if rng is not None:
            self.qu_range = (float(rng[0]), float(rng[1]))
        elif (qu_limits := limits[self.unactuated_index]) is not None:
            self.qu_range = qu_limits
        else:
            half = math.pi / 2 if self._qu_unit() == "rad" else 1.0
            self.qu_range = (self.qu_nominal - half, self.qu_nominal + half)
        if model.neq:
            warn(RobotModelWarning, log, "%s: equality constraints are ignored by the robot dynamics", where)

    @functools.cached_property
    def _actuation(self) -> ActuatorGroups | str:
        names = tuple(self.model.actuator(i).name or f"u{i}" for i in range(self.model.nu))
        gains = np.asarray(self.model.actuator_gainprm[:, 0], dtype=np.float64)
        return actuator_groups(self.input_matrix_np[list(self.actuated_index)], gains, names, tuple(self.actuated_names))

    @property
    def actuation(self) -> ActuatorGroups:
        """One command per actuated coordinate → the actuators' ``ctrl`` (:mod:`bemlearn.robots.actuation`).

        Raises:
            RobotModelError: the actuators are not one per coordinate and not a grouping (:meth:`actuator_mismatch`).
        """
        out = self._actuation
        if isinstance(out, str):
            raise RobotModelError(f"{self.source}: {out}")
        return out

    @functools.cached_property
    def traction_limits(self) -> np.ndarray:
        """``(nu,)`` |f_i| an actuator may apply before its wheel slips, at the actuator (``inf`` where it turns no
        wheel): |gear_i f_i| ≤ μ N r_eff, the wheel's contact friction μ times its normal load N at the pose of rest
        (``mj_contactForce`` of its contacts with zero ctrl) times its rolling radius (wheel inertia left out).
        The rolling model (no slip) holds only within it.  A free body on wheels (:mod:`bemlearn.robots.floating`);
        ``inf`` for every other robot."""
        model = self.model
        out = np.full(model.nu, np.inf)
        if self.floating is None:
            return out
        data = mujoco.MjData(model)
        data.qpos[:] = self.floating.qpos_ground
        mujoco.mj_forward(model, data)
        radius = {c.wheel_joint: c.radius for c in self.floating.contacts}
        force = np.zeros(6)
        load: dict[int, float] = {}
        mu: dict[int, float] = {}
        for k in range(data.ncon):
            con = data.contact[k]
            for g in (int(con.geom1), int(con.geom2)):
                body = int(model.geom_bodyid[g])
                joints = [j for j in self.floating.wheels if int(model.jnt_bodyid[j]) == body]
                if not joints:
                    continue
                mujoco.mj_contactForce(model, data, k, force)
                load[joints[0]] = load.get(joints[0], 0.0) + abs(float(force[0]))
                mu[joints[0]] = min(mu.get(joints[0], np.inf), float(con.friction[0]))
        for i in range(model.nu):
            j = int(model.actuator_trnid[i, 0])
            name = model.joint(j).name or f"joint{j}"
            gear = abs(float(model.actuator_gear[i, 0]))
            if j in load and name in radius and gear > 0:
                out[i] = mu[j] * load[j] * radius[name] / gear
        return out

    def actuator_mismatch(self) -> str | None:
        """Why the excitation, the EIC and their LQR cannot command this robot, or ``None``: they give one
        command per actuated coordinate (u has m entries), which reaches the actuators when there is one per
        coordinate or when the actuators of each coordinate can be commanded together (:mod:`bemlearn.robots.actuation`)."""
        out = self._actuation
        if not isinstance(out, str):
            return None
        return (f"{self.source}: {out} (the excitation, the EIC and their LQR give one command per actuated coordinate; "
                "`bemlearn robot info` and `bemlearn robot bem` work on it)")

    def _qu_unit(self) -> str:
        if self.coordinate_joints is None:
            return "rad"
        return "rad" if self._coordinate_kinds[self.unactuated_index] == "hinge" else "m"

    @functools.cached_property
    def coordinate_limits(self) -> tuple[tuple[float, float] | None, ...]:
        """Per coordinate, ``(lo, hi)`` in its unit, or ``None`` where it is unlimited (or not one joint).

        A coordinate that is one MJCF joint takes the joint's range (a free body's wheel angle θ: every wheel's
        range divided by its sign s_k; its pitch: ``None``); a freedom that depends on it alone
        by rolling (q_d = s·q_i, :mod:`bemlearn.robots.rolling`) adds its own range divided by s (a base
        slide of ±2 m limits a wheel of r_eff = 0.1525 m to ±13.1 rad).  A model-declared map
        (``bemlearn_coordinates``) gives ``None`` for every coordinate.
        """
        model = self.model
        if self.floating is not None:   # θ is the first wheel's hinge angle, each wheel turning s_k θ; the pitch is free
            lo, hi = -math.inf, math.inf
            for j, sk in zip(self.floating.wheels, self.floating.signs):
                if model.jnt_limited[j]:
                    a, b = sorted((float(model.jnt_range[j, 0] / sk), float(model.jnt_range[j, 1] / sk)))
                    lo, hi = max(lo, a), min(hi, b)
            wheel = (lo, hi) if math.isfinite(lo) or math.isfinite(hi) else None
            return tuple(wheel if k != self.unactuated_index else None for k in range(self.n))
        if self.coordinate_joints is None:
            return (None,) * self.n
        out: list[tuple[float, float] | None] = []
        for k, j in enumerate(self.coordinate_joints):
            lo, hi = (float(model.jnt_range[j, 0]), float(model.jnt_range[j, 1])) if model.jnt_limited[j] else (-math.inf, math.inf)
            for d in (self.rolling.dependent if self.rolling is not None else ()):
                row = self.rolling.S[d] if self.rolling is not None else np.zeros(0)
                if not model.jnt_limited[d] or np.count_nonzero(row) != 1 or row[k] == 0:
                    continue
                a, b = sorted((float(model.jnt_range[d, 0] / row[k]), float(model.jnt_range[d, 1] / row[k])))
                lo, hi = max(lo, a), min(hi, b)
            out.append((lo, hi) if math.isfinite(lo) or math.isfinite(hi) else None)
        return tuple(out)

    def _search_upright(self, declared_range: np.ndarray | None) -> UprightSearch:
        """Equilibria of q_u with the actuated coordinates at 0 (:func:`~bemlearn.robots.upright.find_upright`)."""
        iu = self.unactuated_index
        kind = self._coordinate_kinds[iu] if self.coordinate_joints is not None else "hinge"
        limits = None
        if declared_range is not None:
            limits = (float(declared_range[0]), float(declared_range[1]))
        elif (own := self.coordinate_limits[iu]) is not None:
            limits = own
        z = np.zeros(self.n - 1)
        return find_upright(lambda qu: self.gamma0_scalar(qu, z, z, z), kind=kind, limits=limits)

    @functools.cached_property
    def T(self) -> torch.Tensor:
        """``(n, n_j)`` the coordinate map q = T q_j (the identity unless the model declares one or the robot rolls), float64."""
        return torch.from_numpy(self.T_np)

    @functools.cached_property
    def Tinv(self) -> torch.Tensor:
        """``(n_j, n)`` q_j = T⁻¹ q (the inverse of a square T, the rolling map S otherwise), float64."""
        return torch.from_numpy(self.Tinv_np)

    @functools.cached_property
    def input_matrix(self) -> torch.Tensor:
        """``(n, nu)`` B = T⁻ᵀ B_j: the generalized force is B @ actuator force (eq. 1), float64."""
        return torch.from_numpy(self.input_matrix_np)

    @property
    def coordinate_kinds(self) -> tuple[str, ...]:
        """``"hinge"`` or ``"slide"`` per coordinate (the MJCF joints' kinds; see :mod:`bemlearn.units`)."""
        return self._coordinate_kinds

    @classmethod
    def from_xml(cls, path: str | Path, *, name: str | None = None,
                 coordinates: CoordinatesConfig | Mapping[str, Any] | None = None) -> MujocoRobot:
        """The robot of the MJCF file at ``path``; ``coordinates`` (a config's ``coordinates:`` block,
        :mod:`bemlearn.robots.coordinates`) declares its coordinates beside the file."""
        path = Path(path)
        if not path.is_file():
            raise MissingFileError(f"{path}: MJCF file not found")
        from bemlearn.robots.coordinates import coordinates_mapping, custom_entries
        from bemlearn.robots.mjcf_compile import compile_mjcf

        # non-finite attributes refused; large files compiled where a signal can stop them
        model = compile_mjcf(path, custom_entries(coordinates))
        return cls(model, name=name or path.stem, source=str(path), coordinates=coordinates_mapping(coordinates))

    @classmethod
    def from_xml_string(cls, xml: str, *, name: str | None = None) -> MujocoRobot:
        try:
            model = mujoco.MjModel.from_xml_string(xml)
        except ValueError as exc:
            raise RobotModelError(f"<xml string>: MuJoCo could not load the model: {exc}") from exc
        return cls(model, name=name, source=name or "<xml string>")

    # ---- per-state MuJoCo evaluation ---------------------------------------------------
    def mj_qpos(self, qj: np.ndarray) -> np.ndarray:
        """``(nq,)`` MuJoCo's positions of the joint-space vector ``qj = T⁻¹ q`` (``(n_j,)``; for a free body
        on wheels the tangent displacement from the pose on the ground, :mod:`bemlearn.robots.floating`)."""
        if self.floating is not None:
            return self.floating.qpos(self.model, qj)
        out = np.array(self.model.qpos0, dtype=np.float64)
        out[self._qadr] = qj
        return out

    def state_to_mujoco(self, q: np.ndarray, qd: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(qpos (nq,), qvel (nv,))`` of coordinates ``q`` and rates ``qd`` ``(n,)`` (rad / m, rad/s / m/s)."""
        qvel = np.zeros(self.model.nv)
        if qd is not None:
            qvel[self._dadr] = self.Tinv_np @ qd
        return self.mj_qpos(self.Tinv_np @ q), qvel

    def coordinates_of(self, qpos: np.ndarray) -> np.ndarray:
        """``(n,)`` the coordinates q of MuJoCo's positions ``qpos (nq,)`` (the inverse of :meth:`state_to_mujoco`)."""
        if self.floating is not None:
            return self.T_np @ self.floating.displacement(self.model, qpos)
        return self.T_np @ np.asarray(qpos)[self._qadr]

    def _load_state(self, qj: np.ndarray, qdj: np.ndarray | None) -> None:
        d = self.data
        if self.floating is not None:
            d.qpos[:] = self.floating.qpos(self.model, qj)
        else:
            d.qpos[self._qadr] = qj
        if qdj is not None:
            d.qvel[self._dadr] = qdj
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_comPos(self.model, d)

    def _to_joint(self, q: torch.Tensor) -> np.ndarray:
        return (q @ self.Tinv.T).numpy()

    def _from_joint_force(self, f: np.ndarray) -> torch.Tensor:
        # generalized force in coordinates: T^{-T} f_j  -> row form f_j @ T^{-1}
        return torch.as_tensor(f) @ self.Tinv

    def mass_matrix(self, q: torch.Tensor) -> torch.Tensor:
        """D(q) (eq. 1) from MuJoCo's CRB algorithm. ``q: (B, n)`` → ``(B, n, n)``."""
        q = as_batch(q, self.n, "q", func="mass_matrix", units="rad")
        qj = self._to_joint(q)
        out = np.empty((q.shape[0], self._dadr.size, self._dadr.size))
        idx = self._ix_dd
        for b in range(q.shape[0]):
            self._load_state(qj[b], None)
            make_mass_matrix(self.model, self.data)
            out[b] = full_mass_matrix(self.model, self.data, self._M)[idx]
        Dj = torch.as_tensor(out)
        return self.Tinv.T @ Dj @ self.Tinv

    def _rne(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor | None) -> np.ndarray:
        qj, qdj = self._to_joint(q), self._to_joint(qd)
        qddj = None if qdd is None else self._to_joint(qdd)
        out = np.empty((q.shape[0], self._dadr.size))
        d = self.data
        for b in range(q.shape[0]):
            self._load_state(qj[b], qdj[b])
            mujoco.mj_comVel(self.model, d)
            if qddj is not None:
                d.qacc[self._dadr] = qddj[b]
            mujoco.mj_rne(self.model, d, 0 if qddj is None else 1, self._vec)
            out[b] = self._vec[self._dadr] + (0.0 if qddj is None else self._armature * qddj[b])
        return out

    def bias(self, q: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """C(q, q̇) q̇ + G(q) (eq. 1) from MuJoCo's RNE. ``q, qd: (B, n)`` → ``(B, n)``."""
        q, qd = self._states(q, qd, func="bias")
        return self._from_joint_force(self._rne(q, qd, None))

    def passive(self, q: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """Passive forces τ_p (joint damping and stiffness, ``mj_passive``), ``(B, n)``."""
        q, qd = self._states(q, qd, func="passive")
        qj, qdj = self._to_joint(q), self._to_joint(qd)
        out = np.empty((q.shape[0], self._dadr.size))
        d = self.data
        for b in range(q.shape[0]):
            self._load_state(qj[b], qdj[b])
            mujoco.mj_comVel(self.model, d)
            mujoco.mj_passive(self.model, d)
            out[b] = d.qfrc_passive[self._dadr]
        return self._from_joint_force(out)

    def _inverse_joint(self, qj: np.ndarray, qdj: np.ndarray, qddj: np.ndarray) -> np.ndarray:
        """τ_j = D_j q̈_j + C_j q̇_j + G_j − τ_p,j per row, in joint coordinates, one RNE pass per row.

        ``qj, qdj, qddj (R, n)`` joint positions, rates, accelerations (rad, rad/s, rad/s²; m, m/s, m/s² for
        slides) → ``(R, n)`` N·m (N).  The MuJoCo calls of :meth:`_load_state` and the RNE written out in one
        loop (per row: kinematics, com positions, com velocities, passive forces, RNE with q̈), the same
        numbers as row-by-row calls.
        """
        m, d, vec = self.model, self.data, self._vec
        kinematics, com_pos, com_vel, passive, rne = (mujoco.mj_kinematics, mujoco.mj_comPos, mujoco.mj_comVel,
                                                       mujoco.mj_passive, mujoco.mj_rne)
        R = qj.shape[0]
        out = np.empty((R, self._dadr.size))
        if self._joint_order:  # coordinates in model order: whole-vector writes and reads
            qpos, qvel, qacc, qfrc_passive = d.qpos, d.qvel, d.qacc, d.qfrc_passive
            subtract = np.subtract
            for b in range(R):
                qpos[:] = qj[b]
                qvel[:] = qdj[b]
                kinematics(m, d)
                com_pos(m, d)
                com_vel(m, d)
                passive(m, d)
                qacc[:] = qddj[b]
                rne(m, d, 1, vec)
                subtract(vec, qfrc_passive, out=out[b])
            return out + self._armature * qddj   # MuJoCo's RNE leaves out the armature its mass matrix holds
        dadr = self._dadr
        for b in range(R):
            self._load_state(qj[b], qdj[b])   # a free body's position goes through its quaternion
            com_vel(m, d)
            passive(m, d)
            d.qacc[dadr] = qddj[b]
            rne(m, d, 1, vec)
            out[b] = vec[dadr] - d.qfrc_passive[dadr]
        return out + self._armature * qddj

    def inverse_dynamics(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor) -> torch.Tensor:
        """D q̈ + C q̇ + G − τ_p in one RNE pass per state (same value as the base class)."""
        q, qd, qdd = self._states(q, qd, qdd, func="inverse_dynamics")
        out = self._inverse_joint(self._to_joint(q), self._to_joint(qd), self._to_joint(qdd))
        return self._from_joint_force(out)

    def gamma_rows(self, qu: np.ndarray, qa: np.ndarray, qad: np.ndarray, qadd: np.ndarray,
                   qud: np.ndarray | None = None, qudd: np.ndarray | None = None) -> np.ndarray:
        """Γ (eq. 5) for many states in NumPy (N·m, N for a slide q_u); Γ_0 (eq. 7) with q̇_u = q̈_u = 0 (the default).

        Row r is :meth:`gamma0_scalar` of row r, the same numbers.

        Args:
            qu: ``(R,)`` q_u in its joint's unit (rad or m).
            qa: ``(R, m)`` q_a (rad; m for slides).
            qad: ``(R, m)`` q̇_a (rad/s; m/s for slides).
            qadd: ``(R, m)`` q̈_a (rad/s²; m/s² for slides).
            qud: ``(R,)`` q̇_u (default 0).
            qudd: ``(R,)`` q̈_u (default 0).

        Returns:
            ``(R,)`` Γ.
        """
        qu = np.asarray(qu, dtype=np.float64).reshape(-1)
        R, u, ia = qu.shape[0], self.unactuated_index, self._ia
        q, qd, qdd = np.empty((R, self.n)), np.zeros((R, self.n)), np.zeros((R, self.n))
        q[:, ia], q[:, u] = np.asarray(qa, dtype=np.float64).reshape(R, -1), qu
        qd[:, ia], qdd[:, ia] = np.asarray(qad, dtype=np.float64).reshape(R, -1), np.asarray(qadd, dtype=np.float64).reshape(R, -1)
        if qud is not None:
            qd[:, u] = qud
        if qudd is not None:
            qdd[:, u] = qudd
        if self.identity_coordinates:
            return self._inverse_joint(q, qd, qdd)[:, u]
        Tinv = self.Tinv_np  # row by row, as gamma0_scalar maps one state (a matrix product may round differently)
        to_joint = lambda x: np.array([Tinv @ row for row in x]).reshape(R, Tinv.shape[0])  # noqa: E731  (joint space: wider than the coordinates of a rolling robot)
        f = self._inverse_joint(to_joint(q), to_joint(qd), to_joint(qdd))
        return np.array([(Tinv.T @ row)[u] for row in f])

    def _bem_basis(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """:func:`~bemlearn.robots.bem.hinge_basis` when q_u is a hinge in joint coordinates (Γ_0 is a combination of
        1, cos, sin of q_u and 2 q_u there; checked per problem by the scan), else None."""
        if self.identity_coordinates and self.coordinate_kinds[self.unactuated_index] == "hinge":
            from bemlearn.robots.bem import hinge_basis

            return hinge_basis
        return None

    def _bem_residual(self, qa: np.ndarray, qad: np.ndarray, qadd: np.ndarray) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
        """Γ_0 through :meth:`gamma_rows` for :meth:`bem` when the coordinates are the joints (T = I: the same
        numbers as :meth:`gamma0`, whose coordinate maps then only multiply by ones); None otherwise."""
        if not self.identity_coordinates:
            return None

        def fun(x: np.ndarray, rows: np.ndarray) -> np.ndarray:  # (R, K) -> (R, K)
            R, K = x.shape
            rep = lambda a: np.repeat(a[rows], K, axis=0)  # noqa: E731
            return self.gamma_rows(x.reshape(-1), rep(qa), rep(qad), rep(qadd)).reshape(R, K)

        return fun

    # ---- single-state numpy fast path (control loops) ------------------------------------
    def terms(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """D(q) and h = C(q, q̇)q̇ + G(q) − τ_p for one state, as numpy, without torch overhead.

        Args:
            q: ``(n,)`` coordinates, each in its joint's unit (rad for a hinge, m for a slide).
            qd: ``(n,)`` rates, each in its joint's unit (rad/s for a hinge, m/s for a slide).

        Returns:
            ``D (n, n)`` and ``h (n,)`` in coordinates (eq. 1: D q̈ + h = B u).
        """
        m, d = self.model, self.data
        if self._joint_order and self.identity_coordinates:  # T = I, model order: no maps, no re-indexing
            d.qpos[:] = q
            d.qvel[:] = qd
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            make_mass_matrix(m, d)
            D = full_mass_matrix(m, d, self._M).copy()
            mujoco.mj_comVel(m, d)
            mujoco.mj_rne(m, d, 0, self._vec)
            mujoco.mj_passive(m, d)
            return D, self._vec - d.qfrc_passive
        Tinv = self.Tinv_np
        self._load_state(Tinv @ q, Tinv @ qd)
        make_mass_matrix(m, d)
        Dj = full_mass_matrix(m, d, self._M)[self._ix_dd]
        mujoco.mj_comVel(m, d)
        mujoco.mj_rne(m, d, 0, self._vec)
        mujoco.mj_passive(m, d)
        hj = self._vec[self._dadr] - d.qfrc_passive[self._dadr]
        return Tinv.T @ Dj @ Tinv, Tinv.T @ hj

    def gamma0_scalar(self, qu: float, qa: np.ndarray, qad: np.ndarray, qadd: np.ndarray, qud: float = 0.0, qudd: float = 0.0) -> float:
        """Γ (eq. 5) for one state, numpy fast path (N·m); Γ_0 (eq. 7) with the default q̇_u = q̈_u = 0."""
        n, u, ia = self.n, self.unactuated_index, self._ia
        if self._joint_order and self.identity_coordinates:  # the state written straight into MjData (_inverse_joint's steps)
            m, d = self.model, self.data
            qpos, qvel, qacc = d.qpos, d.qvel, d.qacc
            qpos[ia], qpos[u] = qa, qu
            qvel[ia], qvel[u] = qad, qud
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_comVel(m, d)
            mujoco.mj_passive(m, d)
            qacc[ia], qacc[u] = qadd, qudd
            mujoco.mj_rne(m, d, 1, self._vec)
            return float(self._vec[u] + self._armature[u] * qudd - d.qfrc_passive[u])
        q = np.empty((1, n))
        qd = np.zeros((1, n))
        qdd = np.zeros((1, n))
        q[0, ia], q[0, u] = qa, qu
        qd[0, ia], qd[0, u] = qad, qud
        qdd[0, ia], qdd[0, u] = qadd, qudd
        if self.identity_coordinates:  # T = I: the maps would only multiply by ones and add zeros
            return float(self._inverse_joint(q, qd, qdd)[0, u])
        Tinv = self.Tinv_np
        f = self._inverse_joint((Tinv @ q[0])[None], (Tinv @ qd[0])[None], (Tinv @ qdd[0])[None])[0]
        return float((Tinv.T @ f)[u])

    # ---- kinematics --------------------------------------------------------------------
    @property
    def chain(self):
        """The pytorch-kinematics chain of the model (built once, float64)."""
        if self._chain is None:
            from bemlearn.robots.kinematics import chain_from_model

            self._chain = chain_from_model(self.model)
        return self._chain

    def forward_kinematics(self, q: torch.Tensor, frames: list[str] | tuple[str, ...]) -> dict[str, torch.Tensor]:
        """World positions of named bodies/sites via pytorch-kinematics.

        Args:
            q: ``(B, n)`` coordinates (rad / m).
            frames: body or site names.

        Returns:
            ``{name: (B, 3)}`` positions in m, world frame.
        """
        from bemlearn.robots.kinematics import frame_positions

        q = as_batch(q, self.n, "q", func="forward_kinematics", units="rad")
        qj = q @ self.Tinv.T
        return frame_positions(self.chain, self.model, qj, frames)
