"""What the core uses of a robot, as typed protocols (PEP 544): :class:`BalanceRobot`, :class:`ControlRobot`.

A balance robot has n coordinates q (rad for a hinge, m for a slide: units follow the joint,
:mod:`bemlearn.units`), one unactuated coordinate q_u and m = n − 1 actuated q_a (eq. 2a/2b),
with the dynamics of eq. (1)

    D(q) q̈ + C(q, q̇) q̇ + G(q) − τ_p(q, q̇) = B u.

:class:`~bemlearn.robots.Robot` (and so :class:`~bemlearn.robots.MujocoRobot`) implements
both protocols; any other object with these members works too (structural typing).  Code that
needs the MuJoCo model itself (the simulated plant, the actuator inverse, the LQR) takes a
:class:`~bemlearn.robots.MujocoRobot`.

Both protocols are ``runtime_checkable``: ``isinstance(obj, BalanceRobot)`` checks that the
members exist (not their signatures).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from bemlearn._lazy import lazy_module
from bemlearn.robots.bem import BEMResult

if TYPE_CHECKING:
    import torch
else:
    torch = lazy_module("torch")

__all__ = ["BalanceRobot", "ControlRobot"]


@runtime_checkable
class BalanceRobot(Protocol):
    """A robot with one unactuated coordinate: partition, dynamics terms and model-based BEM (eq. 1–9).

    Tensors are float64 with a leading batch dimension B; q, q̇, q̈ in the joints' units
    (rad, rad/s, rad/s² or m, m/s, m/s²); generalized forces in N·m (hinge) or N (slide).
    """

    @property
    def name(self) -> str:
        """Registry name or model name."""
        ...

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The n coordinate names, in column order of every ``q``."""
        ...

    @property
    def unactuated_index(self) -> int:
        """Column of q_u in ``q``."""
        ...

    @property
    def qu_range(self) -> tuple[float, float]:
        """``(lo, hi)`` admissible range of q_u searched for the BEM, in q_u's unit."""
        ...

    @property
    def qu_nominal(self) -> float:
        """Nominal (upright) q_u, in its unit; the BEM root nearest it is returned."""
        ...

    @property
    def n(self) -> int:
        """Number of coordinates."""
        ...

    @property
    def m(self) -> int:
        """Number of actuated coordinates, n − 1."""
        ...

    @property
    def actuated_index(self) -> tuple[int, ...]:
        """Columns of q_a in ``q``, ``(m,)``."""
        ...

    @property
    def actuated_names(self) -> tuple[str, ...]:
        """Names of the actuated coordinates, ``(m,)``."""
        ...

    @property
    def unactuated_name(self) -> str:
        """Name of q_u."""
        ...

    @property
    def coordinate_kinds(self) -> tuple[str, ...]:
        """``"hinge"`` (rad) or ``"slide"`` (m) per coordinate."""
        ...

    def split(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``q (B, n)`` → ``(q_a (B, m), q_u (B,))``."""
        ...

    def join(self, qa: torch.Tensor, qu: torch.Tensor) -> torch.Tensor:
        """``q_a (B, m)``, ``q_u (B,)`` → ``q (B, n)``."""
        ...

    def mass_matrix(self, q: torch.Tensor) -> torch.Tensor:
        """D(q) of eq. (1): ``q (B, n)`` → ``(B, n, n)``."""
        ...

    def bias(self, q: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """C(q, q̇) q̇ + G(q) of eq. (1): ``q, qd (B, n)`` → ``(B, n)``."""
        ...

    def passive(self, q: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """Passive generalized forces τ_p (damping, springs), ``(B, n)``."""
        ...

    def inverse_dynamics(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor) -> torch.Tensor:
        """τ = D q̈ + C q̇ + G − τ_p, ``(B, n)``; its unactuated entry is Γ (eq. 5)."""
        ...

    def gamma(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor) -> torch.Tensor:
        """Γ of eq. (5), ``(B,)``."""
        ...

    def gamma0(self, qu: torch.Tensor, qa: torch.Tensor, qad: torch.Tensor, qadd: torch.Tensor) -> torch.Tensor:
        """Γ_0(q_u; q_a) = Γ at q̇_u = q̈_u = 0 (eq. 7): ``qu (B,)``, ``qa, qad, qadd (B, m)`` → ``(B,)``."""
        ...

    def momentum_u(self, q: torch.Tensor, qd_u: torch.Tensor) -> torch.Tensor:
        """H_u = D_uu(q) q̇_u (Lemma 1): ``q (B, n)``, ``qd_u (B,)`` → ``(B,)``."""
        ...

    def bem(self, qa, qad, qadd, *, qu_range: tuple[float, float] | None = ..., n_grid: int = ...,
            on_missing: str = ...) -> BEMResult:
        """Model-based BEM q_u^e, the root of Γ_0 = 0 nearest :attr:`qu_nominal` (eq. 6, 7, 9):
        ``qa, qad, qadd (B, m)`` → :class:`~bemlearn.robots.bem.BEMResult` with ``qu (B,)``."""
        ...


@runtime_checkable
class ControlRobot(BalanceRobot, Protocol):
    """A :class:`BalanceRobot` with the single-state numpy fast path a control loop calls every tick
    (the EIC's nominal model, the model-based BEM source)."""

    def terms(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """D(q) ``(n, n)`` and h = C q̇ + G − τ_p ``(n,)`` for one state ``q, qd (n,)`` (eq. 1: D q̈ + h = B u)."""
        ...

    def gamma0_scalar(self, qu: float, qa: np.ndarray, qad: np.ndarray, qadd: np.ndarray, qud: float = ...,
                      qudd: float = ...) -> float:
        """Γ (eq. 5) for one state; Γ_0 (eq. 7) with the default q̇_u = q̈_u = 0."""
        ...
