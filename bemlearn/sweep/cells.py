"""The cells of a sweep: every combination of the grid, resolved and identified by a hash.

A cell's config is the sweep's base (with its overrides) with one value of each grid key set
(:func:`~bemlearn.config.set_dotted`), resolved by the stage (for pipeline configs: strict
parse and the model's derived values, :func:`~bemlearn.pipeline.resolve.resolve_pipeline_config`).
:func:`expand_cells` resolves every cell before anything runs, so a bad value in the last
cell fails in seconds, naming the sweep file, the cell and the key.

The cell id is the first 12 hex digits of the SHA-256 of the cell's stage and resolved config
(:func:`cell_id`), in which every input file a config names (``robot:`` MJCF, ``data:``,
``simulate.predictor``, …) stands for the SHA-256 of its bytes, and keys that only change how a
cell runs (``collect.workers``) are left out.  The same cell therefore keeps its id (and
``--resume`` finds it) when the checkout moves or the grid gains other cells, and gets a new one
when a value or an input file changes.  An MJCF's included files are not hashed.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bemlearn.config import rebase_paths, set_dotted, to_dict
from bemlearn.errors import ConfigError
from bemlearn.files import file_sha256
from bemlearn.pipeline.resolve import memoized_derivation
from bemlearn.sweep.config import LoadedSweep
from bemlearn.sweep.stage import SweepStage, dotted_get, get_stage

__all__ = ["Cell", "expand_cells", "cell_id"]


@dataclass(frozen=True)
class Cell:
    """One point of the grid, ready to run.

    Attributes:
        index: its position in the grid (first key slowest).
        cell_id: 12 hex digits identifying its stage and resolved config (module docstring).
        grid: the grid key → value of this cell, as the sweep file wrote them.
        stage: the stage's name.
        application: the application whose stage it is (``None``: the core's).
        config: the stage's resolved config (what :attr:`SweepStage.execute` takes).
    """

    index: int
    cell_id: str
    grid: dict[str, Any]
    stage: str
    application: str | None
    config: Any

    @property
    def label(self) -> str:
        """``key=value, …`` of its grid values (``base`` for a sweep without a grid)."""
        return ", ".join(f"{k}={v}" for k, v in self.grid.items()) or "base"


def cell_id(stage: SweepStage, application: str | None, resolved: Any, *, file_hashes: dict[str, str] | None = None) -> str:
    """The id of a cell running ``stage`` on ``resolved`` (module docstring)."""
    return _id_of_plain(stage, application, to_dict(stage.config_of(resolved)), file_hashes)


def _with_dotted(plain: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    """A copy of ``plain`` with ``plain[a][b] = value`` (``dotted = "a.b"``); only the mappings on the path are
    copied, ``plain`` is unchanged.  ``value is _DROP`` removes the key."""
    head, _, rest = dotted.partition(".")
    out = dict(plain)
    if not rest:
        if value is _DROP:
            out.pop(head, None)
        else:
            out[head] = value
    elif isinstance(out.get(head), dict):
        out[head] = _with_dotted(out[head], rest, value)
    return out


_DROP = object()


def _id_of_plain(stage: SweepStage, application: str | None, plain: dict[str, Any], hashes: dict[str, str] | None) -> str:
    hashes = {} if hashes is None else hashes
    for key in stage.path_keys:
        value = dotted_get(plain, key)
        if isinstance(value, str) and Path(value).is_file():
            if value not in hashes:
                hashes[value] = file_sha256(value)
            plain = _with_dotted(plain, key, f"sha256:{hashes[value]}")
    for key in stage.execution_keys:
        plain = _with_dotted(plain, key, _DROP)
    text = json.dumps({"stage": stage.name, "application": application, "config": plain}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def _absolute_paths(raw: dict[str, Any], keys: tuple[str, ...]) -> None:
    """Values of ``keys`` that name an existing file relative to the current directory → absolute paths."""
    for key in keys:
        value = dotted_get(raw, key)
        if isinstance(value, str) and not Path(value).is_absolute() and Path(value).is_file():
            set_dotted(raw, key, str(Path(value).absolute()))


def expand_cells(sweep: LoadedSweep) -> list[Cell]:
    """Every cell of ``sweep``, resolved and validated (module docstring).

    Raises:
        ConfigError: a cell's config is invalid (the message names the sweep file, the cell's
            index and grid values, and the key), or two cells resolve to the same config.
    """
    spec, source = sweep.spec, sweep.source
    application = sweep.base.get("application")
    stage = get_stage(spec.stage, application, where=f"{source}: stage")
    keys = list(spec.grid)
    with memoized_derivation():
        return _expand(sweep, stage, application, keys)


def _expand(sweep: LoadedSweep, stage: SweepStage, application: str | None, keys: list[str]) -> list[Cell]:
    """Resolve every cell.  With a stage that can :attr:`~SweepStage.patch`, a cell is resolved in full only
    when it is the first of its *shape* (its values of the keys that cannot be patched: paths, and any key
    whose value was seen to change more than itself) or holds a value of a patchable key not resolved in full
    before; every other cell is its shape's resolved template with its grid values set and checked
    (:func:`~bemlearn.config.replace_checked`).  Each full resolution of a cell that could have been patched
    is compared with its patched form; a key whose value changes anything else is no longer patched, and the
    grid is expanded again.  A grid of 10⁴ seed pairs thus costs about 200 full resolutions."""
    patchable = [k for k in keys if stage.patch is not None and k not in stage.path_keys]
    while True:
        try:
            return _expand_with(sweep, stage, application, keys, patchable)
        except _NotLocal as exc:
            patchable = [k for k in patchable if k not in exc.keys]


class _NotLocal(Exception):  # internal signal of _expand_with, never raised out of expand_cells
    def __init__(self, keys: set[str]):
        super().__init__(sorted(keys))
        self.keys = keys


def _expand_with(sweep: LoadedSweep, stage: SweepStage, application: str | None, keys: list[str],
                 patchable: list[str]) -> list[Cell]:
    spec, source = sweep.spec, sweep.source
    cells: list[Cell] = []
    seen: dict[str, Cell] = {}
    hashes: dict[str, str] = {}
    templates: dict[str, tuple[Any, dict[str, Any]]] = {}   # shape → (resolved, its plain config)
    resolved_values: set[tuple[str, Any]] = set()             # (patchable key, value) resolved in full at least once
    for index, values in enumerate(itertools.product(*spec.grid.values())):
        grid = dict(zip(keys, values))
        where = f"{source}: cell {index} ({', '.join(f'{k}={v}' for k, v in grid.items()) or 'base'})"
        shape = json.dumps([grid[k] for k in keys if k not in patchable], sort_keys=True, default=str)
        marks = {(k, _value_key(grid[k])) for k in patchable}
        template = templates.get(shape)
        resolved = None
        if template is not None and stage.patch is not None and marks <= resolved_values:
            resolved = stage.patch(template[0], {k: grid[k] for k in patchable}, where)
        if resolved is not None:
            plain = template[1]  # type: ignore[index]
            for key in patchable:
                plain = _with_dotted(plain, key, to_dict(_dotted_attr(stage.config_of(resolved), key)))
        else:
            raw = copy.deepcopy(sweep.base)
            for key, value in grid.items():
                set_dotted(raw, key, copy.deepcopy(value))
            rebase_paths(raw, stage.path_keys, sweep.folder)  # the grid's paths: relative to the sweep file's folder
            _absolute_paths(raw, stage.path_keys)
            resolved = stage.resolve(raw, where)
            if template is not None and stage.patch is not None:
                try:
                    patched = stage.patch(template[0], {k: grid[k] for k in patchable}, where)
                except ConfigError:
                    patched = False
                if patched is not None and patched != resolved:   # a value that changes more than itself
                    raise _NotLocal({k for k, _ in marks - resolved_values} or set(patchable))
            plain = to_dict(stage.config_of(resolved))
            if template is None:
                templates[shape] = (resolved, plain)
            resolved_values |= marks
        cid = _id_of_plain(stage, application, plain, hashes)
        cell = Cell(index, cid, grid, stage.name, application, resolved)
        if cid in seen:
            raise ConfigError(f"{source}: cells {seen[cid].index} ({seen[cid].label}) and {index} ({cell.label}) "
                              f"resolve to the same config (cell {cid}); remove one of the values")
        seen[cid] = cell
        cells.append(cell)
    return cells


def _value_key(value: Any) -> tuple[str, Any]:
    """A hashable key of a grid value that tells ``1``, ``1.0`` and ``True`` apart."""
    if isinstance(value, (str, int, float, bool)) or value is None:
        return (type(value).__name__, value)
    return ("json", json.dumps(value, sort_keys=True, default=str))


def _dotted_attr(obj: Any, dotted: str) -> Any:
    """``obj.a.b`` for ``dotted = "a.b"``."""
    for part in dotted.split("."):
        obj = getattr(obj, part)
    return obj
