"""The Quanser SRV02 motor law, V = (τ + b_emf θ̇) / k_u clipped to ±V_max (paper Section IV-A).

The core drives the shipped Furuta through :class:`~bemlearn.control.MujocoActuatorInverse`,
the generic inverse of its MJCF affine actuator, which reproduces this law to 1e-12
(``tests/test_derive.py``); :class:`FurutaMotor` is the closed form, kept as that reference.
"""

from __future__ import annotations

import numpy as np

from bemlearn.apps.furuta.model import FurutaParameters

__all__ = ["FurutaMotor"]


class FurutaMotor:
    """Quanser motor inverse: V = (τ + b_emf θ̇)/k_u (V), clipped to ±V_max; θ is coordinate 0.

    ``command(tau_a (1,) N·m, q (2,) rad, qd (2,) rad/s) -> V (1,)``.
    """

    def __init__(self, params: FurutaParameters = FurutaParameters()) -> None:
        self.k_u, self.b_emf = params.k_u, params.b_emf
        self.limit = np.array([params.V_max])

    def command(self, tau_a, q, qd):
        return np.clip((tau_a + self.b_emf * qd[:1]) / self.k_u, -self.limit, self.limit)
