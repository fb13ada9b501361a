"""The main job: collect → train → export → evaluate → closed loop → report, in one run folder.

With ``robot:`` (a registry name or any MJCF path) the run collects excitation data in MuJoCo,
unless ``data:`` names a trajectory file to train on instead; the learned BEM is compared with
the robot's model-based BEM and flown in the EIC loop.  Without ``robot:`` (``data:`` only) the
run is model-free: train → export → data-only evaluation → report, and nothing is compared with
a model unless ``model:`` names one.

The run folder holds ``config.yaml`` (the resolved config), ``config_resolved.json`` (every
value with its origin), ``data.npz`` (+ ``data.truth.npz``) when collected, the training run
(``checkpoint.pt``, ``metrics.json``, ``tb/``), the predictors, ``simulate/`` and ``report.md``.
``metrics.json`` gains ``closed_loop.<source>.{fell, diverged, tracking_rmse, ...}`` per BEM source
and ``verdict`` (:mod:`bemlearn.pipeline.verdict`): ``ok``, ``degraded`` or ``unusable`` with its
reasons, also the first lines of ``report.md``.

Before collecting, a robot run checks from the model that the robot can be balanced over the
design region (:mod:`bemlearn.pipeline.feasibility`); when it cannot, the run stops there with an
``unusable`` verdict in ``metrics.json`` and ``report.md``.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

from bemlearn.config import save_yaml
from bemlearn.errors import DataError
from bemlearn.files import atomic_write_text, new_run_dir
from bemlearn.pipeline.config import PipelineConfig
from bemlearn.pipeline.resolve import ResolvedConfig, resolve_pipeline_config
from bemlearn.pipeline.results import CollectResult, DataSummary, RunResult, SimulateResult
from bemlearn.pipeline.run_metrics import DataInfo, Equilibrium, LoopMetrics, ModelCheck, RunMetrics
from bemlearn.pipeline.verdict import judge_run

__all__ = ["run_pipeline"]

log = logging.getLogger(__name__)


def run_pipeline(config: PipelineConfig | ResolvedConfig, out_dir: str | Path | None = None, *,
                 device: str | None = None, progress: bool = True, jobs: int = 1) -> RunResult:
    """Run every stage of ``config`` into ``out_dir`` (default: a new ``runs/<robot or data stem>-<timestamp>``,
    :func:`~bemlearn.files.new_run_dir`).

    The stages hand their typed results to each other in memory (:mod:`bemlearn.pipeline.results`): the
    robot is loaded once, the collected data go to training as they are, and ``metrics.json`` is written
    once with the verdict judged once.

    ``jobs``: worker processes for the work that can overlap the serial stages (the closed loops, the
    ``.pt2`` export: :mod:`bemlearn.pipeline.overlap`); ``1`` runs every stage in order in this process.
    The results do not depend on it.
    """
    from bemlearn.pipeline.overlap import RunOverlap

    resolved = config if isinstance(config, ResolvedConfig) else resolve_pipeline_config(_as_dict(config))
    out = Path(out_dir) if out_dir else new_run_dir(Path(resolved.config.robot or resolved.config.data or "run").stem)
    with RunOverlap(resolved.config, out, jobs=jobs) as overlap:
        return _run_stages(resolved, out, overlap, device=device, progress=progress)


def _run_stages(resolved: ResolvedConfig, out: Path, overlap, *, device: str | None, progress: bool) -> RunResult:
    """The stages of :func:`run_pipeline`, with the work ``overlap`` (a :class:`~bemlearn.pipeline.overlap.RunOverlap`)
    runs beside them."""
    from bemlearn.data.trajectory_io import ground_truth_path, read_trajectory, write_trajectory
    from bemlearn.pipeline.report import write_report
    from bemlearn.pipeline.simulate import simulate_stage
    from bemlearn.pipeline.train import train_run
    from bemlearn.sim.collect import collect

    cfg = resolved.config
    out.mkdir(parents=True, exist_ok=True)
    started_ns = time.time_ns()
    save_yaml(cfg, out / "config.yaml")
    atomic_write_text(out / "config_resolved.json", json.dumps(resolved.to_json_dict(), indent=2, ensure_ascii=False))
    t0 = time.perf_counter()
    stages = 5 if cfg.robot else 3
    feasibility: list = []
    equilibrium: dict | None = None
    loaded = None
    if cfg.robot:
        from bemlearn.pipeline.feasibility import equilibrium_stiffness, model_feasibility
        from bemlearn.robots import MujocoRobot, resolve_robot

        loaded = resolve_robot(cfg.robot, coordinates=cfg.coordinates)
        robot = loaded[0]
        equilibrium = equilibrium_stiffness(robot)      # a stable equilibrium is never reported as balanced
        if isinstance(robot, MujocoRobot):
            feasibility = [c.to_dict() for c in model_feasibility(robot, cfg)]
            stop = [c for c in feasibility if not c["passed"] and c["severity"] == "unusable"]
            if stop:
                return _stop_after_preflight(out, cfg, resolved, feasibility, t0)
        overlap.start_model_loops(robot)   # they need no training: beside collection and training (jobs > 1)
    collected: CollectResult | None = None
    if cfg.data is None:
        log.info("[1/%d] collecting excitation data", stages)
        assert cfg.robot is not None  # PipelineConfig needs robot or data
        try:
            data, truth = collect(cfg.robot, cfg.collect, progress=progress, coordinates=cfg.coordinates)
        except DataError as exc:   # e.g. every excitation trial fell at once: a finding about the robot, not a crash
            overlap.cancel()
            return _stop_after_collect(out, cfg, resolved, feasibility, exc, t0)
        data_path = write_trajectory(data, out / "data.npz")
        write_trajectory(truth, ground_truth_path(data_path))
        collected = CollectResult(data, truth, data_path, DataSummary.of(data, data_path, collected=True))
        summary = collected.summary
    else:
        data_path = Path(cfg.data)
        data = read_trajectory(data_path)
        summary = DataSummary.of(data, data_path, collected=False)
        log.info("[1/%d] training data: %s", stages, data_path)
    log.info("[2/%d] training the BEM GP", stages)
    t_train = time.time_ns()
    try:
        train = train_run(cfg, data_path, out, device=device, progress=progress, trajectory=data, loaded=loaded, part_of_run=True,
                          on_checkpoint=overlap.hook(loaded[0] if loaded else None))
    except Exception as exc:
        _train_failed(out, exc, summary.as_dict(), collected=cfg.data is None, since_ns=t_train, started_ns=started_ns)
        raise
    metrics = train.metrics
    stage = "export"
    sim: SimulateResult | None = None
    try:   # the checkpoint exists: a failure from here on keeps the folder, and metrics.json says where it stopped
        log.info("[3/%d] exporting the predictor", stages)
        files = overlap.export()      # export_run(out, fmt="both"), or the overlapped export's files
        if cfg.robot:
            stage = "simulate"
            log.info("[4/%d] closed-loop simulation", stages)
            sim = simulate_stage(cfg, out, predictor=overlap.predictor, progress=progress, robot=train.robot, started=overlap.loops)
            metrics.closed_loop = {src: LoopMetrics.from_dict(loop) for src, loop in sim.summary().items()}
        stage = "verdict"
        metrics.data = DataInfo.from_dict(summary.as_dict())
        metrics.feasibility = tuple(ModelCheck.from_dict(c) for c in feasibility)
        if equilibrium is not None:
            metrics.equilibrium = Equilibrium.from_dict(equilibrium)
        verdict = judge_run(metrics)
        metrics.verdict = verdict
        result = RunResult(out, verdict, metrics, collected, train, sim)
        result.write_metrics()
        _record_data_choices(out, resolved, metrics)
        stage = "report"
        log.info("[%d/%d] report", stages, stages)
        result.report = write_report(out, config=cfg, resolved=resolved, data=metrics.data, train=metrics, export=files,
                                     sim={src: LoopMetrics.from_dict(loop) for src, loop in sim.as_dict().items()} if sim is not None else {})
    except Exception as exc:
        from bemlearn.pipeline.failure import record_failure

        if metrics.data is None:
            metrics.data = DataInfo.from_dict(summary.as_dict())
        if metrics.feasibility is None:
            metrics.feasibility = tuple(ModelCheck.from_dict(c) for c in feasibility)
        record_failure(out, stage, exc, metrics.as_dict(), since_ns=started_ns)
        raise
    log.info("done in %.0f s: %s", time.perf_counter() - t0, result.report)
    return result


def _train_failed(out: Path, exc: Exception, data_info: dict, *, collected: bool, since_ns: int, started_ns: int) -> None:
    """Record a failed training stage in metrics.json when the run keeps something: the checkpoint it wrote
    (train_run recorded where its evaluation stopped; the data's summary is added) or the data it collected."""
    from bemlearn.pipeline.failure import read_metrics, record_failure

    ck = out / "checkpoint.pt"
    if ck.is_file() and ck.stat().st_mtime_ns >= since_ns:
        written = RunMetrics.from_dict(read_metrics(out))
        written.data = DataInfo.from_dict(data_info)
        if written.failed is not None:
            atomic_write_text(out / "metrics.json", json.dumps(written.as_dict(), indent=2, default=float))
            return
        record_failure(out, "train", exc, written.as_dict(), since_ns=started_ns)
    elif collected:
        record_failure(out, "train", exc, {"data": data_info}, since_ns=started_ns)


def _stop_after_preflight(out: Path, cfg: PipelineConfig, resolved: ResolvedConfig, feasibility: list, t0: float) -> RunResult:
    """Write the verdict of a robot its model says cannot be balanced (metrics.json, report.md); no data."""
    from bemlearn.pipeline.report import write_report

    metrics = RunMetrics.from_dict({"robot": {"name": Path(str(cfg.robot)).stem, "source": str(cfg.robot)},
                                    "feasibility": feasibility, "stopped_after": "preflight"})
    verdict = judge_run(metrics)
    metrics.verdict = verdict
    result = RunResult(out, verdict, metrics)
    result.write_metrics()
    result.report = write_report(out, config=cfg, resolved=resolved, data=None, train=metrics, export=[], sim={})
    log.warning("stopped after the model checks (%.1f s): %s", time.perf_counter() - t0, "; ".join(verdict.reasons))
    return result


def _stop_after_collect(out: Path, cfg: PipelineConfig, resolved: ResolvedConfig, feasibility: list, exc: Exception,
                        t0: float) -> RunResult:
    """Write the verdict of a run whose excitation produced no usable data (metrics.json, report.md)."""
    from bemlearn.pipeline.failure import record_failure
    from bemlearn.pipeline.report import write_report

    doc: dict[str, Any] = {"robot": {"name": Path(str(cfg.robot)).stem, "source": str(cfg.robot)}, "feasibility": feasibility,
                           "stopped_after": "collect"}
    metrics = RunMetrics.from_dict(record_failure(out, "collect", exc, doc))   # written there, with its verdict
    assert metrics.verdict is not None
    verdict = metrics.verdict
    result = RunResult(out, verdict, metrics)
    result.report = write_report(out, config=cfg, resolved=resolved, data=None, train=metrics, export=[], sim={})
    log.warning("stopped after collecting (%.1f s): %s", time.perf_counter() - t0, "; ".join(verdict.reasons))
    return result


def _record_data_choices(out: Path, resolved: ResolvedConfig, metrics: RunMetrics) -> None:
    """Add the values chosen from the data when training (e.g. the Gaussian σ) to config_resolved.json."""
    choice = metrics.dataset.derivative_choice if metrics.dataset else None
    if not choice:
        return
    rows = resolved.to_json_dict()
    rows["dataset.derivative_options.sigma_s"] = {"value": choice.sigma_s, "origin": "data", "note": choice.note}
    atomic_write_text(out / "config_resolved.json", json.dumps(rows, indent=2, ensure_ascii=False))


def _as_dict(config: PipelineConfig) -> dict:
    """A parsed config as the mapping it came from (its values then count as given)."""
    from bemlearn.config import to_dict

    return to_dict(config)
