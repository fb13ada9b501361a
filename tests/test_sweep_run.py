"""Sweeps that run: serial and on a real local Ray instance, retries, resume, SIGTERM (issue 24).

The cells are tiny ``train`` cells (2 trials × 2 s of cart-pole excitation, 80 GP points) so the
module stays within seconds per cell; the Ray instance is started once for the module.
"""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bemlearn.errors import OutputExistsError
from bemlearn.sweep import read_outcome, run_sweep

ROOT = Path(__file__).resolve().parents[1]
BASE = {"robot": str(ROOT / "tests/robots/cartpole.xml"), "collect": {"n_trials": 2, "duration_s": 2.0},
        "dataset": {"n_points": 80}, "train": {"max_iter": 15}, "evaluate": {"n_references": 1, "duration_s": 5.0}}
#: one cell that cannot work (a q_u window of 10 µrad holds no sample: it fails while building the
#: datasets, after the config checks) and one that does
SWEEP = {"base": BASE, "grid": {"dataset.qu_window": [1e-5, 0.5]}, "stage": "train"}
TIMING = {"wall_s", "cpu_s", "host", "finished"}


def _events(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]


def _results(out: Path) -> list[dict]:
    return json.loads((out / "results.json").read_text())["cells"]


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "serial"
    return out, run_sweep(SWEEP, out, backend="serial", progress=False)


def test_a_failed_cell_is_retried_once_then_recorded_and_the_sweep_goes_on(serial):
    out, result = serial
    bad, good = result.cells
    assert result.backend == "serial" and result.ran == [bad.cell_id, good.cell_id]
    fail, ok = result.outcomes[bad.cell_id], result.outcomes[good.cell_id]
    assert fail.status == "failed" and fail.attempt == 2
    assert fail.error.startswith("TrajectoryFormatError: choose_sigma: ") and "fewer than 10 samples inside" in fail.error
    assert "Traceback" in fail.traceback and "build_datasets" in fail.traceback
    assert ok.status == "ok" and ok.attempt == 1 and ok.pid == os.getpid() and ok.cpu_s > 0
    started = [e["cell"] for e in _events(out) if e["event"] == "started"]
    assert started.count(bad.cell_id) == 2 and started.count(good.cell_id) == 1
    # the ok cell is the folder `bemlearn collect` + `bemlearn train` write, plus cell.json and cell.log
    folder = out / "cells" / good.cell_id
    for name in ("config.yaml", "config_resolved.json", "data.npz", "data.truth.npz", "checkpoint.pt", "metrics.json",
                 "cell.json", "cell.log"):
        assert (folder / name).is_file(), name
    metrics = json.loads((folder / "metrics.json").read_text())
    assert ok.metrics["bem_heldout.rmse"] == metrics["bem_heldout"]["rmse"] > 0
    assert ok.metrics["bem_heldout.coverage_2sigma_band"] == metrics["bem_heldout"]["coverage_2sigma_band"]
    assert "closed_loop.predictor.tracking_rmse" not in ok.metrics  # a train cell has no closed loop


def test_results_have_one_row_per_cell_with_grid_values_status_and_metrics(serial):
    out, _result = serial
    header = (out / "results.csv").read_text().splitlines()[0].split(",")
    assert header[:5] == ["cell", "index", "dataset.qu_window", "status", "verdict"]
    rows = _results(out)
    assert [(r["dataset.qu_window"], r["status"], r["attempts"]) for r in rows] == [(1e-5, "failed", 2), (0.5, "ok", 1)]
    assert rows[0]["error"].startswith("TrajectoryFormatError: choose_sigma") and rows[1]["error"] is None
    metrics = json.loads((out / "cells" / rows[1]["cell"] / "metrics.json").read_text())
    assert rows[1]["val_rmse"] == metrics["val_rmse"] and rows[1]["verdict"] == (metrics.get("verdict") or {}).get("status")
    assert (out / "summary.png").stat().st_size > 10_000 and (out / "sweep.yaml").is_file()


def test_resume_runs_only_the_incomplete_cells_and_an_existing_sweep_is_not_replaced(serial, tmp_path):
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(serial[0], out)
    good = serial[1].cells[1].cell_id
    marker = (out / "cells" / good / "cell.json").read_bytes()
    with pytest.raises(OutputExistsError, match="use --resume to continue it"):
        run_sweep(SWEEP, out, backend="serial", progress=False)
    n_events = len(_events(out))
    t0 = time.perf_counter()
    again = run_sweep(SWEEP, out, backend="serial", resume=True, progress=False)
    assert again.ran == [serial[1].cells[0].cell_id]  # the failed cell runs again; the complete one does not
    assert (out / "cells" / good / "cell.json").read_bytes() == marker
    assert not [e for e in _events(out)[n_events:] if e["cell"] == good]
    assert time.perf_counter() - t0 < 15


@pytest.fixture(scope="module")
def ray_instance():
    ray = pytest.importorskip("ray", reason="Ray is the [ray] extra (installed by the [test] extra)")
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()
    for sig, handler in handlers.items():   # ray.init leaves its SIGTERM handler: later tests in this process need theirs
        signal.signal(sig, handler)


def test_a_ray_instance_the_backend_starts_leaves_the_signal_handlers_as_they_were():
    """ray.init installs its own SIGTERM handler and leaves it after shutdown (Ray 2.x); a process that goes on after a
    sweep (a notebook, a script calling run_sweep) must get its own handlers back."""
    ray = pytest.importorskip("ray", reason="Ray is the [ray] extra (installed by the [test] extra)")
    from bemlearn.sweep.backends import RayBackend
    from bemlearn.sweep.config import SweepResources

    assert not ray.is_initialized()
    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    backend = RayBackend(SweepResources(cpus=1))
    try:
        assert backend.started_here and signal.getsignal(signal.SIGTERM) is not before[signal.SIGTERM]  # Ray's, while it runs
    finally:
        backend.close()
    assert {sig: signal.getsignal(sig) for sig in before} == before


def test_the_ray_backend_runs_the_same_cells_in_workers_with_the_same_metrics(serial, ray_instance, tmp_path):
    out = tmp_path / "ray"
    result = run_sweep(SWEEP, out, backend="ray", progress=False)
    assert result.backend == "ray" and ray_instance.is_initialized()  # an instance it did not start is left running
    assert {o.pid for o in result.outcomes.values()}.isdisjoint({os.getpid()})  # ran in Ray workers
    ray_rows, serial_rows = _results(out), _results(serial[0])
    assert [r["cell"] for r in ray_rows] == [r["cell"] for r in serial_rows]
    for r, s in zip(ray_rows, serial_rows):
        assert {k: v for k, v in r.items() if k not in TIMING} == {k: v for k, v in s.items() if k not in TIMING}
    assert [r["status"] for r in ray_rows] == ["failed", "ok"] and ray_rows[1]["bem_heldout.rmse"] > 0


def test_a_cell_larger_than_the_ray_cluster_is_refused_before_any_runs(ray_instance, tmp_path):
    from bemlearn.errors import SweepError

    with pytest.raises(SweepError, match=r"a cell asks for 3 CPU\(s\) and 0 GPU\(s\); the Ray cluster has 2 CPU\(s\)"):
        run_sweep({**SWEEP, "resources": {"cpus": 3}}, tmp_path / "big", backend="ray", progress=False)
    assert not (tmp_path / "big").exists()   # a sweep that ran no cell leaves no folder it created (issue 29)


def _driver(args: list[str], *, block_ray: bool) -> subprocess.Popen:
    """``bemlearn ARGS`` in a child process (its own session: what it leaves behind can be ended by group)."""
    preamble = ""
    if block_ray:
        preamble = ("import sys\nclass _NoRay:\n    def find_spec(self, name, path=None, target=None):\n"
                    "        if name == 'ray' or name.startswith('ray.'):\n            raise ImportError('ray is blocked')\n"
                    "sys.meta_path.insert(0, _NoRay())\n")
    code = preamble + f"import sys\nfrom bemlearn.cli.main import main\nsys.exit(main({args!r}))\n"
    return subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def test_sigterm_cancels_the_sweep_and_resume_completes_it_without_rerunning_a_cell(tmp_path):
    # closed-loop cells with the model BEM: a short one, then a longer one the signal interrupts
    sweep = {"base": {**BASE, "simulate": {"bem_source": "model"}}, "grid": {"simulate.duration_s": [1.5, 3.0]},
             "stage": "simulate"}
    path = tmp_path / "s.yaml"
    path.write_text(json.dumps(sweep))  # JSON is YAML
    out = tmp_path / "sweep"
    # without Ray (blocked in the child): the ray backend falls back to serial, with a message
    proc = _driver(["sweep", str(path), "--out", str(out), "--no-progress"], block_ray=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if (out / "log.jsonl").is_file() and sum(e["event"] == "started" for e in _events(out)) == 2:
            break  # the first cell is complete and the second has started
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Ray is not installed" in err and "continue with `bemlearn sweep" in err
    first, second = (json.loads((out / "results.json").read_text())["cells"][i]["cell"] for i in (0, 1))
    assert read_outcome(out / "cells" / first).status == "ok"
    assert not (out / "cells" / second).exists()  # the interrupted cell's folder is removed
    assert [r["status"] for r in _results(out)] == ["ok", "pending"]
    result = run_sweep(path, out, backend="serial", resume=True, progress=False)
    assert result.ran == [second] and [r["status"] for r in _results(out)] == ["ok", "ok"]
    completed = [e["cell"] for e in _events(out) if e["event"] == "completed"]
    assert sorted(completed) == sorted([first, second])  # each cell ran to completion exactly once


@pytest.mark.slow
def test_a_killed_ray_driver_leaves_complete_cells_and_resume_runs_each_cell_to_completion_once(tmp_path):
    pytest.importorskip("ray")
    sweep = {"base": {**BASE, "simulate": {"bem_source": "model"}}, "grid": {"simulate.duration_s": [1.5, 6.0, 7.0, 8.0]},
             "stage": "simulate"}
    path = tmp_path / "s.yaml"
    path.write_text(json.dumps(sweep))
    out = tmp_path / "sweep"
    proc = _driver(["sweep", str(path), "--out", str(out), "--backend", "ray", "--no-progress"], block_ray=False)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if (out / "log.jsonl").is_file() and any(e["event"] == "completed" for e in _events(out)):
            break
        time.sleep(0.05)
    proc.kill()  # SIGKILL of the driver alone: no handler runs; Ray's raylet and workers share its fate
    proc.communicate(timeout=60)
    time.sleep(2)
    with contextlib.suppress(ProcessLookupError):  # Ray 2.60 leaves its two agent processes hanging (docs/sweeps.md)
        os.killpg(proc.pid, signal.SIGKILL)
    cells = json.loads((out / "results.json").read_text())["cells"]
    complete_before = [r["cell"] for r in cells if (o := read_outcome(out / "cells" / r["cell"])) and o.status == "ok"]
    assert 1 <= len(complete_before) < 4
    result = run_sweep(path, out, backend="ray", resume=True, progress=False)
    assert set(result.ran).isdisjoint(complete_before) and result.n_ok == 4
    completed = [e["cell"] for e in _events(out) if e["event"] == "completed"]
    assert sorted(completed) == sorted(c.cell_id for c in result.cells)  # no cell ran to completion twice
