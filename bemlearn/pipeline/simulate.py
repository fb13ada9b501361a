"""A closed-loop stage: run the EIC loop with one or more BEM sources, log, plot, measure.

Returns a :class:`~bemlearn.pipeline.results.SimulateResult` (one
:class:`~bemlearn.pipeline.results.LoopResult` per source); writes ``simulate/metrics.json``,
``simulate/fig2_<source>.png`` (the paper's Fig. 2 layout) and TensorBoard scalars under
``tb/simulate``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path
from typing import Literal, cast

import numpy as np
import torch

from bemlearn.files import atomic_write_text
from bemlearn.pipeline.config import PipelineConfig
from bemlearn.pipeline.results import Lemma1Check, LoopResult, SimulateResult
from bemlearn.robots import MujocoRobot, load
from bemlearn.robots.protocol import BalanceRobot
from bemlearn.sim.closed_loop import nominal_robot, simulate
from bemlearn.sim.figures import plot_run
from bemlearn.units import joint_unit

__all__ = ["simulate_stage"]

log = logging.getLogger(__name__)


def simulate_stage(config: PipelineConfig, out_dir: str | Path, *, predictor: str | Path | None = None,
                   sources: tuple[Literal["predictor", "model", "zero"], ...] = ("predictor", "model", "zero"), progress: bool = True,
                   gif: bool = False, robot: BalanceRobot | None = None) -> SimulateResult:
    """Run the closed loop for each BEM source in ``sources``.

    ``robot``: the robot of ``config.robot`` when the caller has loaded it already (a run loads it once).
    ``gif=True`` also writes ``simulate/<source>.gif`` (first 10 s, offscreen rendering;
    the OpenGL backend is picked by :func:`~bemlearn.sim.render.require_offscreen_backend`).
    """
    out = Path(out_dir) / "simulate"
    out.mkdir(parents=True, exist_ok=True)
    scfg = config.simulate
    predictor = predictor or scfg.predictor
    assert config.robot is not None and scfg.rate_hz is not None  # a robot run, completed by complete_section
    loops: dict[str, LoopResult] = {}
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(Path(out_dir) / "tb" / "simulate"))
    robot = robot if robot is not None else load(str(config.robot))   # the callers check that the config names a robot
    nominal = nominal_robot(robot, scfg.nominal)
    for src in sources:
        cfg = dataclasses.replace(scfg, bem_source=src, predictor=str(predictor) if predictor else None)
        res = simulate(robot, cfg, progress=progress)
        m = dict(res.metrics)
        # a run that stayed up but whose actuated coordinates left the reference (e.g. the zero BEM's
        # drifting arm: for m = 1 the external loop acts only through the BEM) has diverged
        span = float(np.abs(res.qa_ref).max()) if len(res.qa_ref) else 0.0
        diverged = bool(not res.fell and span > 0 and np.isfinite(m["tracking_max"]) and m["tracking_max"] > 2 * span)
        vs_model = inside = None
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
            inside = float(np.mean(np.abs(mean - model_bem) <= 2 * std)) if len(x) else float("nan")
            ref = cfg.reference.build(mm)
            if np.isfinite(ref.period):
                from bemlearn.pipeline.lemma import learned_lemma1

                L = learned_lemma1(pred, pred.full, nominal, ref)
                check = Lemma1Check(L.r, L.r_hdot, L.model_gap)
                lemma = {"t": L.t, "delta_gamma": L.delta_gamma_learned, "hdot": L.hdot, "delta_gamma_model": L.delta_gamma_model}
        ia, iu = nominal.actuated_index[0], nominal.unactuated_index
        kinds = nominal.coordinate_kinds
        plot_run(res, out / f"fig2_{src}.png", model_bem=model_bem, band=band, lemma=lemma,
                 joint_names=(nominal.joint_names[ia], nominal.joint_names[iu]),
                 units=(joint_unit(kinds[ia]), joint_unit(kinds[iu])), indices=(ia, iu),
                 input_label=f"u ({config.collect.input_units or 'ctrl'})")
        if gif:
            from bemlearn.sim.render import render_gif

            render_gif(cast(MujocoRobot, robot), res.q, out / f"{src}.gif", rate_hz=scfg.rate_hz)
        loop = LoopResult(src, bool(res.fell), diverged, float(m["duration_s"]), float(m["tracking_rmse"]), float(m["tracking_max"]),
                          float(m["qu_max"]), float(m["qu_dev_max"]), float(m["u_max"]), float(m["real_time_factor"]), m, vs_model,
                          inside, check)
        for k in ("tracking_rmse", "tracking_max", "qu_max", "u_max", "real_time_factor"):
            writer.add_scalar(f"simulate/{src}/{k}", getattr(loop, k), 0)
        loops[src] = loop
        log.info("simulate %s: fell %s, tracking RMSE %.4g, max |u| %.3g", src, loop.fell, loop.tracking_rmse, loop.u_max)
    writer.close()
    result = SimulateResult(loops)
    atomic_write_text(out / "metrics.json", json.dumps(result.as_dict(), indent=2, default=float))
    return result
