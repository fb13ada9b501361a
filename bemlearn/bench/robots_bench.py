"""``bemlearn bench robots``: the whole chain on MJCF robots with derived values only.

Per robot (no per-robot tuning; every value derived from the model exactly as ``bemlearn run`` derives it for a
config naming only the file, :func:`~bemlearn.pipeline.resolve.resolve_pipeline_config`):
collect → write → train (exact GP) → export → learned vs model BEM on the derived held-out
references, errors over |q_u^e − nominal| ≤ d (the design bound) → closed loop with the
BEM sources ``predictor``, ``model`` and ``zero`` at the derived rate, gains and reference.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

if TYPE_CHECKING:
    from bemlearn.models.predictor_state import PredictorState
    from bemlearn.robots.protocol import BalanceRobot
    from bemlearn.robots.reference import CompositeSinusoid

__all__ = ["robot_chain", "format_robots_bench"]


def _configs(robot_path: str, *, n_trials: int, duration_s: float, sim_duration_s: float, workers: int, seed: int):
    """The pipeline config of ``robot_path`` with derived values only (as ``bemlearn run`` resolves a config
    naming just the file), and the run length of the bench; returns ``(config, resolved)``."""
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    resolved = resolve_pipeline_config({
        "robot": robot_path,
        "collect": {"n_trials": n_trials, "duration_s": duration_s, "workers": workers, "seed": seed},
        "simulate": {"duration_s": sim_duration_s},
    }, source=f"bench robots: {robot_path}")
    return resolved.config, resolved


def heldout_bem_errors(state: PredictorState, robot: BalanceRobot, references: list[CompositeSinusoid], *, bound: float, duration_s: float, rate_hz: float) -> dict:
    """Learned (μ at x_0^e, eq. 14) minus model BEM (eq. 9) on ``references``, over |q_u^e − nominal| ≤ ``bound``."""
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    errs, peaks, nan = [], [], 0
    for ref in references:
        qa, qad, qadd = ref.evaluate(t)
        model = robot.bem(qa, qad, qadd).qu.numpy()
        x = np.concatenate([qadd, qad, qa, np.zeros((t.size, 2))], axis=1)
        mean = state.predict_reference(torch.from_numpy(x))[0].numpy()
        ok = np.isfinite(model) & (np.abs(model - robot.qu_nominal) <= bound)
        nan += int((~np.isfinite(model)).sum())
        errs.append((mean - model)[ok])
        peaks.append(float(np.nanmax(np.abs(model - robot.qu_nominal))))
    e = np.concatenate(errs)
    return {"rmse": float(np.sqrt(np.mean(e**2))), "max_abs": float(np.abs(e).max()), "n_points": int(e.size),
            "bem_peak": max(peaks), "no_model_root": nan}


def robot_chain(robot_path: str, out_dir: str | Path, *, n_trials: int = 24, duration_s: float = 20.0, sim_duration_s: float = 30.0,
                workers: int = 1, seed: int = 0, progress: Callable[[str], None] = lambda s: None) -> dict:
    """Run the chain of the module docstring on one MJCF file; returns a row of figures."""
    from bemlearn.data.trajectory_io import ground_truth_path, write_trajectory
    from bemlearn.export.export_run import export_run
    from bemlearn.pipeline.evaluation import held_out_references
    from bemlearn.pipeline.train import train_run
    from bemlearn.robots import load
    from bemlearn.sim.closed_loop import simulate
    from bemlearn.sim.collect import collect

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    robot = load(robot_path)
    cfg, resolved = _configs(robot_path, n_trials=n_trials, duration_s=duration_s, sim_duration_s=sim_duration_s, workers=workers, seed=seed)
    rows = resolved.to_json_dict()
    row: dict = {"robot": robot.name, "path": robot_path,
                 "derived": {k: {"value": repr(r["value"]), "note": r["note"]} for k, r in rows.items() if r["origin"] == "derived"}}
    t0 = time.perf_counter()
    data, truth = collect(robot_path, cfg.collect, progress=False)
    data_path = write_trajectory(data, out / "data.npz")
    write_trajectory(truth, ground_truth_path(data_path))
    iu = robot.unactuated_index
    row["collect"] = {"trials": len(data.meta.trial_failed), "fell": int(sum(data.meta.trial_failed.values())),
                      "samples": int(data.n_samples), "qu_p99": float(np.percentile(np.abs(truth.q[:, iu] - robot.qu_nominal), 99)),
                      "u_sat_frac": _saturation(robot, truth.u), "seconds": time.perf_counter() - t0}
    progress(f"{robot.name}: collected {row['collect']}")
    t0 = time.perf_counter()
    train = train_run(cfg, data_path, out, progress=False)
    export_run(out)
    row["train"] = {"val_rmse": train.metrics.val_rmse, "seconds": time.perf_counter() - t0}
    state = train.state
    refs = held_out_references(cfg.evaluate, robot.m)
    bound = cfg.collect.fall_window / 3
    row["bem"] = heldout_bem_errors(state, robot, refs, bound=bound, duration_s=cfg.evaluate.duration_s, rate_hz=cfg.evaluate.rate_hz)
    progress(f"{robot.name}: held-out BEM {row['bem']}")
    row["closed_loop"] = {}
    for src in ("predictor", "model", "zero"):
        scfg = dataclasses.replace(cfg.simulate, bem_source=src, predictor=str(out / "bem_predictor.pt") if src == "predictor" else None)
        t0 = time.perf_counter()
        m = simulate(robot, scfg, progress=False).metrics
        row["closed_loop"][src] = {k: m[k] for k in ("fell", "duration_s", "tracking_rmse", "qu_max", "u_max", "bem_rejected", "command_rejected")}
        row["closed_loop"][src]["seconds"] = time.perf_counter() - t0
        progress(f"{robot.name}: closed loop {src}: {row['closed_loop'][src]}")
    (out / "robots_bench.json").write_text(json.dumps(row, indent=2, default=float))
    return row


def _saturation(robot, u: np.ndarray) -> float:
    model = robot.model
    lim = model.actuator_ctrllimited.astype(bool)
    if not lim.any():
        return 0.0
    hi = np.maximum(np.abs(model.actuator_ctrlrange[:, 0]), np.abs(model.actuator_ctrlrange[:, 1]))
    return float(np.mean(np.any(np.abs(u[:, lim]) >= 0.999 * hi[lim], axis=1)))


def format_robots_bench(rows: list[dict]) -> str:
    """A table: robot | rate | trials fell | BEM RMSE/max (rad) | closed loop per source (fell / tracking RMSE)."""
    head = f"{'robot':<17}{'rate':>6}{'fell':>7}{'|q_u|p99':>9}{'BEM rmse':>10}{'BEM max':>9}{'BEM peak':>9}"
    head += "".join(f"{s:>24}" for s in ("predictor", "model", "zero"))
    lines = [head, "-" * len(head)]
    for r in rows:
        c = r["collect"]
        rate = json.loads(r["derived"]["collect.rate_hz"]["value"])
        line = f"{r['robot']:<17}{rate:>6.0f}{c['fell']:>3}/{c['trials']:<3}{c['qu_p99']:>9.3f}{r['bem']['rmse']:>10.4f}{r['bem']['max_abs']:>9.4f}{r['bem']['bem_peak']:>9.3f}"
        for s in ("predictor", "model", "zero"):
            m = r["closed_loop"][s]
            txt = f"fell@{m['duration_s']:.1f}s" if m["fell"] else f"up, rmse {m['tracking_rmse']:.4f}"
            txt += f" rej{m['bem_rejected']}" if m["bem_rejected"] else ""
            line += f"{txt:>24}"
        lines.append(line)
    lines.append("BEM errors over |q_u^e − nominal| ≤ design bound on the derived held-out references (rad); tracking RMSE in the actuated joint's units.")
    return "\n".join(lines)
