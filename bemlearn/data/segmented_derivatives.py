"""Derivatives estimated segment by segment: no window across an impact.

A log whose motion has discontinuities (a walker's foot strikes, a scuff, a hard stop) is not
one smooth signal per trial: q̇ jumps at each event, and any smoothing window that spans one
spreads the jump over its width (a Savitzky–Golay or Gaussian q̈ then carries a spike of
≈ Δv / window at every sample whose window reaches the event).  Here each trial is cut into
*segments* at its events and the estimator runs on each segment as if it were a trial of its own:

    trial rows [a, b), events e_1 < … < e_k  →  segments [a, e_1), [e_1, e_2), …, [e_k, b)

(an event at row e means the discontinuity lies between rows e − 1 and e).  Events come from the
log (markers it carries, e.g. the touchdowns a walker records) or from the data
(:func:`~bemlearn.data.velocity_jumps.detect_velocity_jumps`), or both.

What happens at a segment's ends is stated, never silent (:class:`SegmentReport`):

* ``edges="one-sided"``: the estimator's own treatment of a trial's ends applies at every segment
  end (Savitzky–Golay: the edge polynomial, one-sided; Gaussian: the first and last K samples are
  not valid);
* ``edges="drop"``: additionally, the :meth:`edge_samples` nearest each *event* (where the window
  would be one-sided) are not valid — only centred windows inside one segment are used next to an
  event (trial ends keep the estimator's own rule);
* ``settle``: the first ``settle`` samples after each event are not valid either (the event's own
  transient, e.g. a soft contact's compression, during which the motion is no longer the one the
  model describes);
* a segment shorter than the estimator's :meth:`min_samples` has no valid sample.

The counts of each are returned, so a caller can report how many samples the events cost.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from bemlearn.data.trajectory import Trajectory
from bemlearn.errors import ArgumentError

__all__ = ["SegmentReport", "segment_bounds", "estimate_segmented"]

Edges = Literal["one-sided", "drop"]


@dataclass(frozen=True)
class SegmentReport:
    """What splitting at events cost (:func:`estimate_segmented`).

    Attributes:
        events: events inside trials (segment starts that are not trial starts).
        segments: segments estimated on (including those too short).
        segments_too_short: segments shorter than the estimator's ``min_samples`` (rows not valid).
        rows_too_short: rows in those segments.
        rows_settle: rows not valid because they lie within ``settle`` samples after an event.
        rows_event_dropped: rows within a window's half width of an event that are not valid
            (``edges="drop"``, or the estimator's own rule at a segment end), ``settle`` rows apart.
        rows_one_sided: rows within a window's half width of an event kept with a one-sided window.
        rows_trial_edges: rows not valid at trial ends by the estimator's own rule.
        edges: ``"one-sided"`` or ``"drop"``.
        settle: ``settle`` samples.
    """

    events: int
    segments: int
    segments_too_short: int
    rows_too_short: int
    rows_settle: int
    rows_event_dropped: int
    rows_one_sided: int
    rows_trial_edges: int
    edges: str
    settle: int
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary."""
        return {"events": self.events, "segments": self.segments, "segments_too_short": self.segments_too_short,
                "rows_too_short": self.rows_too_short, "rows_settle": self.rows_settle,
                "rows_event_dropped": self.rows_event_dropped, "rows_one_sided": self.rows_one_sided, "edges": self.edges,
                "rows_trial_edges": self.rows_trial_edges, "settle": self.settle, **self.extra}


def segment_bounds(trial: np.ndarray, events: np.ndarray | None) -> list[tuple[int, int, bool, bool]]:
    """The segments of a log: ``(start, stop, starts_at_event, ends_at_event)`` row ranges.

    Args:
        trial: ``(T,)`` trial ids (contiguous runs).
        events: ``(T,)`` bool, True at the first row after a discontinuity; ``None``: none.
            An event at a trial's first row is that trial's start (no new segment).
    """
    trial = np.asarray(trial)
    T = trial.shape[0]
    starts = np.zeros(T, dtype=bool)
    if T:
        starts[0] = True
        starts[1:] = trial[1:] != trial[:-1]
    at_event = np.zeros(T, dtype=bool)
    if events is not None:
        events = np.asarray(events, dtype=bool)
        if events.shape != (T,):
            raise ArgumentError(f"segment_bounds: events must have shape ({T},), got {events.shape}")
        at_event = events & ~starts
    cut = np.flatnonzero(starts | at_event)
    stops = np.r_[cut[1:], T]
    return [(int(a), int(b), bool(at_event[a]), bool(b < T and at_event[b])) for a, b in zip(cut, stops)]


def estimate_segmented(traj: Trajectory, estimator, *, events: np.ndarray | None, edges: Edges = "drop",
                       settle: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, SegmentReport]:
    """q, q̇, q̈ of ``traj`` estimated within each segment (module docstring).

    Args:
        traj: the trajectory.
        estimator: a derivative estimator (:mod:`bemlearn.data.derivatives`); one that smooths
            (``smooths = True``, the Gaussian) also returns its smoothed q, per segment.
        events: ``(T,)`` bool, True at the first row after each discontinuity (``None``: the
            trials are the segments, as :func:`~bemlearn.data.derivative_choice.estimate_states`
            without ``within``).
        edges: ``"drop"`` or ``"one-sided"`` (module docstring).
        settle: rows after each event that are not valid, ≥ 0.

    Returns:
        ``q, qd, qdd`` ``(T, n)`` each (zeros where a segment was too short), ``valid (T,)`` bool
        and the :class:`SegmentReport`.
    """
    if edges not in ("drop", "one-sided"):
        raise ArgumentError(f"estimate_segmented: edges must be 'drop' or 'one-sided', got {edges!r}")
    if settle < 0:
        raise ArgumentError(f"estimate_segmented: settle must be >= 0, got {settle}")
    rate = traj.meta.sample_rate_hz
    need = estimator.min_samples(rate)
    smooths = bool(getattr(estimator, "smooths", False))
    own = 0 if getattr(estimator, "edges_valid", True) else estimator.edge_samples(rate)
    half = estimator.edge_samples(rate)
    q = traj.q.astype(np.float64, copy=True)
    qd = np.zeros_like(q)
    qdd = np.zeros_like(q)
    valid = np.zeros(traj.n_samples, dtype=bool)
    bounds = segment_bounds(traj.trial, events)
    short = rows_short = rows_settle = rows_dropped = rows_one_sided = rows_trial_edges = 0
    for a, b, ev_a, ev_b in bounds:
        if b - a < need:
            short += 1
            rows_short += b - a
            continue
        if smooths:
            q[a:b], qd[a:b], qdd[a:b] = estimator.filter(traj.q[a:b], sample_rate_hz=rate)
        else:
            qd[a:b], qdd[a:b] = estimator(traj.q[a:b], sample_rate_hz=rate)
        n = b - a
        idx = np.arange(n)
        settle_rows = (idx < settle) & ev_a
        near_event = ((idx < half) & ev_a) | ((idx >= n - half) & ev_b)
        trial_edge = ((idx < own) & (not ev_a)) | ((idx >= n - own) & (not ev_b))
        event_edge = ((idx < own) & ev_a) | ((idx >= n - own) & ev_b)
        dropped = event_edge | (near_event & (edges == "drop"))
        ok = ~(settle_rows | trial_edge | dropped)
        rows_settle += int(settle_rows.sum())
        rows_trial_edges += int((trial_edge & ~settle_rows).sum())
        # next to an event: dropped (edges="drop", or the estimator's own rule), or kept one-sided
        rows_dropped += int((near_event & ~settle_rows & ~trial_edge & dropped).sum())
        rows_one_sided += int((near_event & ok).sum())
        valid[a:b] = ok
    n_events = sum(1 for a, _, ev, _ in bounds if ev)
    report = SegmentReport(n_events, len(bounds), short, rows_short, rows_settle, rows_dropped, rows_one_sided, rows_trial_edges,
                           edges, int(settle))
    return q, qd, qdd, valid, report
