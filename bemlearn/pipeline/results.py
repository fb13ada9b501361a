"""What the stages of a run hand each other, in memory: :class:`CollectResult`, :class:`TrainResult`,
:class:`SimulateResult` (one :class:`LoopResult` per BEM source) and :class:`RunResult`.

A run passes these from stage to stage; its files (``data.npz``, ``metrics.json``, ``simulate/…``)
are outputs written from them, never the channel between stages of one run.  A stage run alone by
its own command (``bemlearn train``, ``bemlearn simulate``) still reads its inputs from files.

``metrics.json`` of a run is written once, by :meth:`RunResult.write_metrics`, from the typed
result (the closed loops as :meth:`LoopResult.summary`, the verdict judged once).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bemlearn.files import atomic_write_text

if TYPE_CHECKING:
    from bemlearn.data.trajectory import Trajectory
    from bemlearn.models.predictor_state import PredictorState
    from bemlearn.pipeline.run_metrics import RunMetrics
    from bemlearn.pipeline.verdict import Verdict
    from bemlearn.robots.protocol import BalanceRobot

__all__ = ["DataSummary", "CollectResult", "TrainResult", "Lemma1Check", "LoopResult", "SimulateResult", "RunResult"]


@dataclass(frozen=True)
class DataSummary:
    """The training data of a run, as the report and the verdict's excitation check read it.

    Attributes:
        file: the trajectory file (written by the run when it collected, else the config's ``data:``).
        collected: whether the run collected the data itself (excitation trials in MuJoCo).
        trials: number of trials in the data.
        failed: trials that ended in a fall.
        samples: rows of the trajectory.
        rate_hz: its sample rate (Hz).
        input_units: the unit of the logged input ``u``.
    """

    file: str
    collected: bool
    trials: int
    failed: int
    samples: int
    rate_hz: float
    input_units: str

    @classmethod
    def of(cls, data: Trajectory, path: Path, *, collected: bool) -> DataSummary:
        """The summary of trajectory ``data`` stored at ``path``."""
        meta = data.meta
        return cls(str(path), collected, len(meta.trial_failed), sum(meta.trial_failed.values()), data.n_samples,
                   meta.sample_rate_hz, meta.units.get("u", "actuator units"))

    def as_dict(self) -> dict[str, Any]:
        """The ``data`` entry of ``metrics.json``."""
        return {"file": self.file, "collected": self.collected, "trials": self.trials, "failed": self.failed,
                "samples": self.samples, "rate_hz": self.rate_hz, "input_units": self.input_units}


@dataclass(frozen=True)
class CollectResult:
    """The collect stage: what a rig would log and the simulator's truth, and where they were written.

    Attributes:
        data: the logged trajectory (quantized angles, inputs, trial outcomes).
        truth: the same rows with the simulator's q, q̇, q̈ (``None`` for data read from a file).
        path: the file ``data`` is stored in.
        summary: :class:`DataSummary` of ``data``.
    """

    data: Trajectory
    truth: Trajectory | None
    path: Path
    summary: DataSummary


@dataclass
class TrainResult:
    """The train stage: the fitted predictor, the data it learned from, and its evaluation.

    Attributes:
        metrics: the training run's summary (fit, hyperparameters, validation, held-out and design-region
            BEM evaluations, data-only checks): the entries of ``metrics.json`` training produces, typed
            (:class:`~bemlearn.pipeline.run_metrics.RunMetrics`).
        state: the frozen predictor (what the exporters write).
        trajectory: the trajectory it was trained on.
        robot: the robot that collected the data (``None`` for a model-free run).
    """

    metrics: RunMetrics
    state: PredictorState
    trajectory: Trajectory
    robot: BalanceRobot | None = None


@dataclass(frozen=True)
class Lemma1Check:
    """Lemma 1 (eq. 10) along the closed loop of the learned BEM: correlations of the learned ΔΓ and its split
    a Ḣ_u + b (b_u q̇_u^e) (:class:`~bemlearn.pipeline.lemma.LearnedLemma1`)."""

    r_learned_vs_model_delta_gamma: float
    r_learned_vs_hdot: float
    model_gap: float
    hdot_coefficient: float = float("nan")
    damping_coefficient: float = float("nan")
    r_model_damping: float = float("nan")
    damping_qu: float = 0.0
    delta_gamma_qu: float = float("nan")

    def as_dict(self) -> dict[str, float]:
        return {"r_learned_vs_model_delta_gamma": self.r_learned_vs_model_delta_gamma,
                "r_learned_vs_hdot": self.r_learned_vs_hdot, "model_gap": self.model_gap,
                "hdot_coefficient": self.hdot_coefficient, "damping_coefficient": self.damping_coefficient,
                "r_model_damping": self.r_model_damping, "damping_qu": self.damping_qu,
                "delta_gamma_qu": self.delta_gamma_qu}


#: The entries of a loop that a run's ``metrics.json`` keeps under ``closed_loop.<source>``.
_SUMMARY = ("fell", "diverged", "tracking_rmse", "tracking_max", "qu_max", "qu_dev_max", "u_max", "duration_s")
#: The learned-vs-model BEM entries along a loop (``predictor`` only), kept in both files when present.
_VS_MODEL = ("bem_vs_model_rmse", "bem_vs_model_max", "bem_inside_2sigma")


@dataclass(frozen=True)
class LoopResult:
    """One closed EIC loop (eq. 3, 8) of the simulate stage with one BEM source.

    Attributes:
        source: ``predictor`` (the learned BEM), ``model`` (eq. 9) or ``zero``.
        fell: the robot fell (|q_u − upright| beyond the fall bound) before the end.
        diverged: it stayed up but its actuated coordinates left the reference (> 2× its span).
        duration_s: simulated time (s): the loop's length, or the time of the fall.
        tracking_rmse: RMSE of q_a against its reference after the warm-up (q_a's unit).
        tracking_max: the largest |q_a − reference| after the warm-up.
        qu_max: the largest |q_u| (q_u's unit).
        qu_dev_max: the largest |q_u − upright| (q_u's unit).
        u_max: the largest |u| (actuator units).
        real_time_factor: simulated over wall time.
        metrics: every figure of the loop as ``simulate/metrics.json`` stores it (the fields above, the
            per-tick timings, rejected BEM values and commands).
        bem_vs_model_rmse: the learned BEM against the model's at the loop's BEM inputs (``predictor`` only).
        bem_vs_model_max: the largest |learned − model BEM| there (``predictor`` only).
        bem_inside_2sigma: the share of the model BEM inside the learned ±2σ band there (``predictor`` only).
        lemma1: Lemma 1 along the loop (``predictor`` with a periodic reference only).
    """

    source: str
    fell: bool
    diverged: bool
    duration_s: float
    tracking_rmse: float
    tracking_max: float
    qu_max: float
    qu_dev_max: float
    u_max: float
    real_time_factor: float
    metrics: Mapping[str, Any] = field(repr=False)
    bem_vs_model_rmse: float | None = None
    bem_inside_2sigma: float | None = None
    lemma1: Lemma1Check | None = None
    bem_vs_model_max: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """The entry of ``simulate/metrics.json``."""
        out = {**self.metrics, "diverged": self.diverged}
        out.update(self._vs_model())
        if self.lemma1 is not None:
            out["lemma1"] = self.lemma1.as_dict()
        return out

    def _vs_model(self) -> dict[str, float]:
        return {k: v for k in _VS_MODEL if (v := getattr(self, k)) is not None}

    def summary(self) -> dict[str, Any]:
        """The entry of a run's ``metrics.json`` under ``closed_loop.<source>``."""
        out: dict[str, Any] = {k: getattr(self, k) for k in _SUMMARY}
        out.update(self._vs_model())
        if self.lemma1 is not None:
            out["lemma1"] = self.lemma1.as_dict()
        return out


@dataclass(frozen=True)
class SimulateResult:
    """The simulate stage: one :class:`LoopResult` per BEM source, in the order they ran."""

    loops: dict[str, LoopResult]

    def as_dict(self) -> dict[str, dict[str, Any]]:
        """``simulate/metrics.json``: ``{source: LoopResult.as_dict()}``."""
        return {src: loop.as_dict() for src, loop in self.loops.items()}

    def summary(self) -> dict[str, dict[str, Any]]:
        """A run's ``closed_loop`` entry: ``{source: LoopResult.summary()}``."""
        return {src: loop.summary() for src, loop in self.loops.items()}


@dataclass
class RunResult:
    """A whole run (``bemlearn run``): its folder, its verdict, and the results of its stages.

    Attributes:
        out: the run folder.
        verdict: the run's verdict (:func:`~bemlearn.pipeline.verdict.judge_run`), judged once.
        metrics: the run's ``metrics.json``, typed (:class:`~bemlearn.pipeline.run_metrics.RunMetrics`; written
            by :meth:`write_metrics`).
        collect: the collect stage (``None`` when the run trained on a file or stopped before).
        train: the train stage (``None`` when the run stopped before training).
        simulate: the closed loops (``None`` for a model-free run or one that stopped before).
        report: ``report.md``.
    """

    out: Path
    verdict: Verdict
    metrics: RunMetrics
    collect: CollectResult | None = None
    train: TrainResult | None = None
    simulate: SimulateResult | None = None
    report: Path | None = None

    def write_metrics(self) -> Path:
        """Write ``out/metrics.json`` (atomically); returns its path."""
        path = self.out / "metrics.json"
        atomic_write_text(path, json.dumps(self.metrics.as_dict(), indent=2, default=float))
        return path
