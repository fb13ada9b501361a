"""What a sweep cell runs: :class:`SweepStage`, the core's stages and the registry.

The core's stages take a pipeline config (:class:`~bemlearn.pipeline.config.PipelineConfig`,
resolved with the model's derived values) and write the same files as the command they
stand for:

========== ====================================================== =====================================
stage      what a cell runs                                       its folder (as the command's)
========== ====================================================== =====================================
``run``    collect → train → export → evaluate → closed loop →    ``bemlearn run``: ``config.yaml``,
           report (:func:`~bemlearn.pipeline.run.run_pipeline`)   ``metrics.json``, predictors, …
``train``  collect (unless ``data:``) → train + held-out          ``bemlearn collect`` + ``bemlearn
           evaluation (:func:`~bemlearn.pipeline.train.train_run`) train``: ``data.npz``, ``checkpoint.pt``,
                                                                  ``metrics.json``
``simulate`` the closed loop of ``simulate.bem_source``            ``bemlearn simulate``: ``simulate/``
           (:func:`~bemlearn.pipeline.simulate.simulate_stage`)   ``{metrics.json, fig2_<source>.png}``
========== ====================================================== =====================================

An application adds stages for the configs that name it (``application: NAME``) through
:attr:`bemlearn.applications.Application.sweep_stages` (the biped's ``biped-bem``: the learned
torso BEM over collect and dataset seeds).  :func:`get_stage` finds a stage by name and lists
the valid ones when the name is wrong.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bemlearn.errors import BemlearnError, ConfigError
from bemlearn.pipeline.run_metrics import LoopMetrics, RunMetrics

__all__ = ["SweepStage", "core_stages", "get_stage", "stage_names", "dotted_get"]

_MISSING = object()


def dotted_get(data: Any, dotted: str, default: Any = None) -> Any:
    """``data["a"]["b"]`` for ``dotted = "a.b"``; ``default`` where a part is missing or not a mapping."""
    for part in dotted.split("."):
        if not isinstance(data, Mapping) or part not in data:
            return default
        data = data[part]
    return data


@dataclass(frozen=True)
class SweepStage:
    """One kind of sweep cell.

    Attributes:
        name: the ``stage:`` of a sweep file.
        description: one line for ``bemlearn sweep --help``.
        schema: the config dataclass the stage runs (grid and override keys are checked against it).
        resolve: ``resolve(raw, where) -> resolved``: the cell's config mapping → the typed,
            picklable object :attr:`execute` takes; checks every file it needs and raises
            :class:`~bemlearn.errors.ConfigError` starting with ``where``.  Runs in the driver,
            before any cell runs.
        execute: ``execute(resolved, out_dir, cpus)`` writes the cell's folder (``cpus``: the
            cell's declared cores; torch's threads are already set to it).
        metrics_file: the cell folder's metrics file (relative), read for :attr:`headline` and
            for the run's ``verdict`` (``{"status": …, "reasons": […]}``) when it has one.
        headline: ``headline(metrics) -> {column: value}``: the figures of ``results.csv``;
            each column is named by its dotted key in the metrics file.
        config_of: ``config_of(resolved)``: the config dataclass inside ``resolved`` (its plain
            form, :func:`~bemlearn.config.to_dict`, identifies the cell).
        path_keys: dotted keys whose values may name input files: made absolute before the cells
            run (a Ray worker's working directory may differ) and identified by the file's
            SHA-256, not its path.
        execution_keys: dotted keys that change how a cell runs, not what it computes (left
            out of the cell id).
        patch: ``patch(template, {dotted key: value}, where) -> resolved | None``: ``template`` (a
            resolved cell) with the given leaf values set and checked as :attr:`resolve` checks them
            (``None``: a key is not a plain leaf).  Lets a large grid be validated in seconds
            (:func:`~bemlearn.sweep.cells.expand_cells`, which checks it against :attr:`resolve`).
            ``None``: every cell is resolved in full.
    """

    name: str
    description: str
    schema: type
    resolve: Callable[[dict[str, Any], str], Any]
    execute: Callable[[Any, Path, int], None]
    metrics_file: str
    headline: Callable[[Mapping[str, Any]], dict[str, Any]]
    config_of: Callable[[Any], Any] = lambda resolved: resolved
    path_keys: tuple[str, ...] = ()
    execution_keys: tuple[str, ...] = ()
    patch: Callable[[Any, Mapping[str, Any], str], Any] | None = None


# ---------------------------------------------------------------- the core's stages

#: results.csv columns of a run / train cell, by their dotted key in ``metrics.json`` (those present;
#: results only, no timings: the same cell gives the same figures on every backend).  The closed loop
#: (:data:`LOOP_HEADLINE` per source) comes between the first three and the rest.
RUN_HEADLINE = (
    "bem_heldout.rmse",                     # held-out BEM vs the model BEM (eq. 9), q_u's unit
    "bem_design_region.gain",
    "bem_heldout.coverage_2sigma_band",     # fraction of the model BEM inside the exported ±2σ band
)
RUN_HEADLINE_MORE = (
    "bem_heldout.max_abs",
    "bem_heldout.design_region.rmse",       # the same over |q_u^e − nominal| ≤ design bound
    "val_rmse",                             # validation trials, f(x) vs measured q_u
    "data_heldout.rmse",                    # model-free runs: held-out trials' q_u from f(x)
    "data_heldout.coverage",
)
#: per closed-loop source (``closed_loop.<source>.<key>``).
LOOP_HEADLINE = ("fell", "tracking_rmse", "diverged", "bem_vs_model_rmse", "bem_inside_2sigma")


#: How each column of :data:`RUN_HEADLINE` / :data:`RUN_HEADLINE_MORE` is read from the typed metrics.
_COLUMNS: dict[str, Callable[[RunMetrics], Any]] = {
    "bem_heldout.rmse": lambda m: m.bem_heldout and m.bem_heldout.rmse,
    "bem_design_region.gain": lambda m: m.bem_design_region and m.bem_design_region.gain,
    "bem_heldout.coverage_2sigma_band": lambda m: m.bem_heldout and m.bem_heldout.coverage_2sigma_band,
    "bem_heldout.max_abs": lambda m: m.bem_heldout and m.bem_heldout.max_abs,
    "bem_heldout.design_region.rmse": lambda m: m.bem_heldout and m.bem_heldout.design_region and m.bem_heldout.design_region.rmse,
    "val_rmse": lambda m: m.val_rmse,
    "data_heldout.rmse": lambda m: m.data_heldout and m.data_heldout.rmse,
    "data_heldout.coverage": lambda m: m.data_heldout and m.data_heldout.coverage,
}


def _run_headline(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """The headline of a run / train cell from its ``metrics.json`` (read once into :class:`RunMetrics`)."""
    return _headline(RunMetrics.from_dict(metrics))


def _headline(m: RunMetrics) -> dict[str, Any]:
    def pick(keys):
        return {k: v for k in keys if (v := _COLUMNS[k](m)) is not None}

    out = pick(RUN_HEADLINE)
    for src, loop in (m.closed_loop or {}).items():
        out.update({f"closed_loop.{src}.{k}": v for k in LOOP_HEADLINE if (v := getattr(loop, k)) is not None})
    out.update(pick(RUN_HEADLINE_MORE))
    return out


def _simulate_headline(metrics: Mapping[str, Any]) -> dict[str, Any]:
    loops = {src: LoopMetrics.from_dict(m) for src, m in metrics.items() if isinstance(m, Mapping)}
    return _headline(RunMetrics(closed_loop=loops))


def _resolve_pipeline(raw: dict[str, Any], where: str):
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    try:
        resolved = resolve_pipeline_config(raw, source="config")
    except BemlearnError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    data = resolved.config.data
    if data is not None and not Path(data).is_file():
        raise ConfigError(f"{where}: data: no trajectory file {data}")
    return resolved


def _patch_pipeline(template, values: Mapping[str, Any], where: str):
    """``template`` (a :class:`~bemlearn.pipeline.resolve.ResolvedConfig`) with leaf ``values`` set (:attr:`SweepStage.patch`)."""
    from bemlearn.config import replace_checked
    from bemlearn.pipeline.resolve import ResolvedConfig

    cfg = template.config
    for key, value in values.items():
        try:
            cfg = replace_checked(cfg, key, value, where="config")
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
        if cfg is None:
            return None
    return ResolvedConfig(cfg, template.origins, template.notes, template.source)


def _resolve_simulate(raw: dict[str, Any], where: str):
    resolved = _resolve_pipeline(raw, where)
    cfg = resolved.config
    if cfg.robot is None:
        raise ConfigError(f"{where}: the simulate stage needs robot: (a model to simulate); the config names only data")
    pred = cfg.simulate.predictor
    if cfg.simulate.bem_source == "predictor":
        if pred is None or not Path(pred).is_file():
            raise ConfigError(f"{where}: simulate.predictor: {'not given' if pred is None else f'no file {pred}'}; "
                              "bem_source predictor needs an exported bem_predictor.pt (of `bemlearn run` or `bemlearn export`)")
        if (Path(pred).parent / "checkpoint.pt").is_file():
            from bemlearn.export.staleness import check_predictor_matches

            try:
                check_predictor_matches(Path(pred), Path(pred).parent / "checkpoint.pt")
            except BemlearnError as exc:
                raise ConfigError(f"{where}: simulate.predictor: {exc}") from exc
    return resolved


def _with_workers(resolved, cpus: int):
    """``resolved`` with ``collect.workers = cpus`` unless the config gives it (the cell's cores)."""
    from bemlearn.pipeline.resolve import ResolvedConfig

    if resolved.origins.get("collect.workers") == "given":
        return resolved
    cfg = resolved.config
    cfg = dataclasses.replace(cfg, collect=dataclasses.replace(cfg.collect, workers=cpus))
    origins = {**resolved.origins, "collect.workers": "derived"}
    notes = {**resolved.notes, "collect.workers": "the sweep cell's resources.cpus"}
    return ResolvedConfig(cfg, origins, notes, resolved.source)


def _write_configs(resolved, out: Path) -> None:
    from bemlearn.config import save_yaml
    from bemlearn.files import atomic_write_text

    save_yaml(resolved.config, out / "config.yaml")
    atomic_write_text(out / "config_resolved.json", json.dumps(resolved.to_json_dict(), indent=2, ensure_ascii=False))


def _execute_run(resolved, out: Path, cpus: int) -> None:
    from bemlearn.pipeline.run import run_pipeline

    run_pipeline(_with_workers(resolved, cpus), out, progress=False, jobs=cpus)   # the cell's cores: its closed loops at once


def _execute_train(resolved, out: Path, cpus: int) -> None:
    from bemlearn.pipeline.train import train_run

    resolved = _with_workers(resolved, cpus)
    cfg = resolved.config
    _write_configs(resolved, out)
    if cfg.data is None:
        from bemlearn.data.trajectory_io import ground_truth_path, write_trajectory
        from bemlearn.sim.collect import collect

        data, truth = collect(cfg.robot, cfg.collect, progress=False, coordinates=cfg.coordinates)
        data_path = write_trajectory(data, out / "data.npz")
        write_trajectory(truth, ground_truth_path(data_path))
    else:
        data_path = Path(cfg.data)
    train_run(cfg, data_path, out, progress=False, threads=None)  # threads: the cell's, already set


def _execute_simulate(resolved, out: Path, cpus: int) -> None:
    from bemlearn.pipeline.simulate import simulate_stage

    _write_configs(resolved, out)
    cfg = resolved.config
    simulate_stage(cfg, out, sources=(cfg.simulate.bem_source,), progress=False, jobs=cpus)


def core_stages() -> dict[str, SweepStage]:
    """The stages of pipeline configs (module docstring), by name."""
    from bemlearn.pipeline.config import PATH_KEYS, PipelineConfig

    common: dict[str, Any] = dict(schema=PipelineConfig, config_of=lambda r: r.config,
                  path_keys=PATH_KEYS, execution_keys=("collect.workers",), patch=_patch_pipeline)
    return {
        "run": SweepStage("run", "the whole `bemlearn run`: collect → train → export → evaluate → closed loop → report",
                          resolve=_resolve_pipeline, execute=_execute_run, metrics_file="metrics.json",
                          headline=_run_headline, **common),
        "train": SweepStage("train", "collect (unless data:) → train with the held-out evaluation, as `bemlearn train`",
                            resolve=_resolve_pipeline, execute=_execute_train, metrics_file="metrics.json",
                            headline=_run_headline, **common),
        "simulate": SweepStage("simulate", "the closed loop of simulate.bem_source, as `bemlearn simulate`",
                               resolve=_resolve_simulate, execute=_execute_simulate, metrics_file="simulate/metrics.json",
                               headline=_simulate_headline, **common),
    }


def stage_names() -> dict[str, list[str]]:
    """``{"": core stage names, application name: its stage names}`` (for help texts)."""
    from bemlearn.applications import applications

    out = {"": list(core_stages())}
    out.update({name: list(app.sweep_stages) for name, app in applications().items() if app.sweep_stages})
    return out


def get_stage(name: str, application: str | None = None, *, where: str = "stage") -> SweepStage:
    """The stage ``name`` of the core (``application=None``) or of the application a config names.

    Raises:
        ConfigError: no such stage (the message lists the valid ones) or no such application.
    """
    stages: dict[str, Any]  # the core's stages, or an application's stages and stage factories
    if application is None:
        stages = core_stages()
        owner = "pipeline configs"
    else:
        from bemlearn.applications import get_application

        try:
            app = get_application(str(application))
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
        stages = dict(app.sweep_stages)
        owner = f"configs of application {application!r}"
        if name in stages and callable(stages[name]) and not isinstance(stages[name], SweepStage):
            stages[name] = stages[name]()
    if name not in stages:
        raise ConfigError(f"{where}: unknown stage {name!r}; the stages of {owner} are {sorted(stages) or 'none'}")
    return stages[name]
