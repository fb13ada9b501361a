"""The oracle of a generated robot: its true upright, its model BEM and whether its actuators can hold it.

Computed with MuJoCo alone (never ``bemlearn.robots`` or the pipeline), so that the pipeline's derivations
can be checked against it.  Coordinates are MuJoCo's: ``qpos`` of the joints (rad for hinges whatever the
file's ``compiler angle``, m for slides), the actuated joints in actuator order, q_u the one joint no actuator
drives.

* **Upright** q_u*: known by construction (the generator writes it into the ground truth); checked here as an
  unstable equilibrium of q_u at the actuated rest pose q_a0 = ``qpos0``: the unactuated row of the static
  inverse dynamics vanishes, ∂τ_u/∂q_u = ∂²V/∂q_u² < 0 (gravity's stiffness sign, never its magnitude), and
  the potential energy V(q_a0, q_u) (``mj_energyPos``) is largest at q_u* over a grid of q_u ∈ (−π, π].
* **Model BEM** (paper eq. 9): q_u^e(q_a, q̇_a, q̈_a) is the root of the unactuated row of ``mj_inverse``,

      τ_u(q_a, q_u, q̇_a, q̇_u = 0, q̈_a, q̈_u = 0) = 0,

  found by Newton's method started at q_u* (the upright branch), with central-difference slopes.  Dry friction
  (``frictionloss``) and all constraints are disabled for the inverse: at q̇_u = 0 friction is a set, not a force,
  and the BEM of the class is that of the smooth dynamics.  Queries are arrays, shape (B, m).
* **Design region**: the actuated motions with |q_u^e − q_u*| ≤ ``bound`` (0.2 rad).  Its scales are the
  oracle's own: per actuated joint the acceleration a_i (others at rest) that moves q_u^e by ``bound``, the
  velocity a_i / ω_u (ω_u = √(|∂²V/∂q_u²| / M_uu) the upright's divergence rate), and the position span
  (the joint range, or the offset that moves q_u^e by ``bound``).  A joint whose acceleration alone never
  moves q_u^e at rest (an x-y cart's y slide under a pole that tilts in x-z, a turntable's yaw) has no such
  a_i (q_u^e within 10⁻⁶ × the bound up to the search's bracket) takes the smallest a_i over the poses with one other
  joint at k/4 of its span (k = 1 … 4; a turntable at ψ turns the y slide into the pole's plane: a_y = g tan 0.2 at
  ψ = π/2, where at rest it looked flat); one flat at all of them gets the balance's own scale, a sine at ω_u
  across its range, a_i = ω_u² × its position half span, not the search's bracket (10³ per s², which asked the
  learned BEM about 1300 m/s² and 200 m/s).  No joint moves faster than v_tip, the speed at which its velocity
  alone doubles the upright's stiffness (:meth:`Oracle.stiffening_speed`; a turntable's yaw rate: its centrifugal
  forces then tip the pole as hard as gravity, v_tip ≈ ω_u for a thin rod); the flat fallback's a_i is then
  ω_u · v_tip.  Before 2026-11-28 a full-circle turntable swept ψ̇ to π ω_u ≈ 17 rad/s, where the yaw rate alone
  cut the BEM's response to the slides tenfold.
* **Holdable**: (1) *static* — along the design region, the actuated generalized forces ``mj_inverse`` demands,
  widened by each joint's ``frictionloss``, lie inside what each actuator delivers at that state:
  gear · ([gain · ctrl + bias(L, L̇)] over ``ctrlrange``, ∩ ``forcerange``) for the affine actuators of MuJoCo
  (motor, position, velocity, general with fixed gain and affine bias); (2) *closed loop* — a discrete LQR
  from ``mjd_transitionFD`` at the upright (central differences of one ``mj_step`` for RK4, which it does not take; frictionloss disabled for the linearisation only: finite differences
  at rest see dry friction stick), Bryson weights, balances the full model (friction on, controls clipped to
  ``ctrlrange`` by MuJoCo, ``forcerange`` by MuJoCo) for ``hold_s`` seconds from q_u* ± ``start_error``
  without leaving the joint ranges, and ends within 0.02 of the upright.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import scipy.linalg

from bemlearn.errors import RobotModelError

__all__ = ["Oracle", "HoldCheck", "mass_matrix", "wrap_angle"]

#: half-width of the design region (rad for a hinge q_u), issue 28
DESIGN_BOUND = 0.2
#: bracket of the acceleration search, per s² of the joint's unit; a direction that reaches it never moves the BEM
ACC_CAP = 1e3


def mass_matrix(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Dense (nv, nv) mass matrix of ``data``'s state (after ``mj_forward``), armature included (kg | kg·m²)."""
    M = np.zeros((model.nv, model.nv))
    try:
        mujoco.mj_fullM(model, data, M)
    except TypeError:  # older MuJoCo: mj_fullM(m, dst, qM)
        mujoco.mj_fullM(model, M, data.qM)
    return M


def wrap_angle(x: np.ndarray | float) -> np.ndarray:
    """x wrapped into (−π, π] (rad)."""
    return -((np.pi - np.asarray(x, dtype=float)) % (2 * np.pi) - np.pi)


@dataclasses.dataclass
class HoldCheck:
    """Whether the actuators hold the design region; ``reason`` says why not (or how it holds)."""

    holdable: bool
    reason: str
    static_ratio: float  # largest demanded / deliverable generalized force along the design region
    static_worst: str  # the actuator and state of that ratio
    lqr_ok: bool
    lqr_reason: str
    lqr_peak_ctrl_ratio: float  # largest |ctrl − mid| / half-width of ctrlrange seen in the balancing simulation
    lqr_r_scale: float  # R scale of the LQR that balanced (nan when none did)

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def _transition_fd_rk4(m: mujoco.MjModel, d: mujoco.MjData, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Central differences of one ``mj_step`` (RK4, which ``mjd_transitionFD`` does not take) in (qpos, qvel, ctrl)
    at ``d``'s state; hinge/slide joints only (qpos is a vector space).  Returns A (2nv × 2nv), B (2nv × nu)."""
    nv, nu = m.nv, m.nu
    x0 = np.concatenate([d.qpos, d.qvel])
    u0 = d.ctrl.copy()
    w = mujoco.MjData(m)

    def step(x, u):
        w.time = 0.0
        w.qpos[:], w.qvel[:], w.ctrl[:] = x[:nv], x[nv:], u
        w.act[:] = 0.0
        mujoco.mj_step(m, w)
        return np.concatenate([w.qpos, w.qvel])

    A = np.zeros((2 * nv, 2 * nv))
    B = np.zeros((2 * nv, nu))
    for i in range(2 * nv):
        e = np.zeros(2 * nv)
        e[i] = eps
        A[:, i] = (step(x0 + e, u0) - step(x0 - e, u0)) / (2 * eps)
    for i in range(nu):
        e = np.zeros(nu)
        e[i] = eps
        B[:, i] = (step(x0, u0 + e) - step(x0, u0 - e)) / (2 * eps)
    return A, B


class Oracle:
    """MuJoCo-only ground truth of one robot (module docstring).

    Args:
        xml: the MJCF text.
        qu_upright: q_u* by construction (rad; ``None``: found as the potential-energy maximum at q_a0).
    """

    def __init__(self, xml: str, qu_upright: float | None = None):
        self.xml = xml
        self.model = mujoco.MjModel.from_xml_string(xml)
        m = self.model
        if m.nq != m.nv or np.any((m.jnt_type != int(mujoco.mjtJoint.mjJNT_SLIDE)) & (m.jnt_type != int(mujoco.mjtJoint.mjJNT_HINGE))):
            raise RobotModelError("oracle: only hinge and slide joints are supported")
        act_dofs = []
        for i in range(m.nu):
            if int(m.actuator_trntype[i]) != int(mujoco.mjtTrn.mjTRN_JOINT):
                raise RobotModelError(f"oracle: actuator {i} does not drive a joint")
            act_dofs.append(int(m.jnt_dofadr[m.actuator_trnid[i, 0]]))
        self.act_dofs = np.array(act_dofs, dtype=int)
        un = sorted(set(range(m.nv)) - set(act_dofs))
        if len(un) != 1 or len(set(act_dofs)) != m.nu:
            raise RobotModelError(f"oracle: expected exactly one unactuated joint and one actuator per actuated joint, got {un}")
        self.u = un[0]
        self.m = m.nu
        self.qa0 = m.qpos0[self.act_dofs].copy()
        # the smooth model of the inverse and the linearisation: no dry friction, no constraints
        self.smooth = mujoco.MjModel.from_xml_string(xml)
        self.smooth.dof_frictionloss[:] = 0.0
        self.smooth.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
        self._d = mujoco.MjData(self.smooth)
        em = mujoco.MjModel.from_xml_string(xml)
        em.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_ENERGY)
        self._energy = (em, mujoco.MjData(em))
        self.qu_star = float(qu_upright) if qu_upright is not None else self._energy_argmax()
        self._scales: dict | None = None

    # ---- inverse dynamics -----------------------------------------------------------------------------
    def inverse(self, qa: np.ndarray, qu: float, qda: np.ndarray, qdda: np.ndarray) -> np.ndarray:
        """τ = M q̈ + c − τ_passive of the smooth model at (q_a, q_u, q̇_a, q̇_u = 0, q̈_a, q̈_u = 0); (nv,)."""
        d = self._d
        d.qpos[:] = 0.0
        d.qvel[:] = 0.0
        d.qacc[:] = 0.0
        d.qpos[self.act_dofs] = qa
        d.qpos[self.u] = qu
        d.qvel[self.act_dofs] = qda
        d.qacc[self.act_dofs] = qdda
        mujoco.mj_inverse(self.smooth, d)
        return d.qfrc_inverse.copy()

    def _tau_u(self, qa, qu, qda, qdda) -> float:
        return float(self.inverse(qa, qu, qda, qdda)[self.u])

    def stiffness(self, qa: np.ndarray | None = None, qu: float | None = None, qda: np.ndarray | None = None) -> float:
        """∂τ_u/∂q_u (N·m/rad) at rest = ∂²V/∂q_u²; negative at an unstable (upright) equilibrium.  With actuated
        velocities ``qda`` (q̈ = 0) it includes the velocity forces' share (a turntable's centrifugal tipping)."""
        qa = self.qa0 if qa is None else qa
        qu = self.qu_star if qu is None else qu
        h = 1e-5
        z = np.zeros(self.m)
        qd = z if qda is None else np.asarray(qda, dtype=float)
        return (self._tau_u(qa, qu + h, qd, z) - self._tau_u(qa, qu - h, qd, z)) / (2 * h)

    def stiffening_speed(self, j: int) -> float:
        """The speed of actuated joint ``j`` alone (rad/s | m/s) at which the upright's stiffness (:meth:`stiffness`)
        has doubled — its velocity forces tip the pole as hard as gravity — by bisection on a doubling bracket up to
        ``ACC_CAP``; ``inf`` if it never does (a slide's velocity does not change the balance)."""
        k0 = self.stiffness()

        def doubled(v: float) -> bool:
            e = np.zeros(self.m)
            e[j] = v
            return abs(self.stiffness(qda=e) - k0) >= abs(k0)

        v = 1e-3
        while v < ACC_CAP and not doubled(v):
            v *= 2.0
        if v >= ACC_CAP:
            return math.inf
        lo, hi = v / 2.0, v
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if doubled(mid) else (mid, hi)
        return float(hi)

    def potential(self, qa: np.ndarray, qu: float) -> float:
        """Gravitational potential energy V(q_a, q_u) (J), MuJoCo's ``mj_energyPos``."""
        m, d = self._energy
        d.qpos[self.act_dofs] = qa
        d.qpos[self.u] = qu
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_energyPos(m, d)
        return float(d.energy[0])

    def _energy_argmax(self) -> float:
        grid = np.linspace(-np.pi, np.pi, 721)[1:]
        v = np.array([self.potential(self.qa0, q) for q in grid])
        q = float(grid[int(np.argmax(v))])
        for _ in range(50):  # Newton on τ_u at rest from the grid's best point
            z = np.zeros(self.m)
            f = self._tau_u(self.qa0, q, z, z)
            k = self.stiffness(self.qa0, q)
            if k == 0:
                break
            step = f / k
            q -= step
            if abs(step) < 1e-13:
                break
        return float(wrap_angle(q))

    def check_upright(self) -> dict:
        """The checks of the module docstring on q_u*: residual, stiffness sign, energy maximum."""
        z = np.zeros(self.m)
        res = self._tau_u(self.qa0, self.qu_star, z, z)
        k = self.stiffness()
        grid = np.linspace(-np.pi, np.pi, 721)[1:]
        v = np.array([self.potential(self.qa0, q) for q in grid])
        v_star = self.potential(self.qa0, self.qu_star)
        return {"residual": res, "stiffness": k, "unstable": bool(k < 0),
                "energy_max": bool(v_star >= v.max() - 1e-9 * max(1.0, abs(v.max()))),
                "ok": bool(abs(res) < 1e-8 * max(1.0, abs(k)) and k < 0 and v_star >= v.max() - 1e-9 * max(1.0, abs(v.max())))}

    # ---- the BEM ----------------------------------------------------------------------------------------
    def bem(self, qa: np.ndarray, qda: np.ndarray, qdda: np.ndarray, *, tol: float = 1e-11, max_iter: int = 60) -> np.ndarray:
        """q_u^e at each query (eq. 9), Newton from q_u* on the unactuated row of ``mj_inverse``.

        Args:
            qa, qda, qdda: (B, m) actuated positions (rad | m), velocities (/s), accelerations (/s²).
        Returns:
            (B,) q_u^e (rad), NaN where Newton leaves |q_u − q_u*| < π/2 or does not converge.
        """
        qa, qda, qdda = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (qa, qda, qdda))
        out = np.full(qa.shape[0], np.nan)
        h = 1e-6
        for i in range(qa.shape[0]):
            q = self.qu_star
            for _ in range(max_iter):
                f = self._tau_u(qa[i], q, qda[i], qdda[i])
                k = (self._tau_u(qa[i], q + h, qda[i], qdda[i]) - self._tau_u(qa[i], q - h, qda[i], qdda[i])) / (2 * h)
                if not np.isfinite(k) or k == 0:
                    break
                step = float(np.clip(f / k, -0.2, 0.2))
                q -= step
                if abs(q - self.qu_star) > np.pi / 2:
                    break
                if abs(step) < tol:
                    out[i] = q
                    break
        return out

    # ---- the design region -----------------------------------------------------------------------------
    def scales(self) -> dict:
        """Per actuated joint: acceleration, velocity and position spans of the design region (module docstring)."""
        if self._scales is not None:
            return self._scales
        z = np.zeros(self.m)
        k = abs(self.stiffness())
        self._d.qpos[self.act_dofs] = self.qa0
        self._d.qpos[self.u] = self.qu_star
        mujoco.mj_forward(self.smooth, self._d)
        M = mass_matrix(self.smooth, self._d)
        omega = math.sqrt(k / M[self.u, self.u])
        acc, vel, pos = [], [], []
        for j in range(self.m):
            e = np.zeros(self.m)
            e[j] = 1.0
            jid = self.smooth.dof_jntid[self.act_dofs[j]]
            lo, hi = (self.smooth.jnt_range[jid] if self.smooth.jnt_limited[jid] else (-np.inf, np.inf))
            p = self._reach(lambda s, e=e: (self.qa0 + s * e, z, z), np.pi if self.smooth.jnt_type[jid] == int(mujoco.mjtJoint.mjJNT_HINGE) else 10.0)
            lo_j = max(lo, self.qa0[j] - p) if np.isfinite(lo) else self.qa0[j] - p
            hi_j = min(hi, self.qa0[j] + p) if np.isfinite(hi) else self.qa0[j] + p
            if np.isfinite(lo) and np.isfinite(hi):  # keep clear of the stops by a tenth of the range
                margin = 0.1 * (hi - lo)
                lo_j, hi_j = max(lo_j, lo + margin), min(hi_j, hi - margin)
            pos.append((float(lo_j), float(hi_j)))
        for j in range(self.m):
            e = np.zeros(self.m)
            e[j] = 1.0
            lo_j, hi_j = pos[j]
            v_tip = self.stiffening_speed(j)
            a = self._reach(lambda s, e=e: (self.qa0, z, s * e), ACC_CAP)
            if a >= ACC_CAP and self._flat(lambda s, e=e: (self.qa0, z, s * e), ACC_CAP):
                # flat at rest; where another joint's position makes it move the BEM (a turntable turning the y slide
                # into the pole's plane), the smallest reach over those poses
                a = min((self._reach(lambda s, e=e, at=at: (at, z, s * e), ACC_CAP) for at in self._poses(pos, j)), default=ACC_CAP)
                if a >= ACC_CAP:  # flat everywhere: a sine at ω_u across the span, no faster than v_tip
                    a = omega**2 * 0.5 * (hi_j - lo_j) if 0.5 * (hi_j - lo_j) * omega <= v_tip else omega * v_tip
            acc.append(a)
            v = self._reach(lambda s, e=e: (self.qa0, s * e, z), a / omega)
            vel.append(min(v, a / omega, v_tip))
        self._scales = {"omega_u": omega, "acc": acc, "vel": vel, "pos": pos}
        return self._scales

    def _poses(self, pos: list, j: int, steps: int = 4) -> list[np.ndarray]:
        """Actuated poses q_a0 with one other joint i ≠ ``j`` at k/``steps`` of the way to either end of its span
        (k = 1 … steps)."""
        out = []
        for i in range(self.m):
            if i == j:
                continue
            for k in range(1, steps + 1):
                for end in pos[i]:
                    at = self.qa0.copy()
                    at[i] = self.qa0[i] + k / steps * (end - self.qa0[i])
                    out.append(at)
        return out

    def _flat(self, query, cap: float) -> bool:
        """Whether q_u^e stays within 10⁻⁶ × the bound of q_u* all the way to ±``cap`` (the BEM does not depend on it)."""
        for sign in (1.0, -1.0):
            qa, qd, qdd = query(sign * cap)
            q = self.bem(qa[None], qd[None], qdd[None])[0]
            if not (np.isfinite(q) and abs(q - self.qu_star) <= 1e-6 * DESIGN_BOUND):
                return False
        return True

    def _reach(self, query, cap: float) -> float:
        """Smallest s ≤ cap with |q_u^e(query(s)) − q_u*| ≥ bound (bisection on a doubling bracket); cap if none."""
        def dev(s):
            worst = 0.0
            for sign in (1.0, -1.0):
                qa, qd, qdd = query(sign * s)
                q = self.bem(qa[None], qd[None], qdd[None])[0]
                worst = max(worst, abs(q - self.qu_star) if np.isfinite(q) else np.inf)
            return worst
        s = min(1e-3, cap)
        while s < cap and dev(s) < DESIGN_BOUND:
            s *= 2.0
        if s >= cap and dev(cap) < DESIGN_BOUND:
            return float(cap)
        lo, hi = s / 2.0, min(s, cap)
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            if dev(mid) < DESIGN_BOUND:
                lo = mid
            else:
                hi = mid
        return float(lo)

    def design_queries(self, n: int, seed: int = 0, *, bound: float = DESIGN_BOUND) -> dict:
        """``n`` actuated motions drawn uniformly in the oracle's box (:meth:`scales`), kept where
        |q_u^e − q_u*| ≤ ``bound``; returns ``{"qa", "qda", "qdda"}`` (n', m) and ``"bem"`` (n',)."""
        lo, hi, vel, acc = self._box()
        rng = np.random.default_rng(seed)
        got = 0
        rows = []
        for _ in range(20):
            qa = lo + (hi - lo) * rng.random((n, self.m))
            qd = vel * (2 * rng.random((n, self.m)) - 1)
            qdd = acc * (2 * rng.random((n, self.m)) - 1)
            q = self.bem(qa, qd, qdd)
            ok = np.isfinite(q) & (np.abs(q - self.qu_star) <= bound)
            rows.append((qa[ok], qd[ok], qdd[ok], q[ok]))
            got += int(ok.sum())
            if got >= n:
                break
        qa, qd, qdd, q = (np.concatenate([r[i] for r in rows])[:n] for i in range(4))
        return {"qa": qa, "qda": qd, "qdda": qdd, "bem": q}

    def clip_to_box(self, qa: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The actuated motion ``(qa, qd, qdd)`` (each (m,)) moved into the box :meth:`design_queries` draws from:
        each position into its span, each velocity within ±``vel``, each acceleration within ±1.3 ``acc``."""
        lo, hi, vel, acc = self._box()
        return np.clip(qa, lo, hi), np.clip(qd, -vel, vel), np.clip(qdd, -acc, acc)

    def _box(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The design queries' box from :meth:`scales`: ``(lo, hi)`` positions, velocity half-widths ``vel`` and
        acceleration half-widths 1.3 ``acc`` (each (m,))."""
        sc = self.scales()
        lo = np.array([p[0] for p in sc["pos"]])
        hi = np.array([p[1] for p in sc["pos"]])
        return lo, hi, np.asarray(sc["vel"], dtype=np.float64), 1.3 * np.asarray(sc["acc"], dtype=np.float64)

    # ---- holding ------------------------------------------------------------------------------------------
    def deliverable(self, i: int, L: float, Ldot: float) -> tuple[float, float]:
        """Generalized-force interval actuator ``i`` delivers at actuator length ``L``, velocity ``Ldot``
        (affine actuators: force = gain·ctrl + b0 + b1·L + b2·L̇, clipped to forcerange; times gear)."""
        m = self.model
        if int(m.actuator_gaintype[i]) != int(mujoco.mjtGain.mjGAIN_FIXED) or int(m.actuator_biastype[i]) not in (
                int(mujoco.mjtBias.mjBIAS_NONE), int(mujoco.mjtBias.mjBIAS_AFFINE)) or int(m.actuator_dyntype[i]) != int(mujoco.mjtDyn.mjDYN_NONE):
            raise RobotModelError(f"oracle: actuator {i} is not an affine actuator without dynamics")
        g = m.actuator_gainprm[i, 0]
        b = m.actuator_biasprm[i, :3] if int(m.actuator_biastype[i]) == int(mujoco.mjtBias.mjBIAS_AFFINE) else np.zeros(3)
        c = m.actuator_ctrlrange[i] if m.actuator_ctrllimited[i] else np.array([-np.inf, np.inf])
        bias = b[0] + b[1] * L + b[2] * Ldot
        f = np.sort([g * c[0] + bias, g * c[1] + bias])
        if m.actuator_forcelimited[i]:
            f = np.clip(f, *m.actuator_forcerange[i])
        gear = m.actuator_gear[i, 0]
        return tuple(sorted((float(gear * f[0]), float(gear * f[1]))))  # type: ignore[return-value]

    def static_demand(self, q: dict) -> tuple[float, str]:
        """Largest demanded / deliverable ratio over the design queries ``q`` (:meth:`design_queries`)."""
        worst, where = 0.0, ""
        fl = self.model.dof_frictionloss[self.act_dofs]
        for k in range(q["qa"].shape[0]):
            tau = self.inverse(q["qa"][k], q["bem"][k], q["qda"][k], q["qdda"][k])[self.act_dofs]
            for i in range(self.m):
                gear = self.model.actuator_gear[i, 0]
                lo, hi = self.deliverable(i, gear * q["qa"][k, i], gear * q["qda"][k, i])
                need_hi, need_lo = tau[i] + fl[i], tau[i] - fl[i]
                r = max(need_hi / hi if need_hi > 0 and hi > 0 else (np.inf if need_hi > 0 else 0.0),
                        need_lo / lo if need_lo < 0 and lo < 0 else (np.inf if need_lo < 0 else 0.0))
                if r > worst:
                    worst, where = float(r), (f"actuator {mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_ACTUATOR, i)!r}: "
                                              f"{tau[i]:+.3g} ± {fl[i]:.3g} demanded, [{lo:.3g}, {hi:.3g}] deliverable at "
                                              f"q_a={np.round(q['qa'][k], 3).tolist()}, q̇_a={np.round(q['qda'][k], 3).tolist()}")
        return worst, where

    def rest_control(self) -> np.ndarray:
        """Controls that hold the upright at rest: gear·(gain·u + bias(L, 0)) = τ_a(q_a0, q_u*)."""
        z = np.zeros(self.m)
        tau = self.inverse(self.qa0, self.qu_star, z, z)[self.act_dofs]
        m = self.model
        u = np.zeros(self.m)
        for i in range(self.m):
            gear = m.actuator_gear[i, 0]
            b = m.actuator_biasprm[i, :3] if int(m.actuator_biastype[i]) == int(mujoco.mjtBias.mjBIAS_AFFINE) else np.zeros(3)
            u[i] = (tau[i] / gear - (b[0] + b[1] * gear * self.qa0[i])) / m.actuator_gainprm[i, 0]
        return u

    def lqr(self, r_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Discrete LQR gain K (nu × 2nv) of ``mjd_transitionFD`` at the upright, frictionloss off; returns (K, u0)."""
        m = self.smooth
        d = mujoco.MjData(m)
        d.qpos[self.act_dofs] = self.qa0
        d.qpos[self.u] = self.qu_star
        u0 = self.rest_control()
        d.ctrl[:] = u0
        mujoco.mj_forward(m, d)
        nx = 2 * m.nv
        A = np.zeros((nx, nx))
        B = np.zeros((nx, m.nu))
        if int(m.opt.integrator) == int(mujoco.mjtIntegrator.mjINT_RK4):  # mjd_transitionFD has no RK4
            A, B = _transition_fd_rk4(m, d)
        else:
            mujoco.mjd_transitionFD(m, d, 1e-6, 1, A, B, None, None)
        sc = self.scales()
        qw = np.zeros(m.nv)
        vw = np.zeros(m.nv)
        qw[self.u] = 1.0 / 0.1**2
        vw[self.u] = 1.0 / (sc["omega_u"] * 0.1) ** 2
        for j, dof in enumerate(self.act_dofs):
            lo, hi = sc["pos"][j]
            span = max(0.5 * (hi - lo), 1e-3)
            jid = m.dof_jntid[dof]
            qw[dof] = 1.0 / span**2 if m.jnt_limited[jid] else 1.0 / (10 * span) ** 2
            vw[dof] = 1.0 / max(sc["vel"][j], 1e-3) ** 2
        Q = np.diag(np.concatenate([qw, vw]))
        half = np.array([0.5 * (self.model.actuator_ctrlrange[i, 1] - self.model.actuator_ctrlrange[i, 0])
                         if self.model.actuator_ctrllimited[i] else 1.0 for i in range(m.nu)])
        R = np.diag(r_scale / half**2)
        P = scipy.linalg.solve_discrete_are(A, B, Q, R)
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        return K, u0

    def simulate_hold(self, K: np.ndarray, u0: np.ndarray, *, start_error: float, hold_s: float) -> tuple[bool, str, float]:
        """The full model (friction on) under u = u0 − K Δx from q_u* + ``start_error``; (ok, reason, peak ctrl ratio)."""
        m = self.model
        d = mujoco.MjData(m)
        d.qpos[self.act_dofs] = self.qa0
        d.qpos[self.u] = self.qu_star + start_error
        x0 = np.concatenate([self.qa0_full(), np.zeros(m.nv)])
        lo_c, hi_c = m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1]
        mid = np.where(m.actuator_ctrllimited, 0.5 * (lo_c + hi_c), 0.0)
        half = np.where(m.actuator_ctrllimited, 0.5 * (hi_c - lo_c), np.inf)
        peak = 0.0
        n = int(round(hold_s / m.opt.timestep))
        for _ in range(n):
            dx = np.concatenate([d.qpos - x0[: m.nv], d.qvel])
            u = u0 - K @ dx
            peak = max(peak, float(np.max(np.abs(u - mid) / half)))
            d.ctrl[:] = u
            mujoco.mj_step(m, d)
            if not np.all(np.isfinite(d.qpos)):
                return False, "diverged (non-finite state)", peak
            if abs(d.qpos[self.u] - self.qu_star) > 0.6:
                return False, f"fell: |q_u − q_u*| > 0.6 at t = {d.time:.2f} s", peak
            for dof in self.act_dofs:
                jid = m.dof_jntid[dof]
                if m.jnt_limited[jid]:
                    lo, hi = m.jnt_range[jid]
                    if d.qpos[dof] < lo + 1e-3 * (hi - lo) or d.qpos[dof] > hi - 1e-3 * (hi - lo):
                        return False, f"hit the stop of joint {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, jid)!r} at t = {d.time:.2f} s", peak
        err = abs(d.qpos[self.u] - self.qu_star)
        if err > 0.02:
            return False, f"not settled: |q_u − q_u*| = {err:.3f} after {hold_s:g} s", peak
        return True, f"balanced {hold_s:g} s from {start_error:+g}, end error {err:.2e}", peak

    def qa0_full(self) -> np.ndarray:
        q = np.zeros(self.model.nq)
        q[self.act_dofs] = self.qa0
        q[self.u] = self.qu_star
        return q

    def hold_check(self, *, n_queries: int = 400, start_error: float = 0.05, hold_s: float = 5.0, seed: int = 0) -> HoldCheck:
        """Static demand along the design region and the LQR balance test (module docstring)."""
        q = self.design_queries(n_queries, seed=seed)
        ratio, worst = self.static_demand(q) if q["qa"].shape[0] else (np.inf, "no design-region query found")
        lqr_ok, lqr_reason, peak, used = False, "", float("nan"), float("nan")
        reasons = []
        for r_scale in (1.0, 10.0, 0.1, 100.0):
            try:
                K, u0 = self.lqr(r_scale)
            except (np.linalg.LinAlgError, ValueError) as exc:
                reasons.append(f"R×{r_scale:g}: DARE failed ({exc})")
                continue
            results = [self.simulate_hold(K, u0, start_error=s * start_error, hold_s=hold_s) for s in (1.0, -1.0)]
            if all(r[0] for r in results):
                lqr_ok, lqr_reason, peak, used = True, results[0][1], max(r[2] for r in results), r_scale
                break
            bad = next(r for r in results if not r[0])
            reasons.append(f"R×{r_scale:g}: {bad[1]} (peak ctrl {max(r[2] for r in results):.2g}× half-range)")
        if not lqr_ok:
            lqr_reason = "; ".join(reasons)
        static_ok = ratio <= 1.0
        if static_ok and lqr_ok:
            reason = f"holds: design region needs ≤ {ratio:.2f}× the deliverable force; LQR {lqr_reason}"
        elif not static_ok:
            reason = f"cannot hold the design region: {ratio:.2f}× the deliverable force ({worst})"
        else:
            reason = f"no LQR within the limits balances it: {lqr_reason}"
        return HoldCheck(holdable=bool(static_ok and lqr_ok), reason=reason, static_ratio=float(ratio), static_worst=worst,
                         lqr_ok=lqr_ok, lqr_reason=lqr_reason, lqr_peak_ctrl_ratio=peak, lqr_r_scale=used)
