"""scripts/measure_timings.py writes the README's timings with the machine they were measured on."""

from pathlib import Path

from tests.file_module import load_file_module

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "measure_timings.py"


def _module():
    return load_file_module(SCRIPT)


def test_table_states_the_machine_and_every_run():
    mod = _module()
    facts = mod.machine_facts()
    for key in ("date (UTC)", "cores", "CPU", "load average (1/5/15 min) at start", "python", "torch", "mujoco"):
        assert facts[key], key
    doc = mod.format_timings(facts, [("bemlearn run configs/furuta.yaml", [61.0, 70.0, 64.0], 0, "run folder: x"),
                                     ("python -m pytest -q", [218.4], 0, "500 passed")], "1.00 / 2.00 / 3.00")
    assert "| `bemlearn run configs/furuta.yaml` | 3 | 64 | 61–70 | 0 |" in doc  # median and range of the repeats
    assert "| `python -m pytest -q` | 1 | 218 | 218–218 | 0 |" in doc
    assert f"| cores | {facts['cores']} |" in doc and "| load average (1/5/15 min) at end | 1.00 / 2.00 / 3.00 |" in doc


def test_timed_reports_wall_time_status_and_last_line(tmp_path):
    import sys

    mod = _module()
    seconds, rc, tail = mod.timed([sys.executable, "-c", "import time; time.sleep(0.2); print('a'); print('done')"], cwd=tmp_path)
    assert 0.2 <= seconds < 10 and rc == 0 and tail == "done"
