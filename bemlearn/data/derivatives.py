"""Derivative estimation by name: q̇, q̈ of recorded angles, computed trial by trial.

The GP input of eq. (11) needs q̇ and q̈, which recorded data do not contain.  An
estimator is chosen by name from :data:`DERIVATIVE_ESTIMATORS`:

- ``"gaussian"`` (the default): :class:`~bemlearn.data.gaussian_derivative.GaussianDerivative`
  (``sigma_s``, ``truncate``): the derivatives of the Gaussian-smoothed angles, which also
  smooths the label consistently; σ chosen from the data when not given;
- ``"central"``: :class:`~bemlearn.data.finite_difference.CentralDifference` (no options);
- ``"savgol"``: :class:`~bemlearn.data.savitzky_golay.SavitzkyGolay` (``window_s`` or
  ``window``, ``polyorder``).

:func:`estimate_derivatives` applies one to every trial separately (a stencil never spans
two trials); each estimator states how it treats the samples at a trial's ends.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any, ClassVar, Protocol

import numpy as np
from tqdm.auto import tqdm

from bemlearn.config import from_dict
from bemlearn.data.finite_difference import CentralDifference
from bemlearn.data.gaussian_derivative import GaussianDerivative
from bemlearn.data.savitzky_golay import SavitzkyGolay
from bemlearn.data.trajectory import Trajectory
from bemlearn.errors import ConfigError, DataError

__all__ = ["DerivativeEstimator", "DERIVATIVE_ESTIMATORS", "make_estimator", "estimate_derivatives"]

logger = logging.getLogger(__name__)


class DerivativeEstimator(Protocol):
    """q̇, q̈ of one uniformly sampled trial."""

    name: ClassVar[str]

    def min_samples(self, sample_rate_hz: float) -> int:
        """Shortest trial the estimator can handle, samples."""
        ...

    def edge_samples(self, sample_rate_hz: float) -> int:
        """Samples at each end of a trial whose estimates are one-sided (less accurate)."""
        ...

    def __call__(self, q: np.ndarray, *, sample_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """``q`` (T, n) rad → (qd (T, n) rad/s, qdd (T, n) rad/s²)."""
        ...

    def neighbours(self, sample_rate_hz: float) -> tuple[DerivativeEstimator, ...]:
        """The estimators next to this one in its own option space (e.g. a wider and a narrower
        window), each as plausible a choice; the spread of the BEM over them is the estimator
        term of the calibrated band (:mod:`bemlearn.fitting.estimator_sensitivity`).  Empty
        for an estimator without options."""
        ...


#: Estimator classes by name; each class is also its own (frozen, strict) config.
DERIVATIVE_ESTIMATORS: dict[str, type] = {
    GaussianDerivative.name: GaussianDerivative,
    CentralDifference.name: CentralDifference,
    SavitzkyGolay.name: SavitzkyGolay,
}


def make_estimator(
    name: str, options: Mapping[str, Any] | None = None, *, where: str = "derivative"
) -> DerivativeEstimator:
    """The estimator registered as ``name``, configured with ``options``.

    Args:
        name: a key of :data:`DERIVATIVE_ESTIMATORS`.
        options: the estimator's options (e.g. ``{"window_s": 0.2, "polyorder": 3}``).
        where: label for error messages (a config key path).

    Raises:
        ValueError: unknown name (the message lists the valid ones).
        ConfigError: unknown or badly typed option.
    """
    if name not in DERIVATIVE_ESTIMATORS:
        raise ConfigError(
            f"{where}: unknown derivative estimator {name!r}; valid names are {sorted(DERIVATIVE_ESTIMATORS)}"
        )
    return from_dict(DERIVATIVE_ESTIMATORS[name], dict(options or {}), where=f"{where} ({name})")


def estimate_derivatives(
    traj: Trajectory, estimator: DerivativeEstimator, *, progress: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Apply ``estimator`` to each trial of ``traj`` separately.

    Args:
        traj: the trajectory (validated, uniformly sampled at ``meta.sample_rate_hz``).
        estimator: e.g. ``make_estimator("savgol", {"window_s": 0.2})``.
        progress: show a tqdm bar over trials.

    Returns:
        qd (T, n) rad/s and qdd (T, n) rad/s², aligned with ``traj.q``.

    Raises:
        ValueError: a trial is shorter than ``estimator.min_samples`` (names the trial);
            drop such trials first (see :class:`bemlearn.data.DatasetConfig.short_trials`).
    """
    rate = traj.meta.sample_rate_hz
    need = estimator.min_samples(rate)
    qd = np.empty_like(traj.q)
    qdd = np.empty_like(traj.q)
    slices = traj.trial_slices()
    for s in tqdm(slices, desc=f"derivatives ({estimator.name})", disable=not progress, leave=False):
        if s.n_samples < need:
            raise DataError(
                f"trial {s.trial_id} (rows {s.rows.start}..{s.rows.stop - 1}) has {s.n_samples} samples; "
                f"the {estimator.name!r} estimator needs at least {need}"
            )
        qd[s.rows], qdd[s.rows] = estimator(traj.q[s.rows], sample_rate_hz=rate)
    logger.debug("estimated derivatives of %d trials with %r", len(slices), estimator)
    return qd, qdd
