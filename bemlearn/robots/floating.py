"""A free-floating body on coaxial wheels (a two-wheeled self-balancing robot), reduced to planar rolling.

**What the model must say.**  One free joint, on a body of the world; every other joint a hinge that
turns a wheel geom (:func:`bemlearn.robots.rolling.wheel_geoms`), all with parallel axes (the axle
direction e, perpendicular to gravity) and each driven by an actuator.  Then the body's pitch about the
axle is the only freedom without an actuator, and nothing else needs to be configured.

**On the ground.**  The file may place the robot anywhere (the public hobby robot starts 0.1 m above
its floor).  The body is lowered along gravity until its wheels touch the static geoms they collide
with (``mj_geomDistance``; the wheels must touch together, else the body would have to roll) and then
pressed in until MuJoCo's contact carries its weight at rest (the vertical acceleration of one
``mj_forward`` is zero, by bisection on the depth): the pose of static equilibrium, whose penetration
sets the effective rolling radius r_eff (:mod:`bemlearn.robots.rolling`).

**Planar rolling.**  Velocities live in MuJoCo's tangent space v (``qvel``: the free joint's world
linear and body-frame angular velocity, then the wheel rates).  With both wheels turning alike in the
world (the straight-running mode: wheel k's hinge rate is s_k θ̇, s_k = sign(a_k · a_1)) and the body
rotating about e, the rolling contacts (no slip, R1, and no motion along the normal) fix the body's
travel along the ground f = e × up:

    v = S [θ̇, φ̇]ᵀ,   S = [v_θ + c_θ v_f,  v_φ + c_φ v_f],   c = −(J v_f)⁺ J [v_θ, v_φ]            (F1)

with J all no-slip and normal rows of the contacts, v_f a unit travel along f, v_φ the angular
velocity R_bᵀ e in the body frame and v_θ the wheel rates.  The rotation stays about one axis, so S is
constant and (F1) integrates exactly through MuJoCo's own position integration:

    qpos(q) = qpos_g ⊕ S q   (``mj_integratePos``),   q = T (qpos ⊖ qpos_g)   (``mj_differentiatePos``)   (F2)

with qpos_g the pose on the ground and T S = I (T reads θ from the first wheel's hinge and φ from the
angular velocity along R_bᵀ e).  As for any constant map, the hard-constraint dynamics projected by
Sᵀ are D = Sᵀ M S, h = Sᵀ (bias − passive), B = Sᵀ B_j (R4 of :mod:`bemlearn.robots.rolling`); J S = 0
is checked at other poses.  The yaw (wheels turning opposite ways), roll, height and sideways motion
are left out: roll, height and sideways motion are held by the contacts, the yaw mode is not excited
by equal wheel torques on a symmetric robot.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from bemlearn.errors import RobotModelError
from bemlearn.robots.rolling import RollingContact, describe_contacts, rolling_rows, wheel_geoms

__all__ = ["FloatingRolling", "find_floating"]

#: Relative tolerance of the parallel-axes and residual tests.
_TOL = 1e-7


@dataclass(frozen=True)
class FloatingRolling:
    """The planar rolling reduction (F1, F2) of a free body on coaxial wheels.

    Attributes:
        body: the free body's name.
        wheels: the wheel hinges' joint indices (the first one's angle is the coordinate θ).
        signs: ``(k,)`` s_k, each wheel's hinge rate per θ̇.
        axle: ``(3,)`` e, the world axle direction (the first wheel's hinge axis).
        qpos_ground: ``(nq,)`` the pose on the ground (static equilibrium, F2).
        S: ``(nv, 2)`` v = S [θ̇, φ̇].
        T: ``(2, nv)`` [θ, φ] = T v, T S = I.
        contacts: the rolling contacts at the pose on the ground.
    """

    body: str
    wheels: tuple[int, ...]
    signs: np.ndarray
    axle: np.ndarray
    qpos_ground: np.ndarray
    S: np.ndarray
    T: np.ndarray
    contacts: tuple[RollingContact, ...]

    def qpos(self, model: mujoco.MjModel, v: np.ndarray) -> np.ndarray:
        """``(nq,)`` MuJoCo's positions at the tangent displacement ``v (nv,)`` = S q from the pose on the ground (F2)."""
        out = self.qpos_ground.copy()
        mujoco.mj_integratePos(model, out, np.asarray(v, dtype=np.float64), 1.0)
        return out

    def displacement(self, model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
        """``(nv,)`` the tangent displacement qpos ⊖ qpos_ground (F2)."""
        out = np.zeros(model.nv)
        mujoco.mj_differentiatePos(model, out, 1.0, self.qpos_ground, np.asarray(qpos, dtype=np.float64))
        return out

    def describe(self, model: mujoco.MjModel) -> str:
        """``travel = 0.0339·θ + 0.0339·φ``: the body's travel per coordinate, and r_eff."""
        travel = np.cross(self.axle, _up(model))
        lin = self.S[:3].T @ travel
        names = [model.joint(j).name or f"joint{j}" for j in self.wheels]
        radii = ", ".join(f"{c.geom} r_eff {c.radius:.6g} m (geometric {c.geometric_radius:.6g} m, {c.points} contact points)"
                          for c in self.contacts)
        wheels = " = ".join(f"{'' if s > 0 else '−'}{n}" for n, s in zip(names, self.signs))
        return (f"{self.body}: free body on wheels {wheels}; pitch about the axle ({' '.join(f'{a:.3g}' for a in self.axle)}) "
                f"is q_u; travel along ({' '.join(f'{a:.3g}' for a in travel)}) = {lin[0]:.6g}·{names[0]} + {lin[1]:.6g}·pitch "
                f"(rolling without slip: {radii}); height, roll and sideways motion held by the contacts, yaw not modelled")


def _up(model: mujoco.MjModel) -> np.ndarray:
    g = np.asarray(model.opt.gravity, dtype=np.float64)
    return -g / np.linalg.norm(g)


def _collides(model: mujoco.MjModel, g1: int, g2: int) -> bool:
    pairs = {(int(a), int(b)) for a, b in zip(model.pair_geom1, model.pair_geom2)}
    if (g1, g2) in pairs or (g2, g1) in pairs:
        return True
    return bool(int(model.geom_contype[g1]) & int(model.geom_conaffinity[g2]) or int(model.geom_contype[g2]) & int(model.geom_conaffinity[g1]))


def find_floating(model: mujoco.MjModel, *, where: str) -> FloatingRolling | None:
    """The reduction (F1, F2) when ``model`` is one free body on coaxial driven wheels, else ``None``
    (the model has no free joint).

    Raises:
        RobotModelError: a free-joint model outside the supported kind (more than one free joint, joints
            other than wheel hinges, wheels not coaxial or not driven, wheels that do not reach the ground
            together, rolling that changes with the pose), naming what was found.
    """
    free = [j for j in range(model.njnt) if int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE)]
    if not free:
        return None
    where = f"{where}: a ball/free joint is supported only as one free body on coaxial driven wheels, but"
    if len(free) > 1 or int(model.body_parentid[int(model.jnt_bodyid[free[0]])]) != 0:
        raise RobotModelError(f"{where} there are {len(free)} free joints, or the free body is not a child of the world")
    if np.linalg.norm(model.opt.gravity) == 0:
        raise RobotModelError(f"{where} <option gravity> is zero")
    fj = free[0]
    body = int(model.jnt_bodyid[fj])
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, data)
    wheels = wheel_geoms(model, data)
    hinges = [j for j in range(model.njnt) if j != fj]
    driven = {int(model.actuator_trnid[i, 0]) for i in range(model.nu) if int(model.actuator_trntype[i]) == int(mujoco.mjtTrn.mjTRN_JOINT)}
    names = [model.joint(j).name or f"joint{j}" for j in range(model.njnt)]
    not_wheels = [names[j] for j in hinges if j not in set(wheels.values())]
    if not_wheels or not hinges:
        raise RobotModelError(f"{where} joints {not_wheels} do not turn a wheel (a cylinder coaxial with its hinge or a "
                              "sphere on its axis)" if not_wheels else f"{where} the free body has no wheels")
    if undriven := [names[j] for j in hinges if j not in driven]:
        raise RobotModelError(f"{where} wheels {undriven} have no actuator")
    axes = [data.xaxis[j] / np.linalg.norm(data.xaxis[j]) for j in hinges]
    axle, up = axes[0], _up(model)
    if any(np.linalg.norm(np.cross(a, axle)) > 1e-6 for a in axes) or abs(axle @ up) > 1e-6:
        raise RobotModelError(f"{where} the wheels {[names[j] for j in hinges]} are not on one horizontal axle "
                              "(steered or cambered wheels are not supported yet)")
    signs = np.array([float(np.sign(a @ axle)) for a in axes])
    _origin_on_axle(model, data, body, fj, hinges)
    data.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, data)
    wheels = wheel_geoms(model, data)
    qpos_g = _settle(model, data, fj, wheels, where=where)
    mujoco.mj_fwdPosition(model, data)
    tangential, normal, found = rolling_rows(model, data, wheels)
    if {w for w, _, _ in found} != set(wheels):
        raise RobotModelError(f"{where} not every wheel touches the ground on the pose of rest")
    J = np.vstack([tangential, normal])
    nv, a = model.nv, int(model.jnt_dofadr[fj])
    Rb = data.xmat[body].reshape(3, 3)
    v_f, v_phi, v_theta = np.zeros(nv), np.zeros(nv), np.zeros(nv)
    v_f[a : a + 3] = np.cross(axle, up)
    v_phi[a + 3 : a + 6] = Rb.T @ axle
    for j, s in zip(hinges, signs):
        v_theta[int(model.jnt_dofadr[j])] = s
    Jf = J @ v_f
    c = -(Jf @ J @ np.column_stack([v_theta, v_phi])) / float(Jf @ Jf)
    S = np.column_stack([v_theta + c[0] * v_f, v_phi + c[1] * v_f])
    scale = float(np.abs(J).max())
    if float(np.abs(J @ S).max()) > _TOL * scale:
        raise RobotModelError(f"{where} the wheels cannot roll together without slipping on the pose of rest "
                              f"(residual {float(np.abs(J @ S).max()):.3g}); not a two-wheeled robot on a plane")
    T = np.zeros((2, nv))
    T[0, int(model.jnt_dofadr[hinges[0]])] = 1.0
    T[1, a + 3 : a + 6] = Rb.T @ axle
    out = FloatingRolling(body=model.body(body).name or f"body{body}", wheels=tuple(hinges), signs=signs, axle=axle,
                          qpos_ground=qpos_g, S=S, T=T, contacts=describe_contacts(model, data, found))
    _check_constant(model, data, wheels, out, where=where)
    return out


def _origin_on_axle(model: mujoco.MjModel, data: mujoco.MjData, body: int, fj: int, hinges: list[int]) -> None:
    """Move the free body's frame origin to the axle (the mean of the wheel hinges' anchors), in place.

    The physics is unchanged (every position given in the body's frame is shifted by −δ, the free joint's
    qpos0 by +R δ); the free joint's linear velocity is then the axle's, so pitching about the axle is
    a rotation alone and the map (F1) is constant.
    """
    data.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, data)
    R = data.xmat[body].reshape(3, 3)
    delta = R.T @ (np.mean([data.xanchor[j] for j in hinges], axis=0) - data.xpos[body])
    if float(np.linalg.norm(delta)) == 0.0:
        return
    model.body_ipos[body] -= delta
    model.geom_pos[model.geom_bodyid == body] -= delta
    model.site_pos[model.site_bodyid == body] -= delta
    model.cam_pos[model.cam_bodyid == body] -= delta
    model.light_pos[model.light_bodyid == body] -= delta
    model.body_pos[(model.body_parentid == body) & (np.arange(model.nbody) != body)] -= delta
    qa = int(model.jnt_qposadr[fj])
    model.qpos0[qa : qa + 3] += R @ delta
    model.body_pos[body] += R @ delta
    mujoco.mj_setConst(model, data)


def _settle(model: mujoco.MjModel, data: mujoco.MjData, fj: int, wheels: dict[int, int], *, where: str) -> np.ndarray:
    """The pose on the ground (module docstring): lowered to touch, then pressed in to carry the weight."""
    up = _up(model)
    static = [g for g in range(model.ngeom) if int(model.body_weldid[int(model.geom_bodyid[g])]) == 0]
    gaps = []
    for w in wheels:
        d = [mujoco.mj_geomDistance(model, data, w, g, 10.0, None) for g in static if _collides(model, w, g)]
        if not d:
            raise RobotModelError(f"{where} wheel geom {model.geom(w).name or w} collides with no static geom (no ground)")
        gaps.append(min(d))
    if max(gaps) - min(gaps) > 1e-6:
        raise RobotModelError(f"{where} the wheels are {min(gaps):.6g} and {max(gaps):.6g} m above the ground, they must "
                              "touch it together (a level axle)")
    qa = int(model.jnt_qposadr[fj])
    base = np.array(model.qpos0, dtype=np.float64)
    base[qa : qa + 3] -= gaps[0] * up
    radius = min(float(model.geom_size[w, 0]) for w in wheels)

    def lift(depth: float) -> float:   # vertical acceleration at rest pressed ``depth`` into the ground, m/s²
        data.qpos[:] = base
        data.qpos[qa : qa + 3] -= depth * up
        data.qvel[:] = 0.0
        data.ctrl[:] = 0.0
        mujoco.mj_forward(model, data)
        return float(data.qacc[int(model.jnt_dofadr[fj]) : int(model.jnt_dofadr[fj]) + 3] @ up)

    lo, hi = 0.0, 0.5 * radius
    if not lift(hi) > 0:
        raise RobotModelError(f"{where} the ground does not carry the robot's weight within half a wheel radius of penetration")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if lift(mid) < 0 else (lo, mid)
    base[qa : qa + 3] -= 0.5 * (lo + hi) * up
    data.qpos[:] = base
    return base


def _check_constant(model: mujoco.MjModel, data: mujoco.MjData, wheels: dict[int, int], fr: FloatingRolling, *, where: str) -> None:
    """J S = 0 at other poses (pitch ±0.5 rad, any wheel angle): the map (F1) is the same everywhere."""
    rng = np.random.default_rng(0)
    for _ in range(3):
        data.qpos[:] = fr.qpos(model, fr.S @ np.array([rng.uniform(-3.0, 3.0), rng.uniform(-0.5, 0.5)]))
        mujoco.mj_fwdPosition(model, data)
        tangential, normal, found = rolling_rows(model, data, wheels)
        if len(found) == 0:
            continue
        J = np.vstack([tangential, normal])
        if float(np.abs(J @ fr.S).max()) > 1e-6 * float(np.abs(J).max()):
            raise RobotModelError(f"{where} the rolling map of the free body changes with the pose; not supported")
    data.qpos[:] = fr.qpos_ground
