"""GP training data of eq. (11): x = [q̈_a, q̇_a, q_a, q̈_u, q̇_u] → y = q_u, from trajectories.

:func:`build_datasets` turns a :class:`~bemlearn.data.trajectory.Trajectory` into a
training and a validation :class:`BEMDataset`:

1. trials shorter than the derivative estimator needs are dropped (or rejected), and
   failed trials optionally dropped (the paper keeps them);
2. q̇, q̈ are estimated trial by trial (:mod:`bemlearn.data.derivatives`); an estimator
   that smooths (the default Gaussian, :mod:`bemlearn.data.gaussian_derivative`) also gives
   the smoothed q, used for the q_a inputs and the q_u label alike (eq. G2), and an option it
   leaves to the data (its width σ) is chosen from them first
   (:mod:`bemlearn.data.derivative_choice`);
3. the edge samples of each trial are dropped where the estimator has no valid estimate there
   (the Gaussian), or optionally where they are one-sided (``drop_edges``);
4. samples with |q_u| > ``qu_window`` are dropped (q_u = f(x) is single-valued only
   near upright);
5. trials are split into training / validation sets (seeded, a fraction held out);
6. ``n_points`` training points are drawn at random without replacement (seeded; the
   paper uses N = 500), optionally ``n_val_points`` validation points;
7. mean/std per column are computed on the training points and stored with both sets.

Every removal is counted in :attr:`GPDatasets.report` and logged.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from bemlearn._lazy import lazy_module
from bemlearn.config import Limit, config_limits
from bemlearn.data.derivative_choice import estimate_states, resolve_estimator
from bemlearn.data.derivatives import DerivativeEstimator, make_estimator
from bemlearn.data.features import gp_input_names, gp_inputs, gp_output_name
from bemlearn.data.normalization import Normalization
from bemlearn.data.trajectory import Trajectory
from bemlearn.data.validation import validate
from bemlearn.errors import ConfigError, DataError
from bemlearn.units import q_unit_label
from bemlearn.warnings import DataWarning, warn

if TYPE_CHECKING:
    import torch

    from bemlearn.data.dataset_types import BEMDataset, GPDatasets
else:
    torch = lazy_module("torch")

__all__ = ["DatasetConfig", "build_datasets", "split_trials"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class DatasetConfig:
    """How trajectories become GP data (parse with ``bemlearn.config.from_dict``).

    Attributes:
        derivative: derivative estimator name (``"gaussian"``, ``"savgol"``, ``"central"``).
        derivative_options: the estimator's options, e.g. ``{"sigma_s": 0.1}`` (gaussian) or
            ``{"window_s": 0.3, "polyorder": 4}`` (savgol); an option left out takes the
            estimator's default (the Gaussian's σ: chosen from the data).
        qu_window: keep samples with |q_u| ≤ qu_window, in q_u's unit (``None``: keep all).
        n_points: training points drawn at random from the training pool (``None``: all).
        n_val_points: validation points drawn at random (``None``: all).
        val_fraction: fraction of trials held out for validation, 0 ≤ f < 1.
        seed: seed of the trial split and the draws.
        include_failed: keep trials that fell (the paper does).
        short_trials: ``"drop"`` (counted, logged) or ``"error"`` for trials shorter than
            the estimator needs.
        drop_edges: drop the samples at each trial end whose derivatives are one-sided.
        cyclic: actuated joints whose *position* the GP leaves out of its inputs (ℓ = ∞; the column stays in x):
            cyclic coordinates — the dynamics (D, h of eq. 1), hence the BEM, do not depend on them — without a
            joint range, whose position runs on without bound in use (a wheel's or a free turntable's angle).
            ``None``: derived from the robot's model (:func:`bemlearn.robots.cyclic.unbounded_cyclic`); none in a
            model-free run.  ``[]``: keep every input.
    """

    derivative: str = "gaussian"
    derivative_options: dict[str, Any] = field(default_factory=dict)
    qu_window: float | None = 0.5
    n_points: int | None = 500
    n_val_points: int | None = None
    val_fraction: float = 0.2
    seed: int = 0
    include_failed: bool = True
    short_trials: Literal["drop", "error"] = "drop"
    drop_edges: bool = False
    cyclic: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        self.estimator()  # validates the name and options
        if self.qu_window is not None and not (math.isfinite(self.qu_window) and self.qu_window > 0):
            raise ConfigError(f"qu_window: expected a positive angle in rad or null, got {self.qu_window!r}")
        for key in ("n_points", "n_val_points"):
            value = getattr(self, key)
            if value is not None and value < 1:
                raise ConfigError(f"{key}: expected a positive integer or null, got {value!r}")
        if not 0.0 <= self.val_fraction < 1.0:
            raise ConfigError(f"val_fraction: expected 0 <= val_fraction < 1, got {self.val_fraction!r}")
        if self.short_trials not in ("drop", "error"):
            raise ConfigError(f"short_trials: expected 'drop' or 'error', got {self.short_trials!r}")

    def estimator(self) -> DerivativeEstimator:
        """The configured derivative estimator (options left to the data still unset)."""
        return make_estimator(self.derivative, self.derivative_options, where="derivative_options")

    def with_estimator(self, estimator: DerivativeEstimator) -> DatasetConfig:
        """This config with ``estimator``'s options written out (e.g. a σ chosen from the data)."""
        import dataclasses as dc

        opts = {f.name: getattr(estimator, f.name) for f in dc.fields(estimator)} if dc.is_dataclass(estimator) else dict(self.derivative_options)
        return dc.replace(self, derivative=estimator.name, derivative_options=opts)


# (the lower bounds of qu_window, n_points, n_val_points and val_fraction are checked by __post_init__)
config_limits(DatasetConfig, n_points=Limit(le=10**8), n_val_points=Limit(le=10**8), seed=Limit(ge=0))


def split_trials(
    trial_ids: list[int] | tuple[int, ...], val_fraction: float, rng: np.random.Generator
) -> tuple[list[int], list[int]]:
    """Shuffle ``trial_ids`` and hold out round(f · n_trials) of them (at least 1 if f > 0, never all).

    Returns:
        (train ids, validation ids), each sorted.
    """
    ids = sorted(set(trial_ids))
    if val_fraction <= 0:
        return ids, []
    if len(ids) < 2:
        raise DataError(f"val_fraction = {val_fraction} needs at least 2 trials to split by trial, got {len(ids)}")
    n_val = min(max(1, round(val_fraction * len(ids))), len(ids) - 1)
    perm = rng.permutation(ids)
    return sorted(int(i) for i in perm[n_val:]), sorted(int(i) for i in perm[:n_val])


def _drop_trials(traj: Trajectory, drop: list[int], reason: str, report: dict[str, Any], key: str) -> np.ndarray:
    """Row mask keeping every trial but ``drop``; counts go to ``report``."""
    dropped = np.isin(traj.trial, np.asarray(drop, dtype=np.int64))
    report[f"trials_dropped_{key}"] = len(drop)
    report[f"samples_dropped_{key}"] = int(dropped.sum())
    if drop:
        logger.info("dropped %d %s trial(s) (%d samples): %s", len(drop), reason, int(dropped.sum()), drop)
    return ~dropped


def _draw(pool: np.ndarray, n: int | None, rng: np.random.Generator, label: str, report: dict[str, Any]) -> np.ndarray:
    report[f"{label}_pool"] = int(len(pool))
    if n is None or len(pool) <= n:
        if n is not None and len(pool) < n:
            warn(DataWarning, logger, "%s pool has only %d points, fewer than the %d requested; using all", label, len(pool), n)
        return pool
    return np.sort(rng.choice(pool, size=n, replace=False))


def build_datasets(traj: Trajectory, config: DatasetConfig, *, progress: bool = False) -> GPDatasets:
    """Training and validation sets of eq. (11) from ``traj`` (see module docstring).

    Args:
        traj: the trajectory (a data file's; it is validated again, any trial length allowed).
        config: the dataset options.
        progress: show a progress bar over trials while estimating derivatives.

    Returns:
        :class:`GPDatasets` (train, val, report); both sets share the training normalization.

    Raises:
        DataError: short trials with ``short_trials="error"``, nothing left to train on,
            or too few trials to split.
    """
    from bemlearn.data.dataset_types import BEMDataset, GPDatasets  # torch: not needed to read a DatasetConfig

    validate(traj, source="build_datasets", min_trial_samples=1)  # cheap; in-memory trajectories too
    meta = traj.meta
    report: dict[str, Any] = {"trials_total": len(traj.trial_ids), "samples_total": traj.n_samples}
    est, choice = resolve_estimator(config.estimator(), traj, qu_window=config.qu_window)
    config = config.with_estimator(est) if choice is not None else config
    if choice is not None:
        report["derivative_choice"] = choice.to_dict()
    traj, source_rows = _kept_trials(traj, est, config, report)                 # step 1
    x_all, y_all, keep = _usable_samples(traj, est, config, report)             # steps 2-4
    train_rows, val_rows, train_ids, val_ids = _split_and_draw(traj, keep, config, report)   # steps 5-6

    names = gp_input_names(meta.joint_names, meta.unactuated)                   # step 7
    x = torch.as_tensor(x_all, dtype=torch.float64)
    y = torch.as_tensor(y_all, dtype=torch.float64)
    norm = Normalization.fit(x[train_rows], y[train_rows], names=names)

    def make(rows: np.ndarray) -> BEMDataset:
        idx = torch.as_tensor(rows, dtype=torch.long)
        return BEMDataset(
            x[idx], y[idx], normalization=norm, input_names=names, output_name=gp_output_name(meta.unactuated),
            meta=meta, trial=torch.as_tensor(traj.trial[rows]),
            row=torch.as_tensor(source_rows[rows], dtype=torch.int64),
        )

    logger.info(
        "GP dataset: %d training points (%d trials), %d validation points (%d trials), d = %d",
        report["n_train"], len(train_ids), report["n_val"], len(val_ids), len(names),
    )
    report["estimator"] = repr(est)
    return GPDatasets(train=make(train_rows), val=make(val_rows), report=report, config=config)


def _qu_unit(traj: Trajectory) -> str:
    """q_u's unit (rad for a hinge, m for a slide)."""
    return q_unit_label([traj.meta.joint_kinds[traj.meta.unactuated_index]])


def _kept_trials(traj: Trajectory, est: DerivativeEstimator, config: DatasetConfig,
                 report: dict[str, Any]) -> tuple[Trajectory, np.ndarray]:
    """Step 1: ``traj`` without the trials shorter than ``est`` needs (or an error) and, unless
    ``include_failed``, the failed ones; with the row in the caller's trajectory of each kept row."""
    meta = traj.meta
    need = est.min_samples(meta.sample_rate_hz)
    short = [s.trial_id for s in traj.trial_slices() if s.n_samples < need]
    if short and config.short_trials == "error":
        raise DataError(
            f"trial(s) {short} are shorter than the {need} samples the {est.name!r} estimator needs "
            "(set short_trials: drop to drop them)"
        )
    failed = [] if config.include_failed else [i for i in traj.trial_ids if meta.trial_failed[i] and i not in short]
    kept = _drop_trials(traj, short, f"short (< {need} samples)", report, "short")
    kept &= _drop_trials(traj, failed, "failed", report, "failed")
    source_rows = np.flatnonzero(kept)
    if len(source_rows) == 0:
        raise DataError("no trials left to build a dataset from (all were dropped; see the log)")
    return (traj.select_rows(kept) if len(source_rows) < traj.n_samples else traj), source_rows


def _usable_samples(traj: Trajectory, est: DerivativeEstimator, config: DatasetConfig,
                    report: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 2–4: the inputs ``x (N, 3n − 1)`` and label ``y (N,)`` of eq. (11) of every row, and the rows
    to keep: a valid derivative estimate (edges dropped where asked or where a smoother has no full
    kernel) and |q_u| within ``qu_window``."""
    meta = traj.meta
    rate = meta.sample_rate_hz
    raw_inside = traj.qu_window_mask(config.qu_window)
    q_all, qd, qdd, valid = estimate_states(traj, est, within=raw_inside)
    x_all = gp_inputs(q_all, qd, qdd, unactuated_index=meta.unactuated_index)
    y_all = q_all[:, meta.unactuated_index]

    keep = valid.copy()
    smooths = getattr(est, "smooths", False)
    if smooths:
        # the trials were cut to their runs inside the window before smoothing (no motion outside it
        # is smoothed in); count the rows outside as outside, the runs' ends as edges
        outside = np.zeros_like(valid) if raw_inside is None else ~raw_inside
        report["samples_dropped_edges"] = int((~valid & ~outside).sum())
        logger.info("dropped %d samples within %d of the end of a trial or of a run inside the |%s| window (no full %r "
                    "kernel there)", report["samples_dropped_edges"], est.edge_samples(rate), meta.unactuated, est.name)
        keep = valid | outside          # the window below removes the outside rows and counts them
    elif config.drop_edges:
        k = est.edge_samples(rate)
        for s in traj.trial_slices():
            keep[s.rows.start:s.rows.start + k] = False
            keep[max(s.rows.stop - k, s.rows.start):s.rows.stop] = False
        report["samples_dropped_edges"] = int((~keep).sum())
        logger.info("dropped %d edge samples (%d at each trial end)", report["samples_dropped_edges"], k)
    if config.qu_window is None:
        inside = np.ones_like(keep)
    else:
        inside = raw_inside if smooths and raw_inside is not None else np.abs(y_all - meta.qu_upright) <= config.qu_window
    report["samples_outside_window"] = int((keep & ~inside).sum())
    if config.qu_window is not None:
        logger.info(
            "dropped %d of %d samples with |%s| > %g %s", report["samples_outside_window"], int(keep.sum()),
            meta.qu_from_upright, config.qu_window, _qu_unit(traj),
        )
    return x_all, y_all, keep & inside


def _split_and_draw(traj: Trajectory, keep: np.ndarray, config: DatasetConfig,
                    report: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, list[int], list[int]]:
    """Steps 5–6: split the trials (seeded) and draw the training and validation rows among ``keep``.

    Returns:
        ``(train rows, validation rows, training trial ids, validation trial ids)``.
    """
    split_rng, train_rng, val_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(config.seed).spawn(3))
    train_ids, val_ids = split_trials(traj.trial_ids, config.val_fraction, split_rng)
    report["train_trials"], report["val_trials"] = train_ids, val_ids
    train_pool = np.flatnonzero(keep & np.isin(traj.trial, train_ids))
    val_pool = np.flatnonzero(keep & np.isin(traj.trial, val_ids))
    train_rows = _draw(train_pool, config.n_points, train_rng, "train", report)
    val_rows = _draw(val_pool, config.n_val_points, val_rng, "val", report)
    if len(train_rows) == 0:
        raise DataError(
            f"no training samples left after the |{traj.meta.qu_from_upright}| <= {config.qu_window} {_qu_unit(traj)} window "
            f"(training trials {train_ids})"
        )
    report["n_train"], report["n_val"] = int(len(train_rows)), int(len(val_rows))
    return train_rows, val_rows, train_ids, val_ids
