"""Map the generalized actuated force of eq. (3) to actuator commands.

* :class:`DirectTorque` — actuators are torque motors on the actuated coordinates
  (u = B⁺ τ_a, clipped to each actuator's range).
* :class:`FurutaMotor` — the Quanser DC motor: V = (τ + b_emf θ̇) / k_u, clipped to ±V_max.
"""

from __future__ import annotations

import numpy as np

from bemlearn.apps.furuta.model import FurutaParameters

__all__ = ["ActuatorModel", "DirectTorque", "FurutaMotor"]


class ActuatorModel:
    """Interface: ``command(tau_a (m,), q (n,), qd (n,)) -> u (nu,)``; ``limit`` (nu,) magnitude."""

    limit: np.ndarray

    def command(self, tau_a: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError


class DirectTorque(ActuatorModel):
    """Torque actuators: ``u = gain⁻¹ τ_a`` clipped to ``±limit`` (N·m)."""

    def __init__(self, gain: np.ndarray, limit: np.ndarray) -> None:
        self.gain_inv = np.linalg.pinv(np.asarray(gain, dtype=np.float64))
        self.limit = np.asarray(limit, dtype=np.float64)

    def command(self, tau_a, q, qd):
        return np.clip(self.gain_inv @ tau_a, -self.limit, self.limit)


class FurutaMotor(ActuatorModel):
    """Quanser motor inverse: V = (τ + b_emf θ̇)/k_u (V), clipped to ±V_max; θ is coordinate 0."""

    def __init__(self, params: FurutaParameters = FurutaParameters()) -> None:
        self.k_u, self.b_emf = params.k_u, params.b_emf
        self.limit = np.array([params.V_max])

    def command(self, tau_a, q, qd):
        return np.clip((tau_a + self.b_emf * qd[:1]) / self.k_u, -self.limit, self.limit)
