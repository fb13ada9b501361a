"""Discrete LQR of MuJoCo's own linearisation at the upright equilibrium.

The plant held over one control tick of N = ``substeps`` physics steps with a zero-order-hold
input is, linearised at x* = [q_a = 0, q_u = q_u,nominal, q̇ = 0], u = 0,

    δx_{k+1} = A_N δx_k + B_N u_k,   A_N = A^N,   B_N = Σ_{i<N} A^i B

where (A, B) is one physics step's Jacobian from ``mujoco.mjd_transitionFD`` (joint state
[q_j, q̇_j], inputs in actuator ``ctrl`` units; an RK4 model is linearised with its
integrator set to Euler, which ``mjd_transitionFD`` supports).  The design's input is one command per actuated
coordinate, ctrl = W u (:mod:`bemlearn.robots.actuation`: the actuators of a coordinate commanded together;
W = I with one actuator per coordinate), so its input matrix is B_N W and its limits are the group's.  In the robot's coordinates q = T q_j the
state is S x_j, S = diag(T, T).  The gain minimises Σ δxᵀQδx + uᵀR_u u (+ fᵀR_f f, below; ``scipy.linalg.solve_discrete_are``)
with Bryson's rule Q = diag(1/x_max²),
x_max from the design region (|q_u − nominal| ≤ 0.2 rad or less if the joint range is
smaller; actuated positions from their joint ranges, 0.5 rad / 0.5 m when unlimited;
rates from those times the instability rate).  Two designs, in order:

1. effort weight on ``ctrl`` alone, R = 1/u_ctrl² (half the ``ctrlrange`` width, 1 where unlimited),
   raised ×4 until the linear response to a q_u error ``qu0`` stays within the ``ctrlrange``;
2. if MuJoCo itself (every limit clipped) does not bring the robot back with design 1 from the
   q_u start and from each actuated start ``qa0`` (:func:`holds_in_mujoco`), the actuator force
   f = gain·ctrl + b0 + b1·l + b2·l̇ (l = gear·q_j, MuJoCo clips it to the ``forcerange``) is
   weighed too: linearised f = G u + F δx, so a servo's force limit (its ``ctrl`` is a setpoint) is
   weighed with the state it depends on (R = R_u + G R_f G, Q += Fᵀ R_f F, cross term
   S = Fᵀ R_f G, R_f = 1/f_max²), raised ×4 until every start's linear response stays within both
   ranges.  Design 2 is kept when MuJoCo brings the robot back with it; :attr:`LQRResult.notes`
   says which design was kept and why.

A short saturation of a servo's force is harmless where the plant recovers from it (design 1
keeps the gains such files always had); where it is not, the check in MuJoCo says so.

Dry friction (joint ``frictionloss``) makes the dynamics non-smooth at rest: finite differences
there see the joint stick (B collapses).  The linearisation is taken with ``frictionloss`` set to
0 (the sliding dynamics the controller acts through); :attr:`LQRResult.notes` says so.

Sign convention of collect: u = K e, e = [q − q_t, q̇ − q̇_t], so K = −K_lqr.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from bemlearn.errors import ArgumentError, NumericalError
from bemlearn.warnings import DesignWarning, warn

if TYPE_CHECKING:
    from bemlearn.robots.mujoco_robot import MujocoRobot

__all__ = ["LQRResult", "ActuatorLimits", "GainSchedule", "actuator_limits", "holds_in_mujoco", "linearize", "discrete_lqr", "fill_between_poses", "pose_gain_schedule", "riccati_iteration", "tracking_gains", "turning_maps", "turning_rate_limit",
           "TurningMaps", "upright_at"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LQRResult:
    """A discrete LQR design (module docstring).

    Attributes:
        K: ``(m, 2n)`` gains for u = K e, e = [q − q_t, q̇ − q̇_t] in the robot's coordinates
            (command units per rad or m, per rad/s or m/s; ctrl = W u, :mod:`bemlearn.robots.actuation`).
        A: ``(2n, 2n)`` the tick map's state matrix in coordinates.
        B: ``(2n, m)`` its input matrix per command (B_N W).
        Q: the state weight used.
        R: the input weight used.
        rate_hz: control rate.
        substeps: physics steps per tick.
        timestep: physics step, s.
        spectral_radius: of A + B K (< 1 when stabilising).
        u_peak: max |u| / u_max of the linear closed loop from the check's initial error.
        r_scale: factor applied to Bryson's R to respect ctrlrange and forcerange.
        notes: how the linearisation departed from the plain model (dry friction left out), for messages.
        S: the state-input cross weight of design 2 (``None``: design 1, no cross term).
    """

    K: np.ndarray
    A: np.ndarray
    B: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    rate_hz: float
    substeps: int
    timestep: float
    spectral_radius: float
    u_peak: float
    r_scale: float
    notes: tuple[str, ...] = ()
    S: np.ndarray | None = None


def linearize(robot: MujocoRobot, *, rate_hz: float, timestep: float | None = None, eps: float = 1e-6,
              at: np.ndarray | None = None, at_rate: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int, float]:
    """Tick map (A_N, B_N) of ``robot`` (a MujocoRobot) in its coordinates at upright.

    Args:
        rate_hz: control rate, Hz; 1/rate must be a whole number of physics steps.
        timestep: physics step override, s (default: the model's).
        at: ``(m,)`` actuated pose q_a (joint units; default 0): the linearisation is taken there, at rest, with q_u
            at the BEM of that pose (the root of Γ_0(q_u; q_a, 0, 0) nearest nominal, :func:`upright_at`) and the
            actuators commanded to hold it (their inverse, :class:`~bemlearn.control.actuator_inverse.MujocoActuatorInverse`).
        at_rate: ``(m,)`` actuated rates q̇_a (joint units per s; default 0): the linearisation is taken moving at them
            (q_u at ``at``'s BEM of rest, q̇_u = 0), the actuators commanded to keep q̈ = 0 there — a turntable
            turning at ψ̇ with its pole upright, a motion the robot can keep.

    Returns:
        ``(A (2n, 2n), B (2n, nu), substeps, timestep)``.
    """
    model = _model_copy(robot.model, timestep)
    if np.any(model.dof_frictionloss > 0):
        # at rest a joint with dry friction sticks: finite differences would see B ≈ 0 (module docstring)
        import copy

        model = copy.deepcopy(model)
        model.dof_frictionloss[:] = 0.0
    if int(model.opt.integrator) == int(mujoco.mjtIntegrator.mjINT_RK4):
        # mjd_transitionFD does not support RK4: linearise the same dynamics with Euler steps
        import copy

        model = copy.deepcopy(model)
        model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    h = float(model.opt.timestep)
    steps = 1.0 / (rate_hz * h)
    if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
        raise ArgumentError(f"linearize: 1/rate_hz = {1 / rate_hz} s is not a whole number of physics steps ({h} s)")
    N = int(round(steps))
    data = mujoco.MjData(model)
    n = robot.n
    q0 = np.zeros(n)
    q0[robot.unactuated_index] = robot.qu_nominal
    if at is not None:
        q0[list(robot.actuated_index)] = at
        q0[robot.unactuated_index] = upright_at(robot, np.asarray(at, dtype=np.float64))
    qd0 = np.zeros(n)
    if at_rate is not None:
        qd0[list(robot.actuated_index)] = at_rate
    data.qpos[:], qvel = robot.state_to_mujoco(q0, qd0)
    if at_rate is not None:
        data.qvel[:] = qvel
    if (at is not None and np.any(at)) or (at_rate is not None and np.any(at_rate)):
        # held at rest (or moving steadily) there: the actuators' command that balances the pose's static and velocity
        # forces (a servo's setpoint at the pose), else the linearisation is of a state accelerating away from it
        from bemlearn.control.actuator_inverse import MujocoActuatorInverse

        bias = np.asarray(robot.terms(q0, qd0)[1], dtype=np.float64)
        data.ctrl[:] = MujocoActuatorInverse(robot).command(bias[list(robot.actuated_index)], q0, qd0, clip=False)
    mujoco.mj_forward(model, data)
    nx = 2 * model.nv + model.na
    A1 = np.zeros((nx, nx))
    B1 = np.zeros((nx, model.nu))
    mujoco.mjd_transitionFD(model, data, eps, True, A1, B1, None, None)
    nv = model.nv
    A1, B1 = A1[: 2 * nv, : 2 * nv], B1[: 2 * nv]
    AN, BN = np.eye(2 * nv), np.zeros_like(B1)
    for _ in range(N):
        BN = A1 @ BN + B1
        AN = A1 @ AN
    # state in coordinates: x = P x_j, x_j = P⁺ x (P⁺ = P⁻¹ for a square map; the rolling map S otherwise)
    T, Tinv = robot.T_np, robot.Tinv_np
    P = np.block([[T, np.zeros_like(T)], [np.zeros_like(T), T]])
    Pplus = np.block([[Tinv, np.zeros_like(Tinv)], [np.zeros_like(Tinv), Tinv]])
    return P @ AN @ Pplus, P @ BN, N, h


def upright_at(robot: MujocoRobot, qa: np.ndarray) -> float:
    """q_u^e(q_a, 0, 0): the root of Γ_0 (eq. 9 at rest) nearest q_u,nominal in :attr:`qu_range` with the actuated
    coordinates at ``qa (m,)``; q_u,nominal where there is none (or ``qa`` is 0)."""
    if not np.any(qa):
        return float(robot.qu_nominal)
    from bemlearn.robots.bem import find_roots

    z = np.zeros(robot.m)
    lo, hi = robot.qu_range

    def gamma0(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return np.array([[robot.gamma0_scalar(float(v), qa, z, z) for v in row] for row in x])

    root = float(find_roots(gamma0, 1, lo=lo, hi=hi, nominal=robot.qu_nominal)[0][0])
    return root if math.isfinite(root) else float(robot.qu_nominal)


def _model_copy(model: mujoco.MjModel, timestep: float | None) -> mujoco.MjModel:
    if timestep is None or timestep == model.opt.timestep:
        return model
    import copy

    out = copy.deepcopy(model)
    out.opt.timestep = timestep
    return out


def bryson_scales(robot: MujocoRobot, *, design_qu: float = 0.2) -> tuple[np.ndarray, np.ndarray, float]:
    """Bryson maxima ``(x_max (2n,), u_max (nu,), λ)`` (module docstring); λ = √(Γ_q/D_uu), 1/s.

    An unlimited actuated coordinate gets at least the amplitude a sine at λ needs to move the
    BEM by ``design_qu`` (a reaction wheel turns through many radians to balance); an unlimited hinge whose
    motion does not move the BEM at rest (a turntable's yaw) a half turn.
    """
    from bemlearn.robots.scales import bem_gain, bem_slopes, instability_rate, qa_half_ranges, qu_half_range

    n, iu, ia = robot.n, robot.unactuated_index, list(robot.actuated_index)
    lam = instability_rate(robot)
    xmax = np.empty(2 * n)
    dq = min(design_qu, qu_half_range(robot))
    xmax[iu] = dq
    qa_max = qa_half_ranges(robot)
    slopes = bem_slopes(robot)
    gain = bem_gain(slopes, lam)
    need = dq / np.maximum(gain, 1e-12)
    limited = _limited_actuated(robot)
    # an unlimited hinge that does not move the BEM at rest (a turntable's yaw: it turns the slides' slopes instead)
    # would get no weight at all, and nothing would hold it to its reference: a half turn is its scale.  Slopes of
    # rounding size (≤ 1e-9 per unit, as in the excitation's extents, derive.excitation_directions) are no motion of the
    # BEM: fam0_041's yaw, s_a = 1.1e-12 rad per rad/s², got a scale of 5.8e9 rad and gains of 1e-9, and ran off its
    # reference by tens of turns
    flat = np.max(np.abs(np.asarray(slopes)), axis=0) <= 1e-9
    kinds = tuple(getattr(robot, "coordinate_kinds", ()))
    idle = np.array([(g <= 1e-12 or f) and len(kinds) == n and kinds[j] == "hinge" for g, f, j in zip(gain, flat, ia)], dtype=bool)
    need = np.where(~limited & idle, np.maximum(qa_max, math.pi), need)
    xmax[ia] = np.where(limited, qa_max, np.maximum(qa_max, need))
    xmax[n:] = xmax[:n] * max(lam, 1.0)
    return xmax, actuator_limits(robot).u_max, lam


@dataclass(frozen=True)
class ActuatorLimits:
    """What each command (one per actuated coordinate, :mod:`bemlearn.robots.actuation`) may be asked for,
    linearised at rest (module docstring).  The command v (m,) reaches the actuators as ctrl = W v.

    Attributes:
        u_max: ``(m,)`` command units: the smallest of its actuators' half ``ctrlrange`` widths and |f_max / gain|
            (each divided by |W_ic|: the most restrictive member binds; 1 where none is limited).
        u_ctrl: ``(m,)`` the same from the ``ctrlrange`` alone (``inf`` where unlimited).
        f_max: ``(nu,)`` force limit (``forcerange``, joint ``actuatorfrcrange``), ``inf`` where unlimited.
        gain: ``(nu,)`` ∂f/∂ctrl at rest.
        f_state: ``(nu, 2n)`` ∂f/∂x at rest for x = [q, q̇] in the robot's coordinates (bias terms b1·l + b2·l̇,
            l = gear·q_j).
        binding: per command, ``"ctrlrange"``, ``"forcerange"`` or ``"none"``: which limit sets u_max.
        W: ``(nu, m)`` ctrl = W v (the identity with one actuator per coordinate).
        ctrl_limit: ``(nu,)`` each actuator's half ``ctrlrange`` width (``inf`` where unlimited).
        hold: ``(nu,)`` φ_i (eq. A3 of :mod:`bemlearn.robots.actuation`) when the command is held over a tick: the
            force limits bound the tick's mean force, the first instant's / φ (``None``: the force now).
    """

    u_max: np.ndarray
    u_ctrl: np.ndarray
    f_max: np.ndarray
    gain: np.ndarray
    f_state: np.ndarray
    binding: tuple[str, ...]
    W: np.ndarray
    ctrl_limit: np.ndarray
    hold: np.ndarray | None = None

    @property
    def force_gain(self) -> np.ndarray:
        """``(nu, m)`` ∂f/∂v = diag(gain) W."""
        return self.gain[:, None] * self.W

    def peak(self, u: np.ndarray, x: np.ndarray) -> float:
        """max over actuators of |ctrl| / ctrl limit and |f(x, u)| / f_max for commands ``u (m,)``, ``x (2n,)``."""
        ctrl = self.W @ u
        f = self.gain * ctrl + self.f_state @ x
        if self.hold is not None:
            f = f / self.hold
        return float(max(np.max(np.abs(ctrl) / self.ctrl_limit, initial=0.0), np.max(np.abs(f) / self.f_max, initial=0.0)))


def actuator_limits(robot: MujocoRobot) -> ActuatorLimits:
    """The :class:`ActuatorLimits` of ``robot``'s commands (joint transmissions; gain and bias read from the model)."""
    from bemlearn.robots.actuation import force_limits

    model = robot.model
    nu, n = model.nu, robot.n
    groups = robot.actuation
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    ulim = model.actuator_ctrllimited.astype(bool)
    ctrl_limit = np.where(ulim, 0.5 * (hi - lo), np.inf)
    f_max = force_limits(model, robot.traction_limits)
    gain = model.actuator_gainprm[:, 0].astype(np.float64).copy()
    affine_bias = model.actuator_biastype == int(mujoco.mjtBias.mjBIAS_AFFINE)
    b1 = np.where(affine_bias, model.actuator_biasprm[:, 1], 0.0)
    b2 = np.where(affine_bias, model.actuator_biasprm[:, 2], 0.0)
    f_state = np.zeros((nu, 2 * n))
    Tinv = robot.Tinv_np
    dof_col = {int(a): k for k, a in enumerate(robot._dadr)}
    for i in range(nu):
        gear = float(model.actuator_gear[i, 0])
        col = dof_col.get(int(model.jnt_dofadr[model.actuator_trnid[i, 0]]))
        if col is None:
            continue
        f_state[i, :n] = b1[i] * gear * Tinv[col]
        f_state[i, n:] = b2[i] * gear * Tinv[col]
    by_force_ctrl = np.where(np.abs(gain) > 0, f_max / np.maximum(np.abs(gain), 1e-300), np.inf)
    u_ctrl = groups.command_limits(ctrl_limit)
    by_force = groups.command_limits(by_force_ctrl)
    u_max = np.minimum(u_ctrl, by_force)
    binding = tuple("none" if not np.isfinite(um) else ("forcerange" if bf < uc else "ctrlrange")
                    for um, bf, uc in zip(u_max, by_force, u_ctrl))
    return ActuatorLimits(np.where(np.isfinite(u_max), u_max, 1.0), u_ctrl, f_max, gain, f_state, binding, groups.W, ctrl_limit)


def _limited_actuated(robot: MujocoRobot) -> np.ndarray:
    from bemlearn.robots.scales import qa_limited

    return qa_limited(robot)


def _lqr_scaled(robot: MujocoRobot, A: np.ndarray, B: np.ndarray, Q0: np.ndarray, R0: np.ndarray, Qf: np.ndarray | None,
                S0: np.ndarray | None, starts: list[np.ndarray], steps: int, limits: ActuatorLimits, *,
                force: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """``(K, Q, R, peak, scale)``: the effort weights (R0, and Qf, S0 of a force weight) raised ×4 until the linear
    response from every start stays within the limits (ctrl only unless ``force``); at most 12 times."""
    from scipy.linalg import solve_discrete_are

    u_ref = np.where(np.isfinite(limits.u_ctrl), limits.u_ctrl, 1.0)   # Bryson's 1 where ctrl is unlimited, as its weight
    scale = 1.0
    for _ in range(13):
        R = scale * R0
        Q = Q0 + (scale * Qf if Qf is not None else 0.0)
        S = scale * S0 if S0 is not None else None
        try:
            P = solve_discrete_are(A, B, Q, R, s=S)
        except (np.linalg.LinAlgError, ValueError) as exc:
            raise NumericalError(
                f"discrete_lqr: {robot.name}: no stabilising LQR for MuJoCo's linearisation ({exc}); "
                "the upright may be uncontrollable from the actuators at this rate") from None
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A + (S.T if S is not None else 0.0))
        Acl = A - B @ K
        peak = 0.0
        for x0 in starts:
            x = x0.copy()
            for _ in range(steps):
                u = -K @ x
                peak = max(peak, limits.peak(u, x) if force else float(np.max(np.abs(u) / u_ref)))
                x = Acl @ x
        if peak <= 1.0:
            break
        scale *= 4.0
    return K, Q, R, peak, scale


def holds_in_mujoco(robot: MujocoRobot, K: np.ndarray, *, rate_hz: float, timestep: float | None, starts: list[np.ndarray],
                    check_s: float, qu0: float) -> tuple[bool, str]:
    """Whether u = K e (collect's convention, ``K (m, 2n)``; ctrl = W u clipped to ``ctrlrange``, forces to ``forcerange`` by MuJoCo)
    brings the robot back in MuJoCo itself from each start ``(2n,)`` (deviation from upright, coordinates): at the
    end |q_u − nominal| ≤ qu0/2 and |q̇_u| small, never beyond 4·qu0 on the way.  Returns ``(holds, why not)``."""
    model = _model_copy(robot.model, timestep)
    data = mujoco.MjData(model)
    n, iu = robot.n, robot.unactuated_index
    N = max(1, int(round(1.0 / (rate_hz * float(model.opt.timestep)))))
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    limited = model.actuator_ctrllimited.astype(bool)
    T, groups = robot.T_np, robot.actuation
    nominal = np.zeros(n)
    nominal[iu] = robot.qu_nominal
    ticks = int(math.ceil(check_s * rate_hz))
    for k, x0 in enumerate(starts):
        mujoco.mj_resetData(model, data)
        data.qpos[:], data.qvel[:] = robot.state_to_mujoco(nominal + x0[:n], x0[n:])
        for _ in range(ticks):
            q = robot.coordinates_of(data.qpos)
            qd = T @ data.qvel[robot._dadr]
            if not abs(q[iu] - robot.qu_nominal) <= 4 * qu0:
                return False, f"it leaves |q_u − nominal| ≤ {4 * qu0:.3g} from start {k} in MuJoCo"
            u = groups.ctrl(K @ np.concatenate([q - nominal, qd]))
            data.ctrl[:] = np.where(limited, np.clip(u, lo, hi), u)
            for _ in range(N):
                mujoco.mj_step(model, data)
        q = robot.coordinates_of(data.qpos)
        if not abs(q[iu] - robot.qu_nominal) <= qu0 / 2:
            return False, f"q_u is still {abs(q[iu] - robot.qu_nominal):.3g} from nominal after {check_s:g} s from start {k} in MuJoCo"
    return True, ""


def discrete_lqr(
    robot: MujocoRobot,
    *,
    rate_hz: float,
    timestep: float | None = None,
    design_qu: float = 0.2,
    qu0: float = 0.05,
    qa0: float | None = None,
    check_s: float = 3.0,
) -> LQRResult:
    """Discrete LQR gains in collect's convention (module docstring).

    Args:
        robot: a MujocoRobot.
        rate_hz: control rate, Hz.  timestep: physics step override, s.
        design_qu: |q_u − nominal| design bound of Bryson's rule, rad (or m).
        qu0: initial q_u error of the ctrlrange check, rad (or m).
        qa0: if given, the check also starts from an error of ``qa0`` on each actuated coordinate alone (rad or m:
            the excitation trials' initial range), and its peak is the worst of all starts.
        check_s: duration of the check, s.
    """
    A, B, N, h = linearize(robot, rate_hz=rate_hz, timestep=timestep)
    if robot.actuation.grouped:
        B = B @ robot.actuation.W   # one command per actuated coordinate (ctrl = W u)
    xmax, umax, _ = bryson_scales(robot, design_qu=design_qu)
    from bemlearn.robots.actuation import held_servo_factors

    # held over a tick of 1/rate: the force limits bound the mean force (a servo that settles within the tick, A3, A5)
    limits = dataclasses.replace(actuator_limits(robot), hold=held_servo_factors(robot, 1.0 / rate_hz))
    notes = []
    if np.any(robot.model.dof_frictionloss > 0):
        notes.append("linearised without dry friction (frictionloss: a joint at rest sticks and finite differences see no input)")
    forced = [robot.actuation.names[i] for i, b in enumerate(limits.binding) if b == "forcerange"]
    if forced:
        notes.append(f"forcerange binds before ctrlrange on {', '.join(forced)}")
    Q0 = np.diag(1.0 / xmax**2)
    steps = int(math.ceil(check_s * rate_hz))
    qu_start = np.zeros(A.shape[0])
    qu_start[robot.unactuated_index] = qu0
    qa_starts = []
    for j in (robot.actuated_index if qa0 else ()):
        qa_starts.append(np.zeros(A.shape[0]))
        qa_starts[-1][j] = qa0
    # First design: weights on ctrl alone, its linear response to a q_u error within ctrlrange (a short
    # saturation of a servo's force is harmless where the plant recovers from it).  It is kept when MuJoCo
    # itself, with every limit clipped, brings the robot back from each start; else the second design also
    # weighs the actuator force f = G u + F x against its forcerange (a servo's force depends on the state: the
    # cross term S = Fᵀ R_f G) and checks every start's linear response against all limits.
    G, F = limits.force_gain, limits.f_state
    Ru = np.diag(1.0 / np.where(np.isfinite(limits.u_ctrl), limits.u_ctrl, 1.0) ** 2)
    first = _lqr_scaled(robot, A, B, Q0, Ru, None, None, [qu_start], steps, limits, force=False)
    starts = [qu_start, *qa_starts]
    K, Q, R, peak, scale = first
    S: np.ndarray | None = None
    holds, why = holds_in_mujoco(robot, -K, rate_hz=rate_hz, timestep=timestep, starts=starts, check_s=check_s, qu0=qu0)
    if not holds:
        Ru2 = np.diag(np.where(np.isfinite(limits.u_ctrl), 1.0 / limits.u_ctrl**2, 0.0))
        Rf = np.diag(np.where(np.isfinite(limits.f_max), 1.0 / limits.f_max**2, 0.0))
        force_limited = (np.isfinite(limits.f_max)[:, None] & (np.abs(G) > 0)).any(axis=0)   # (m,): a member's force is limited
        Ru2 += np.diag(np.where(np.isfinite(limits.u_ctrl) | force_limited, 0.0, 1.0 / umax**2))
        second = _lqr_scaled(robot, A, B, Q0, Ru2 + G.T @ Rf @ G, F.T @ Rf @ F, F.T @ Rf @ G, starts, steps, limits, force=True)
        holds2, why2 = holds_in_mujoco(robot, -second[0], rate_hz=rate_hz, timestep=timestep, starts=starts, check_s=check_s, qu0=qu0)
        if holds2:
            K, Q, R, peak, scale = second
            S = scale * (F.T @ Rf @ G)
            notes.append(f"weighs the actuator force too: with ctrl weights alone {why}")
        else:
            notes.append(f"neither design brings the robot back in MuJoCo ({why}; with force weights: {why2})")
    if peak > 1.0:
        warn(DesignWarning, log, "discrete_lqr: %s needs %.2f× its actuator limits for a %.3g initial q_u error%s even with R × %g", robot.name,
                                 peak, qu0, f" (or {qa0:.3g} of an actuated coordinate)" if qa0 else "", scale)
    rho = float(np.max(np.abs(np.linalg.eigvals(A - B @ K))))
    return LQRResult(-K, A, B, Q, R, float(rate_hz), N, h, rho, peak, scale, tuple(notes), S)


@dataclass(frozen=True)
class GainSchedule:
    """Gains scheduled over the actuated coordinates whose pose changes the linearisation (:func:`pose_gain_schedule`):

        u = (K + Σ_i ΔK_i(q_a,i)) e,   ΔK_i(q) = K_i*(q) − K_i*(0)

    K_i*(q) the discrete LQR of the tick map linearised at q on coordinate i alone (the others at 0, q_u at that pose's
    BEM) with the weights of the design at rest; ΔK_i linear between the grid poses, held beyond the grid's ends, and
    periodic over [−π, π) for an unlimited hinge.

    Attributes:
        coords: indices into the actuated coordinates (0 … m−1) that are scheduled.
        grids: per scheduled coordinate the poses ``(points,)``, its unit, increasing.
        deltas: per scheduled coordinate ΔK ``(points, m, 2n)`` (collect's convention u = K e).
        periodic: per scheduled coordinate whether it wraps (an unlimited hinge).
        rho_fixed: per scheduled coordinate the worst spectral radius of the fixed gains over its grid (≥ 1: why it is
            scheduled).
        rho_scheduled: per scheduled coordinate the worst spectral radius of the scheduled gains over its grid.
        turn_rate: per scheduled coordinate (a periodic one whose rates were given) the largest steady rate (its unit
            per s) at which the scheduled loop turning over a whole turn decays (:func:`turning_rate_limit`), or
            ``None``; ``growth`` the fastest growth (1/s) over a turn at the given rates.
    """

    coords: tuple[int, ...]
    grids: tuple[np.ndarray, ...]
    deltas: tuple[np.ndarray, ...]
    periodic: tuple[bool, ...]
    rho_fixed: tuple[float, ...]
    rho_scheduled: tuple[float, ...]
    turn_rate: tuple[float | None, ...] | None = None
    growth: tuple[float | None, ...] | None = None

    def delta(self, qa: np.ndarray) -> np.ndarray:
        """ΔK ``(m, 2n)`` at the actuated pose ``qa (m,)`` (joint units)."""
        out = np.zeros(self.deltas[0].shape[1:])
        for i, g, d, per in zip(self.coords, self.grids, self.deltas, self.periodic):
            q = float(qa[i])
            if per:
                q = (q + math.pi) % (2 * math.pi) - math.pi
            k, w = _bracket(g, q)
            out += (1.0 - w) * d[k] + w * d[k + 1]
        return out

    def describe(self, names: list[str]) -> str:
        """One line for messages: which coordinates are scheduled and why."""
        turn = self.turn_rate or (None,) * len(self.coords)
        growth = self.growth or (None,) * len(self.coords)
        return "; ".join(f"gains scheduled over {names[i]} ({len(g)} poses{', periodic' if per else ''}): the fixed gains' "
                         f"spectral radius reaches {rf:.3g} there, the scheduled {rs:.3g}"
                         + (f"; turning steadily they hold to {tr:.3g}/s (over a turn at the given rates the loop's "
                            f"fastest growth is {gr:.3g} 1/s)" if tr is not None and gr is not None else "")
                         for i, g, per, rf, rs, tr, gr in zip(self.coords, self.grids, self.periodic, self.rho_fixed,
                                                              self.rho_scheduled, turn, growth))


def _bracket(g: np.ndarray, q: float) -> tuple[int, float]:
    """``(k, w)``: q between g[k] and g[k+1] at fraction w ∈ [0, 1] (held at the ends) of an increasing grid ``g``."""
    if q <= g[0]:
        return 0, 0.0
    if q >= g[-1]:
        return len(g) - 2, 1.0
    k = int(np.searchsorted(g, q)) - 1
    return k, float((q - g[k]) / (g[k + 1] - g[k]))


def _pose_grid(robot: MujocoRobot, j: int, extent: float, points: int) -> tuple[np.ndarray, bool]:
    """Poses of actuated coordinate ``j``: ±1.5 × ``extent`` within the coordinate's range, or [−π, π] (periodic) on an
    unlimited hinge whose ±1.5 × extent reaches a half turn."""
    from bemlearn.robots.scales import qa_limited

    kinds = tuple(getattr(robot, "coordinate_kinds", ()))
    i = robot.actuated_index[j]
    limited = bool(qa_limited(robot)[j])
    if not limited and len(kinds) == robot.n and kinds[i] == "hinge" and 1.5 * extent >= math.pi:
        return np.linspace(-math.pi, math.pi, points), True
    lo, hi = -1.5 * extent, 1.5 * extent
    if limited and (lim := robot.coordinate_limits[i]) is not None:   # a pose at the stop would linearise the stop
        lo, hi = max(lo, 0.98 * lim[0]), min(hi, 0.98 * lim[1])
    return np.linspace(lo, hi, points), False


_SCHEDULES: dict = {}


def riccati_iteration(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, S: np.ndarray | None = None, *,
                      tol: float = 1e-12, max_iter: int = 200_000) -> np.ndarray | None:
    """The stabilising solution ``P (nx, nx)`` of the discrete algebraic Riccati equation by its recursion,

        P ← Q + AᵀPA − (AᵀPB + S)(R + BᵀPB)⁻¹(BᵀPA + Sᵀ),   P₀ = Q,

    which converges (at the rate ρ(A − BK)² per step) wherever (A, B) is stabilisable and the cost detectable — where
    ``scipy.linalg.solve_discrete_are``'s Schur reordering fails as "very ill-conditioned" on a well-posed pair.
    ``A (nx, nx)``, ``B (nx, nu)``, ``Q (nx, nx)``, ``R (nu, nu)``, ``S (nx, nu)`` the cross term.  ``None`` where it
    does not settle to relative change ``tol`` in ``max_iter`` steps or its gain does not stabilise A − BK."""
    Sx = S if S is not None else np.zeros(B.shape)
    P = np.array(Q, dtype=np.float64)
    for _ in range(max_iter):
        G = A.T @ P @ B + Sx
        P_next = Q + A.T @ P @ A - G @ np.linalg.solve(R + B.T @ P @ B, G.T)
        P_next = 0.5 * (P_next + P_next.T)
        if not np.all(np.isfinite(P_next)):
            return None
        done = float(np.max(np.abs(P_next - P))) <= tol * max(1.0, float(np.max(np.abs(P_next))))
        P = P_next
        if done:
            K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A + Sx.T)
            return P if float(np.max(np.abs(np.linalg.eigvals(A - B @ K)))) < 1.0 else None
    return None


def fill_between_poses(grid: np.ndarray, d: np.ndarray, ok: np.ndarray, *, periodic: bool) -> np.ndarray:
    """``d`` with its rows where ``ok`` is False interpolated linearly over ``grid`` from the rows where it is True.

    Args:
        grid: ``(G,)`` increasing poses of one coordinate (rad or m).
        d: ``(G, ...)`` a value per pose (a gain change); rows where ``ok`` is False are replaced.
        ok: ``(G,)`` bool, at least one True.
        periodic: the grid spans a full turn of an unlimited hinge: interpolate across ±2π (the first and last poses
            are neighbours); else a pose beyond the last good one takes its value.

    Returns:
        a copy of ``d``.
    """
    good = grid[ok]
    x = good if not periodic else np.concatenate([good - 2 * math.pi, good, good + 2 * math.pi])
    y = d[ok] if not periodic else np.concatenate([d[ok]] * 3)
    flat = y.reshape(len(y), -1)
    out = d.copy()
    out[~ok] = np.stack([np.interp(grid[~ok], x, flat[:, c]) for c in range(flat.shape[1])], axis=1).reshape(-1, *d.shape[1:])
    return out


def pose_gain_schedule(robot: MujocoRobot, K: np.ndarray, *, rate_hz: float, timestep: float | None, extents: np.ndarray,
                       design_qu: float, qu0: float, qa0: float | None, points: int = 49,
                       rates: np.ndarray | None = None, horizon_s: float | None = None) -> GainSchedule | None:
    """Which actuated coordinates' pose makes the fixed gains ``K (m, 2n)`` (collect's convention) fail, and the gains
    scheduled over them (:class:`GainSchedule`).

    Coordinate j is scheduled when u = K e does not stabilise the tick map linearised at some pose of j alone within
    ``extents[j]`` (:func:`_pose_grid`; :func:`linearize` with ``at``):
    spectral radius of A(q) + B(q) K ≥ 1.  A turntable's yaw ψ turns the pole's plane: at ψ = π/2 the slide that
    balanced it at ψ = 0 moves it no more.  There the design of :func:`discrete_lqr` (``design_qu``, ``qu0``, ``qa0``,
    its Bryson weights, effort scale and, for design 2, force weights) is solved at each pose with the same weights
    (``scipy.linalg.solve_discrete_are``), and its change from rest is added to K.  ``None`` where no coordinate needs
    it (a cart's slides, whose linearisation does not change with the pose: the excitation is then unchanged).

    ``rates (m,)`` (joint units per s) with ``horizon_s``: for a periodic coordinate (an unlimited hinge) that turns at up
    to rates[j], the largest steady rate at which the scheduled loop grows over a turn by less than e per ``horizon_s``
    (:func:`turning_rate_limit`: the schedule is designed at rest, and a turntable turning at ψ̇ turns the pole's plane
    under the slides' loop).
    Cached per robot, gains, rate and extents.
    """
    K = np.asarray(K, dtype=np.float64)
    key = (robot.name, robot.model.nq, K.tobytes(), float(rate_hz), timestep, tuple(float(x) for x in extents),
           float(design_qu), float(qu0), qa0, points, None if rates is None else tuple(float(x) for x in rates), horizon_s)
    if key in _SCHEDULES:
        return _SCHEDULES[key]
    m = robot.m
    tables = []
    for j in range(m):
        grid, periodic = _pose_grid(robot, j, float(extents[j]), points)
        maps, rho = [], 0.0
        for q in grid:
            at = np.zeros(m)
            at[j] = q
            A, B, _, _ = linearize(robot, rate_hz=rate_hz, timestep=timestep, at=at)
            if robot.actuation.grouped:
                B = B @ robot.actuation.W   # one command per actuated coordinate (ctrl = W u)
            maps.append((A, B))
            rho = max(rho, float(np.max(np.abs(np.linalg.eigvals(A + B @ K)))))
        if rho >= 1.0:
            tables.append((j, grid, periodic, maps, rho))
    if not tables:
        _SCHEDULES[key] = None
        return None
    res = discrete_lqr(robot, rate_hz=rate_hz, timestep=timestep, design_qu=design_qu, qu0=qu0, qa0=qa0)
    Q, R, S = res.Q, res.R, res.S

    def design(A: np.ndarray, B: np.ndarray) -> np.ndarray | None:
        return _design(A, B, Q, R, S)

    K_rest = design(res.A, res.B)
    if K_rest is None:
        _SCHEDULES[key] = None
        return None
    coords, grids, deltas, periodics, rho_fixed, rho_sched = [], [], [], [], [], []
    turn_rates: list = []
    growths: list = []
    for j, grid, periodic, maps, rho in tables:
        d = np.zeros((len(grid), *K.shape))
        worst = 0.0
        ok = np.zeros(len(grid), dtype=bool)
        for k, (A, B) in enumerate(maps):
            Kq = design(A, B)
            if Kq is not None:
                d[k], ok[k] = Kq - K_rest, True
        if ok.any() and not ok.all():   # no stabilising design at a pose: its neighbours' change, not the gains at rest
            d = fill_between_poses(grid, d, ok, periodic=periodic)
        for k, (A, B) in enumerate(maps):
            worst = max(worst, float(np.max(np.abs(np.linalg.eigvals(A + B @ (K + d[k]))))))
        coords.append(j)
        grids.append(grid)
        deltas.append(d)
        periodics.append(periodic)
        rho_fixed.append(rho)
        rho_sched.append(worst)
        limit = grow = None
        if periodic and rates is not None and horizon_s is not None and float(rates[j]) > 0:
            limit, grow = turning_rate_limit(robot, K, j, grid, d, float(rates[j]), rate_hz=rate_hz, timestep=timestep,
                                             horizon_s=float(horizon_s))
        turn_rates.append(limit)
        growths.append(grow)
    given = any(t is not None for t in turn_rates)
    out = GainSchedule(tuple(coords), tuple(grids), tuple(deltas), tuple(periodics), tuple(rho_fixed), tuple(rho_sched),
                       tuple(turn_rates) if given else None, tuple(growths) if given else None)
    log.info("%s: %s", robot.name, out.describe([robot.joint_names[i] for i in robot.actuated_index]))
    _SCHEDULES[key] = out
    return out


def _turn(grid: np.ndarray, maps: list, rate: float, dt: float) -> tuple[np.ndarray, list]:
    """One steady turn at ``rate`` (rad/s ≠ 0) in ticks of ``dt`` over a periodic pose ``grid`` [−π, π] with tick maps
    ``maps`` [(A, B)] there: ``(poses (N,), [(A_k, B_k)])``, the maps linear between the grid poses."""
    N = max(2, int(round(2 * math.pi / (abs(rate) * dt))))
    poses = (-math.pi + rate * dt * np.arange(N) + math.pi) % (2 * math.pi) - math.pi
    ticks = []
    for q in poses:
        k, w = _bracket(grid, float(q))
        ticks.append(((1 - w) * maps[k][0] + w * maps[k + 1][0], (1 - w) * maps[k][1] + w * maps[k + 1][1]))
    return poses, ticks


def _turn_growth(ticks: list, gains: list, dt: float) -> float:
    """The fastest growth (1/s) of x_{k+1} = (A_k + B_k K_k) x_k over a turn: log ρ(Π_k (A_k + B_k K_k)) / (N dt), the
    Floquet exponent of the periodic loop."""
    Phi = np.eye(ticks[0][0].shape[0])
    for (A, B), Kk in zip(ticks, gains):
        Phi = (A + B @ Kk) @ Phi
    rho = float(np.max(np.abs(np.linalg.eigvals(Phi))))
    return math.log(max(rho, 1e-300)) / (len(ticks) * dt)


def turning_rate_limit(robot: MujocoRobot, K: np.ndarray, j: int, grid: np.ndarray, d: np.ndarray, rate_max: float, *,
                       rate_hz: float, timestep: float | None, horizon_s: float, levels: int = 12,
                       refine: int = 4) -> tuple[float, float]:
    """How fast an unlimited hinge j may turn under the gains ``K (nu, 2n)`` scheduled over its pose (``d (points, nu,
    2n)`` on the periodic ``grid``, :func:`pose_gain_schedule`): ``(Ω_hold, growth)``.

    Turning steadily at Ω the robot keeps its pole upright (a motion it can keep); the tick map is linearised at each
    grid pose moving at Ω (:func:`linearize`, ``at_rate``) and the loop x_{k+1} = (A_k + B_k K(ψ_k)) x_k over a whole
    turn ψ_k = ψ_0 + Ω k/rate grows at its Floquet exponent (:func:`_turn_growth`).  Ω_hold is the largest rate (both
    directions, from ±rate_max·i/levels, then ``refine`` bisections) up to which no turn grows faster than 1/horizon_s
    (e-fold within a trial: a neutral mode, a yaw without position feedback, is not growth), ``rate_max`` where none
    does; ``growth`` the fastest exponent (1/s) over the levels."""
    dt = 1.0 / rate_hz

    def growth(om: float) -> float:
        maps = []
        for q in grid:
            at = np.zeros(robot.m)
            at[j] = q
            rate = np.zeros(robot.m)
            rate[j] = om
            A, B, _, _ = linearize(robot, rate_hz=rate_hz, timestep=timestep, at=at, at_rate=rate)
            maps.append((A, B))
        poses, ticks = _turn(grid, maps, om, dt)
        gains = []
        for q in poses:
            k, w = _bracket(grid, float(q))
            gains.append(K + (1 - w) * d[k] + w * d[k + 1])
        return _turn_growth(ticks, gains, dt)

    def worst(om: float) -> float:
        return max(growth(om), growth(-om))

    omegas = rate_max * np.arange(1, levels + 1) / levels
    grows = [worst(float(om)) for om in omegas]
    fastest = max(grows)
    bad = [i for i, g in enumerate(grows) if g > 1.0 / horizon_s]
    if not bad:
        return float(rate_max), fastest
    lo = float(omegas[bad[0] - 1]) if bad[0] > 0 else 0.0
    hi = float(omegas[bad[0]])
    for _ in range(refine):
        mid = 0.5 * (lo + hi)
        if worst(mid) > 1.0 / horizon_s:
            hi = mid
        else:
            lo = mid
    return lo, fastest



def _design(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, S: np.ndarray | None) -> np.ndarray | None:
    """Discrete LQR gains ``(nu, 2n)`` in collect's convention (u = K x) of (A, B) with the weights Q, R, S: SciPy's DARE,
    or the Riccati recursion where its Schur reordering fails (:func:`riccati_iteration`); ``None`` where neither
    stabilises."""
    from scipy.linalg import solve_discrete_are

    try:
        P = solve_discrete_are(A, B, Q, R, s=S)
    except (np.linalg.LinAlgError, ValueError):   # SciPy's Schur reordering can fail at a well-posed pose
        P = riccati_iteration(A, B, Q, R, S)
        if P is None:
            return None
    return -np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A + (S.T if S is not None else 0.0))


@dataclass(frozen=True)
class TurningMaps:
    """Tick maps of the robot linearised at poses *and* rates of one actuated hinge (:func:`turning_maps`), with the
    weights of the rest design.

    Attributes:
        j: the actuated coordinate (0 … m−1).
        poses: ``(P,)`` its poses (its unit), increasing (:func:`_pose_grid`); ``periodic``: they span [−π, π] of an
            unlimited hinge.
        rates: ``(R,)`` its rates (unit/s), increasing, symmetric about 0.
        A: ``(P, R, 2n, 2n)``, B: ``(P, R, 2n, m)``: the tick maps there (:func:`linearize` with ``at``, ``at_rate``;
            B per command, ctrl = W u).
        periodic: whether the poses wrap.
        Q, R, S: the rest design's weights (:func:`discrete_lqr`; S ``None`` for its design 1).
        K_rest: ``(m, 2n)`` the gains of those weights at rest (collect's convention).
        settle_s: the rest loop's slowest time constant, −(1/rate)/ln ρ(A + B K_rest), s.
    """

    j: int
    poses: np.ndarray
    rates: np.ndarray
    A: np.ndarray
    B: np.ndarray
    periodic: bool
    Q: np.ndarray
    R: np.ndarray
    S: np.ndarray | None
    K_rest: np.ndarray
    settle_s: float


_TURNING: dict = {}


def turning_maps(robot: MujocoRobot, *, j: int, extent: float, rate_max: float, rate_hz: float, timestep: float | None,
                 design_qu: float, qu0: float, qa0: float | None, points: int = 49, levels: int = 12) -> TurningMaps:
    """:class:`TurningMaps` of actuated hinge ``j``: the poses of :func:`pose_gain_schedule`'s grid (``points`` over ±1.5
    ``extent`` within its range, or [−π, π] on an unlimited hinge reaching a half turn), 2·``levels`` + 1 rates over
    ±``rate_max`` (unit/s), and the weights of :func:`discrete_lqr`'s design (``design_qu``, ``qu0``, ``qa0``).  The
    pole's plane turning at q̇_j brings Coriolis and centrifugal terms into the maps (linear and quadratic in the rate:
    a turntable's slides see the pole's reaction turn).  Cached per robot and arguments."""
    key = (robot.name, robot.model.nq, j, float(extent), float(rate_max), float(rate_hz), timestep, float(design_qu),
           float(qu0), qa0, points, levels)
    if key in _TURNING:
        return _TURNING[key]
    m = robot.m
    grid, periodic = _pose_grid(robot, j, extent, points)
    rates = float(rate_max) * np.arange(-levels, levels + 1) / levels
    As = np.empty((len(grid), len(rates), 2 * robot.n, 2 * robot.n))
    Bs = np.empty((len(grid), len(rates), 2 * robot.n, m))
    for a, q in enumerate(grid):
        for b, om in enumerate(rates):
            at = np.zeros(m)
            at[j] = q
            rate = np.zeros(m)
            rate[j] = om
            A, B, _, _ = linearize(robot, rate_hz=rate_hz, timestep=timestep, at=at, at_rate=rate)
            As[a, b], Bs[a, b] = A, (B @ robot.actuation.W if robot.actuation.grouped else B)
    res = discrete_lqr(robot, rate_hz=rate_hz, timestep=timestep, design_qu=design_qu, qu0=qu0, qa0=qa0)
    K_rest = _design(res.A, res.B, res.Q, res.R, res.S)
    if K_rest is None:
        raise NumericalError(f"turning_maps: {robot.name}: no stabilising LQR at rest with the design's weights")
    rho = float(np.max(np.abs(np.linalg.eigvals(res.A + res.B @ K_rest))))
    settle = -1.0 / (rate_hz * math.log(min(max(rho, 1e-300), 1.0 - 1e-12)))
    out = TurningMaps(j, grid, rates, As, Bs, periodic, res.Q, res.R, res.S, K_rest, settle)
    _TURNING[key] = out
    return out


def tracking_gains(maps: TurningMaps, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """``(T, m, 2n)`` gains (collect's convention, u = K x) of the finite-horizon LQR along a known motion of the hinge
    ``maps.j``: its poses ``q (T,)`` and rates ``qd (T,)`` at the ticks, the tick maps (A_k, B_k) interpolated
    (bilinear, held at the grid's ends, periodic poses wrapped) from ``maps``, the rest design's weights, the
    recursion run backward from P = Q after the last tick:

        K_k = −(R + B_kᵀ P_{k+1} B_k)⁻¹ (B_kᵀ P_{k+1} A_k + Sᵀ),   P_k = Q + A_kᵀ P_{k+1} A_k + (A_kᵀ P_{k+1} B_k + S) K_k

    Unlike a schedule over the pose and rate, the gains at tick k anticipate the motion after it (a sweep's reversal).
    The gains far (several settling times) before the end do not depend on the start P."""
    g, r = maps.poses, maps.rates
    qq = np.asarray(q, dtype=np.float64)
    if maps.periodic:
        qq = (qq + math.pi) % (2 * math.pi) - math.pi
    qq = np.clip(qq, g[0], g[-1])
    rr = np.clip(np.asarray(qd, dtype=np.float64), r[0], r[-1])
    ki = np.clip(np.searchsorted(g, qq) - 1, 0, len(g) - 2)
    wi = ((qq - g[ki]) / (g[ki + 1] - g[ki]))[:, None, None]
    li = np.clip(np.searchsorted(r, rr) - 1, 0, len(r) - 2)
    wl = ((rr - r[li]) / (r[li + 1] - r[li]))[:, None, None]

    def at(M: np.ndarray) -> np.ndarray:
        return ((1 - wi) * ((1 - wl) * M[ki, li] + wl * M[ki, li + 1])
                + wi * ((1 - wl) * M[ki + 1, li] + wl * M[ki + 1, li + 1]))

    A, B = at(maps.A), at(maps.B)
    Q, R = maps.Q, maps.R
    S = maps.S if maps.S is not None else np.zeros(B.shape[1:])
    P = Q.copy()
    out = np.empty((len(qq), B.shape[2], A.shape[1]))
    for k in range(len(qq) - 1, -1, -1):
        Ak, Bk = A[k], B[k]
        PB = P @ Bk
        Kk = -np.linalg.solve(R + Bk.T @ PB, PB.T @ Ak + S.T)
        P = Q + Ak.T @ P @ Ak + (Ak.T @ PB + S) @ Kk
        P = 0.5 * (P + P.T)
        out[k] = Kk
    return out
