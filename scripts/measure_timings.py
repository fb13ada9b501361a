"""Measure the README's timings and write them, with the machine, to docs/timings.md.

    python scripts/measure_timings.py [--out docs/timings.md] [--repeats 1] [--no-tests]
    python scripts/measure_timings.py --only-startup        # the start-up rows only, printed

Times the start-up of the command (``python -m bemlearn --help``, ``python -m bemlearn
config show configs/furuta.yaml`` and ``config show`` of a config naming only a robot file,
``--startup-repeats`` times each; the targets are 0.5 s and 1.5 s on an idle 2-core machine), runs the
quickstart's main job (``python -m bemlearn run configs/furuta.yaml`` into a
temporary folder, also ``configs/biped.yaml`` unless ``--no-biped``) and the test command
(``python -m pytest -q``), each ``--repeats`` times, and writes a small Markdown table:
wall time of each run, and the machine facts the numbers depend on (cores, CPU model,
load average before and after, Python / torch / MuJoCo versions, date).  Other processes
loading the machine change the numbers; the load average says how much.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["machine_facts", "timed", "format_timings", "main"]

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # this checkout's bemlearn, also when another one is installed


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _load() -> str:
    try:
        return " / ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "unknown"


def machine_facts() -> dict[str, str]:
    """Cores, CPU model, load average (1 / 5 / 15 min), versions, date (UTC)."""
    import mujoco
    import torch

    return {
        "date (UTC)": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M"),  # noqa: UP017 (dt.UTC: Python ≥ 3.11)
        "cores": str(os.cpu_count()),
        "CPU": _cpu_model(),
        "load average (1/5/15 min) at start": _load(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "mujoco": mujoco.__version__,
        "platform": platform.platform(),
    }


def timed(cmd: list[str], *, cwd: Path) -> tuple[float, int, str]:
    """Wall time (s), exit status and the last output line of ``cmd``."""
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    tail = (done.stdout.strip().splitlines() or done.stderr.strip().splitlines() or [""])[-1]
    return seconds, done.returncode, tail


def _seconds(s: float) -> str:
    """Whole seconds for runs, hundredths below ten seconds (start-up)."""
    return f"{s:.2f}" if s < 10 else f"{s:.0f}"


def format_timings(facts: dict[str, str], rows: list[tuple[str, list[float], int, str]], load_after: str) -> str:
    """The Markdown document: one row per command (median, min–max of the repeats)."""
    out = ["# Measured timings", "",
           "Written by `python scripts/measure_timings.py`; rerun it to refresh. Wall-clock seconds of one process each.", "",
           "| command | runs | median (s) | min–max (s) | exit status | last line |", "| --- | --- | --- | --- | --- | --- |"]
    for cmd, secs, rc, tail in rows:
        med, lo, hi = (_seconds(v) for v in (statistics.median(secs), min(secs), max(secs)))
        out.append(f"| `{cmd}` | {len(secs)} | {med} | {lo}–{hi} | {rc} | {tail.replace('|', '/')[:80]} |")
    out += ["", "| machine | |", "| --- | --- |"]
    out += [f"| {k} | {v} |" for k, v in facts.items()]
    out.append(f"| load average (1/5/15 min) at end | {load_after} |")
    out += ["", "Other processes share these cores: compare the load average with the core count before "
            "reading the numbers as this machine's speed.", ""]
    return "\n".join(out)


#: The start-up commands: (label, arguments after ``python -m bemlearn``).
#: ``{robot_only}`` is a temporary config holding only ``robot: tests/robots/cartpole.xml`` (every default derived).
STARTUP = (("bemlearn --help", ["--help"]),
           ("bemlearn config show configs/furuta.yaml", ["config", "show", "configs/furuta.yaml"]),
           ("bemlearn config show ROBOT.yaml (only robot: tests/robots/cartpole.xml)", ["config", "show", "{robot_only}"]))


def startup_rows(repeats: int) -> list[tuple[str, list[float], int, str]]:
    """Wall time of each start-up command, ``repeats`` runs each, through ``python -m bemlearn``
    (this checkout's package, whatever ``bemlearn`` script is on the PATH)."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="bemlearn-timing-") as tmp:
        robot_only = Path(tmp) / "robot.yaml"
        robot_only.write_text(f"robot: {ROOT / 'tests' / 'robots' / 'cartpole.xml'}\n")
        for label, cmd in STARTUP:
            secs, rc, tail = [], 0, ""
            for _ in range(repeats):
                s, rc, tail = timed([sys.executable, "-m", "bemlearn", *(c.format(robot_only=robot_only) for c in cmd)], cwd=ROOT)
                secs.append(s)
            print(f"{label}: best {min(secs):.2f} s of {repeats} (exit {rc})", flush=True)
            rows.append((label, secs, rc, tail))
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=None, help="default: docs/timings.md (--only-startup: print instead)")
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--no-tests", action="store_true", help="skip the test command")
    p.add_argument("--no-biped", action="store_true", help="skip `run configs/biped.yaml`")
    p.add_argument("--startup-repeats", type=int, default=5, help="runs of each start-up command (the fastest counts)")
    p.add_argument("--only-startup", action="store_true",
                   help="time the start-up commands only and print the table (written only with an explicit --out)")
    args = p.parse_args(argv)
    facts = machine_facts()
    rows = startup_rows(args.startup_repeats)
    jobs = [] if args.only_startup else [("bemlearn run configs/furuta.yaml", "configs/furuta.yaml")]
    if not (args.no_biped or args.only_startup):
        jobs.append(("bemlearn run configs/biped.yaml", "configs/biped.yaml"))
    for label, cfg in jobs:
        secs, rc, tail = [], 0, ""
        for _ in range(args.repeats):
            with tempfile.TemporaryDirectory(prefix="bemlearn-timing-") as tmp:
                s, rc, tail = timed([sys.executable, "-m", "bemlearn", "run", cfg, "--out", str(Path(tmp) / "run"), "--no-progress"], cwd=ROOT)
            secs.append(s)
            print(f"{label}: {s:.0f} s (exit {rc})", flush=True)
        rows.append((label, secs, rc, tail))
    if not (args.no_tests or args.only_startup):
        secs = []
        for _ in range(args.repeats):
            s, rc, tail = timed([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"], cwd=ROOT)
            secs.append(s)
            print(f"python -m pytest -q: {s:.0f} s (exit {rc}): {tail}", flush=True)
        rows.append(("python -m pytest -q", secs, rc, tail))
    doc = format_timings(facts, rows, _load())
    if args.only_startup and args.out is None:
        print(doc)
        return 0
    from bemlearn.files import atomic_write_text

    out = args.out or ROOT / "docs" / "timings.md"
    atomic_write_text(out, doc)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
