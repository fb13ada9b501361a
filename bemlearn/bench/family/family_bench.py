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


# ---- run: every robot zero-config through `bemlearn run`, scored against its oracle ----------------------------

#: issue 28's bar for a right learned BEM over the design region (rad for the family's hinge q_u)
RMSE_MAX, MAX_MAX, GAIN_RANGE = 0.01, 0.04, (0.95, 1.05)
#: how far (rad) the closed loop's q_u may stray from the true upright and still count as balanced there
BALANCE_TOL = 0.3
#: features of the table, in the issue's order
FEATURES = ("actuator_kind", "friction", "m", "upright_at", "zero_by", "angle")


def compare_predictor(predictor_path: str | Path, xml: str, truth: dict, *, n_queries: int = 400, seed: int = 0) -> dict:
    """Learned BEM (the run's exported predictor, loaded with bemlearn's loader) vs the oracle's on design-region queries.

    Queries: :meth:`Oracle.design_queries` (q̇_u = q̈_u = 0 by construction of the BEM; |q_u^e − q_u*| ≤ 0.2).
    Errors are wrapped into (−π, π] (a predictor on another 2π sheet is not penalised for it).  ``gain`` is the
    least-squares slope (with intercept) of learned − q_u* on oracle − q_u*.

    Returns: ``{"rmse", "max_abs", "gain", "intercept", "n_queries", "learned_at_rest"}`` (rad).
    """
    import torch

    from bemlearn.bench.family.oracle import Oracle, wrap_angle
    from bemlearn.errors import CheckpointError
    from bemlearn.export.torchscript import load_torchscript

    oracle = Oracle(xml, qu_upright=truth["qu_upright"])
    q = oracle.design_queries(n_queries, seed=seed)
    module = load_torchscript(predictor_path)
    meta = json.loads(module.metadata())
    names = list(meta["actuated_names"])
    if sorted(names) != sorted(truth["actuated_joints"]):
        raise CheckpointError(f"{predictor_path}: actuated inputs {names}, the robot's actuated joints are {truth['actuated_joints']}")
    order = [truth["actuated_joints"].index(n) for n in names]
    x = np.concatenate([q["qdda"][:, order], q["qda"][:, order], q["qa"][:, order]], axis=1)
    with torch.no_grad():
        learned = module.bem_mean(torch.from_numpy(np.ascontiguousarray(x, dtype=np.float64))).numpy()
        z = np.zeros((1, 3 * len(names)))
        z[0, 2 * len(names):] = np.asarray(truth["qa_rest"])[order]
        at_rest = float(module.bem_mean(torch.from_numpy(z)).numpy()[0])
    qs = truth["qu_upright"]
    err = wrap_angle(learned - q["bem"])
    xo = wrap_angle(q["bem"] - qs)
    yl = wrap_angle(learned - qs)
    gain, icpt = (np.polyfit(xo, yl, 1) if xo.size > 2 and np.ptp(xo) > 0 else (float("nan"), float("nan")))
    return {"rmse": float(np.sqrt(np.mean(err**2))), "max_abs": float(np.abs(err).max()), "gain": float(gain),
            "intercept": float(icpt), "n_queries": int(err.size), "learned_at_rest_minus_upright": float(wrap_angle(at_rest - qs))}


def balanced_at_upright(metrics: dict, qu_upright: float) -> tuple[bool | None, str]:
    """Whether the run's closed loop with the learned BEM stayed up at the *true* upright.

    ``closed_loop.predictor.qu_max`` is max |q_u| over the loop in the robot's coordinates (MuJoCo's qpos;
    ``bemlearn/sim/closed_loop.py``).  A loop that did not fall balanced at q_u* only if that maximum is
    consistent with staying within ``BALANCE_TOL`` of q_u*: | qu_max − |q_u*| | ≤ BALANCE_TOL (at q_u* = 0:
    qu_max ≤ BALANCE_TOL).  ``None`` when the run has no closed loop of the predictor.
    """
    cl = (metrics.get("closed_loop") or {}).get("predictor")
    if not cl:
        return None, "no closed loop with the learned BEM"
    if cl.get("fell") or cl.get("diverged"):
        return False, "the learned-BEM loop fell" if cl.get("fell") else "the learned-BEM loop diverged"
    qmax = cl.get("qu_max")
    if qmax is None or not np.isfinite(qmax):
        return None, "closed loop without qu_max"
    a = abs(qu_upright)
    if (a < 1e-9 and qmax <= BALANCE_TOL) or (a >= 1e-9 and abs(qmax - a) <= BALANCE_TOL):
        return True, f"stayed up at q_u* = {qu_upright:.3f} (max |q_u| {qmax:.3f})"
    return False, f"stayed up away from the upright: max |q_u| = {qmax:.3f} rad, q_u* = {qu_upright:.3f} rad"


#: words of a verdict reason that claim the robot cannot be held, or that the learned BEM / data are at fault
#: (used when the verdict carries no finding keys)
_HOLD_WORDS = ("cannot be balanced", "cannot hold", "can not be balanced", "infeasible", "not feasible", "beyond the actuator",
               "exceeds the actuator", "outside the actuator", "limits cannot")
_LEARN_WORDS = ("held-out", "heldout", "rmse", "slope", "resolve", "coverage", "extrapolat", "not supported", "correlat",
                "gain", "flat", "design region", "lengthscale", "too few", "fewer than")
_FALL_WORDS = ("fell", "fall", "diverged")
#: the verdict's finding keys (bemlearn/pipeline/verdict.py) by what they claim
_LEARN_CHECKS = ("design_region", "resolution", "heldout", "band", "derivatives", "fit", "lemma1", "coverage", "support")


def judge_reason(reason: str, *, holdable: bool, bem_right: bool | None, check: str = "") -> tuple[bool | None, str]:
    """Is a non-ok verdict's first reason true by the oracle?  ``(None, why)`` where it cannot be judged.

    By the first finding's key (``check``) when there is one, else by the reason's words:

    * ``model:*`` (the model says the robot cannot be held / balanced) — true iff the oracle cannot hold it;
    * ``excitation`` (excitation trials fell) — true iff the oracle cannot hold it (a holdable robot whose
      excitation falls is the pipeline's failure);
    * ``closed_loop`` (the learned-BEM loop fell or wandered) — true iff the oracle cannot hold it or the learned
      BEM is off;
    * the learned BEM's own checks (design region, resolution, held-out, band, derivatives, fit, Lemma 1) — true iff
      the comparison with the oracle fails.
    """
    c = check.lower()
    if c.startswith("model:"):
        return (not holdable), f"{check}: the model says it cannot be held"
    if c == "excitation":
        return (not holdable), f"{check}: blames falls during excitation"
    if c == "closed_loop":
        return ((not holdable) or (bem_right is False)), f"{check}: the learned-BEM loop"
    if c and any(c.startswith(k) for k in _LEARN_CHECKS):
        return (None if bem_right is None else not bem_right), f"{check}: claims the learned BEM is unresolved or off"
    r = reason.lower()
    if any(w in r for w in _HOLD_WORDS):
        return (not holdable), "claims it cannot be held"
    if any(w in r for w in _FALL_WORDS):
        return (not holdable), "blames falls"
    if any(w in r for w in _LEARN_WORDS):
        return (None if bem_right is None else not bem_right), "claims the learned BEM is unresolved or off"
    return None, f"not judged ({check or 'no key'})"


def score_run(run_dir: Path, xml: str, truth: dict, record: dict) -> dict:
    """One row of results: the run's verdict and closed loop, its learned BEM vs the oracle, the judgements."""
    row: dict = {"name": truth["name"], "topology": truth["topology"], **{f: truth["features"][f] for f in FEATURES},
                 "qu_upright": truth["qu_upright"], "holdable": bool(truth["holdable"]), "hold_reason": truth["hold"]["reason"],
                 "exit_code": record.get("exit_code"), "wall_s": record.get("wall_s")}
    mpath = run_dir / "metrics.json"
    metrics = json.loads(mpath.read_text()) if mpath.is_file() else {}
    verdict = metrics.get("verdict") or {}
    # no verdict: exit 2 is a named error (BemlearnError, one line), anything else a crash (traceback, timeout)
    code = record.get("exit_code")
    row["verdict"] = verdict.get("status") or ("none" if code in (0, 3, 4) else "error" if code == 2 else "crash")
    reasons = verdict.get("reasons") or []
    first = reasons[0] if reasons else ""
    row["first_reason"] = first if isinstance(first, str) else json.dumps(first)
    findings = verdict.get("findings") or []
    row["first_check"] = findings[0].get("check", "") if findings and isinstance(findings[0], dict) else ""
    if row["verdict"] in ("error", "crash"):
        row["first_reason"] = record.get("error_tail", "")
    pred = run_dir / "bem_predictor.pt"
    row.update({"rmse": None, "max_abs": None, "gain": None, "learned_at_rest_minus_upright": None})
    if pred.is_file():
        try:
            row.update(compare_predictor(pred, xml, truth))
        except Exception as exc:  # noqa: BLE001 - recorded: a predictor the bench cannot score is a finding, not a crash
            row["compare_error"] = f"{type(exc).__name__}: {exc}"
    bal, why = balanced_at_upright(metrics, truth["qu_upright"])
    row["balanced_at_upright"], row["balance_note"] = bal, why
    bem_right = None if row["rmse"] is None else bool(row["rmse"] <= RMSE_MAX and row["max_abs"] <= MAX_MAX
                                                      and GAIN_RANGE[0] <= row["gain"] <= GAIN_RANGE[1])
    row["bem_right"] = bem_right
    row["right"] = bool(row["verdict"] == "ok" and bem_right and bal)
    row["false_ok"] = bool(row["verdict"] == "ok" and not (bem_right and bal))
    if row["verdict"] not in ("ok",):
        row["reason_true"], row["reason_judged_as"] = judge_reason(row["first_reason"] or "", holdable=row["holdable"],
                                                                   bem_right=bem_right, check=row["first_check"])
        if row["verdict"] in ("error", "crash", "none"):
            row["reason_true"], row["reason_judged_as"] = False, f"{row['verdict']}: no verdict"
    else:
        row["reason_true"], row["reason_judged_as"] = None, ""
    return row


def _median(v: list) -> float | None:
    v = [x for x in v if x is not None and np.isfinite(x)]
    return float(np.median(v)) if v else None


def feature_table(rows: list[dict]) -> list[dict]:
    """Per feature value: count, holdable, ok-and-right rate among holdable, false ok, median RMSE and gain,
    first reason true (judged / non-ok)."""
    out = []
    groups: list[tuple[str, str, list[dict]]] = [("all", "", rows)]
    for f in FEATURES:
        for val in sorted({str(r[f]) for r in rows}):
            groups.append((f, val, [r for r in rows if str(r[f]) == val]))
    for f, val, rs in groups:
        hold = [r for r in rs if r["holdable"]]
        nonok = [r for r in rs if r["verdict"] != "ok"]
        judged = [r for r in nonok if r["reason_true"] is not None]
        out.append({"feature": f, "value": val, "count": len(rs), "holdable": len(hold),
                    "ok_right": sum(r["right"] for r in hold), "ok_rate": (sum(r["right"] for r in hold) / len(hold)) if hold else None,
                    "false_ok": sum(r["false_ok"] for r in rs), "median_rmse": _median([r["rmse"] for r in rs]),
                    "median_gain": _median([r["gain"] for r in rs]), "non_ok": len(nonok), "reason_judged": len(judged),
                    "reason_true": sum(bool(r["reason_true"]) for r in judged),
                    "no_verdict": sum(r["verdict"] in ("error", "crash", "none") for r in rs),
                    "verdicts": {v: sum(r["verdict"] == v for r in rs) for v in sorted({r["verdict"] for r in rs})}})
    return out


def format_table(table: list[dict]) -> str:
    """The issue's table as Markdown."""
    def num(x, fmt):
        return "–" if x is None else format(x, fmt)

    lines = ["| feature | value | n | holdable | ok & right / holdable | false ok | median RMSE (rad) | median gain | "
             "first reason true / judged (non-ok) | verdicts |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for t in table:
        rate = f"{t['ok_right']}/{t['holdable']}" + (f" ({100 * t['ok_rate']:.0f} %)" if t["ok_rate"] is not None else "")
        verd = ", ".join(f"{k} {v}" for k, v in t["verdicts"].items())
        lines.append(f"| {t['feature']} | {t['value']} | {t['count']} | {t['holdable']} | {rate} | {t['false_ok']} | "
                     f"{num(t['median_rmse'], '.3g')} | {num(t['median_gain'], '.3f')} | {t['reason_true']}/{t['reason_judged']} "
                     f"({t['non_ok']}) | {verd} |")
    return "\n".join(lines)


def _run_one(xml_path: str, cfg_path: str, run_dir: str, log_path: str, timeout_s: float) -> dict:
    """``python -m bemlearn run CFG --out RUN --force --no-progress`` in a child process; its exit code, time, last error line."""
    import subprocess
    import sys

    t0 = time.time()
    with open(log_path, "w") as log:
        try:
            proc = subprocess.run([sys.executable, "-m", "bemlearn", "run", cfg_path, "--out", run_dir, "--force", "--no-progress"],
                                  stdout=log, stderr=subprocess.STDOUT, timeout=timeout_s, check=False)
            code = proc.returncode
        except subprocess.TimeoutExpired:
            code = -1
    text = Path(log_path).read_text(errors="replace").strip().splitlines()
    tail = next((ln for ln in reversed(text) if "error" in ln.lower() or "Error" in ln), text[-1] if text else "")
    return {"exit_code": code, "wall_s": time.time() - t0, "error_tail": tail[-400:] if code not in (0, 3, 4) else "",
            "timed_out": code == -1}


def run_family(seed: int, count: int, out: str | Path, *, only: list[int] | None = None, backend: str = "serial",
               jobs: int = 1, timeout_s: float = 3600.0, force: bool = False, rerun: bool = False,
               progress: Callable[[str], None] = lambda s: None) -> dict:
    """Generate (or reuse) the family in ``OUT/robots``, run each selected robot zero-config (``robot: FILE``) with
    ``bemlearn run`` into ``OUT/runs/NAME``, score it against its oracle, write ``OUT/results.{csv,json}`` and
    ``OUT/table.md``; returns ``{"rows", "table", "markdown"}``.

    A robot whose run folder holds ``family_run.json`` (the record of a finished run) is not run again unless
    ``rerun``.  ``backend``: ``serial`` (one child process at a time) or ``ray`` (``jobs`` child processes at once
    as Ray tasks).
    """
    from bemlearn.files import atomic_write_text

    out = Path(out)
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
            finish(item, _run_one(*item[1:], timeout_s))
    elif backend == "ray":
        import ray

        ray.init(num_cpus=jobs, include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)
        try:
            task = ray.remote(num_cpus=1)(_run_one)
            pending = {task.remote(*item[1:], timeout_s): item for item in todo}
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
    md = format_table(table)
    write_results(out, rows, table, md, seed=seed, count=count)
    return {"rows": rows, "table": table, "markdown": md}


def write_results(out: Path, rows: list[dict], table: list[dict], md: str, *, seed: int, count: int) -> None:
    """``results.csv`` (one row per robot), ``results.json`` (rows + table), ``table.md``."""
    import csv
    import io

    from bemlearn.files import atomic_write_files

    cols = ["name", "topology", *FEATURES, "qu_upright", "holdable", "verdict", "right", "false_ok", "rmse", "max_abs", "gain",
            "learned_at_rest_minus_upright", "balanced_at_upright", "bem_right", "reason_true", "first_check", "first_reason", "hold_reason",
            "balance_note", "exit_code", "wall_s"]
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
    md = format_table(table)
    write_results(sweep_dir, rows, table, md, seed=index["seed"], count=index["count"])
    return {"rows": rows, "table": table, "markdown": md}
