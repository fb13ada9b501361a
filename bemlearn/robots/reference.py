"""Desired actuated trajectories q_a^d(t): composite sinusoids with exact derivatives.

    q_a^d(t) = c + Σ_k A_k sin(2π f_k t + φ_k)        (per actuated joint)

The paper's Fig. 2 reference ("a composite sinusoidal curve") and the excitation
reference θ_t of Section IV-A are of this form.  When every f_k is an integer multiple
of 1/T the trajectory is T-periodic (:attr:`CompositeSinusoid.period`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction
from typing import TYPE_CHECKING

import numpy as np

from bemlearn._lazy import lazy_module
from bemlearn.errors import ArgumentError

if TYPE_CHECKING:
    import torch
else:
    torch = lazy_module("torch")

__all__ = ["CompositeSinusoid", "ConstantAcceleration"]


@dataclass(frozen=True)
class CompositeSinusoid:
    """A sum of sines per actuated joint.

    Attributes:
        amplitudes: ``(m, K)`` rad.
        frequencies: ``(m, K)`` Hz.
        phases: ``(m, K)`` rad.
        offsets: ``(m,)`` rad.
    """

    amplitudes: tuple[tuple[float, ...], ...]
    frequencies: tuple[tuple[float, ...], ...]
    phases: tuple[tuple[float, ...], ...]
    offsets: tuple[float, ...]
    # numpy copies set in __post_init__ for the per-tick fast path (:meth:`evaluate`)
    _A: np.ndarray = field(init=False, repr=False, compare=False)
    _w: np.ndarray = field(init=False, repr=False, compare=False)
    _ph: np.ndarray = field(init=False, repr=False, compare=False)
    _c: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        m = len(self.offsets)
        for name in ("amplitudes", "frequencies", "phases"):
            arr = getattr(self, name)
            if len(arr) != m or len({len(r) for r in arr}) > 1:
                raise ArgumentError(f"CompositeSinusoid.{name}: expected {m} rows of equal length, got {arr}")
        # numpy copies for the per-tick fast path (:meth:`evaluate`)
        object.__setattr__(self, "_A", np.asarray(self.amplitudes, dtype=np.float64))
        object.__setattr__(self, "_w", 2 * math.pi * np.asarray(self.frequencies, dtype=np.float64))
        object.__setattr__(self, "_ph", np.asarray(self.phases, dtype=np.float64))
        object.__setattr__(self, "_c", np.asarray(self.offsets, dtype=np.float64))

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Numpy fast path of :meth:`__call__`: ``t (T,)`` s → three ``(T, m)`` arrays."""
        arg = self._w[None] * np.asarray(t, dtype=np.float64)[:, None, None] + self._ph[None]
        s, c = np.sin(arg), np.cos(arg)
        return (self._A * s).sum(-1) + self._c, (self._A * self._w * c).sum(-1), -(self._A * self._w**2 * s).sum(-1)

    @classmethod
    def single(cls, amplitudes, frequencies, phases=None, offset: float = 0.0) -> CompositeSinusoid:
        """One actuated joint: ``amplitudes`` (its unit: rad, or m for a slide), ``frequencies`` (Hz), ``phases`` (rad)."""
        phases = [0.0] * len(amplitudes) if phases is None else phases
        return cls((tuple(map(float, amplitudes)),), (tuple(map(float, frequencies)),), (tuple(map(float, phases)),), (float(offset),))

    @property
    def m(self) -> int:
        return len(self.offsets)

    @property
    def period(self) -> float:
        """Smallest common period (s) of all components (frequencies taken to 1e-9 Hz)."""
        fracs = [Fraction(f).limit_denominator(10**9) for row in self.frequencies for f in row if f != 0]
        if not fracs:
            return math.inf
        # common period = 1 / gcd of the frequencies
        num = 0
        den = 1
        for fr in fracs:
            den = den * fr.denominator // math.gcd(den, fr.denominator)
        for fr in fracs:
            num = math.gcd(num, fr.numerator * (den // fr.denominator))
        return float(Fraction(den, num))

    def derivative(self, t, order: int = 0) -> torch.Tensor:
        """The ``order``-th time derivative of q_a^d at times ``t``: ``(T,)`` s → ``(T, m)``."""
        t = torch.as_tensor(np.asarray(t, dtype=np.float64))
        A = torch.tensor(self.amplitudes, dtype=torch.float64)  # (m, K)
        w = 2 * math.pi * torch.tensor(self.frequencies, dtype=torch.float64)
        ph = torch.tensor(self.phases, dtype=torch.float64)
        arg = w[None] * t[:, None, None] + ph[None] + order * math.pi / 2  # d/dt sin = sin(· + π/2)
        out = (A * w**order)[None] * torch.sin(arg)
        out = out.sum(-1)
        if order == 0:
            out = out + torch.tensor(self.offsets, dtype=torch.float64)
        return out

    def __call__(self, t) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(q_a^d, q̇_a^d, q̈_a^d)`` at times ``t``, each ``(T, m)`` (rad, rad/s, rad/s²; m, m/s, m/s² for slides)."""
        return self.derivative(t, 0), self.derivative(t, 1), self.derivative(t, 2)


@dataclass(frozen=True)
class ConstantAcceleration:
    """q_a^d(t) = q0 + v0 t + ½ a t² per actuated joint (Section III-A's constant-θ̈ example).

    Attributes:
        q0: ``(m,)`` rad.  v0: ``(m,)`` rad/s.  a: ``(m,)`` rad/s².
    """

    q0: tuple[float, ...]
    v0: tuple[float, ...]
    a: tuple[float, ...]

    @property
    def m(self) -> int:
        return len(self.q0)

    @property
    def period(self) -> float:
        return math.inf

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``t (T,)`` s → ``(q, q̇, q̈)`` each ``(T, m)``."""
        t = np.asarray(t, dtype=np.float64)[:, None]
        q0, v0, a = (np.asarray(v, dtype=np.float64)[None] for v in (self.q0, self.v0, self.a))
        return q0 + v0 * t + 0.5 * a * t**2, v0 + a * t, np.broadcast_to(a, (t.shape[0], a.shape[1])).copy()

    def derivative(self, t, order: int = 0) -> torch.Tensor:
        q, qd, qdd = self.evaluate(np.asarray(t, dtype=np.float64))
        if order > 2:
            return torch.zeros(q.shape, dtype=torch.float64)
        return torch.from_numpy((q, qd, qdd)[order])

    def __call__(self, t) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        q, qd, qdd = self.evaluate(np.asarray(t, dtype=np.float64))
        return torch.from_numpy(q), torch.from_numpy(qd), torch.from_numpy(qdd)
