"""``bemlearn bench sweep SWEEP.yaml``: the Ray backend against the serial one on the same sweep.

Runs the sweep twice from scratch, ``--backend serial`` into ``OUT/serial`` and ``--backend
ray`` (a local Ray instance with this machine's cores) into ``OUT/ray``, then resumes the
finished Ray sweep once, and reports:

* wall times of both (validation included; Ray's includes starting and stopping its instance)
  and their ratio, with and without Ray's start;
* the Ray backend's overhead per cell, ``(started − submitted) + (received − finished)`` of
  each attempt (:class:`~bemlearn.sweep.driver.CellTiming`): dispatch, the worker's start-up and
  imports (unpickling a cell's config imports the pipeline), and the return of the record; the
  first cell on each worker process carries the start-up, so it is reported apart;
* the stage time summed over the cells of each backend (how much the cells slowed down by
  sharing the machine's cores);
* whether both backends gave the same results (every column but the timings; NaN equals NaN);
* the resume of the finished sweep (nothing to run);
* the load average before and after (other processes on the machine change every figure).
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

__all__ = ["run_sweep_bench", "format_sweep_bench"]


def run_sweep_bench(sweep: str | Path, out_dir: str | Path, *, max_parallel: int | None = None, force: bool = False,
                    progress: bool = True) -> dict:
    """Run the benchmark (module docstring); returns its figures."""
    from bemlearn.sweep import run_sweep
    from bemlearn.sweep.results import differing_columns

    out = Path(out_dir)
    load_before = os.getloadavg()
    serial = run_sweep(sweep, out / "serial", backend="serial", force=force, progress=progress)
    ray = run_sweep(sweep, out / "ray", backend="ray", force=force, max_parallel=max_parallel, progress=progress)
    t0 = time.perf_counter()
    resumed = run_sweep(sweep, out / "ray", backend="ray", resume=True, progress=False)
    resume_s = time.perf_counter() - t0
    load_after = os.getloadavg()
    differ = []
    for a, b in zip(serial.rows, ray.rows):
        bad = differing_columns(a, b)
        if bad:
            differ.append({"cell": a["cell"], "columns": bad})
    seen_pids: set[int | None] = set()
    first: list[float] = []
    rest: list[float] = []
    for t in sorted(ray.timings, key=lambda t: t.started):
        pid = ray.outcomes[t.cell_id].pid if t.cell_id in ray.outcomes else None
        (first if pid not in seen_pids else rest).append(t.overhead_s)
        seen_pids.add(pid)
    overhead = [t.overhead_s for t in ray.timings]
    return {
        "sweep": str(sweep), "cells": len(ray.cells), "cores": os.cpu_count(),
        "load_before": load_before, "load_after": load_after,
        "serial_s": serial.wall_s, "ray_s": ray.wall_s, "ray_startup_s": ray.backend_startup_s,
        "ratio": ray.wall_s / serial.wall_s, "ratio_without_startup": (ray.wall_s - ray.backend_startup_s) / serial.wall_s,
        "stage_s_serial": sum(o.wall_s for o in serial.outcomes.values()),
        "stage_s_ray": sum(o.wall_s for o in ray.outcomes.values()),
        "cpu_s_serial": sum(o.cpu_s for o in serial.outcomes.values()),
        "cpu_s_ray": sum(o.cpu_s for o in ray.outcomes.values()),
        "overhead_mean_s": statistics.fmean(overhead) if overhead else float("nan"),
        "overhead_max_s": max(overhead, default=float("nan")),
        "overhead_first_on_worker_s": first, "overhead_later_mean_s": statistics.fmean(rest) if rest else float("nan"),
        "serial_overhead_mean_s": statistics.fmean(t.overhead_s for t in serial.timings) if serial.timings else float("nan"),
        "ok": (serial.n_ok, ray.n_ok), "identical": not differ, "differences": differ,
        "resume_s": resume_s, "resume_ran": len(resumed.ran),
    }


def format_sweep_bench(r: dict) -> str:
    """The figures of :func:`run_sweep_bench` as lines of text."""
    lb, la = r["load_before"], r["load_after"]
    first = ", ".join(f"{v:.2f}" for v in r["overhead_first_on_worker_s"])
    return "\n".join([
        f"sweep {r['sweep']}: {r['cells']} cells on {r['cores']} cores; load average before "
        f"{lb[0]:.2f} {lb[1]:.2f} {lb[2]:.2f}, after {la[0]:.2f} {la[1]:.2f} {la[2]:.2f}",
        f"serial: {r['serial_s']:.1f} s ({r['ok'][0]} ok); ray: {r['ray_s']:.1f} s ({r['ok'][1]} ok), of which "
        f"{r['ray_startup_s']:.1f} s starting Ray",
        f"ray / serial wall time: {r['ratio']:.3f} ({r['ratio_without_startup']:.3f} without Ray's start)",
        f"stage time summed over the cells: serial {r['stage_s_serial']:.1f} s, ray {r['stage_s_ray']:.1f} s "
        f"(CPU time: serial {r['cpu_s_serial']:.1f} s, ray {r['cpu_s_ray']:.1f} s)",
        f"Ray overhead per cell: mean {r['overhead_mean_s']:.3f} s, max {r['overhead_max_s']:.3f} s; first cell on "
        f"each worker {first} s, later cells mean {r['overhead_later_mean_s']:.3f} s "
        f"(serial backend: {r['serial_overhead_mean_s']:.4f} s)",
        "results: " + ("identical on both backends (every column but wall_s, cpu_s, host, finished)" if r["identical"] else
                       f"DIFFER in {len(r['differences'])} cells: {r['differences']}"),
        f"resume of the finished sweep: {r['resume_s']:.1f} s in this process, {r['resume_ran']} cells run",
    ])
