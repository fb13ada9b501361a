"""Freedoms that move only through a rolling contact, recognised from the model and eliminated.

**Wheels.**  A *wheel geom* is a geom that is round about the hinge that turns it: a cylinder
coaxial with the hinge, or a sphere centred on its axis (the hinge is the joint of the nearest body
at or above the geom's body that has joints; that body must have exactly one joint, a hinge).  A
*rolling contact* is a contact of a wheel geom with a static geom (the ground).

**No slip.**  The wheel rolls without slipping when the wheel's material point at each contact
has no tangential velocity:

    t_kᵀ J_p(q_j) q̇_j = 0,   k = 1, 2                                                        (R1)

with t_k the tangents of MuJoCo's contact frame and J_p (3 × n_j) the wheel body's translational
Jacobian at the contact point (``mj_jac``).  MuJoCo puts the contact point midway through the
penetration, so the distance from the hinge axis to it is the *effective rolling radius*
r_eff (for a wheel pressed into a plane: hub height + half the penetration), and (R1) carries it:
a planar wheel with base slide x and angle θ gives ẋ = r_eff θ̇.

**Dependent freedoms.**  The rows of (R1) over all rolling contacts, reduced to an orthonormal
basis of their span, form J (r × n_j).  The joints split into independent (i) and dependent (d)
ones, where the dependent ones are r joints without an actuator whose block J_d is invertible and
that leave exactly one joint without an actuator (the unactuated coordinate); where several choices
fit (a wheel hinged on the pendulum rolls with the chassis slide *and* the pendulum), the one made of
slides alone is taken (the chassis translates because the wheel rolls), else the robot is refused:

    q̇_j = S q̇,   S_i = I,   S_d = −J_d⁻¹ J_i,   J S = 0.                                      (R2)

The coordinates q are the independent joints.  When S is the same at every pose (a wheel on a
plane whose axis keeps its direction: planar rolling) (R2) integrates to q_j = S q and J̇ S = 0, so
the constrained equations of motion, the KKT system

    D_j q̈_j + h_j = B_j u + Jᵀ λ,   J q̈_j = −J̇ q̇_j,                                          (R3)

premultiplied by Sᵀ (Sᵀ Jᵀ = 0, the constraint force drops out) are the reduced dynamics

    (Sᵀ D_j S) q̈ + Sᵀ h_j = Sᵀ B_j u,                                                          (R4)

the same transformation as a constant coordinate map (:mod:`bemlearn.robots.mujoco_robot`).  A map
S that changes with the pose (a wheel that steers or leans: nonholonomic rolling) is refused.
:func:`kkt_acceleration` solves (R3) itself (J̇ q̇_j by central differences of J along q̇_j): an
independent check of (R4), and the hard-constraint dynamics for any state.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from bemlearn.errors import NumericalError, RobotModelError
from bemlearn.robots._mujoco_compat import full_mass_matrix
from bemlearn.robots.coordinates import declared_text

__all__ = ["RollingContact", "RollingMap", "find_rolling", "rolling_rows", "wheel_geoms", "kkt_acceleration"]

#: Relative tolerance of the rank and null-space tests.
_RTOL = 1e-9
#: Geometric tolerance (m, and radians for axis directions) of "centred on the axis" and "coaxial".
_GEOM_TOL = 1e-6


@dataclass(frozen=True)
class RollingContact:
    """One wheel's rolling contact at the reference pose.

    Attributes:
        wheel_joint: the MJCF name of the hinge that turns the wheel.
        geom: the wheel geom's name (or ``geom<i>``).
        radius: r_eff, m: the distance from the hinge axis to MuJoCo's contact point.
        geometric_radius: the geom's own radius, m.
        points: number of MuJoCo contact points of this geom with the ground.
    """

    wheel_joint: str
    geom: str
    radius: float
    geometric_radius: float
    points: int


@dataclass(frozen=True)
class RollingMap:
    """The constant velocity map (R2) of a robot whose dependent freedoms move only by rolling.

    Attributes:
        independent: ``(n,)`` joint indices of the coordinates, in joint order.
        dependent: joint indices of the dependent freedoms.
        S: ``(n_j, n)`` q_j = S q (and q̇_j = S q̇), joint order.
        T: ``(n, n_j)`` q = T q_j (the rows of the identity for the independent joints).
        contacts: the rolling contacts found.
    """

    independent: tuple[int, ...]
    dependent: tuple[int, ...]
    S: np.ndarray
    T: np.ndarray
    contacts: tuple[RollingContact, ...]

    def describe(self, model: mujoco.MjModel) -> str:
        """One line per dependent freedom: ``x = 0.1525 · wheel`` and where r_eff came from."""
        names = [model.joint(j).name or f"joint{j}" for j in range(model.njnt)]
        parts = []
        for d in self.dependent:
            terms = " + ".join(f"{self.S[d, k]:.6g}·{names[self.independent[k]]}" for k in range(len(self.independent))
                               if abs(self.S[d, k]) > 0)
            parts.append(f"{names[d]} = {terms or '0'}")
        radii = ", ".join(f"{c.geom} r_eff {c.radius:.6g} m (geometric {c.geometric_radius:.6g} m, {c.points} contact points)"
                          for c in self.contacts)
        return f"{'; '.join(parts)} (rolling without slip: {radii})"


def _joint_name(model: mujoco.MjModel, j: int) -> str:
    return model.joint(j).name or f"joint{j}"


def wheel_geoms(model: mujoco.MjModel, data: mujoco.MjData) -> dict[int, int]:
    """``{geom id: hinge joint id}`` for every wheel geom (module docstring), with ``data`` at a pose
    whose kinematics have been computed (``mj_kinematics``)."""
    out: dict[int, int] = {}
    for g in range(model.ngeom):
        gtype = int(model.geom_type[g])
        if gtype not in (int(mujoco.mjtGeom.mjGEOM_CYLINDER), int(mujoco.mjtGeom.mjGEOM_SPHERE)):
            continue
        b = int(model.geom_bodyid[g])
        while b > 0 and int(model.body_jntnum[b]) == 0:
            b = int(model.body_parentid[b])
        if b == 0 or int(model.body_jntnum[b]) != 1:
            continue
        j = int(model.body_jntadr[b])
        if int(model.jnt_type[j]) != int(mujoco.mjtJoint.mjJNT_HINGE):
            continue
        anchor, axis = data.xanchor[j], data.xaxis[j] / np.linalg.norm(data.xaxis[j])
        rel = data.geom_xpos[g] - anchor
        if np.linalg.norm(rel - (rel @ axis) * axis) > _GEOM_TOL:
            continue   # not centred on the axis: the contact point would move as the wheel turns
        if gtype == int(mujoco.mjtGeom.mjGEOM_CYLINDER):
            geom_axis = data.geom_xmat[g].reshape(3, 3)[:, 2]
            if np.linalg.norm(np.cross(geom_axis, axis)) > _GEOM_TOL:
                continue
        out[g] = j
    return out


def _static(model: mujoco.MjModel, g: int) -> bool:
    return int(model.body_weldid[int(model.geom_bodyid[g])]) == 0


def rolling_rows(model: mujoco.MjModel, data: mujoco.MjData, wheels: dict[int, int]) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, np.ndarray]]]:
    """The no-slip rows (R1) and the normal rows of the rolling contacts at ``data``'s pose.

    ``data`` must hold the pose's positions (``mj_fwdPosition``: kinematics, com, collision).

    Returns:
        ``(tangential (2k, n_v), normal (k, n_v), contacts)``: rows in dof order; ``contacts`` lists
        ``(wheel geom, hinge joint, contact point (3,) m)`` for each of the k contacts.
    """
    jacp = np.zeros((3, model.nv))
    tangential, normal, found = [], [], []
    for c in data.contact[: data.ncon]:
        g1, g2 = int(c.geom[0]), int(c.geom[1])
        for wheel, other, sign in ((g1, g2, 1.0), (g2, g1, -1.0)):
            if wheel in wheels and _static(model, other):
                mujoco.mj_jac(model, data, jacp, None, np.asarray(c.pos, dtype=np.float64), int(model.geom_bodyid[wheel]))
                frame = np.asarray(c.frame, dtype=np.float64).reshape(3, 3)
                rows = frame @ jacp
                normal.append(sign * rows[0])
                tangential += [rows[1].copy(), rows[2].copy()]
                found.append((wheel, wheels[wheel], np.array(c.pos, dtype=np.float64)))
                break
    nv = model.nv
    return np.array(tangential).reshape(-1, nv), np.array(normal).reshape(-1, nv), found


def _row_basis(rows: np.ndarray) -> np.ndarray:
    """An orthonormal basis ``(r, n_v)`` of the span of ``rows`` (numerical rank by SVD)."""
    if rows.size == 0:
        return np.zeros((0, rows.shape[1]))
    _, s, vt = np.linalg.svd(rows, full_matrices=False)
    r = int(np.sum(s > _RTOL * max(float(s[0]), 1e-300)))
    return vt[:r]


def _positions(model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray) -> None:
    data.qpos[:] = qpos
    data.qvel[:] = 0.0
    mujoco.mj_fwdPosition(model, data)


def find_rolling(model: mujoco.MjModel, undriven: Sequence[int], *, where: str) -> RollingMap | None:
    """The rolling map (R2) of ``model`` at its reference pose ``qpos0``, or ``None`` when no rolling
    contact makes all but one of the ``undriven`` joints dependent.

    Args:
        model: a model whose joints are hinges and slides (qpos and qvel indexed alike).
        undriven: joint indices without an actuator.
        where: a label for messages (the file).

    Raises:
        RobotModelError: the choice of dependent joints is ambiguous, a wheel can leave the ground
            (its contact's normal row is not zero: a free height needs settling, not supported), or the
            map changes with the pose (nonholonomic rolling, not supported).
    """
    if model.nq != model.nv or model.nv != model.njnt:
        return None
    data = mujoco.MjData(model)
    qpos0 = np.array(model.qpos0, dtype=np.float64)
    _positions(model, data, qpos0)
    wheels = wheel_geoms(model, data)
    if not wheels:
        return None
    tangential, normal, found = rolling_rows(model, data, wheels)
    if not found:
        return None
    J = _row_basis(tangential)
    r = J.shape[0]
    if r == 0 or len(undriven) - r != 1:
        return None
    scale = float(np.abs(tangential).max())
    if normal.size and float(np.abs(normal).max()) > _RTOL * max(scale, 1.0):
        moved = [_joint_name(model, j) for j in range(model.njnt) if np.abs(normal[:, j]).max() > _RTOL * max(scale, 1.0)]
        raise RobotModelError(f"{where}: a wheel can move into or off the ground through {moved}; rolling robots whose "
                              "wheels are free in height are not supported yet")
    choices = []
    for dep in itertools.combinations(sorted(int(j) for j in undriven), r):
        block = J[:, list(dep)]
        if np.linalg.matrix_rank(block, tol=_RTOL * max(1.0, float(np.abs(block).max()))) == r:
            choices.append(dep)
    if not choices:
        return None
    text = declared_text(model, "bemlearn_rolling_dependent")
    declared = text.split() if text is not None else None
    if declared is not None:   # the model or the config's coordinates block names the choice
        names = {_joint_name(model, j): j for j in range(model.njnt)}
        unknown = [n for n in declared if n not in names]
        if unknown:
            raise RobotModelError(f"{where}: rolling_dependent names {unknown}, which are not joints of the model; its joints "
                                  f"are {sorted(names)}")
        pick = tuple(sorted(names[n] for n in declared))
        if pick not in choices:
            options = " or ".join("(" + ", ".join(_joint_name(model, j) for j in c) + ")" for c in choices)
            raise RobotModelError(f"{where}: rolling_dependent {list(declared)} cannot be the joints that roll with the wheels: "
                                  f"the rolling contacts determine {r} of the joints without an actuator, as {options}")
        choices = [pick]
    if len(choices) > 1:   # a chassis that translates only by rolling: prefer the one choice made of slides alone
        slides = [c for c in choices if all(int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_SLIDE) for j in c)]
        choices = slides if len(slides) == 1 else choices
    if len(choices) > 1:
        options = " or ".join("(" + ", ".join(_joint_name(model, j) for j in c) + ")" for c in choices)
        raise RobotModelError(f"{where}: rolling contacts make {r} of the joints without an actuator dependent, but which "
                              f"is ambiguous: {options}; name them in the config (coordinates: rolling_dependent: [...]) or "
                              "in the MJCF (<custom><text name=\"bemlearn_rolling_dependent\" data=\"...\"/></custom>)")
    dep = choices[0]
    indep = tuple(j for j in range(model.njnt) if j not in dep)
    S = np.zeros((model.nv, len(indep)))
    S[list(indep), np.arange(len(indep))] = 1.0
    S[list(dep)] = -np.linalg.solve(J[:, list(dep)], J[:, list(indep)])
    S[np.abs(S) < _RTOL * float(np.abs(S).max())] = 0.0
    T = np.zeros((len(indep), model.nv))
    T[np.arange(len(indep)), list(indep)] = 1.0
    _check_constant(model, data, wheels, qpos0, S, indep, where=where)
    contacts = describe_contacts(model, data, found)
    return RollingMap(independent=indep, dependent=tuple(dep), S=S, T=T, contacts=contacts)


def _check_constant(model: mujoco.MjModel, data: mujoco.MjData, wheels: dict[int, int], qpos0: np.ndarray, S: np.ndarray,
                    indep: tuple[int, ...], *, where: str) -> None:
    """S must annihilate the no-slip rows at other poses too (holonomic planar rolling), module docstring."""
    rng = np.random.default_rng(0)
    for _ in range(3):
        step = np.zeros(len(indep))
        for k, j in enumerate(indep):
            lo, hi = (model.jnt_range[j] if model.jnt_limited[j] else (qpos0[j] - 1.0, qpos0[j] + 1.0))
            half = 0.25 * (float(hi) - float(lo))
            step[k] = rng.uniform(-1.0, 1.0) * min(half, 1.0)
        _positions(model, data, qpos0 + S @ step)
        tangential, _, found = rolling_rows(model, data, wheels)
        if not found:
            continue   # the pose lifted the wheels: nothing to compare
        scale = max(float(np.abs(tangential).max()), 1e-300)
        if float(np.abs(tangential @ S).max()) > 1e-7 * scale:
            raise RobotModelError(f"{where}: the rolling constraint's velocity map changes with the pose (nonholonomic "
                                  "rolling, e.g. a wheel that steers or leans); such robots are not supported yet")
    _positions(model, data, qpos0)


def describe_contacts(model: mujoco.MjModel, data: mujoco.MjData, found: list[tuple[int, int, np.ndarray]]) -> tuple[RollingContact, ...]:
    by_geom: dict[int, list[float]] = {}
    for g, j, p in found:
        anchor, axis = data.xanchor[j], data.xaxis[j] / np.linalg.norm(data.xaxis[j])
        rel = p - anchor
        by_geom.setdefault(g, []).append(float(np.linalg.norm(rel - (rel @ axis) * axis)))
    out = []
    for g, radii in by_geom.items():
        j = int(next(jj for gg, jj, _ in found if gg == g))
        out.append(RollingContact(wheel_joint=_joint_name(model, j), geom=model.geom(g).name or f"geom{g}",
                                  radius=float(np.mean(radii)), geometric_radius=float(model.geom_size[g, 0]), points=len(radii)))
    return tuple(out)


def kkt_acceleration(model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray, qvel: np.ndarray, force: np.ndarray,
                     wheels: dict[int, int], *, fd_step: float = 1e-6, drift: bool = True,
                     normal: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """q̈_j and λ of the hard-constraint dynamics (R3) at one state, with MuJoCo's M, bias and contact Jacobians.

        [ M   −Jᵀ ] [ q̈_j ]   [ f − c ]
        [ J    0  ] [  λ  ] = [ −J̇ q̇_j ],    J̇ q̇_j ≈ (J(q + ε q̇) − J(q − ε q̇)) q̇ / (2ε)

    with c = ``qfrc_bias`` − ``qfrc_passive`` and J the no-slip rows (R1) at the state's contacts
    (reduced to a basis of their span: redundant contact points carry the same constraint), with
    ``normal`` also the contacts' normal rows (a wheel that can leave the ground held on it: a free
    body on wheels).  Positions q ± ε q̇ are MuJoCo's (``mj_integratePos``: quaternions of free and
    ball joints stay unit), so qpos ``(n_q,)`` and qvel ``(n_v,)`` may differ in size.

    Args:
        model: the MuJoCo model.
        data: a scratch ``MjData`` of ``model`` (overwritten).
        qpos: ``(n_q,)`` MuJoCo's positions (rad / m, quaternions), on the constraint.
        qvel: ``(n_v,)`` velocities (rad/s, m/s), consistent with the constraint.
        force: ``(n_v,)`` applied generalized force f (e.g. B_j u), N·m / N.
        wheels: :func:`wheel_geoms` of the model.
        fd_step: ε, s.
        drift: include J̇ q̇ (``False`` solves J q̈_j = 0 instead: what a constraint without its drift term gives).
        normal: include the contacts' normal rows.

    Returns:
        ``(q̈_j (n_v,), λ (r,))``.
    """
    def rows_at(q: np.ndarray) -> np.ndarray:
        _positions(model, data, q)
        tangential, normals, _ = rolling_rows(model, data, wheels)
        return np.vstack([tangential, normals]) if normal else tangential

    def moved(step: float) -> np.ndarray:
        out = np.array(qpos, dtype=np.float64)
        mujoco.mj_integratePos(model, out, np.asarray(qvel, dtype=np.float64), step)
        return out

    J0 = rows_at(qpos)
    basis = _row_basis(J0)
    # J̇ q̇ in the same row combination: the rows at q ± ε q̇ projected on the basis at q
    coeff = np.linalg.lstsq(J0.T, basis.T, rcond=None)[0].T            # basis = coeff @ J0
    jdot_qd = np.zeros(basis.shape[0])
    if drift:
        Jp, Jm = rows_at(moved(fd_step)), rows_at(moved(-fd_step))
        if not Jp.shape == Jm.shape == J0.shape:
            raise NumericalError(f"kkt_acceleration: the rolling contacts change within ±{fd_step:g} s of the state; "
                                 "J̇ q̇ cannot be differenced there")
        jdot_qd = coeff @ ((Jp - Jm) @ qvel) / (2 * fd_step)
    data.qpos[:], data.qvel[:] = qpos, qvel
    mujoco.mj_forward(model, data)
    M = full_mass_matrix(model, data, np.zeros((model.nv, model.nv)))
    rhs_dyn = force - (data.qfrc_bias - data.qfrc_passive)
    r = basis.shape[0]
    K = np.block([[M, -basis.T], [basis, np.zeros((r, r))]])
    sol = np.linalg.solve(K, np.concatenate([rhs_dyn, -jdot_qd]))
    return sol[: model.nv], sol[model.nv:]
