"""A run whose excitation yields no data ends with a verdict, not a crash (own cart-pole)."""

from __future__ import annotations

import json
from pathlib import Path

import bemlearn.sim.collect as collect_module
from bemlearn.errors import DataError
from bemlearn.pipeline.resolve import resolve_pipeline_config
from bemlearn.pipeline.run import run_pipeline

ROBOT = Path(__file__).parent / "robots" / "cartpole.xml"


def test_every_trial_falling_at_once_is_an_unusable_verdict(tmp_path, monkeypatch):
    def fell(*args, **kwargs):
        raise DataError("collect: every trial fell immediately; check the gains and initial ranges")

    monkeypatch.setattr(collect_module, "collect", fell)
    cfg = tmp_path / "r.yaml"
    cfg.write_text(f"robot: {ROBOT}\n")
    out = run_pipeline(resolve_pipeline_config(cfg), tmp_path / "run", progress=False).out
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["verdict"]["status"] == "unusable"
    assert metrics["failed"]["stage"] == "collect"
    assert "every trial fell immediately" in metrics["verdict"]["reasons"][0]
    assert (out / "report.md").read_text().startswith("# bemlearn run")
    assert "unusable" in (out / "report.md").read_text()[:400]
