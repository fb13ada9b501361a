"""Per-column input/output standardization, fitted on the training split.

    x̃ = (x − x_mean) / x_std,      ỹ = (y − y_mean) / y_std,

with means and (population, ddof = 0) standard deviations of the training points.  A
column with zero spread gets std 1 (logged as a warning) so x̃ stays finite.  The GP is
fitted on (x̃, ỹ); predictions map back with μ = y_mean + y_std μ̃, σ = y_std σ̃.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from bemlearn._lazy import lazy_module
from bemlearn.errors import ArgumentError
from bemlearn.warnings import DataWarning, warn

if TYPE_CHECKING:
    import torch
else:
    torch = lazy_module("torch")

__all__ = ["Normalization"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Normalization:
    """Standardization of x (eq. 11 inputs) and y = q_u.

    Attributes:
        x_mean: (d,) float64, physical units of each column.
        x_std: (d,) float64, > 0, physical units of each column.
        y_mean: () float64, in q_u's unit (rad or m).
        y_std: () float64, > 0, in q_u's unit.
    """

    x_mean: torch.Tensor
    x_std: torch.Tensor
    y_mean: torch.Tensor
    y_std: torch.Tensor

    def __post_init__(self) -> None:
        d = self.x_mean.shape
        if self.x_mean.ndim != 1 or self.x_std.shape != d or self.y_mean.shape != () or self.y_std.shape != ():
            raise ArgumentError(
                f"Normalization: expected x_mean (d,), x_std (d,), y_mean (), y_std (); got "
                f"{tuple(self.x_mean.shape)}, {tuple(self.x_std.shape)}, "
                f"{tuple(self.y_mean.shape)}, {tuple(self.y_std.shape)}"
            )
        if not (bool((self.x_std > 0).all()) and float(self.y_std) > 0):
            raise ArgumentError("Normalization: x_std and y_std must be positive")

    @classmethod
    def fit(cls, x: torch.Tensor, y: torch.Tensor, *, names: Sequence[str] | None = None) -> Normalization:
        """Means and standard deviations (ddof = 0) of ``x`` (N, d) and ``y`` (N,), N ≥ 1."""
        if x.ndim != 2 or y.shape != (x.shape[0],) or x.shape[0] == 0:
            raise ArgumentError(
                f"Normalization.fit: expected x (N >= 1, d) and y (N,), got {tuple(x.shape)}, {tuple(y.shape)}"
            )
        x_mean = x.mean(0)
        x_std = x.std(0, correction=0)
        y_mean = y.mean()
        y_std = y.std(correction=0)
        flat = x_std <= 0
        if bool(flat.any()):
            cols = [names[i] if names else i for i in flat.nonzero().flatten().tolist()]
            warn(DataWarning, logger, "input column(s) %s are constant over the training points; using std 1 for them", cols)
            x_std = torch.where(flat, torch.ones_like(x_std), x_std)
        if float(y_std) <= 0:
            warn(DataWarning, logger, "the output is constant over the training points; using std 1")
            y_std = torch.ones_like(y_std)
        return cls(x_mean=x_mean, x_std=x_std, y_mean=y_mean, y_std=y_std)

    @property
    def dim(self) -> int:
        return int(self.x_mean.shape[0])

    def normalize_x(self, x: torch.Tensor) -> torch.Tensor:
        """x̃ = (x − x_mean) / x_std for ``x`` (..., d) physical inputs."""
        return (x - self.x_mean) / self.x_std

    def normalize_y(self, y: torch.Tensor) -> torch.Tensor:
        """ỹ = (y − y_mean) / y_std for ``y`` (...,) in q_u's unit."""
        return (y - self.y_mean) / self.y_std

    def denormalize_y(self, y_tilde: torch.Tensor) -> torch.Tensor:
        """y = y_mean + y_std ỹ, in q_u's unit."""
        return self.y_mean + self.y_std * y_tilde

    def denormalize_std(self, std_tilde: torch.Tensor) -> torch.Tensor:
        """σ = y_std σ̃, in q_u's unit (a standard deviation, no shift)."""
        return self.y_std * std_tilde

    def to_dict(self) -> dict[str, torch.Tensor]:
        """``{x_mean, x_std, y_mean, y_std}`` (``torch.load(weights_only=True)``-safe)."""
        return {"x_mean": self.x_mean, "x_std": self.x_std, "y_mean": self.y_mean, "y_std": self.y_std}
