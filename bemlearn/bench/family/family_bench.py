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

from bemlearn.bench.family.score import (
    FEATURES,
    GAIN_RANGE,
    MAX_MAX,
    RMSE_MAX,
    feature_table,
    format_table,
    score_run,
    unscored_note,
)
from bemlearn.errors import ArgumentError, OutputExistsError

__all__ = ["write_family", "family_rows", "to_json_text", "run_family", "score_sweep", "write_results"]


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


def checkout_commit(checkout: str | Path | None) -> str | None:
    """The git commit of the bemlearn checkout a child process runs (``None`` outside git)."""
    import subprocess

    where = Path(checkout) if checkout is not None else Path(__file__).resolve().parents[3]
    try:
        res = subprocess.run(["git", "-C", str(where), "rev-parse", "HEAD"], capture_output=True, text=True, check=False, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return res.stdout.strip() or None


def _run_one(xml_path: str, cfg_path: str, run_dir: str, log_path: str, timeout_s: float, checkout: str | None = None) -> dict:
    """``python -m bemlearn run CFG --out RUN --force --no-progress`` in a child process (in ``checkout``, the bemlearn
    source tree whose pipeline is measured; default this one); its exit code, time, last error line."""
    import os
    import subprocess
    import sys

    t0 = time.time()
    env = None
    if checkout is not None:  # `python -m` puts the working directory first on sys.path: that tree's bemlearn runs
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    with open(log_path, "w") as log:
        try:
            proc = subprocess.run([sys.executable, "-m", "bemlearn", "run", cfg_path, "--out", run_dir, "--force", "--no-progress"],
                                  stdout=log, stderr=subprocess.STDOUT, timeout=timeout_s, check=False, cwd=checkout, env=env)
            code = proc.returncode
        except subprocess.TimeoutExpired:
            code = -1
    text = Path(log_path).read_text(errors="replace").strip().splitlines()
    tail = next((ln for ln in reversed(text) if "error" in ln.lower() or "Error" in ln), text[-1] if text else "")
    return {"exit_code": code, "wall_s": time.time() - t0, "error_tail": tail[-400:] if code not in (0, 3, 4) else "",
            "timed_out": code == -1, "checkout": checkout, "commit": checkout_commit(checkout)}


def run_family(seed: int, count: int, out: str | Path, *, only: list[int] | None = None, backend: str = "serial",
               jobs: int = 1, timeout_s: float = 3600.0, force: bool = False, rerun: bool = False,
               checkout: str | Path | None = None, progress: Callable[[str], None] = lambda s: None) -> dict:
    """Generate (or reuse) the family in ``OUT/robots``, run each selected robot zero-config (``robot: FILE``) with
    ``bemlearn run`` into ``OUT/runs/NAME``, score it against its oracle, write ``OUT/results.{csv,json}`` and
    ``OUT/table.md``; returns ``{"rows", "table", "markdown"}``.

    A robot whose run folder holds ``family_run.json`` (the record of a finished run) is not run again unless
    ``rerun``.  ``backend``: ``serial`` (one child process at a time) or ``ray`` (``jobs`` child processes at once
    as Ray tasks).  ``checkout``: run another bemlearn source tree's pipeline (e.g. a worktree with a fix); the
    scoring is this one's, and each ``family_run.json`` records the commit that ran.
    """
    from bemlearn.errors import MissingFileError
    from bemlearn.files import atomic_write_text

    if checkout is not None:
        checkout = str(Path(checkout).absolute())
        if not (Path(checkout) / "bemlearn" / "__main__.py").is_file():
            raise MissingFileError(f"--checkout {checkout}: no bemlearn source tree there (bemlearn/__main__.py)")
    out = Path(out).absolute()
    robots = out / "robots"
    if (robots / "index.json").is_file():
        index = json.loads((robots / "index.json").read_text())
        if (index.get("seed"), index.get("count")) != (seed, count) and not force:
            raise OutputExistsError(f"{robots}: holds family seed {index.get('seed')} × {index.get('count')}, not "
                                    f"{seed} × {count}; use another --out or --force")
        if (index.get("seed"), index.get("count")) != (seed, count):
            write_family(seed, count, robots, force=True, progress=progress)
    else:
        write_family(seed, count, robots, force=force, progress=progress)
    index = json.loads((robots / "index.json").read_text())
    names = [r["name"] for r in index["robots"]]
    idx = list(range(count)) if only is None else list(only)
    bad = [i for i in idx if not 0 <= i < count]
    if bad:
        raise ArgumentError(f"--only: indices {bad} outside 0..{count - 1}")
    todo = []
    for i in idx:
        name = names[i]
        cfg = out / "configs" / f"{name}.yaml"
        if not cfg.is_file():
            atomic_write_text(cfg, f"# zero config: the robot file alone (bemlearn bench family run)\nrobot: {(robots / f'{name}.xml').absolute()}\n")
        run_dir = out / "runs" / name
        if (run_dir / "family_run.json").is_file() and not rerun:
            continue
        (out / "logs").mkdir(parents=True, exist_ok=True)
        todo.append((name, str((robots / f"{name}.xml").absolute()), str(cfg.absolute()), str(run_dir.absolute()),
                     str((out / "logs" / f"{name}.log").absolute())))
    progress(f"{len(idx)} robots selected, {len(todo)} to run ({backend})")

    def finish(item, record):
        name, _, _, run_dir, _ = item
        Path(run_dir).mkdir(parents=True, exist_ok=True)
        atomic_write_text(Path(run_dir) / "family_run.json", to_json_text(record))
        progress(f"{name}: exit {record['exit_code']} in {record['wall_s']:.0f} s")

    if backend == "serial" or not todo:
        for item in todo:
            finish(item, _run_one(*item[1:], timeout_s, checkout))
    elif backend == "ray":
        import ray

        ray.init(num_cpus=jobs, include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)
        try:
            task = ray.remote(num_cpus=1)(_run_one)
            pending = {task.remote(*item[1:], timeout_s, checkout): item for item in todo}
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                item = pending.pop(ready[0])
                finish(item, ray.get(ready[0]))
        finally:
            ray.shutdown()
    else:
        raise ArgumentError(f"--backend: expected serial or ray, got {backend!r}")
    rows = []
    for i in idx:
        name = names[i]
        run_dir = out / "runs" / name
        rec_path = run_dir / "family_run.json"
        if not rec_path.is_file():
            continue
        xml = (robots / f"{name}.xml").read_text()
        truth = json.loads((robots / f"{name}.json").read_text())
        rows.append(score_run(run_dir, xml, truth, json.loads(rec_path.read_text())))
    table = feature_table(rows)
    md = format_table(table) + unscored_note(rows)
    write_results(out, rows, table, md, seed=seed, count=count)
    return {"rows": rows, "table": table, "markdown": md}


def write_results(out: Path, rows: list[dict], table: list[dict], md: str, *, seed: int, count: int) -> None:
    """``results.csv`` (one row per robot), ``results.json`` (rows + table), ``table.md``."""
    import csv
    import io

    from bemlearn.files import atomic_write_files

    cols = ["name", "topology", *FEATURES, "qu_upright", "holdable", "verdict", "right", "false_ok", "rmse", "max_abs", "max_sampled", "gain",
            "learned_at_rest_minus_upright", "band_coverage", "balanced_at_upright", "bem_right", "reason_true", "first_check", "first_reason", "hold_reason",
            "balance_note", "exit_code", "wall_s", "commit", "compare_error"]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({k: r.get(k) for k in cols})
    head = (f"# bench family: seed {seed}, {len(rows)} of {count} robots scored\n\n"
            f"right = verdict ok and RMSE ≤ {RMSE_MAX}, max ≤ {MAX_MAX}, gain in [{GAIN_RANGE[0]}, {GAIN_RANGE[1]}] over "
            f"|q_u^e − q_u*| ≤ 0.2 and the learned-BEM loop balanced at the true upright; false ok = verdict ok otherwise.\n\n")
    atomic_write_files({out / "results.csv": buf.getvalue().encode(),
                        out / "results.json": to_json_text({"seed": seed, "count": count, "rows": rows, "table": table}).encode(),
                        out / "table.md": (head + md + "\n").encode()})


def score_sweep(sweep_dir: str | Path, family_dir: str | Path) -> dict:
    """Score the cells of a ``bemlearn sweep`` over family robots (``configs/sweeps/family.yaml``) against their oracles.

    Each complete cell (``cells/<id>/cell.json``) whose ``robot`` is a family file ``NAME.xml`` is scored like a run of
    :func:`run_family` (its folder is the run folder); a failed cell is a row without a verdict.  Writes and returns
    the results as :func:`run_family` does, into ``sweep_dir``.
    """
    from bemlearn.errors import MissingFileError

    sweep_dir, family_dir = Path(sweep_dir), Path(family_dir)
    if not (family_dir / "index.json").is_file():
        raise MissingFileError(f"--family {family_dir}: no index.json (write the family with `bemlearn bench family generate`)")
    index = json.loads((family_dir / "index.json").read_text())
    names = {r["name"] for r in index["robots"]}
    rows = []
    for marker in sorted((sweep_dir / "cells").glob("*/cell.json")):
        cell = json.loads(marker.read_text())
        robot = (cell.get("grid") or {}).get("robot")
        name = Path(robot).stem if isinstance(robot, str) else None
        if name not in names:
            continue
        failed = cell.get("status") != "ok"
        record = {"exit_code": 1 if failed else 0, "wall_s": cell.get("wall_s"), "error_tail": (cell.get("error") or "")[-400:]}
        rows.append(score_run(marker.parent, (family_dir / f"{name}.xml").read_text(),
                              json.loads((family_dir / f"{name}.json").read_text()), record))
    if not rows:
        raise MissingFileError(f"--sweep {sweep_dir}: no complete cell runs a robot of {family_dir}")
    rows.sort(key=lambda r: r["name"])
    table = feature_table(rows)
    md = format_table(table) + unscored_note(rows)
    write_results(sweep_dir, rows, table, md, seed=index["seed"], count=index["count"])
    return {"rows": rows, "table": table, "markdown": md}
