"""One command per actuated coordinate: the actuators that drive the same coordinate commanded together.

The reduced input matrix B = Sᵀ B_j (``(n, nu)``, :attr:`MujocoRobot.input_matrix_np`) maps the actuator
forces f to generalized forces; its actuated rows B_a (``(m, nu)``) say which coordinate each actuator drives.
The excitation, the LQR and the EIC give one command per actuated coordinate (u has m entries).

* nu = m: the commands are the actuators' own ``ctrl`` (W = I), whatever B_a (a declared coordinate map may
  spread one actuator over several coordinates; B_a is then inverted as a whole).
* nu > m: the actuators must form a *grouping*: each actuator drives exactly one actuated coordinate c (one
  non-zero entry in its column of B_a) and each coordinate has at least one actuator, the group I_c.  The group
  is one virtual actuator with command v_c, in the ``ctrl`` units of its first actuator k_c:

      f_{I_c} = b_c⁺ τ_c = b_cᵀ τ_c / |b_c|²   (b_c = B_a[c, I_c]: the least-norm split of a coordinate force)   (A1)
      ctrl_i = W_ic v_c,   W_ic = (b_ci / g_i) / (b_{c k_c} / g_{k_c})                                      (A2)

  with g_i = ∂f_i/∂ctrl_i the actuator's gain at rest: the ``ctrl`` part of each member's force is then its
  least-norm share of the coordinate force (two like wheel motors on opposite hinge axes: W = (1, −1)).
  The limits of the group are what its members deliver together: |v_c| ≤ min_i ctrl_limit_i / |W_ic| (the most
  restrictive member binds), and each member's force limit on its own share.
* otherwise (an actuator on several coordinates with nu > m, or fewer actuators than coordinates): refused,
  with a one-line reason (:func:`actuator_groups`).

A servo held over a control tick (:func:`servo_relaxation`, :func:`hold_factors`).  An actuator whose force falls
with its joint's rate (affine bias b2 < 0: a velocity servo, a motor's back-EMF) drives its coordinate a toward
its set point at the rate κ = −(D⁻¹)_aa Σ_k B_ak b2_k g_k (T⁻¹)_{j(k) a} (1/s: the coordinate's own mobility at
upright, the other coordinates free, times the group's velocity feedback).  Held over a tick Δt its force decays
as e^{−κt}: the tick's mean force is the first instant's divided by

    φ = κΔt / (1 − e^{−κΔt})   (φ → 1 for a slow servo, κΔt for one far faster than the tick)           (A3)

so a command meant to deliver a mean force f over the tick starts at φ f (:class:`MujocoActuatorInverse` with
``hold_s``), and a limit is on the mean force (a servo faster than the tick that hits its ``forcerange`` or its
wheel's grip reaches its set point later in the same tick: the impulse it can deliver is the limit × Δt).

When the correction is made (:func:`held_servo_factors`).  A command computed for the force now and held over the
tick delivers the mean force f/φ: the loop through that actuator (the EIC's actuated feedback and its feedforward)
runs at gain 1/φ.  A loop with the classical gain margin of 2 (6 dB) stays stable and keeps its form down to half
its gain, and the EIC's gains are moreover checked on MuJoCo's own tick map, which holds the servo's relaxation
(:func:`~bemlearn.control.eic_linear.eic_tick_loop`, :func:`~bemlearn.pipeline.derive.eic_recovery`).  So the
held force is corrected only where it would deliver less than half the force asked for,

    φ ≥ 2   ⇔   κΔt ≥ 1.594   (the servo's time constant 1/κ at most 0.63 Δt: it settles within the tick)      (A5)

and an actuator below it keeps the force-now inverse and its limits unchanged.  Measured (control rate derived by
``derive.control_rate``): the 64 seed-0 family robots reach φ = 1.35 at most with one actuated coordinate
(a velocity-servo pendubot, κΔt = 0.64) and 1.82 on any (a two-link arm's velocity servo, κΔt = 1.35), none
selected; the public two-wheeled ``balance_robot``'s wheel velocity servos have κΔt = 30.3 (φ = 30.3).

Force limits (:func:`force_limits`): an actuator's ``forcerange``, the ``actuatorfrcrange`` of the joint it
drives (MuJoCo clamps the joint's actuator force gear·f to it; counted as |f| ≤ range/|gear| when the actuator
is the joint's only one), and for a wheel its grip μ N r_eff / |gear| (beyond it the wheel slips and the rolling
model no longer holds: :attr:`~bemlearn.robots.mujoco_robot.MujocoRobot.traction_limits`).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

__all__ = ["HOLD_CORRECTION_MIN", "ActuatorGroups", "actuator_groups", "force_limits", "held_servo_factors", "hold_factors",
           "servo_relaxation"]

#: φ (A3) from which a held servo's mean force is corrected (A5): the uncorrected loop would run below half its gain.
HOLD_CORRECTION_MIN = 2.0

#: Entries of B_a below this fraction of its largest are zero.
_ZERO = 1e-12


@dataclass(frozen=True)
class ActuatorGroups:
    """The map from one command per actuated coordinate to the actuators' ``ctrl`` (module docstring).

    Attributes:
        W: ``(nu, m)`` ctrl = W v (A2); the identity when nu = m.
        force_split: ``(nu, m)`` f = B_a⁺ τ_a, the least-norm actuator forces of actuated generalized forces (A1).
        members: per command, the actuator indices it drives (its first is the one whose ``ctrl`` it is).
        names: ``(m,)`` a name per command: the actuator's own, or its members' joined by ``+``.
        grouped: True when some command drives more than one actuator.
        actuator_names: ``(nu,)`` the actuators' names.
    """

    W: np.ndarray
    force_split: np.ndarray
    members: tuple[tuple[int, ...], ...]
    names: tuple[str, ...]
    grouped: bool
    actuator_names: tuple[str, ...]

    def ctrl(self, v: np.ndarray) -> np.ndarray:
        """``v (m,)`` commands → ``ctrl (nu,)`` (A2); ``v`` itself with one actuator per coordinate (W = I)."""
        return self.W @ v if self.grouped else np.asarray(v, dtype=np.float64)

    def command_of(self, ctrl: np.ndarray) -> np.ndarray:
        """``ctrl (nu,)`` → ``(m,)`` the command each group's first actuator received (the inverse of :meth:`ctrl`
        on its range)."""
        return np.asarray(ctrl, dtype=np.float64)[[g[0] for g in self.members]]

    def command_limits(self, ctrl_limit: np.ndarray) -> np.ndarray:
        """``(m,)`` |v_c| ≤ min_{i ∈ I_c} ctrl_limit_i / |W_ic| for per-actuator limits ``ctrl_limit (nu,)``
        (``inf`` where unlimited): the most restrictive member binds."""
        with np.errstate(divide="ignore"):
            per = np.where(np.abs(self.W) > 0, np.asarray(ctrl_limit, dtype=np.float64)[:, None] / np.abs(self.W), np.inf)
        return per.min(axis=0)

    def describe(self, coordinate_names: tuple[str, ...]) -> str:
        """``wheel ← motor_l (×1) + motor_r (×−1)`` per grouped coordinate; ``""`` when nothing is grouped."""
        if not self.grouped:
            return ""
        parts = []
        for c, (members, cname) in enumerate(zip(self.members, coordinate_names)):
            parts.append(f"{cname} ← " + " + ".join(f"{self.actuator_names[i]} (×{self.W[i, c]:.4g})" for i in members))
        return ("one command per actuated coordinate, in its first actuator's ctrl units (each member's least-norm share): "
                + "; ".join(parts))


def actuator_groups(Ba: np.ndarray, gains: np.ndarray, names: tuple[str, ...],
                    coordinate_names: tuple[str, ...]) -> ActuatorGroups | str:
    """The :class:`ActuatorGroups` of the actuated input rows ``Ba (m, nu)`` (module docstring), or why there is none.

    Args:
        Ba: ``(m, nu)`` the actuated rows of B (generalized force per unit actuator force).
        gains: ``(nu,)`` g_i = ∂f_i/∂ctrl_i at rest (``gainprm[0]``).
        names: ``(nu,)`` actuator names.  coordinate_names: ``(m,)`` the actuated coordinates' names.

    Returns:
        the groups, or a one-line reason naming the actuators and coordinates.
    """
    Ba = np.asarray(Ba, dtype=np.float64)
    m, nu = Ba.shape
    split = np.linalg.pinv(Ba)
    if nu == m:
        return ActuatorGroups(np.eye(m), split, tuple((i,) for i in range(m)), tuple(names), False, tuple(names))
    if nu < m:
        return (f"{nu} actuators {list(names)} drive {m} actuated coordinates {list(coordinate_names)}; "
                "every actuated coordinate needs its own actuator")
    nz = np.abs(Ba) > _ZERO * max(float(np.abs(Ba).max(initial=0.0)), 1e-300)
    for i in range(nu):
        if int(nz[:, i].sum()) != 1:
            on = [coordinate_names[c] for c in np.flatnonzero(nz[:, i])]
            return (f"actuator {names[i]!r} drives {len(on)} actuated coordinates {on}; with {nu} actuators for {m} coordinates "
                    "each actuator must drive exactly one (the actuators of a coordinate are commanded together)")
    W = np.zeros((nu, m))
    members = []
    for c in range(m):
        group = tuple(int(i) for i in np.flatnonzero(nz[c]))
        if not group:
            return f"no actuator drives the actuated coordinate {coordinate_names[c]!r}"
        dead = [names[i] for i in group if not abs(gains[i]) > 0]
        if dead:
            return f"actuators {dead} have zero gain (gainprm[0] = 0): their ctrl moves nothing"
        share = np.array([split[i, c] / gains[i] for i in group])
        W[list(group), c] = share / share[0]
        members.append(group)
    out_names = tuple("+".join(names[i] for i in g) for g in members)
    return ActuatorGroups(W, split, tuple(members), out_names, any(len(g) > 1 for g in members), tuple(names))


def force_limits(model: mujoco.MjModel, traction: np.ndarray | None = None) -> np.ndarray:
    """``(nu,)`` |f_i| limits of the actuators, N·m or N at the actuator (``inf`` where none): ``forcerange``,
    for the only actuator on its joint the joint's ``actuatorfrcrange`` / |gear| (module docstring), and
    ``traction (nu,)`` when given (a wheel's grip, :attr:`MujocoRobot.traction_limits`)."""
    out = np.where(model.actuator_forcelimited.astype(bool),
                   np.maximum(np.abs(model.actuator_forcerange[:, 0]), np.abs(model.actuator_forcerange[:, 1])), np.inf)
    joint_of = [int(model.actuator_trnid[i, 0]) for i in range(model.nu)]
    limited = np.asarray(getattr(model, "jnt_actfrclimited", np.zeros(model.njnt)), dtype=bool)
    for i, j in enumerate(joint_of):
        if int(model.actuator_trntype[i]) != int(mujoco.mjtTrn.mjTRN_JOINT) or not limited[j] or joint_of.count(j) != 1:
            continue
        gear = abs(float(model.actuator_gear[i, 0]))
        if gear > 0:
            lim = max(abs(float(model.jnt_actfrcrange[j, 0])), abs(float(model.jnt_actfrcrange[j, 1])))
            out[i] = min(out[i], lim / gear)
    return out if traction is None else np.minimum(out, traction)


def servo_relaxation(robot) -> np.ndarray:
    """``(nu,)`` κ_i, 1/s: how fast actuator i's velocity feedback (affine b2 < 0) drives its coordinate to its set
    point at upright (module docstring, A3); 0 for an actuator without velocity feedback or on no single coordinate."""
    model = robot.model
    n = robot.n
    q = np.zeros(n)
    q[robot.unactuated_index] = robot.qu_nominal
    D = robot.terms(q, np.zeros(n))[0]
    mobility = np.diag(np.linalg.inv(D))
    affine = model.actuator_biastype == int(mujoco.mjtBias.mjBIAS_AFFINE)
    b2 = np.where(affine, model.actuator_biasprm[:, 2], 0.0)
    dof_col = {int(a): k for k, a in enumerate(robot._dadr)}
    B = robot.input_matrix_np
    feedback = np.zeros(n)   # ∂τ_a/∂q̇_a of each coordinate's servos
    coord = np.full(model.nu, -1)
    for i in range(model.nu):
        col = dof_col.get(int(model.jnt_dofadr[model.actuator_trnid[i, 0]]))
        on = [a for a in robot.actuated_index if abs(B[a, i]) > 0]
        if col is None or len(on) != 1:
            continue
        a = on[0]
        coord[i] = a
        feedback[a] += B[a, i] * b2[i] * float(model.actuator_gear[i, 0]) * robot.Tinv_np[col, a]
    return np.array([max(0.0, -mobility[a] * feedback[a]) if a >= 0 else 0.0 for a in coord])


def hold_factors(kappa: np.ndarray, dt: float) -> np.ndarray:
    """``(nu,)`` φ = κΔt / (1 − e^{−κΔt}) (A3) of relaxation rates ``kappa (nu,)`` (1/s) over a tick ``dt`` (s)."""
    x = np.asarray(kappa, dtype=np.float64) * float(dt)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(x > 1e-9, x / -np.expm1(-np.maximum(x, 1e-300)), 1.0 + 0.5 * x)
    return out


def held_servo_factors(robot, dt: float) -> np.ndarray | None:
    """``(nu,)`` φ_i (A3) of the actuators whose held force is corrected over a tick ``dt`` (s), φ_i ≥ 2 (A5), and 1
    for the others; ``None`` where no actuator is (the force-now inverse and limits, unchanged)."""
    phi = hold_factors(servo_relaxation(robot), dt)
    selected = phi >= HOLD_CORRECTION_MIN
    if not bool(np.any(selected)):
        return None
    return np.where(selected, phi, 1.0)
