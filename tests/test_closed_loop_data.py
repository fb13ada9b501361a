"""The closed-loop-only target (issue 28): a pendubot balanced by a plain LQR with small torques on both
joints, logged, imported with `bemlearn data import` and run model-free, must not be ok; the same loop
playing `bemlearn excite`'s schedule must be ok with the learned slopes within 10 % of the model's.
Slow (about 5–7 minutes: two simulations, two imports, two runs): `python -m pytest -m slow tests/test_closed_loop_data.py`."""

from __future__ import annotations

from pathlib import Path

import pytest

ROBOT = Path(__file__).resolve().parent / "robots" / "pendubot.xml"


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_verdict_flips_from_lockstep_to_excited_data(tmp_path):
    from bemlearn.bench.closed_loop_bench import ClosedLoopCase, bench_closed_loop_data

    res = bench_closed_loop_data(ClosedLoopCase(robot=str(ROBOT)), tmp_path)
    lock, excited = res["cases"]
    assert lock["sim"]["fell"] == 0 and excited["sim"]["fell"] == 0
    assert lock["verdict"].status != "ok"
    first = next(f for f in lock["verdict"].findings if f.check == "support")
    assert "qdd_elbow ≈" in first.reason and "qdd_shoulder (corr -0.9" in first.reason and "bemlearn excite" in first.reason
    assert excited["verdict"].status == "ok", excited["verdict"]
    model = res["model_slopes"]
    for key in ("q_shoulder", "qdd_shoulder"):
        assert abs(excited["slopes"][key] / model[key] - 1.0) <= 0.10, (key, excited["slopes"][key], model[key])
    # the lockstep data's learned q̈_a slope is the one the verdict refused: far from the model's
    assert abs(lock["slopes"]["qdd_shoulder"] / model["qdd_shoulder"] - 1.0) > 0.5
