"""A sweep's results: ``results.csv`` / ``results.json`` (one row per cell) and ``summary.png``.

Columns, in order: ``cell`` (the id, the folder under ``cells/``), ``index``, one column per grid
key (named by the key), ``status`` (``ok``, ``failed``, or ``pending`` for a cell not run yet),
``verdict`` and ``verdict_reasons`` (the run's own verdict, ``metrics.json["verdict"]``, empty
where the run has none), ``error`` (the first line, for ``failed``), ``attempts``, ``wall_s`` and
``cpu_s`` (the stage's wall and CPU time), ``host``, ``finished`` (UTC), then the stage's headline figures, each named
by its dotted key in the cell's metrics file (``bem_heldout.rmse``,
``closed_loop.predictor.tracking_rmse``, …) and left empty where a cell does not have it.
``results.json`` holds the same rows (``{"columns": […], "cells": [{column: value}]}``).
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bemlearn.files import atomic_path, atomic_write_text
from bemlearn.sweep.cell_runner import CellOutcome
from bemlearn.sweep.cells import Cell

__all__ = ["result_rows", "write_results", "summary_figure", "differing_columns", "FIXED_COLUMNS", "TIMING_COLUMNS"]

#: The columns after the grid keys and before the metrics.
FIXED_COLUMNS = ("status", "verdict", "verdict_reasons", "error", "attempts", "wall_s", "cpu_s", "host", "finished")
#: The columns that depend on when and where a cell ran, not on what it computed.
TIMING_COLUMNS = ("wall_s", "cpu_s", "host", "finished")


def result_rows(cells: Sequence[Cell], outcomes: dict[str, CellOutcome]) -> tuple[list[str], list[dict[str, Any]]]:
    """``(columns, rows)`` of the cells in grid order (module docstring)."""
    grid_keys = list(cells[0].grid) if cells else []
    metric_keys: list[str] = []
    rows = []
    for cell in cells:
        o = outcomes.get(cell.cell_id)
        row: dict[str, Any] = {"cell": cell.cell_id, "index": cell.index, **{k: cell.grid[k] for k in grid_keys}}
        if o is None:
            row.update(status="pending", verdict=None, verdict_reasons=None, error=None, attempts=0, wall_s=None,
                       cpu_s=None, host=None, finished=None)
        else:
            row.update(status=o.status, verdict=o.verdict, verdict_reasons="; ".join(o.verdict_reasons) or None,
                       error=o.error, attempts=o.attempt, wall_s=round(o.wall_s, 3), cpu_s=round(o.cpu_s, 3),
                       host=o.host or None,
                       finished=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(o.finished)) if o.finished else None)
            for k, v in o.metrics.items():
                if k not in metric_keys:
                    metric_keys.append(k)
                row[k] = v
        rows.append(row)
    columns = ["cell", "index", *grid_keys, *FIXED_COLUMNS, *metric_keys]
    return columns, [{c: row.get(c) for c in columns} for row in rows]


def differing_columns(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """The columns (other than :data:`TIMING_COLUMNS`) where rows ``a`` and ``b`` differ; a NaN equals a NaN
    (a run that fell has NaN tracking on every backend)."""
    def same(x: Any, y: Any) -> bool:
        return x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))

    return sorted(k for k in (set(a) | set(b)) - set(TIMING_COLUMNS) if not same(a.get(k), b.get(k)))


def _csv_value(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple, dict)):
        return json.dumps(v)
    return str(v)


def write_results(out_dir: str | Path, columns: list[str], rows: list[dict[str, Any]]) -> tuple[Path, Path]:
    """Write ``results.csv`` and ``results.json`` in ``out_dir`` atomically; returns their paths."""
    out = Path(out_dir)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow([_csv_value(row[c]) for c in columns])
    csv_path = atomic_write_text(out / "results.csv", buf.getvalue())
    json_path = atomic_write_text(out / "results.json", json.dumps({"columns": columns, "cells": rows}, indent=1,
                                                                   default=str))
    return csv_path, json_path


def _numeric(v: Any) -> float | None:
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, (int, float)) and math.isfinite(v):
        return float(v)
    return None


def _tick(v: Any) -> str:
    s = str(v)
    if "/" in s and s.endswith((".xml", ".npz", ".yaml", ".pt")):
        s = Path(s).stem
    return s if len(s) <= 14 else s[:13] + "…"


def summary_figure(path: str | Path, columns: list[str], rows: list[dict[str, Any]], grid_keys: list[str], *,
                   max_metrics: int = 8) -> Path | None:
    """The first ``max_metrics`` numeric headline metrics (rows of panels; true/false columns such as
    ``fell`` are left to the table) against each grid key (columns of panels): the ok cells as points,
    their mean per value as a bar.  ``None`` (and no file) when no metric has a number."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if r["status"] == "ok"]
    start = columns.index(FIXED_COLUMNS[-1]) + 1
    metrics = [c for c in columns[start:] if any(_numeric(r.get(c)) is not None for r in ok)
               and not all(isinstance(r.get(c), bool) for r in ok if r.get(c) is not None)][:max_metrics]
    if not metrics:
        return None
    axes_keys = grid_keys or ["cell"]
    fig, axes = plt.subplots(len(metrics), len(axes_keys), figsize=(3.2 * len(axes_keys) + 1, 2.2 * len(metrics) + 0.6),
                             squeeze=False)
    for i, metric in enumerate(metrics):
        for j, key in enumerate(axes_keys):
            ax = axes[i][j]
            values = list(dict.fromkeys(str(r[key]) for r in rows))
            for k, v in enumerate(values):
                ys = [y for r in ok if str(r[key]) == v and (y := _numeric(r.get(metric))) is not None]
                if ys:
                    xs = [k + 0.08 * (n - (len(ys) - 1) / 2) / max(1, len(ys)) for n in range(len(ys))]
                    ax.bar(k, sum(ys) / len(ys), width=0.6, color="#d0d8e8", zorder=1)
                    ax.plot(xs, ys, "o", color="#2b5c9e", ms=4, zorder=2)
            ax.set_xticks(range(len(values)), [_tick(v) for v in values], rotation=30 if len(values) > 3 else 0,
                          fontsize=7)
            if i == len(metrics) - 1:
                ax.set_xlabel(key, fontsize=8)
            if j == 0:
                ax.set_ylabel(metric.replace(".", ".\n", 1), fontsize=7)
            ax.tick_params(axis="y", labelsize=7)
    n_fail = sum(r["status"] == "failed" for r in rows)
    fig.suptitle(f"{len(ok)} ok cells" + (f", {n_fail} failed (not shown)" if n_fail else "") + "; bar: mean over the other axes",
                 fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / fig.get_figheight()))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return Path(path)
