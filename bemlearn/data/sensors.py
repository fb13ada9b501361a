"""What a real rig measures: quantized encoder angles and a filtered velocity estimate.

* Encoder: y = step · round((q + n) / step), step = 2π / counts_per_rev (Quanser: 4096
  counts/rev → 1.53 mrad) for hinges and ``m_per_count`` (m) for slide joints when set,
  n ~ N(0, noise_std²) optional.
* Velocity estimate used by the *controller* (never written to data files): the
  bilinear (Tustin) discretization of the high-pass differentiator H(s) = ω_c s / (s + ω_c)
  that Quanser's controllers use (ω_c = 50 rad/s by default):
      v_k = a v_{k−1} + b (y_k − y_{k−1}),  a = (2 − ω_c Δt)/(2 + ω_c Δt),  b = 2ω_c/(2 + ω_c Δt).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bemlearn.config import Limit, config_limits
from bemlearn.errors import ConfigError

__all__ = ["SensorConfig", "Encoder", "FilteredDifferentiator"]


@dataclass(frozen=True)
class SensorConfig:
    """Sensor model options.

    Attributes:
        counts_per_rev: encoder resolution; 0 disables quantization.
        noise_std: additive noise before quantization, in each joint's unit (rad, or m for a slide).
        velocity_cutoff: ω_c of the controller's velocity filter, rad/s.
        m_per_count: resolution of slide-joint encoders, m (0: slides use the angle step).
    """

    counts_per_rev: int = 4096
    noise_std: float = 0.0
    velocity_cutoff: float = 50.0
    m_per_count: float = 0.0

    def __post_init__(self) -> None:
        if self.counts_per_rev < 0:
            raise ConfigError(f"sensor.counts_per_rev must be ≥ 0, got {self.counts_per_rev}")
        if self.noise_std < 0:
            raise ConfigError(f"sensor.noise_std must be ≥ 0, got {self.noise_std}")
        if self.velocity_cutoff <= 0:
            raise ConfigError(f"sensor.velocity_cutoff must be > 0 rad/s, got {self.velocity_cutoff}")
        if self.m_per_count < 0:
            raise ConfigError(f"sensor.m_per_count must be ≥ 0 m, got {self.m_per_count}")

    @property
    def step(self) -> float:
        """Quantization step of a hinge encoder, rad (0 when disabled)."""
        return 2 * math.pi / self.counts_per_rev if self.counts_per_rev else 0.0


config_limits(SensorConfig, counts_per_rev=Limit(ge=0, le=2**31), noise_std=Limit(ge=0, unit="rad or m"),
              velocity_cutoff=Limit(gt=0, unit="rad/s"), m_per_count=Limit(ge=0, unit="m"))


class Encoder:
    """Quantize (and optionally perturb) joint coordinates: ``q (n,)`` rad / m by joint kind → ``(n,)``.

    ``kinds`` (the joint kind of each coordinate) selects ``m_per_count`` for slides.
    """

    def __init__(self, config: SensorConfig, rng: np.random.Generator, *, kinds: tuple[str, ...] | None = None) -> None:
        self.step: float | np.ndarray = config.step
        if kinds is not None and config.m_per_count > 0 and "slide" in kinds:
            self.step = np.array([config.m_per_count if k == "slide" else config.step for k in kinds])
        self.noise_std = config.noise_std
        self.rng = rng

    def __call__(self, q: np.ndarray) -> np.ndarray:
        y = q + self.rng.normal(0.0, self.noise_std, size=q.shape) if self.noise_std > 0 else q.copy()
        if np.ndim(self.step):
            safe = np.where(self.step > 0, self.step, 1.0)
            return np.where(self.step > 0, np.round(y / safe) * safe, y)
        return np.round(y / self.step) * self.step if self.step > 0 else y


class FilteredDifferentiator:
    """Tustin-discretized ω_c s/(s + ω_c) velocity estimate of sampled angles (module docstring)."""

    def __init__(self, n: int, *, cutoff: float, dt: float) -> None:
        self.a = (2 - cutoff * dt) / (2 + cutoff * dt)
        self.b = 2 * cutoff / (2 + cutoff * dt)
        self.v = np.zeros(n)
        self.prev: np.ndarray | None = None

    def __call__(self, y: np.ndarray) -> np.ndarray:
        if self.prev is not None:
            self.v = self.a * self.v + self.b * (y - self.prev)
        self.prev = y.copy()
        return self.v.copy()
