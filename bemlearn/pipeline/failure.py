"""A run that fails after it produced something: what it produced stays, and ``metrics.json`` says where it stopped.

A failure after the checkpoint exists (or the collected data) keeps the run folder
(:func:`bemlearn.outputs.worth_keeping` decides); :func:`record_failure` writes the run's
partial metrics with ``failed = {"stage", "error_type", "error", "kept"}`` and a verdict that
:func:`bemlearn.pipeline.verdict.judge_run` makes ``unusable`` on that key: a run that did not
finish is never ``ok``.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from bemlearn.files import INTERNAL_PREFIX, atomic_write_text

__all__ = ["record_failure", "read_metrics"]

log = logging.getLogger(__name__)


def read_metrics(out: Path) -> dict[str, Any]:
    """``out/metrics.json`` as a dict (``{}`` when missing or unreadable)."""
    try:
        doc = json.loads((out / "metrics.json").read_text())
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) else {}


def record_failure(out: Path, stage: str, exc: BaseException, metrics: dict[str, Any], *,
                   since_ns: int | None = None) -> dict[str, Any]:
    """Write ``out/metrics.json`` for a run that failed at ``stage`` with ``exc``; returns what was written.

    Args:
        out: the run folder.
        stage: the stage that failed (``"train: evaluation"``, ``"export"``, ``"simulate"``, ``"report"``, …).
        exc: the exception.
        metrics: the metrics gathered so far; a ``failed`` entry already there (recorded by an inner
            stage) keeps its more precise stage.
        since_ns: when the run started (``time.time_ns()``): ``kept`` lists only what it wrote since
            (a replaced run's files that ``--force`` had not rewritten yet are removed afterwards).
    """
    from bemlearn.pipeline.verdict import judge_run

    doc = dict(metrics)
    earlier = doc.get("failed")
    if isinstance(earlier, dict) and earlier.get("stage"):
        stage = str(earlier["stage"])
    kept = sorted(p.name for p in out.iterdir() if not p.name.startswith(INTERNAL_PREFIX) and p.name != "metrics.json"
                  and (since_ns is None or p.stat().st_mtime_ns >= since_ns))
    text = str(exc).splitlines()[0] if str(exc) else ""
    doc["failed"] = {"stage": stage, "error_type": type(exc).__name__, "error": text, "kept": [*kept, "metrics.json"]}
    doc["verdict"] = judge_run(doc).to_dict()
    atomic_write_text(out / "metrics.json", json.dumps(doc, indent=2, default=float))
    log.error("the run failed at stage '%s' (%s: %s); %s keeps what it produced (%s) and metrics.json marks the run as "
              "failed there", stage, type(exc).__name__, text, out, ", ".join(kept))
    return doc
