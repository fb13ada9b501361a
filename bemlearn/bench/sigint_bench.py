"""Ctrl-C (and SIGTERM) latency of ``bemlearn train`` (``bemlearn bench sigint``).

Starts ``python -m bemlearn train`` in a child process on the shipped data with
``dataset.n_points`` training points, waits until the fit has run for ``delay_s`` seconds
(after the fit's ``fit:`` log line of ``bemlearn.pipeline.gp_stage``: the model is built and the fit's Ctrl-C handling in place), sends SIGINT (or ``signum``, e.g. SIGTERM) and times until
the process exits.  Checks that it exited with status 128 + signum (130 for SIGINT, 143 for
SIGTERM) and left a loadable checkpoint marked ``interrupted``.
With ``twice=True`` a second SIGINT follows the first after ``second_after_s`` and the time
to exit after the second one is reported (it must end the process at once).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

from bemlearn.errors import EnvironmentProblem

__all__ = ["measure_sigint", "format_sigint"]


def _reader(stream, lines: list[str], started: threading.Event, stamps: dict[str, float]) -> None:
    for line in iter(stream.readline, ""):
        lines.append(line)
        for key, marker in (("stopped", "keeping the best parameters"), ("checkpoint", "wrote checkpoint"),
                            ("reported", "bemlearn train: interrupted"), ("reported", "bemlearn train: terminated")):
            if marker in line and key not in stamps:
                stamps[key] = time.perf_counter()
        if "gp_stage: fit:" in line:  # the fit has started: its model is built and its Ctrl-C handling in place
            started.set()
    stream.close()


def measure_sigint(
    config: str | os.PathLike[str],
    data: str | os.PathLike[str],
    *,
    n_points: int = 3000,
    kind: str = "exact",
    max_iter: int = 1000,
    delay_s: float = 5.0,
    twice: bool = False,
    second_after_s: float = 0.2,
    timeout_s: float = 600.0,
    threads: int = 1,
    signum: int = signal.SIGINT,
    workdir: str | os.PathLike[str] | None = None,
) -> dict:
    """One measurement (module docstring); returns latencies in seconds and what was left behind.

    ``workdir`` keeps the config (``config.yaml``) and the run folder (``run/``) there instead
    of in a temporary folder (e.g. to ``train --resume`` from the interrupted checkpoint)."""
    from bemlearn.export.checkpoint import load_checkpoint
    from bemlearn.models.gp_kinds import gp_class

    cfg = yaml.safe_load(Path(config).read_text())
    cfg.setdefault("dataset", {})["n_points"] = n_points
    cfg.setdefault("train", {}).update(kind=kind, max_iter=max_iter, tol=0.0)
    if gp_class(kind).sparse:  # the sparse fit of `bemlearn bench train`: M = 512 inducing points
        cfg["train"]["n_inducing"] = 512
    with (contextlib.nullcontext(str(workdir)) if workdir is not None else tempfile.TemporaryDirectory(prefix="bemlearn-sigint-")) as tmp:
        cfg_path = Path(tmp) / "config.yaml"
        cfg_path.write_text(yaml.safe_dump(cfg, sort_keys=False))
        out = Path(tmp) / "run"
        cmd = [sys.executable, "-m", "bemlearn", "train", str(cfg_path), "--data", str(data), "--out", str(out),
               "--no-progress", "--threads", str(threads)]
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=os.getcwd())
        lines: list[str] = []
        started = threading.Event()
        stamps: dict[str, float] = {}
        reader = threading.Thread(target=_reader, args=(proc.stderr, lines, started, stamps), daemon=True)
        reader.start()
        if not started.wait(timeout_s):
            proc.kill()
            raise EnvironmentProblem(f"bench sigint: the fit did not start within {timeout_s} s: {''.join(lines)[-2000:]}")
        time.sleep(delay_s)
        if proc.poll() is not None:
            raise EnvironmentProblem(f"bench sigint: the fit ended before the signal; raise max_iter ({''.join(lines)[-2000:]})")
        t0 = time.perf_counter()
        proc.send_signal(signum)
        t_second = None
        if twice:
            time.sleep(second_after_s)
            if proc.poll() is None:
                proc.send_signal(signum)
                t_second = time.perf_counter()
        try:
            rc = proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            rc = None
        t_end = time.perf_counter()
        reader.join(5)
        ck_ok, interrupted = False, None
        try:
            ck = load_checkpoint(out)
            ck_ok, interrupted = True, bool(ck.metadata.extra.get("interrupted"))
        except (OSError, ValueError):
            pass
        return {
            "n_points": n_points, "kind": kind, "delay_s": delay_s, "returncode": rc,
            "latency_s": t_end - t0, "stop_s": stamps["stopped"] - t0 if "stopped" in stamps else None,
            "checkpoint_s": stamps["checkpoint"] - t0 if "checkpoint" in stamps else None,
            "reported_s": stamps["reported"] - t0 if "reported" in stamps else None,
            "after_second_s": None if t_second is None else t_end - t_second,
            "checkpoint": ck_ok, "interrupted": interrupted, "stderr_tail": "".join(lines[-5:]),
        }


def format_sigint(rows: list[dict]) -> str:
    """A Markdown table of :func:`measure_sigint` rows, with the median latency."""
    out = ["| kind | N | signal after fit start (s) | exit status | SIGINT → fit stopped (s) | → checkpoint written (s) | "
           "→ exit (s) | checkpoint (interrupted) |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    f = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    for r in rows:
        lat = f(r["latency_s"]) + (f" (after the 2nd SIGINT: {r['after_second_s']:.2f})" if r["after_second_s"] is not None else "")
        out.append(f"| {r['kind']} | {r['n_points']} | {r['delay_s']:g} | {r['returncode']} | {f(r['stop_s'])} | {f(r['checkpoint_s'])} | "
                   f"{lat} | {r['checkpoint']} ({r['interrupted']}) |")
    lats = sorted(r["latency_s"] for r in rows)
    out.append(f"\nmedian SIGINT → exit: {lats[len(lats) // 2]:.2f} s over {len(lats)} run(s); max {lats[-1]:.2f} s")
    return "\n".join(out)
