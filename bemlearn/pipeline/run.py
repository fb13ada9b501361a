"""The main job: collect → train → export → simulate → report, in one run folder."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from bemlearn.config import save_yaml
from bemlearn.pipeline.config import PipelineConfig

__all__ = ["run_pipeline"]

log = logging.getLogger(__name__)


def run_pipeline(config: PipelineConfig, out_dir: str | Path | None = None, *, device: str | None = None, progress: bool = True) -> Path:
    """Run every stage of ``config`` into ``out_dir`` (default ``runs/<robot>-<timestamp>``); returns the folder."""
    from bemlearn.data.collect import collect
    from bemlearn.data.trajectory_io import ground_truth_path, write_trajectory
    from bemlearn.export.export_run import export_run
    from bemlearn.pipeline.report import write_report
    from bemlearn.pipeline.simulate import simulate_stage
    from bemlearn.pipeline.train import train_run

    out = Path(out_dir) if out_dir else Path("runs") / time.strftime(f"{config.robot}-%Y%m%d-%H%M%S")
    out.mkdir(parents=True, exist_ok=True)
    save_yaml(config, out / "config.yaml")
    t0 = time.perf_counter()
    log.info("[1/5] collecting excitation data")
    data, truth = collect(config.robot, config.collect, progress=progress)
    data_path = write_trajectory(data, out / "data.npz")
    write_trajectory(truth, ground_truth_path(data_path))
    data_info = {"trials": len(data.meta.trial_failed), "failed": sum(data.meta.trial_failed.values()), "samples": data.n_samples, "rate_hz": data.meta.sample_rate_hz}
    log.info("[2/5] training the BEM GP")
    train = train_run(config, data_path, out, device=device, progress=progress)
    log.info("[3/5] exporting the predictor")
    files = export_run(out, fmt="both")
    log.info("[4/5] closed-loop simulation")
    sim = simulate_stage(config, out, predictor=out / "bem_predictor.pt", progress=progress)
    log.info("[5/5] report")
    report = write_report(out, robot=config.robot, data=data_info, train=train, export=files, sim=sim)
    log.info("done in %.0f s: %s", time.perf_counter() - t0, report)
    return out
