"""The sweep file: a base config, a grid of dotted keys, the stage every cell runs.

.. code-block:: yaml

    # in the repository's root folder: paths are relative to the sweep file's folder
    base: {robot: tests/robots/cartpole.xml, collect: {n_trials: 6, duration_s: 6.0}}   # or a config file path
    overrides: {simulate.duration_s: 10.0}      # optional: dotted keys set on the base (one value each)
    grid:                                       # every combination of the lists is a cell
      robot: [tests/robots/cartpole.xml, tests/robots/reaction_wheel.xml]
      collect.seed: [0, 1]
    stage: run                                  # run (default) | train | simulate | an application's stage
    resources: {cpus: 1, gpus: 0}               # declared per cell (Ray schedules by them)
    retries: 1                                  # a failed cell is run once more, then recorded

:func:`load_sweep` parses it strictly (:class:`SweepConfig`; an unknown key is an error naming
it) and checks every grid and override key against the stage's config schema; the cells
themselves are resolved and validated by :func:`~bemlearn.sweep.cells.expand_cells`.  Paths
in a sweep file (``base:``, and the files its inline base, overrides and grid name) are relative to the
sweep file's folder, those of a base config file to that file's folder (docs/config.md, "Paths").
"""

from __future__ import annotations

import copy
import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bemlearn.config import check_dotted_key, config_folder, from_dict, load_yaml, rebase_paths, set_dotted, show_value
from bemlearn.errors import ConfigError

__all__ = ["SweepResources", "SweepConfig", "LoadedSweep", "load_sweep", "MAX_CELLS"]


#: The largest grid a sweep accepts (cells); larger grids are refused before any cell is resolved.
MAX_CELLS = 10_000


@dataclass(frozen=True)
class SweepResources:
    """What one cell declares to the scheduler (``resources:`` of a sweep file).

    Attributes:
        cpus: CPU cores per cell (≥ 1).  The cell runs with this many torch threads (in both
            backends, so results do not depend on the backend) and, unless its config gives
            ``collect.workers``, as many collection processes.
        gpus: GPUs per cell (Ray's ``num_gpus``; fractions share a device).  Give
            ``train.device: cuda`` in the config to use it.
    """

    cpus: int = 1
    gpus: float = 0.0

    def __post_init__(self) -> None:
        if self.cpus < 1:
            raise ConfigError(f"resources.cpus: expected an integer ≥ 1, got {self.cpus}")
        if self.gpus < 0:
            raise ConfigError(f"resources.gpus: expected a number ≥ 0, got {self.gpus}")


@dataclass(frozen=True)
class SweepConfig:
    """A sweep file (module docstring).

    Attributes:
        base: a config file path, or an inline config mapping, every cell starts from.
        grid: dotted config key (``collect.seed``; ``robot``, ``data`` for the top level) → the
            list of its values; the cartesian product, first key slowest, is the list of cells.
            Empty: one cell, the base itself.
        overrides: dotted key → one value, set on the base before the grid.
        stage: what each cell runs: ``run`` (the whole ``bemlearn run``), ``train`` (collect →
            train, as ``bemlearn collect`` + ``bemlearn train``), ``simulate`` (the closed loop of
            ``simulate.bem_source``, as ``bemlearn simulate``) or a stage an application adds for
            configs naming it (``application: NAME``); ``bemlearn sweep --help`` lists them.
        resources: CPUs and GPUs declared per cell.
        retries: how many more times a failed cell runs before it is recorded as failed.
    """

    base: str | dict[str, Any]
    grid: dict[str, list[Any]] = field(default_factory=dict)
    overrides: dict[str, Any] = field(default_factory=dict)
    stage: str = "run"
    resources: SweepResources = field(default_factory=SweepResources)
    retries: int = 1

    def __post_init__(self) -> None:
        if self.retries < 0:
            raise ConfigError(f"retries: expected an integer ≥ 0, got {self.retries}")
        n_cells = 1
        for key, values in self.grid.items():
            if not values:
                raise ConfigError(f"grid.{key}: expected a non-empty list of values")
            n_cells *= len(values)
        if n_cells > MAX_CELLS:   # before anything is resolved: a 10⁶ grid is refused at once
            sizes = " × ".join(str(len(v)) for v in self.grid.values())
            raise ConfigError(f"grid: {sizes} = {n_cells} cells; a sweep holds at most {MAX_CELLS} (split it into "
                              "several sweeps, docs/sweeps.md)")
        for key, values in self.grid.items():
            seen: set[str] = set()
            for v in values:
                text = json.dumps(v, sort_keys=True, default=repr)
                if text in seen:
                    raise ConfigError(f"grid.{key}: the value {show_value(v)} is listed twice")
                seen.add(text)
        both = sorted(set(self.grid) & set(self.overrides))
        if both:
            raise ConfigError(f"{both}: a key is either in grid or in overrides, not both")


@dataclass(frozen=True)
class LoadedSweep:
    """A parsed sweep: its spec, the base config mapping it starts from, where it came from.

    Attributes:
        spec: the strict :class:`SweepConfig`.
        base: the base config as a mapping (read from ``spec.base`` when that is a path), with
            ``spec.overrides`` applied.
        source: the sweep file's path (or ``"<dict>"``); error messages start with it.
        folder: the folder the grid's relative paths are resolved against: the sweep file's (the
            current folder for a mapping).
    """

    spec: SweepConfig
    base: dict[str, Any]
    source: str
    folder: Path = field(default_factory=Path.cwd)


def load_sweep(sweep: str | Path | dict[str, Any]) -> LoadedSweep:
    """Parse a sweep file (or mapping) strictly and check its keys against the stage's schema.

    Raises:
        ConfigError: an unknown or mistyped key of the sweep file, a grid or override key that
            names no config field (the message names the key and lists the valid ones there), an
            unknown stage (the message lists the stages), or a missing base file.
    """
    from bemlearn.sweep.stage import get_stage

    if isinstance(sweep, dict):
        raw, source, folder = copy.deepcopy(sweep), "<dict>", Path.cwd()
    else:
        raw, source, folder = load_yaml(sweep), str(sweep), config_folder(sweep)
    base_path = raw.get("base")
    if isinstance(base_path, str) and not Path(base_path).expanduser().is_absolute():
        raw["base"] = str(folder / base_path)
    spec = from_dict(SweepConfig, raw, where=source)
    if isinstance(spec.base, str):
        base = load_yaml(spec.base) if Path(spec.base).is_file() else None
        if base is None:
            where = "relative to the current folder" if isinstance(sweep, dict) else "relative to the sweep file's folder"
            raise ConfigError(f"{source}: base: no config file {base_path} ({where}, or give an inline mapping)")
        base_folder = config_folder(spec.base)
    else:
        base, base_folder = copy.deepcopy(spec.base), folder
    stage = get_stage(spec.stage, base.get("application"), where=f"{source}: stage")
    # paths: a base file's relative to its own folder; an inline base's and the overrides' to the sweep file's
    # (the grid's too, when expand_cells sets them: the grid keeps the values as written, for the cells' labels)
    rebase_paths(base, stage.path_keys, base_folder)
    spec = dataclasses.replace(spec, overrides=rebase_paths(copy.deepcopy(spec.overrides), stage.path_keys, folder))
    for key, value in spec.overrides.items():
        check_dotted_key(stage.schema, key, where=f"{source}: overrides")
        set_dotted(base, key, copy.deepcopy(value))
    for key in spec.grid:
        check_dotted_key(stage.schema, key, where=f"{source}: grid")
    return LoadedSweep(spec, base, source, folder)
