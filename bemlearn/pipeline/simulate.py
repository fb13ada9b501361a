"""A closed-loop stage: run the EIC loop with one or more BEM sources, log, plot, measure.

Returns a :class:`~bemlearn.pipeline.results.SimulateResult` (one
:class:`~bemlearn.pipeline.results.LoopResult` per source); writes ``simulate/metrics.json``,
``simulate/fig2_<source>.png`` (the paper's Fig. 2 layout) and TensorBoard scalars under
``tb/simulate``.

With ``jobs > 1`` the loops run concurrently in forked worker processes
(:func:`~bemlearn.pipeline.workers.worker_pool`): :func:`start_loops` submits them to a
:func:`loop_pool` and returns their futures, which :func:`simulate_stage` takes as ``started``
(a run starts the model and zero loops before training, :mod:`bemlearn.pipeline.run`).  Each
loop is seeded by its own config, so the results are the same for any ``jobs`` and are reported
in the order of ``sources``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
from collections.abc import Mapping
from concurrent.futures import Executor, Future
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, cast

import numpy as np
import torch

from bemlearn.files import atomic_write_bytes, atomic_write_text
from bemlearn.pipeline.config import PipelineConfig
from bemlearn.pipeline.results import Lemma1Check, LoopResult, SimulateResult
from bemlearn.pipeline.workers import check_jobs, worker_pool
from bemlearn.robots import MujocoRobot, load
from bemlearn.robots.protocol import BalanceRobot
from bemlearn.sim.closed_loop import nominal_robot, simulate
from bemlearn.sim.figures import run_png
from bemlearn.units import joint_unit

__all__ = ["simulate_stage", "start_loops", "loop_pool", "LoopOutput", "Source", "SOURCES"]

#: A BEM source of the closed loop (:data:`~bemlearn.control.bem_sources.BEM_SOURCES`).
Source = Literal["predictor", "model", "zero"]
#: The sources of a run, in the order its loops are reported.
SOURCES: tuple[Source, ...] = ("predictor", "model", "zero")


@dataclass(frozen=True)
class LoopOutput:
    """What one closed loop hands back (from a worker or in process): its result and its Fig. 2.

    Attributes:
        loop: the loop's :class:`~bemlearn.pipeline.results.LoopResult`.
        figure_png: ``simulate/fig2_<source>.png`` as bytes (written by :func:`simulate_stage`, so that
            a loop ended early by a failed run leaves no file behind).
    """

    loop: LoopResult
    figure_png: bytes

log = logging.getLogger(__name__)


def simulate_stage(config: PipelineConfig, out_dir: str | Path, *, predictor: str | Path | None = None,
                   sources: tuple[Source, ...] = SOURCES, progress: bool = True, gif: bool = False,
                   robot: BalanceRobot | None = None, jobs: int = 1,
                   started: Mapping[str, Future[LoopOutput]] | None = None) -> SimulateResult:
    """Run the closed loop for each BEM source in ``sources``.

    ``robot``: the robot of ``config.robot`` when the caller has loaded it already (a run loads it once).
    ``gif=True`` also writes ``simulate/<source>.gif`` (first 10 s, offscreen rendering;
    the OpenGL backend is picked by :func:`~bemlearn.sim.render.require_offscreen_backend`); the loops
    then run one after the other (no OpenGL context in a forked worker).
    ``jobs``: worker processes for the loops not in ``started`` (1: one after the other, here).
    ``started``: loops already running (:func:`start_loops`), by source; their results are awaited here,
    and a loop that failed raises its error here.
    """
    check_jobs(jobs)
    out = Path(out_dir) / "simulate"
    out.mkdir(parents=True, exist_ok=True)
    predictor = predictor or config.simulate.predictor
    assert config.robot is not None and config.simulate.rate_hz is not None  # a robot run, completed by complete_section
    robot = robot if robot is not None else load(str(config.robot), coordinates=config.coordinates)   # the callers check that the config names a robot
    futures: dict[str, Future[LoopOutput]] = {src: f for src, f in (started or {}).items() if src in sources}
    todo = tuple(src for src in sources if src not in futures)
    with contextlib.ExitStack() as stack:
        pool = stack.enter_context(loop_pool(robot, min(jobs, len(todo)) or 1)) if jobs > 1 and todo and not gif else None
        if pool is not None:
            futures.update(start_loops(pool, config, out_dir, sources=todo, predictor=predictor))
        from torch.utils.tensorboard import SummaryWriter

        writer = SummaryWriter(str(Path(out_dir) / "tb" / "simulate"))
        nominal = None
        loops: dict[str, LoopResult] = {}
        try:
            for src in sources:
                if src in futures:
                    done = futures[src].result()
                else:
                    nominal = nominal if nominal is not None else nominal_robot(robot, config.simulate.nominal)
                    done = _run_loop(robot, nominal, config, out_dir, src, predictor=predictor, progress=progress, gif=gif)
                atomic_write_bytes(out / f"fig2_{src}.png", done.figure_png)
                loop = done.loop
                for k in ("tracking_rmse", "tracking_max", "qu_max", "u_max", "real_time_factor"):
                    writer.add_scalar(f"simulate/{src}/{k}", getattr(loop, k), 0)
                loops[src] = loop
                log.info("simulate %s: fell %s, tracking RMSE %.4g, max |u| %.3g", src, loop.fell, loop.tracking_rmse, loop.u_max)
        finally:
            writer.close()
    result = SimulateResult(loops)
    atomic_write_text(out / "metrics.json", json.dumps(result.as_dict(), indent=2, default=float))
    return result


_LOOP_ROBOT: BalanceRobot | None = None


def _set_loop_robot(robot: BalanceRobot | None) -> None:
    """A loop worker's initializer: the robot it inherited from the parent (forked, not pickled)."""
    global _LOOP_ROBOT
    _LOOP_ROBOT = robot


def loop_pool(robot: BalanceRobot | None, jobs: int) -> contextlib.AbstractContextManager[Executor | None]:
    """:func:`~bemlearn.pipeline.workers.worker_pool` of ``jobs`` workers that hold ``robot`` (``None``: serial).

    ``robot`` may be ``None`` for a pool that runs no loop (a model-free run's ``.pt2`` export).
    """
    return worker_pool(jobs, initializer=_set_loop_robot, initargs=(robot,))


def start_loops(pool: Executor, config: PipelineConfig, out_dir: str | Path, *, sources: tuple[Source, ...],
                predictor: str | Path | None = None) -> dict[str, Future[LoopOutput]]:
    """Submit the loops of ``sources`` to ``pool`` (a :func:`loop_pool`); their futures by source.

    Each worker runs a loop as :func:`simulate_stage` would (plot included, no progress bar) and returns
    its :class:`LoopOutput` (nothing is written by the worker); pass the futures to :func:`simulate_stage` as
    ``started``.  ``predictor``: the exported predictor file (it must exist when the ``predictor``
    loop starts).
    """
    predictor = predictor or config.simulate.predictor
    return {src: pool.submit(_loop_in_worker, config, out_dir, src, predictor) for src in sources}


def _loop_in_worker(config: PipelineConfig, out_dir: str | Path, src: Source, predictor: str | Path | None) -> LoopOutput:
    assert _LOOP_ROBOT is not None, "loop_pool's initializer sets the robot"
    nominal = nominal_robot(_LOOP_ROBOT, config.simulate.nominal)
    return _run_loop(_LOOP_ROBOT, nominal, config, out_dir, src, predictor=predictor, progress=False, gif=False)


def _run_loop(robot: BalanceRobot, nominal: BalanceRobot, config: PipelineConfig, out_dir: str | Path, src: Source, *,
              predictor: str | Path | None, progress: bool, gif: bool) -> LoopOutput:
    """One closed loop with BEM source ``src``, its comparison with the model BEM (eq. 9) and its Fig. 2."""
    out = Path(out_dir) / "simulate"
    scfg = config.simulate
    assert scfg.rate_hz is not None  # complete_section derives it
    cfg = dataclasses.replace(scfg, bem_source=src, predictor=str(predictor) if predictor else None)
    res = simulate(robot, cfg, progress=progress)
    m = dict(res.metrics)
    # a run that stayed up but whose actuated coordinates left the reference (e.g. the zero BEM's
    # drifting arm: for m = 1 the external loop acts only through the BEM) has diverged
    span = float(np.abs(res.qa_ref).max()) if len(res.qa_ref) else 0.0
    diverged = bool(not res.fell and span > 0 and np.isfinite(m["tracking_max"]) and m["tracking_max"] > 2 * span)
    vs_model = vs_model_max = inside = None
    check = None
    # model-based BEM of the nominal robot at the loop's BEM inputs (eq. 9), for comparison
    x = torch.from_numpy(res.bem_x)
    mm = nominal.m
    model_bem = nominal.bem(x[:, 2 * mm :], x[:, mm : 2 * mm], x[:, :mm]).qu.numpy() if len(x) else np.zeros(0)
    band = None
    lemma = None
    if src == "predictor":
        from bemlearn.control.bem_sources import PredictorBEM

        assert predictor is not None, "simulate_stage: the 'predictor' source needs a predictor file"
        pred = PredictorBEM(predictor, robot=nominal)
        mean, std = pred.mean_std(res.bem_x) if len(x) else (np.zeros(0), np.zeros(0))
        band = (mean, std)
        vs_model = float(np.sqrt(np.nanmean((mean - model_bem) ** 2))) if len(x) else float("nan")
        vs_model_max = float(np.nanmax(np.abs(mean - model_bem))) if len(x) else float("nan")
        inside = float(np.mean(np.abs(mean - model_bem) <= 2 * std)) if len(x) else float("nan")
        ref = cfg.reference.build(mm)
        if np.isfinite(ref.period):
            from bemlearn.pipeline.lemma import learned_lemma1, lemma1_reference

            ref, how = lemma1_reference(ref)   # one period its nodes resolve (written frequencies can repeat only after 1e4 s)
            if how:
                log.info("simulate: Lemma 1 checked %s", how)
            L = learned_lemma1(pred, pred.full, nominal, ref)
            check = Lemma1Check(L.r, L.r_hdot, L.model_gap, L.hdot_coefficient, L.damping_coefficient, L.r_model_damping,
                                L.damping_qu, L.delta_gamma_qu)
            lemma = {"t": L.t, "delta_gamma": L.delta_gamma_learned, "hdot": L.hdot, "delta_gamma_model": L.delta_gamma_model}
    ia, iu = nominal.actuated_index[0], nominal.unactuated_index
    kinds = nominal.coordinate_kinds
    png = run_png(res, model_bem=model_bem, band=band, lemma=lemma, joint_names=(nominal.joint_names[ia], nominal.joint_names[iu]),
                  units=(joint_unit(kinds[ia]), joint_unit(kinds[iu])), indices=(ia, iu),
                  input_label=f"u ({config.collect.input_units or 'ctrl'})")
    if gif:
        from bemlearn.sim.render import render_gif

        render_gif(cast(MujocoRobot, robot), res.q, out / f"{src}.gif", rate_hz=scfg.rate_hz)
    loop = LoopResult(src, bool(res.fell), diverged, float(m["duration_s"]), float(m["tracking_rmse"]), float(m["tracking_max"]),
                      float(m["qu_max"]), float(m["qu_dev_max"]), float(m["u_max"]), float(m["real_time_factor"]), m, vs_model,
                      inside, check, vs_model_max)
    return LoopOutput(loop, png)
