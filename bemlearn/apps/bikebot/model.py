"""The bikebot: parameters and MJCF model.

A rigid bicycle whose steering angle δ and rear-wheel angle θ_R are driven and whose roll φ is free:
the rear frame B on a free joint, the front fork H on a steering hinge, the rear wheel R and the front
wheel F on hinges about their axles, both wheels cylinders on a plane.

**Source of the numbers.**  The geometry, the wheels and the front assembly are the benchmark bicycle
of J. P. Meijaard, J. M. Papadopoulos, A. Ruina, A. L. Schwab, *Linearized dynamics equations for the
balance and steer of a bicycle: a benchmark and review*, Proc. R. Soc. A 463:1955–1982 (2007),
Table 1: wheelbase w = 1.02 m, trail c = 0.08 m, steer-axis tilt λ = π/10, rear wheel r_R = 0.3 m,
m_R = 2 kg, (I_Rxx, I_Ryy) = (0.0603, 0.12) kg·m², front wheel r_F = 0.35 m, m_F = 3 kg,
(I_Fxx, I_Fyy) = (0.1405, 0.28) kg·m², fork and handlebar H at (x_H, z_H) = (0.9, −0.7) m, m_H = 4 kg.
The benchmark's rear body B (at (0.3, −0.9) m, 85 kg) is a frame *with its rider*; a bikebot carries
no rider, so its mass is 20 kg here with the benchmark's inertia scaled by 20/85 (same place, same
shape): 29 kg in all.  The benchmark's wheels are knife edges; here they are cylinders of half-width
``wheel_half_width`` (a 20 mm tyre), which touch the ground at the lower rim of a leaning wheel.

**Axes.**  The benchmark writes x forward, y right, z down; this model writes x forward, y left, z up
(MuJoCo's gravity along −z).  The change is diag(1, −1, −1), so positions keep x and negate z
(z_up = −z_benchmark) and each inertia's product I_xz changes sign.  The steering hinge's axis points
*down* the steer axis, so a positive δ steers right and a positive roll φ (right-handed about the
forward x axis) leans right, as in the benchmark: in a steady turn φ and δ have the same sign.

**Frames in the MJCF** (upright, δ = 0, the rear hub above the origin): the rear frame body's origin is
the rear hub (0, 0, r_R); the fork's origin is the steer axis's ground point (w + c, 0, 0); the
front hub is at (w, 0, r_F).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bemlearn.errors import ArgumentError

__all__ = ["BikeParameters", "bikebot_mjcf"]


@dataclass(frozen=True)
class BikeParameters:
    """The bikebot's physical parameters, SI units (module docstring: Meijaard et al. 2007, Table 1).

    Positions are in the upright bicycle's ground frame (x forward, y left, z up; origin at the rear contact).
    Inertias are the benchmark's (about each body's centre of mass, benchmark axes x forward, y right, z down);
    :meth:`inertia` turns them into this model's axes.
    """

    wheelbase: float = 1.02            # w, m
    trail: float = 0.08                # c, m
    steer_tilt: float = math.pi / 10   # λ, rad: the steer axis leans back from vertical
    gravity: float = 9.81              # g, m/s²
    rear_radius: float = 0.3           # r_R, m
    rear_mass: float = 2.0             # m_R, kg
    rear_inertia: tuple[float, float] = (0.0603, 0.12)      # (I_Rxx diametral, I_Ryy axial), kg·m²
    front_radius: float = 0.35         # r_F, m
    front_mass: float = 3.0            # m_F, kg
    front_inertia: tuple[float, float] = (0.1405, 0.28)     # (I_Fxx, I_Fyy), kg·m²
    frame_com: tuple[float, float] = (0.3, 0.9)             # (x_B, z_B up), m
    frame_mass: float = 20.0           # m_B, kg (benchmark 85 kg with its rider)
    frame_inertia_benchmark: tuple[float, float, float, float] = (9.2, 11.0, 2.8, 2.4)   # (I_xx, I_yy, I_zz, I_xz) at 85 kg
    frame_benchmark_mass: float = 85.0
    fork_com: tuple[float, float] = (0.9, 0.7)              # (x_H, z_H up), m
    fork_mass: float = 4.0             # m_H, kg
    fork_inertia: tuple[float, float, float, float] = (0.05892, 0.06, 0.00708, -0.00756)  # (I_xx, I_yy, I_zz, I_xz)
    wheel_half_width: float = 0.01     # h, m: half the cylinder's length along the axle

    def inertia(self, body: str) -> np.ndarray:
        """``(3, 3)`` inertia about the body's centre of mass in this model's axes (x fwd, y left, z up), kg·m².

        Args:
            body: ``"frame"`` (B), ``"fork"`` (H), ``"rear_wheel"`` (R) or ``"front_wheel"`` (F).
        """
        if body in ("rear_wheel", "front_wheel"):
            dia, ax = self.rear_inertia if body == "rear_wheel" else self.front_inertia
            return np.diag([dia, ax, dia])
        if body == "frame":
            ixx, iyy, izz, ixz = (x * self.frame_mass / self.frame_benchmark_mass for x in self.frame_inertia_benchmark)
        elif body == "fork":
            ixx, iyy, izz, ixz = self.fork_inertia
        else:
            raise ArgumentError(f"BikeParameters.inertia: unknown body {body!r}; expected one of frame, fork, rear_wheel, front_wheel")
        # benchmark's [[ixx, 0, ixz], [0, iyy, 0], [ixz, 0, izz]] under diag(1, -1, -1): I_xz changes sign
        return np.array([[ixx, 0.0, -ixz], [0.0, iyy, 0.0], [-ixz, 0.0, izz]])

    @property
    def steer_axis(self) -> np.ndarray:
        """``(3,)`` unit vector of the steering hinge (down the steer axis: δ > 0 steers right)."""
        return np.array([math.sin(self.steer_tilt), 0.0, -math.cos(self.steer_tilt)])

    @property
    def steer_ground_point(self) -> np.ndarray:
        """``(3,)`` where the steer axis meets the ground, upright, m: (w + c, 0, 0)."""
        return np.array([self.wheelbase + self.trail, 0.0, 0.0])


def bikebot_mjcf(p: BikeParameters = BikeParameters(), *, timestep: float = 0.001) -> str:
    """The MJCF of the bikebot with parameters ``p`` (module docstring for the source and the frames).

    Torque motors on the steering hinge (±20 N·m) and the rear-wheel hinge (±20 N·m); no joint damping
    or armature.  Only the wheel cylinders collide (with the floor); inertias are given explicitly.
    """
    g = lambda x: repr(float(x))  # noqa: E731 - exact round trip of every number

    def full(body: str) -> str:
        i = p.inertia(body)
        return f"{g(i[0, 0])} {g(i[1, 1])} {g(i[2, 2])} {g(i[0, 1])} {g(i[0, 2])} {g(i[1, 2])}"

    rr, rf, h = p.rear_radius, p.front_radius, p.wheel_half_width
    gp = p.steer_ground_point
    fork_pos = gp - np.array([0.0, 0.0, rr])                 # fork origin in the frame body (rear hub at its origin)
    fork_com = np.array([p.fork_com[0], 0.0, p.fork_com[1]]) - gp
    front_hub = np.array([p.wheelbase, 0.0, rf]) - gp
    ax = p.steer_axis
    head = gp + 0.75 * np.array([-math.sin(p.steer_tilt), 0.0, math.cos(p.steer_tilt)]) - gp
    v = lambda x: " ".join(g(c) for c in x)  # noqa: E731
    return f"""<mujoco model="bikebot">
  <!-- A bikebot on the benchmark bicycle of Meijaard et al. 2007 (rear frame without rider, 20 kg);
       see bemlearn/apps/bikebot/model.py. Generated by bemlearn.apps.bikebot.model.bikebot_mjcf: edit the
       parameters there, not this file. -->
  <compiler angle="radian" inertiafromgeom="false"/>
  <option timestep="{g(timestep)}" gravity="0 0 {g(-p.gravity)}"/>
  <default>
    <geom contype="0" conaffinity="0" rgba="0.7 0.7 0.75 1"/>
  </default>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1"/>
    <geom name="floor" type="plane" size="0 0 1" contype="1" conaffinity="1" rgba="0.3 0.35 0.3 1"/>
    <body name="frame" pos="0 0 {g(rr)}">
      <freejoint name="frame_free"/>
      <inertial pos="{g(p.frame_com[0])} 0 {g(p.frame_com[1] - rr)}" mass="{g(p.frame_mass)}" fullinertia="{full("frame")}"/>
      <geom name="chain_stay" type="capsule" fromto="0 0 0 {g(p.frame_com[0])} 0 {g(p.frame_com[1] - rr)}" size="0.02"/>
      <geom name="top_tube" type="capsule" fromto="{g(p.frame_com[0])} 0 {g(p.frame_com[1] - rr)} {v(fork_pos + head)}" size="0.02"/>
      <body name="rear_wheel" pos="0 0 0">
        <joint name="rear_wheel" type="hinge" axis="0 1 0"/>
        <inertial pos="0 0 0" mass="{g(p.rear_mass)}" diaginertia="{v(np.diag(p.inertia("rear_wheel")))}"/>
        <geom name="rear_tyre" type="cylinder" fromto="0 {g(-h)} 0 0 {g(h)} 0" size="{g(rr)}"
              contype="1" conaffinity="1" rgba="0.1 0.1 0.1 1"/>
      </body>
      <body name="fork" pos="{v(fork_pos)}">
        <joint name="steer" type="hinge" axis="{v(ax)}"/>
        <inertial pos="{v(fork_com)}" mass="{g(p.fork_mass)}" fullinertia="{full("fork")}"/>
        <geom name="fork_blade" type="capsule" fromto="{v(front_hub)} {v(head)}" size="0.015"/>
        <body name="front_wheel" pos="{v(front_hub)}">
          <joint name="front_wheel" type="hinge" axis="0 1 0"/>
          <inertial pos="0 0 0" mass="{g(p.front_mass)}" diaginertia="{v(np.diag(p.inertia("front_wheel")))}"/>
          <geom name="front_tyre" type="cylinder" fromto="0 {g(-h)} 0 0 {g(h)} 0" size="{g(rf)}"
                contype="1" conaffinity="1" rgba="0.1 0.1 0.1 1"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="steer_motor" joint="steer" ctrllimited="true" ctrlrange="-20 20"/>
    <motor name="rear_motor" joint="rear_wheel" ctrllimited="true" ctrlrange="-20 20"/>
  </actuator>
</mujoco>
"""
