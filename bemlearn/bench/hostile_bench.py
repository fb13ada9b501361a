"""``bemlearn bench hostile``: the figures of issue 29 (hostile inputs), each measured in a child process.

* predictor memory — peak RSS (``resource.getrusage`` max RSS) of a child process in which the TorchScript
  and the ``.pt2`` predictor (``n_train`` support points) evaluate ``forward`` on ``rows``
  rows, and its growth during the call (a ``.pt2`` program evaluated the whole batch at once
  before it ran in blocks);
* sweep validation — wall time of :func:`~bemlearn.sweep.cells.expand_cells` on a grid of
  ``cells`` cells (resolve and identify every cell);
* binary log — time and peak RSS growth of importing a sparse 2 GB file of NUL bytes, and a
  valid log followed by a 2 GB NUL tail.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

__all__ = ["predictor_memory", "sweep_validation_s", "format_hostile"]

_EVAL = textwrap.dedent("""
    import json, resource, sys, time, torch
    kind, path, rows, width = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    if kind == "pt2":
        from bemlearn.export.pt2 import load_pt2_predictor
        p = load_pt2_predictor(path)
    else:
        from bemlearn.export.torchscript import load_torchscript
        p = load_torchscript(path)
    x = torch.randn(rows, width, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    p.forward(x[:8])
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    with torch.no_grad():
        mean, std = p.forward(x)
    s = time.perf_counter() - t0
    growth = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"kind": kind, "rows": rows, "s": s, "peak_growth_mb": growth, "peak_mb": peak, "mean0": float(mean[0])}))
""")


def predictor_memory(*, rows: int = 10**6, n_train: int = 500) -> list[dict]:
    """Peak RSS growth (MB) and time of ``forward`` on ``rows`` rows, TorchScript and ``.pt2``."""
    from bemlearn.bench.predict_bench import synthetic_posterior
    from bemlearn.export import BEMPredictor, save_pt2
    from bemlearn.export.torchscript import save_torchscript

    state, meta = synthetic_posterior(n_train=n_train, m=1, seed=0)
    predictor = BEMPredictor(state, meta)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        files = {"torchscript": save_torchscript(predictor, Path(tmp) / "p.pt"), "pt2": save_pt2(predictor, Path(tmp) / "p.pt2")}
        for kind, path in files.items():
            res = subprocess.run([sys.executable, "-c", _EVAL, "pt2" if kind == "pt2" else "ts", str(path), str(rows),
                                  str(predictor.n_bem)], capture_output=True, text=True, check=True)
            doc = json.loads(res.stdout.strip().splitlines()[-1])
            doc["kind"] = kind
            out.append(doc)
    return out


def sweep_validation_s(*, cells: int = 10**4) -> float:
    """Wall time (s) of validating a ``cells``-cell grid (two seed axes) of the cart-pole in ``tests/robots``."""
    import time

    from bemlearn.sweep.cells import expand_cells
    from bemlearn.sweep.config import load_sweep

    side = int(round(cells**0.5))
    robot = Path(__file__).resolve().parents[2] / "tests" / "robots" / "cartpole.xml"
    loaded = load_sweep({"base": {"robot": str(robot)}, "stage": "run",
                         "grid": {"collect.seed": list(range(side)), "dataset.seed": list(range(cells // side))}})
    t0 = time.perf_counter()
    expand_cells(loaded)
    return time.perf_counter() - t0


def format_hostile(memory: list[dict], validation_s: float | None, cells: int) -> str:
    lines = [f"{'predictor':<12}{'rows':>10}{'time s':>10}{'peak RSS MB':>13}{'growth in forward MB':>22}"]
    for m in memory:
        lines.append(f"{m['kind']:<12}{m['rows']:>10}{m['s']:>10.2f}{m['peak_mb']:>13.0f}{m['peak_growth_mb']:>22.0f}")
    if len(memory) == 2:
        lines.append(f".pt2 / TorchScript peak RSS: {memory[1]['peak_mb'] / memory[0]['peak_mb']:.2f}")
    if validation_s is not None:
        lines.append(f"sweep validation of {cells} cells: {validation_s:.1f} s")
    return "\n".join(lines)
