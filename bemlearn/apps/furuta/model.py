"""The Furuta (rotary inverted) pendulum: parameters, MJCF model, analytic model, motor.

Coordinates q = [θ, α]: θ the arm angle about the vertical motor axis (actuated, q_a),
α the pendulum angle about the arm's long axis (unactuated, q_u), α = 0 upright; a
positive α tips the pendulum towards −y of the arm frame (right-hand rule about the arm).

Parameters are Quanser's SRV02 + ROTPEN values from Quanser's setup scripts (J. Apkarian,
P. Karam, M. Levis, *Inverted Pendulum Experiment*, Quanser, 2011 — ref. [23] of the paper).

Rigid-body model (this module's :class:`AnalyticFuruta`, ``variant="rigid"``): the
pendulum is a slender rod of mass m_p and length L_p, centre of mass at l = L_p/2 from
the hinge, inertia J_p about both transverse axes through its centre and J_ax (negligible,
MuJoCo needs it positive) about its own axis; the arm has inertia J_r about the motor
axis and its hinge to the pendulum at distance L_r.  Lagrange's equations give

    D_aa = J_r + m_p L_r² + (J_p + m_p l²) sin²α + J_ax cos²α
    D_au = −m_p L_r l cos α,        D_uu = J_p + m_p l²
    C q̇ + G = [ 2K sα cα θ̇ α̇ + m_p L_r l sα α̇²,   −K sα cα θ̇² − m_p g l sα ],   K = J_p + m_p l² − J_ax
    τ_p = [−B_r θ̇, −B_p α̇]

The paper's printed rows (Section IV-A, ``variant="paper"``) are Quanser's
approximation: they keep ¼ m_p L_p² = m_p l² where the rigid rod has J_p + m_p l² in D_aa
and K (and have no J_ax).  With J_p ≈ m_p l²/3 that is a 25 % smaller K, which changes the
BEM noticeably at high arm speed (see ``tests/test_robots_furuta.py`` and
``bemlearn robot furuta --compare-variants``).

Motor (Quanser SRV02): τ = η_g K_g η_m k_t (V_m − K_g k_m θ̇) / R_m on the arm, i.e.
τ = k_u V − b_emf θ̇ with k_u = η_g K_g η_m k_t / R_m and b_emf = k_u K_g k_m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from bemlearn.errors import ArgumentError
from bemlearn.robots.robot import Robot, as_batch

__all__ = ["FurutaParameters", "AnalyticFuruta", "furuta_mjcf", "voltage_to_torque", "torque_to_voltage"]


@dataclass(frozen=True)
class FurutaParameters:
    """Quanser SRV02 + ROTPEN parameters (SI units). Source: Quanser setup scripts, via NOTES.md."""

    m_p: float = 0.127  # pendulum mass, kg
    L_p: float = 0.33655  # pendulum full length, m (centre of mass at L_p / 2)
    J_p: float = 1.199e-3  # pendulum inertia about its centre, transverse axes, kg·m²
    J_ax: float = 1e-9  # pendulum inertia about its own axis (negligible; MuJoCo needs > 0), kg·m²
    L_r: float = 0.2159  # arm length, motor axis to pendulum hinge, m
    J_r: float = 9.983e-4  # arm inertia about the motor axis, kg·m²
    B_r: float = 0.0024  # arm viscous damping, N·m·s/rad
    B_p: float = 0.0024  # pendulum viscous damping, N·m·s/rad
    R_m: float = 2.6  # motor armature resistance, Ω
    k_t: float = 7.683e-3  # motor torque constant, N·m/A
    k_m: float = 7.678e-3  # motor back-EMF constant, V·s/rad
    K_g: float = 70.0  # total gear ratio
    eta_g: float = 0.90  # gearbox efficiency
    eta_m: float = 0.69  # motor efficiency
    V_max: float = 10.0  # usable amplifier voltage, V
    g: float = 9.81  # gravity, m/s² (MuJoCo's default)

    @property
    def l(self) -> float:  # noqa: E743 - the paper's symbol l = L_p / 2
        """Hinge-to-centre-of-mass distance L_p / 2, m."""
        return self.L_p / 2

    @property
    def k_u(self) -> float:
        """Torque per volt at standstill, η_g K_g η_m k_t / R_m, N·m/V."""
        return self.eta_g * self.K_g * self.eta_m * self.k_t / self.R_m

    @property
    def b_emf(self) -> float:
        """Back-EMF damping k_u K_g k_m, N·m·s/rad."""
        return self.k_u * self.K_g * self.k_m


def voltage_to_torque(V: torch.Tensor, theta_dot: torch.Tensor, p: FurutaParameters = FurutaParameters()) -> torch.Tensor:
    """Arm torque τ = k_u V − b_emf θ̇ (N·m) for motor voltage V (V) and arm rate θ̇ (rad/s)."""
    return p.k_u * V - p.b_emf * theta_dot


def torque_to_voltage(tau: torch.Tensor, theta_dot: torch.Tensor, p: FurutaParameters = FurutaParameters()) -> torch.Tensor:
    """Inverse of :func:`voltage_to_torque`: V = (τ + b_emf θ̇) / k_u (V), unsaturated."""
    return (tau + p.b_emf * theta_dot) / p.k_u


def furuta_mjcf(p: FurutaParameters = FurutaParameters(), *, timestep: float = 0.00125) -> str:
    """The MJCF of the Furuta pendulum with parameters ``p``.

    The default physics step is 1.25 ms (RK4): two steps per 400 Hz control tick.  The
    fastest closed-loop mode is ~30 rad/s, so hλ ≈ 0.04, far inside RK4's accuracy.

    The actuator is the Quanser motor: force = k_u · ctrl − b_emf · θ̇ (MuJoCo ``general``
    actuator with affine bias), ctrl in volts limited to ±V_max.  Geoms are visual only
    (no contacts); inertias are given explicitly.
    """
    g = lambda x: repr(float(x))  # noqa: E731 - exact round trip of every number
    arm_side = 0.6 * p.J_r  # arm inertia about its transverse axes: irrelevant (arm turns about z only)
    return f"""<mujoco model="furuta">
  <!-- Quanser SRV02 + ROTPEN rotary pendulum; parameters from Quanser's setup scripts (see
       bemlearn/apps/furuta/model.py). Generated by bemlearn.apps.furuta.model.furuta_mjcf: edit the
       parameters there, not this file. -->
  <compiler angle="radian" inertiafromgeom="false"/>
  <option timestep="{g(timestep)}" integrator="RK4" gravity="0 0 {g(-p.g)}"/>
  <default>
    <geom contype="0" conaffinity="0" rgba="0.7 0.7 0.75 1"/>
  </default>
  <worldbody>
    <light pos="0 0 2" dir="0 0 -1"/>
    <geom name="base" type="cylinder" pos="0 0 -0.05" size="0.05 0.05" rgba="0.2 0.2 0.2 1"/>
    <body name="arm" pos="0 0 0">
      <joint name="theta" type="hinge" axis="0 0 1" damping="{g(p.B_r)}"/>
      <inertial pos="0 0 0" mass="0.257" diaginertia="{g(arm_side)} {g(arm_side)} {g(p.J_r)}"/>
      <geom name="arm" type="capsule" fromto="0 0 0 {g(p.L_r)} 0 0" size="0.008"/>
      <site name="arm_tip" pos="{g(p.L_r)} 0 0"/>
      <body name="pendulum" pos="{g(p.L_r)} 0 0">
        <joint name="alpha" type="hinge" axis="1 0 0" damping="{g(p.B_p)}"/>
        <inertial pos="0 0 {g(p.l)}" mass="{g(p.m_p)}" diaginertia="{g(p.J_p)} {g(p.J_p)} {g(p.J_ax)}"/>
        <geom name="pendulum" type="capsule" fromto="0 0 0 0 0 {g(p.L_p)}" size="0.005" rgba="0.8 0.2 0.2 1"/>
        <site name="pendulum_tip" pos="0 0 {g(p.L_p)}"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <general name="motor" joint="theta" ctrllimited="true" ctrlrange="{g(-p.V_max)} {g(p.V_max)}"
             gainprm="{g(p.k_u)}" biastype="affine" biasprm="0 0 {g(-p.b_emf)}"/>
  </actuator>
  <custom>
    <numeric name="bemlearn_qu_range" data="{g(-math.pi / 2)} {g(math.pi / 2)}"/>
  </custom>
</mujoco>
"""


class AnalyticFuruta(Robot):
    """Closed-form Furuta dynamics (module docstring), vectorized in torch.

    Args:
        params: physical parameters.
        variant: ``"rigid"`` (exact rigid body of :func:`furuta_mjcf`) or ``"paper"``
            (the rows printed in Section IV-A, with C = 1).
    """

    def __init__(self, params: FurutaParameters = FurutaParameters(), *, variant: Literal["rigid", "paper"] = "rigid") -> None:
        if variant not in ("rigid", "paper"):
            raise ArgumentError(f"AnalyticFuruta: variant must be 'rigid' or 'paper', got {variant!r}")
        self.params = params
        self.variant = variant
        self.name = "furuta" if variant == "rigid" else "furuta-paper"
        self.joint_names = ("theta", "alpha")
        self.unactuated_index = 1
        self.qu_range = (-math.pi / 2, math.pi / 2)
        self.qu_nominal = 0.0
        p = params
        ml2 = p.m_p * p.l**2
        if variant == "rigid":
            self._sin2 = p.J_p + ml2  # coefficient of sin²α in D_aa
            self._cos2 = p.J_ax  # coefficient of cos²α in D_aa
        else:
            self._sin2 = ml2
            self._cos2 = 0.0
        self._K = self._sin2 - self._cos2  # ½ dD_aa/dα = K sα cα
        self._Daa0 = p.J_r + p.m_p * p.L_r**2
        self._mLl = p.m_p * p.L_r * p.l
        self._Duu = p.J_p + ml2
        self._mgl = p.m_p * p.g * p.l

    def mass_matrix(self, q: torch.Tensor) -> torch.Tensor:
        """D(q) (module docstring). ``q: (B, 2)`` rad → ``(B, 2, 2)`` kg·m²."""
        q = as_batch(q, 2, "q", func="mass_matrix", units="rad")
        s, c = torch.sin(q[:, 1]), torch.cos(q[:, 1])
        daa = self._Daa0 + self._sin2 * s**2 + self._cos2 * c**2
        dau = -self._mLl * c
        duu = torch.full_like(s, self._Duu)
        return torch.stack([torch.stack([daa, dau], -1), torch.stack([dau, duu], -1)], -2)

    def bias(self, q: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """C q̇ + G (module docstring). ``q, qd: (B, 2)`` → ``(B, 2)`` N·m."""
        q, qd = self._states(q, qd, func="bias")
        s, c = torch.sin(q[:, 1]), torch.cos(q[:, 1])
        td, ad = qd[:, 0], qd[:, 1]
        ha = 2 * self._K * s * c * td * ad + self._mLl * s * ad**2
        hu = -self._K * s * c * td**2 - self._mgl * s
        return torch.stack([ha, hu], -1)

    def terms(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """D(q) and h = C q̇ + G − τ_p for one state, numpy fast path for control loops.

        Args:
            q, qd: ``(2,)`` [θ, α] rad and [θ̇, α̇] rad/s.
        """
        s, c = math.sin(q[1]), math.cos(q[1])
        td, ad = float(qd[0]), float(qd[1])
        daa = self._Daa0 + self._sin2 * s * s + self._cos2 * c * c
        dau = -self._mLl * c
        D = np.array([[daa, dau], [dau, self._Duu]])
        ha = 2 * self._K * s * c * td * ad + self._mLl * s * ad * ad + self.params.B_r * td
        hu = -self._K * s * c * td * td - self._mgl * s + self.params.B_p * ad
        return D, np.array([ha, hu])

    def gamma0_scalar(self, qu: float, qa: np.ndarray, qad: np.ndarray, qadd: np.ndarray, qud: float = 0.0, qudd: float = 0.0) -> float:
        """Γ (eq. 5) for one state, numpy fast path; with the default q̇_u = q̈_u = 0 it is Γ_0 (eq. 7):
        −m L_r l cos α θ̈ − K sin α cos α θ̇² − m g l sin α (+ D_uu α̈ + B_p α̇ for nonzero rates)."""
        s, c = math.sin(qu), math.cos(qu)
        td, tdd = float(qad[0]), float(qadd[0])
        return -self._mLl * c * tdd - self._K * s * c * td * td - self._mgl * s + self._Duu * qudd + self.params.B_p * qud

    def passive(self, q: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """Viscous joint damping [−B_r θ̇, −B_p α̇], ``(B, 2)`` N·m."""
        q, qd = self._states(q, qd, func="passive")
        return -qd * torch.tensor([self.params.B_r, self.params.B_p], dtype=torch.float64)
