"""The biped's ``bemlearn sweep`` stages, for sweeps whose base is a biped config (``application: biped``).

* ``biped-bem`` — one training draw of the learned torso BEM (the unit of ``bemlearn bench
  biped-bem``): collect the training walks of ``collect`` (its ``collect.seed``), draw
  ``dataset.n_points`` pairs of eq. (11) with ``dataset.seed``, fit and export the GP with the
  core's stages (:func:`~bemlearn.apps.biped.bem.train_walking_gp`) and score its μ(x_0^e)
  (eq. 14) against the model-based torso BEM (eq. 9) on the held-out walks
  (:func:`~bemlearn.apps.biped.bem.heldout_bem`).  A grid over ``collect.seed`` × ``dataset.seed``
  is the bench's ``--collect-seeds … --subsets …`` (``configs/sweeps/biped-bem.yaml``); unlike the
  bench, every cell collects its own walks and held-out walks, so cells are independent.
  Folder: ``config.yaml``, ``data.npz`` (+ ``.truth.npz``), ``checkpoint.pt``,
  ``bem_predictor.pt``, ``tb/``, ``metrics.json`` (``fit``, ``dataset``, ``walks``,
  ``heldout.<gait>.{rmse, rmse_single_support, max_abs, …}``).
* ``run`` — the whole biped pipeline (:func:`~bemlearn.apps.biped.pipeline.run_biped_pipeline`,
  as ``bemlearn run configs/biped.yaml``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bemlearn.apps.biped.config import BipedConfig
from bemlearn.apps.biped.walk_config import PATH_KEYS
from bemlearn.config import from_dict, save_yaml

__all__ = ["biped_bem_stage", "biped_run_stage"]

#: Input files a biped config may name.


def _resolve(raw: dict[str, Any], where: str) -> BipedConfig:
    return from_dict(BipedConfig, raw, where=f"{where}: config")


def _execute_bem(config: BipedConfig, out: Path, cpus: int) -> None:  # cpus unused: threads set by the cell
    from bemlearn.apps.biped.pipeline import collect_walks, heldout_bem, train_walking_gp, walking_gp_data, walks_trajectories
    from bemlearn.data import ground_truth_path, write_trajectory
    from bemlearn.files import atomic_write_text

    save_yaml(config, out / "config.yaml")
    walks = collect_walks(config, progress=False)
    measured, truth = walks_trajectories(walks)
    data_path = write_trajectory(measured, out / "data.npz")
    write_trajectory(truth, ground_truth_path(data_path))
    X, y, rep = walking_gp_data(measured, truth, config.dataset)
    t0 = time.perf_counter()
    fit = train_walking_gp(X, y, out, config=config.train, data_path=data_path, progress=False, extra={"dataset": rep})
    fit_seconds = time.perf_counter() - t0
    held = heldout_bem(out / "bem_predictor.pt", config, progress=False)
    metrics = {**fit, "fit_export_seconds": fit_seconds, "dataset": rep,
               "walks": {"n": len(walks), "fell": int(sum(w.fell for w in walks)),
                         "steps": int(sum(len(w.steps) for w in walks))},
               "heldout": held}
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=2, default=float))


def _bem_headline(metrics: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for gait, h in (metrics.get("heldout") or {}).items():
        out.update({f"heldout.{gait}.{k}": h[k] for k in ("rmse", "rmse_single_support") if k in h})
    fit = metrics.get("fit") or {}
    if "loss" in fit:
        out["fit.loss"] = fit["loss"]
    for k in ("n_train", "fit_export_seconds"):
        if k in metrics:
            out[k] = metrics[k]
    return out


def _execute_run(config: BipedConfig, out: Path, cpus: int) -> None:  # cpus unused: threads set by the cell
    from bemlearn.apps.biped.pipeline import run_biped_pipeline

    run_biped_pipeline(config, out, progress=False)


def _run_headline(metrics: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, learned in (metrics.get("learned") or {}).items():
        for gait, h in (learned.get("heldout") or {}).items():
            out[f"learned.{name}.heldout.{gait}.rmse"] = h.get("rmse")
    for gait, m in (metrics.get("loop") or {}).items():
        out.update({f"loop.{gait}.{k}": m[k] for k in ("steps", "fell") if k in m})
    return out


def biped_bem_stage():
    """The ``biped-bem`` stage (module docstring)."""
    from bemlearn.sweep.stage import SweepStage

    return SweepStage("biped-bem", "one training draw of the learned torso BEM, scored on held-out walks",
                      schema=BipedConfig, resolve=_resolve, execute=_execute_bem, metrics_file="metrics.json",
                      headline=_bem_headline, path_keys=PATH_KEYS)


def biped_run_stage():
    """The ``run`` stage of biped configs (module docstring)."""
    from bemlearn.sweep.stage import SweepStage

    return SweepStage("run", "the whole biped pipeline, as `bemlearn run configs/biped.yaml`", schema=BipedConfig,
                      resolve=_resolve, execute=_execute_run, metrics_file="metrics.json", headline=_run_headline,
                      path_keys=PATH_KEYS)
