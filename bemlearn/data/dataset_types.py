"""The GP dataset containers: :class:`BEMDataset` (one split) and :class:`GPDatasets` (both).

A :class:`BEMDataset` holds N points of eq. (11) in physical units,

    x: (N, d) float64, d = 3n − 1, columns ``input_names`` (rad/s², rad/s, rad, rad/s², rad/s),
    y: (N,)  float64, q_u in rad,

and the training split's :class:`~bemlearn.data.normalization.Normalization`; indexing
returns the *normalized* pair (x̃_i, ỹ_i) that the GP is trained on.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch.utils.data import Dataset

from bemlearn.data.normalization import Normalization
from bemlearn.data.trajectory import TrajectoryMeta
from bemlearn.errors import ArgumentError

__all__ = ["BEMDataset", "GPDatasets"]


class BEMDataset(Dataset):
    """N GP points (x, y = q_u) of eq. (11) with the normalization fitted on the training split.

    Args:
        x: (N, d) float64 inputs, physical units, columns ``input_names``.
        y: (N,) float64 outputs q_u, rad.
        normalization: the training split's mean/std (shared by train and validation sets).
        input_names: the d column names (``qdd_<a>…, qd_<a>…, q_<a>…, qdd_<u>, qd_<u>``).
        output_name: ``q_<u>``.
        meta: metadata of the source trajectory (robot, joints, units).
        trial: (N,) int64 trial id of each point.
        row: (N,) int64 row of each point in the source trajectory.
    """

    def __init__(
        self,
        x: torch.Tensor,
        y: torch.Tensor,
        *,
        normalization: Normalization,
        input_names: Sequence[str],
        output_name: str,
        meta: TrajectoryMeta,
        trial: torch.Tensor,
        row: torch.Tensor,
    ) -> None:
        N = x.shape[0]
        if x.ndim != 2 or x.shape[1] != len(input_names) or x.shape[1] != normalization.dim:
            raise ArgumentError(
                f"BEMDataset: x must be (N, {len(input_names)}) to match input_names and the normalization, "
                f"got {tuple(x.shape)}"
            )
        for name, t in (("y", y), ("trial", trial), ("row", row)):
            if tuple(t.shape) != (N,):
                raise ArgumentError(f"BEMDataset: {name} must have shape ({N},), got {tuple(t.shape)}")
        self.x = x.to(torch.float64)
        self.y = y.to(torch.float64)
        self.normalization = normalization
        self.input_names = tuple(input_names)
        self.output_name = output_name
        self.meta = meta
        self.trial = trial.to(torch.int64)
        self.row = row.to(torch.int64)

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def __getitem__(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The normalized pair (x̃_i (d,), ỹ_i ())."""
        return self.normalization.normalize_x(self.x[i]), self.normalization.normalize_y(self.y[i])

    @property
    def dim(self) -> int:
        """d = 3n − 1."""
        return int(self.x.shape[1])

    @property
    def x_normalized(self) -> torch.Tensor:
        """(N, d) x̃ = (x − x_mean) / x_std."""
        return self.normalization.normalize_x(self.x)

    @property
    def y_normalized(self) -> torch.Tensor:
        """(N,) ỹ = (y − y_mean) / y_std."""
        return self.normalization.normalize_y(self.y)

    @property
    def x_mean(self) -> torch.Tensor:
        """(d,) float64, physical units per column."""
        return self.normalization.x_mean

    @property
    def x_std(self) -> torch.Tensor:
        """(d,) float64, physical units per column."""
        return self.normalization.x_std

    @property
    def y_mean(self) -> torch.Tensor:
        """() float64, rad."""
        return self.normalization.y_mean

    @property
    def y_std(self) -> torch.Tensor:
        """() float64, rad."""
        return self.normalization.y_std

    @property
    def trial_ids(self) -> tuple[int, ...]:
        """Sorted ids of the trials the points come from."""
        return tuple(sorted(set(self.trial.tolist())))

    def __repr__(self) -> str:
        return f"BEMDataset(N={len(self)}, d={self.dim}, robot={self.meta.robot!r}, inputs={list(self.input_names)})"


@dataclass(frozen=True, eq=False)
class GPDatasets:
    """Training and validation sets (split by trial) and the counts of what was removed.

    Attributes:
        train: the training points (normalization fitted on them).
        val: the validation points (same normalization); may be empty.
        report: counts: ``trials_total``, ``samples_total``, ``trials_dropped_short``,
            ``samples_dropped_short``, ``trials_dropped_failed``, ``samples_dropped_failed``,
            ``samples_dropped_edges`` (with ``drop_edges``), ``samples_outside_window``,
            ``train_trials``, ``val_trials``, ``train_pool``, ``val_pool``, ``n_train``, ``n_val``,
            ``estimator``, and ``derivative_choice`` when an option was chosen from the data.
        config: the :class:`~bemlearn.data.DatasetConfig` the sets were built with, with every option
            chosen from the data written out (rebuilding with it gives the same sets).
    """

    train: BEMDataset
    val: BEMDataset
    report: dict[str, Any]
    config: Any = None
