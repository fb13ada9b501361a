"""Can the robot be balanced over the design region at all?  Checked from the model, before collecting.

Four checks, each a number with a limit, from the robot's model and the resolved config:

* **hold** — the effort to hold the BEM at the edge of the design region, |q_u^e − nominal| = d.
  The linearised BEM q_u^e ≈ s_p q_a + s_a q̈_a (:func:`~bemlearn.robots.scales.bem_slopes`) offers
  two ways per actuated coordinate j: a pose q_a,j = ±d/s_p,j at rest (within the joint range) or
  an acceleration q̈_a,j = ±d/s_a,j.  For each, with q_u at the model BEM there and q̇ = 0,
  q̈_u = 0, the actuated rows of the inverse dynamics (eq. 2a) give τ_a, MuJoCo's actuator model
  gives the ``ctrl`` (and force) it takes (:class:`~bemlearn.control.actuator_inverse.MujocoActuatorInverse`),
  and the effort is max_i |ctrl_i| / ctrl limit_i (and |f_i| / force limit_i).  The robot can hold
  the design region when for each sign some way needs an effort ≤ 1.
* **eic** — the growth rate ln(ρ)·rate (1/s) of the EIC loop as it runs, linearised at upright with the
  config's gains: sampled at the closed loop's rate, the command held over the tick, the rates from its
  velocity filter (:func:`~bemlearn.control.eic_linear.eic_tick_loop`); ≥ 0 means the closed loop of
  eq. (3), (8) cannot balance the robot near upright.  (The continuous loop with exact rates,
  :func:`~bemlearn.control.eic_linear.eic_linear_abscissa`, misses the filter's lag, which destabilises a
  stiff internal loop: a pendubot it calls stable falls in MuJoCo, docs/family.md.)
* **eic_recovery** (when ``eic`` passes) — the closed loop itself in MuJoCo with the model BEM, the sensors
  and every actuator limit, from a d/4 error of q_u at rest (:func:`~bemlearn.pipeline.derive.eic_recovery`):
  failing means the basin of the EIC at upright is smaller than the errors the robot starts from (an
  acrobot's elbow swings to its stop from a 0.05 rad error).  A robot with dry friction also passes when the
  loop holds it in the friction's stick-slip cycle around a balanced pole (q_u at its BEM, inside the design
  region, and the same loop without the friction recovering: ``derive._friction_cycle``).
* **excitation** — the peak ``ctrl`` and actuator force of the excitation LQR (``collect.gains``, when derived)
  for a d/4 error of q_u, as a multiple of the ctrlrange and forcerange (:func:`~bemlearn.control.lqr.discrete_lqr`):
  above 1 the excitation saturates and trials fall.

``hold``, ``eic`` or ``eic_recovery`` failing makes the run *unusable*: ``bemlearn run`` stops after its preflight
and writes the verdict; ``excitation`` failing makes it *degraded*.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from bemlearn.errors import ArgumentError, NumericalError, RobotModelError

if TYPE_CHECKING:
    from bemlearn.pipeline.config import PipelineConfig
    from bemlearn.robots.mujoco_robot import MujocoRobot
    from bemlearn.robots.protocol import ControlRobot

__all__ = ["FeasibilityCheck", "model_feasibility", "hold_effort"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FeasibilityCheck:
    """One model check: ``value`` against ``limit`` (passes when value ≤ limit, or < limit when ``strict``)."""

    name: str
    value: float
    limit: float
    severity: str          # "unusable" | "degraded": what a failure makes the run
    text: str              # one sentence, with the number
    strict: bool = False

    @property
    def passed(self) -> bool:
        if not np.isfinite(self.value):
            return False
        return bool(self.value < self.limit if self.strict else self.value <= self.limit)

    def to_dict(self) -> dict:
        return {"name": self.name, "value": self.value, "limit": self.limit, "strict": self.strict, "passed": self.passed,
                "severity": self.severity, "text": self.text}


def hold_effort(robot: MujocoRobot, bound: float) -> tuple[float, str]:
    """The smallest effort (multiple of the actuator limits) that holds the BEM at ±``bound``, the
    worse of the two signs, and how (module docstring); ``inf`` when no way is found."""
    from bemlearn.control.actuator_inverse import MujocoActuatorInverse
    from bemlearn.pipeline.derive import actuator_effort
    from bemlearn.robots.scales import bem_slopes, qa_half_ranges

    inv = MujocoActuatorInverse(robot)
    sp, _, sa = bem_slopes(robot)
    half = qa_half_ranges(robot)
    names = list(robot.actuated_names)
    iu, ia = robot.unactuated_index, list(robot.actuated_index)
    worst, how = 0.0, ""
    for sign in (1.0, -1.0):
        best, best_how = math.inf, "no pose or acceleration of the actuated joints moves the BEM there"
        for j in range(robot.m):
            for kind, slope in (("pose", sp[j]), ("acceleration", sa[j])):
                if not abs(slope) > 1e-9:
                    continue
                amount = sign * bound / slope
                qa = np.zeros(robot.m)
                qadd = np.zeros(robot.m)
                if kind == "pose":
                    if abs(amount) > half[j]:
                        continue
                    qa[j] = amount
                else:
                    qadd[j] = amount
                res = robot.bem(torch.from_numpy(qa[None]), torch.zeros(1, robot.m, dtype=torch.float64), torch.from_numpy(qadd[None]))
                if not bool(res.valid[0]):
                    continue
                q = np.zeros(robot.n)
                q[ia] = qa
                q[iu] = float(res.qu[0])
                qdd = np.zeros(robot.n)
                qdd[ia] = qadd
                e = actuator_effort(robot, inv, q, qdd)
                if e < best:
                    unit = "" if kind == "pose" else "/s²"
                    best, best_how = e, f"{names[j]} {kind} {amount:+.3g} {'rad' if robot.coordinate_kinds[ia[j]] == 'hinge' else 'm'}{unit}"
        if best >= worst:
            worst, how = best, best_how
    return worst, how


def model_feasibility(robot: MujocoRobot, config: PipelineConfig) -> list[FeasibilityCheck]:
    """The checks of the module docstring for ``robot`` (a MujocoRobot) and the resolved ``config``."""
    from bemlearn.pipeline.derive import design_region

    d = float(design_region(robot).value)
    out: list[FeasibilityCheck] = []
    qu_unit = "rad" if robot.coordinate_kinds[robot.unactuated_index] == "hinge" else "m"
    try:
        effort, how = hold_effort(robot, d)
        out.append(FeasibilityCheck(
            "hold", effort, 1.0, "unusable",
            f"holding {robot.unactuated_name} {d:g} {qu_unit} from its nominal value (the design region's edge) takes {effort:.2f}× the "
            f"actuator limits at best ({how})" if math.isfinite(effort) else
            f"no pose or acceleration of the actuated joints holds {robot.unactuated_name} {d:g} {qu_unit} from its nominal value"))
    except (RobotModelError, NumericalError) as exc:   # an actuator model the inverse does not cover: no verdict from it
        log.info("feasibility: hold check skipped (%s)", exc)
    gains = config.simulate.gains
    if config.simulate.rate_hz is not None and all(getattr(gains, k) is not None for k in ("kp_a", "kd_a", "kp_u", "kd_u")):
        out.extend(_eic_checks(robot, config, d, qu_unit))
    if config.collect.gains is not None and config.collect.rate_hz is not None:
        from bemlearn.control.lqr import discrete_lqr

        qa0 = config.collect.initial_qa[1] if config.collect.initial_qa is not None else None
        res = discrete_lqr(robot, rate_hz=config.collect.rate_hz, timestep=config.collect.physics_timestep, design_qu=d, qu0=d / 4, qa0=qa0)
        K = np.asarray(config.collect.gains, dtype=np.float64).reshape(res.K.shape)
        if np.allclose(K, res.K, rtol=1e-4, atol=1e-9):      # the derived gains: their peak is the LQR's
            out.append(FeasibilityCheck(
                "excitation", res.u_peak, 1.0, "degraded",
                f"the excitation LQR needs {res.u_peak:.2f}× the actuator limits (ctrlrange, forcerange) for a {d / 4:g} {qu_unit} error of "
                f"{robot.unactuated_name}" + (" (its trials will saturate and fall)" if res.u_peak > 1 else "")))
    return out


def _eic_checks(robot: MujocoRobot, config: PipelineConfig, d: float, qu_unit: str) -> list[FeasibilityCheck]:
    """``eic`` (the sampled loop's growth rate at upright) and, when it decays, ``eic_recovery`` (the loop in MuJoCo
    from a d/4 error of q_u; module docstring)."""
    from bemlearn.control.eic_linear import eic_tick_loop
    from bemlearn.pipeline.derive import RateChoice, eic_recovery

    sim = config.simulate
    assert sim.rate_hz is not None
    wc = sim.sensor.velocity_cutoff
    step = sim.physics_timestep if sim.physics_timestep is not None else float(robot.model.opt.timestep)
    rate = RateChoice(sim.rate_hz, max(1, int(round(1.0 / (sim.rate_hz * step)))), step, sim.physics_timestep is not None)
    try:
        loop = eic_tick_loop(robot, sim.gains, rate_hz=sim.rate_hz, velocity_cutoff=wc, timestep=sim.physics_timestep)
    except (RobotModelError, NumericalError, ArgumentError) as exc:   # an actuator model or rate the linearisation does not take
        log.info("feasibility: eic check skipped (%s)", exc)
        return []
    grow = -loop.decay_rate
    where = f"sampled at {sim.rate_hz:g} Hz with its velocity filter (ω_c = {wc:.3g} rad/s)"
    out = [FeasibilityCheck(
        "eic", grow, 0.0, "unusable",
        f"the EIC loop (eq. 3, 8) with the gains {_gains(sim.gains)}, {where}, is unstable at upright (it grows at "
        f"{grow:.3g} 1/s)" if grow >= 0 else f"the EIC loop {where} is stable at upright (it decays at {-grow:.3g} 1/s)", strict=True)]
    if grow < 0:
        ok, how = eic_recovery(robot, sim.gains, rate, qu0=d / 4, velocity_cutoff=wc)
        out.append(FeasibilityCheck(
            "eic_recovery", 0.0 if ok else 1.0, 0.0, "unusable",
            "the EIC loop with the model BEM in MuJoCo (sensors, actuator limits) " + (
                f"brings {robot.unactuated_name} back: {how}" if ok else
                f"cannot bring {robot.unactuated_name} back from {d / 4:g} {qu_unit} with the gains {_gains(sim.gains)}: {how}")))
    return out


def _gains(g) -> str:
    return "(" + ", ".join(f"{k} {getattr(g, k):.3g}" for k in ("kp_a", "kd_a", "kp_u", "kd_u")) + ")"


def equilibrium_stiffness(robot: ControlRobot, *, step: float = 1e-5) -> dict:
    """Gravity's stiffness of the unactuated row at the equilibrium the run balances, with its sign.

    With the actuated joints held at rest, eq. (5) linearised at q_u = q_u,nominal reads
    D_uu δq̈_u = Γ_q δq_u,  Γ_q = −∂Γ_0/∂q_u (central difference, ``step``): Γ_q > 0 is an
    equilibrium that falls without control (the upright, λ = √(Γ_q/D_uu)); Γ_q < 0 one that is
    stable by itself (a hanging branch), which no run may report as balanced.

    Returns:
        ``{"joint", "qu", "unit", "gravity_stiffness": Γ_q (N·m/rad or N/m), "d_uu",
        "stable_without_control": Γ_q < 0}``.
    """
    from bemlearn.robots.scales import upright_stiffness
    from bemlearn.units import joint_unit

    qu = float(robot.qu_nominal)
    gq, duu = upright_stiffness(robot, step=step)
    kinds = getattr(robot, "coordinate_kinds", None)
    kind = kinds[robot.unactuated_index] if kinds else "hinge"
    return {"joint": robot.unactuated_name, "qu": qu, "unit": joint_unit(kind), "gravity_stiffness": float(gq), "d_uu": duu,
            "stable_without_control": bool(gq < 0)}
