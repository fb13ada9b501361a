"""Bad inputs for every reader: generated files, and whether each ends in a named error.

A *reader* takes a path (:data:`READERS`: trajectory files, configs, MJCF paths,
checkpoints, TorchScript and ``.pt2`` predictors).  A *bad-input class*
(:class:`BadInput`) writes one malformed file of a kind (truncated NPZ, non-UTF-8 YAML,
MJCF with two unactuated joints, …) from a seed.  :func:`run_case` feeds it to its
reader; the outcome is *named* when the reader raises a
:class:`~bemlearn.errors.BemlearnError` (a missing file is a
:class:`~bemlearn.errors.MissingFileError`) whose message names the file.  Anything else — another exception, a message
without the file, or no error at all — counts against the target (zero).

The bad-input classes are in :mod:`bemlearn.bench.fuzz_inputs`.  Extend with one more
reader: ``register_reader("import_map", read_import_map)`` and
``BAD_INPUTS.append(BadInput("import_map", "empty file", make_fn))`` where
``make_fn(folder, seed, base)`` writes the file and returns its path.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bemlearn.bench.fuzz_inputs import BAD_INPUTS, BadInput, make_base

__all__ = ["BadInput", "Outcome", "READERS", "BAD_INPUTS", "register_reader", "run_case", "run_fuzz", "format_fuzz", "make_base"]

#: reader name → function reading one path (raises on bad input).
READERS: dict[str, Callable[[Path], Any]] = {}


def register_reader(name: str, fn: Callable[[Path], Any]) -> None:
    """Add a reader (``fn(path)``) the bad-input classes can target by ``name``."""
    READERS[name] = fn


@dataclass(frozen=True)
class Outcome:
    """What the reader did with one generated bad input."""

    reader: str
    name: str
    named: bool
    error: str  # exception class, or "no error"
    message: str


# ---------------------------------------------------------------- readers


def _read_trajectory(path: Path) -> Any:
    from bemlearn.data.trajectory_io import read_trajectory

    return read_trajectory(path)


def _read_config(path: Path) -> Any:
    from bemlearn.pipeline.config import load_pipeline_config
    from bemlearn.pipeline.preflight import check_config_file, check_robot

    raw = check_config_file(path)
    cfg = load_pipeline_config(path)
    check_robot(raw.get("robot"), where=f"{path}: robot")
    return cfg


def _read_import_map(path: Path) -> Any:
    from bemlearn.data.import_map import load_import_map

    return load_import_map(path)


def _read_mjcf(path: Path) -> Any:
    from bemlearn.robots import load

    return load(path)


def _read_checkpoint(path: Path) -> Any:
    from bemlearn.export.checkpoint import load_checkpoint

    return load_checkpoint(path)


def _read_torchscript(path: Path) -> Any:
    from bemlearn.export.torchscript import load_torchscript

    return load_torchscript(path)


def _read_pt2(path: Path) -> Any:
    from bemlearn.export.pt2 import load_pt2_predictor

    return load_pt2_predictor(path)


def _read_predictor_metadata(path: Path) -> Any:
    from bemlearn.export.staleness import predictor_metadata

    return predictor_metadata(path)


for _name, _fn in (("trajectory", _read_trajectory), ("map", _read_import_map), ("config", _read_config), ("mjcf", _read_mjcf),
                   ("checkpoint", _read_checkpoint), ("torchscript", _read_torchscript), ("pt2", _read_pt2),
                   ("predictor_metadata", _read_predictor_metadata)):
    register_reader(_name, _fn)


def run_case(bad: BadInput, folder: Path, seed: int, base: dict) -> Outcome:
    """Write ``bad``'s file for ``seed`` into ``folder`` and read it with its reader."""
    from bemlearn.errors import BemlearnError

    path = bad.make(folder, seed, base)
    try:
        READERS[bad.reader](path)
    except BemlearnError as exc:
        msg = str(exc)
        named = path.name in msg
        return Outcome(bad.reader, bad.name, named, type(exc).__name__, msg)
    except Exception as exc:  # noqa: BLE001 - an uncaught exception is what the fuzz looks for
        return Outcome(bad.reader, bad.name, False, type(exc).__name__, str(exc)[:300])
    return Outcome(bad.reader, bad.name, False, "no error", "")


def run_fuzz(*, examples: int = 5, seed: int = 0, folder: str | os.PathLike[str] | None = None) -> list[Outcome]:
    """Every bad-input class with ``examples`` seeds; returns the outcomes (one per case)."""
    import logging

    logger = logging.getLogger("bemlearn")
    level = logger.level
    logger.setLevel(logging.ERROR)  # the readers log warnings for some bad inputs
    try:
        return _run_fuzz(examples=examples, seed=seed, folder=folder)
    finally:
        logger.setLevel(level)


def _run_fuzz(*, examples: int, seed: int, folder: str | os.PathLike[str] | None) -> list[Outcome]:
    with tempfile.TemporaryDirectory(prefix="bemlearn-fuzz-") as tmp:
        root = Path(folder) if folder is not None else Path(tmp)
        base = make_base(root / "base")
        out = []
        for bad in BAD_INPUTS:
            for k in range(examples):
                case_dir = root / "cases"
                case_dir.mkdir(exist_ok=True)
                out.append(run_case(bad, case_dir, seed + k, base))
        return out


def format_fuzz(outcomes: list[Outcome]) -> str:
    """Per-class summary and the totals: classes tried, classes whose every case ended in a named error."""
    by: dict[tuple[str, str], list[Outcome]] = {}
    for o in outcomes:
        by.setdefault((o.reader, o.name), []).append(o)
    lines = ["| reader | bad input | cases | named errors | errors seen |", "| --- | --- | --- | --- | --- |"]
    ok = 0
    for (reader, name), os_ in by.items():
        n_named = sum(o.named for o in os_)
        ok += n_named == len(os_)
        kinds = sorted({o.error for o in os_})
        lines.append(f"| {reader} | {name} | {len(os_)} | {n_named} | {', '.join(kinds)} |")
    bad = [o for o in outcomes if not o.named]
    lines.append(f"\nbad-input classes tried: {len(by)}; ending in a named error (every case): {ok}; "
                 f"cases: {len(outcomes)}, named: {len(outcomes) - len(bad)}")
    for o in bad[:20]:
        lines.append(f"NOT NAMED: {o.reader} / {o.name}: {o.error}: {o.message[:200]}")
    return "\n".join(lines)
