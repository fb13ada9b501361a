"""``bemlearn bench family generate|run``: the robot family on disk, and the pipeline scored against its oracle.

``generate`` writes ``OUT/<name>.xml`` (the MJCF), ``OUT/<name>.json`` (its ground truth, :func:`generate_robot`)
per robot and ``OUT/index.json`` (seed, count, one row of features per robot).  Files are written atomically,
all of them or none; an existing family is replaced only with ``force``.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bemlearn.errors import ArgumentError, OutputExistsError

__all__ = ["write_family", "family_rows", "to_json_text"]


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else None if np.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    return x


def to_json_text(obj) -> str:
    """Deterministic JSON text (sorted keys, non-finite floats as null / "inf")."""
    return json.dumps(_jsonable(obj), indent=1, sort_keys=True) + "\n"


def family_rows(seed: int, count: int, *, only: list[int] | None = None, hold_check: bool = True,
                progress: Callable[[str], None] = lambda s: None) -> list[tuple[str, str, dict]]:
    """``(name, xml, truth)`` of robots ``0 … count − 1`` (or ``only``) of family ``seed``."""
    from bemlearn.bench.family.generator import generate_robot, robot_name

    if count < 1:
        raise ArgumentError(f"--count: expected a positive integer, got {count}")
    idx = list(range(count)) if only is None else list(only)
    bad = [i for i in idx if not 0 <= i < count]
    if bad:
        raise ArgumentError(f"--only: indices {bad} outside 0..{count - 1}")
    rows = []
    for i in idx:
        t0 = time.perf_counter()
        xml, truth = generate_robot(seed, i, hold_check=hold_check)
        rows.append((robot_name(seed, i), xml, truth))
        progress(f"{robot_name(seed, i)}: {truth['topology']}, holdable={truth.get('holdable')} ({time.perf_counter() - t0:.1f} s)")
    return rows


def index_row(truth: dict) -> dict:
    """One line of ``index.json``: name, topology, features, upright, holdable and its reason."""
    f = truth["features"]
    return {"name": truth["name"], "index": truth["index"], "topology": truth["topology"], "m": truth["m"],
            "actuator_kind": f["actuator_kind"], "friction": f["friction"], "upright_at": f["upright_at"],
            "zero_by": f["zero_by"], "angle": f["angle"], "timestep": f["timestep"], "qu_upright": truth["qu_upright"],
            "holdable": truth.get("holdable"), "hold_reason": truth.get("hold", {}).get("reason")}


def write_family(seed: int, count: int, out: str | Path, *, force: bool = False,
                 progress: Callable[[str], None] = lambda s: None) -> dict:
    """Generate the family and write it to ``out`` (module docstring); returns the index."""
    from bemlearn.files import atomic_write_files

    out = Path(out)
    rows = family_rows(seed, count, progress=progress)
    files: dict[str | os.PathLike[str], bytes] = {}
    for name, xml, truth in rows:
        files[out / f"{name}.xml"] = xml.encode()
        files[out / f"{name}.json"] = to_json_text(truth).encode()
    index = {"seed": seed, "count": count, "generator": "bemlearn.bench.family.generator",
             "robots": [index_row(t) for _, _, t in rows]}
    files[out / "index.json"] = to_json_text(index).encode()
    existing = sorted(str(p) for p in files if Path(p).exists())
    if existing and not force:
        raise OutputExistsError(f"{out}: {len(existing)} family files exist already (e.g. {existing[0]}); use --force to replace them")
    atomic_write_files(files)
    return index
