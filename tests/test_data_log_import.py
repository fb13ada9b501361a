"""``bemlearn data import``: logger CSVs (simulated rig, jitter, drops, flipped sign) back to the trajectory."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import furuta_section

from bemlearn.cli.main import main
from bemlearn.config import ConfigError, from_dict
from bemlearn.data import (
    TrajectoryFormatError,
    counts_per_revolution,
    detect_quantization_step,
    read_trajectory,
)
from bemlearn.data.import_map import ImportMap, load_import_map
from bemlearn.data.log_import import import_logs
from bemlearn.data.rig_logs import RigLogStyle, rig_log_map, write_rig_logs
from bemlearn.data.sensors import SensorConfig
from bemlearn.errors import ArgumentError
from bemlearn.sim.collect import collect

STEP = 2 * math.pi / 2048


@pytest.fixture(scope="module")
def rig():
    """Three 3-s Furuta excitation trials on a 2048-count encoder (the simulator's data file)."""
    cfg = furuta_section("collect", n_trials=3, duration_s=3.0, workers=1, seed=4, sensor=SensorConfig(counts_per_rev=2048))
    data, _ = collect("furuta", cfg, progress=False)
    return data


def write_map(tmp_path: Path, mapping: dict, name: str = "map.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(mapping, sort_keys=False))
    return path


@pytest.mark.parametrize("style", [RigLogStyle(angle_unit="deg", counts_per_rev=2048),
                                   RigLogStyle(angle_unit="counts", counts_per_rev=2048, drop_prob=0.01, seed=3)])
def test_import_recovers_the_simulated_trajectory(rig, tmp_path, style):
    paths = write_rig_logs(rig, tmp_path / "logs", style)
    assert [p.name for p in paths] == ["episode_000.csv", "episode_001.csv", "episode_002.csv"]
    header = paths[0].read_text().splitlines()[2]
    assert header == "t,target_theta,target_alpha,theta,alpha,control_output,feedforward,plant_input,saturation"
    imap = from_dict(ImportMap, rig_log_map(rig, style))
    got = import_logs(paths, imap)
    assert got.meta.sample_rate_hz == 400.0
    assert got.n_samples == rig.n_samples and got.trial_ids == (0, 1, 2)
    assert got.meta.joint_names == ("theta", "alpha") and got.meta.unactuated == "alpha"
    assert got.meta.joint_kinds == ("hinge", "hinge") and got.meta.units["q"] == "rad"
    # times on the exact nominal grid, each trial starting within the jitter of 0
    for s in got.trial_slices():
        t = got.t[s.rows]
        steps = np.diff(t)
        np.testing.assert_allclose(steps, steps[0], rtol=1e-12, atol=0)  # uniform
        assert steps[0] == pytest.approx(1 / 400.0, rel=1e-5)  # the stamps' fitted step (20 µs jitter)
        assert abs(t[0]) < 1e-4
    # samples the logger wrote: equal up to the printing round-off; dropped ones: within one step
    info = got.meta.extra["import"]
    n_filled = info["filled_samples"]
    err = np.abs(got.q - rig.q)
    assert 0 < n_filled < 0.03 * rig.n_samples
    assert np.sort(err.max(axis=1))[-n_filled - 1] < 1e-6  # all but the filled rows
    assert err.max() <= STEP + 1e-6
    assert np.sort(np.abs(got.u - rig.u)[:, 0])[-n_filled - 1] <= 5e-7  # %.6f
    for j in range(2):
        step = detect_quantization_step(got.q[:, j])
        assert step == pytest.approx(STEP, rel=1e-6) and counts_per_revolution(step) == 2048
    # kept channels, as written (degrees or counts), readable by name
    assert got.meta.channel_names == ("target_theta", "feedforward", "saturation")
    ok = np.sort(np.abs(got.channel("feedforward") - 0.1 * rig.u[:, 0]))[-n_filled - 1]
    assert ok <= 5e-7
    assert set(np.unique(got.channel("saturation"))) <= {0.0, 1.0}


def test_sign_and_offset_follow_the_map(rig, tmp_path):
    paths = write_rig_logs(rig, tmp_path / "logs", RigLogStyle(counts_per_rev=2048, drop_prob=0.0))
    mapping = rig_log_map(rig, RigLogStyle(counts_per_rev=2048))
    mapping["joints"][1]["sign"] = 1  # forget that the logger flips the pendulum
    mapping["joints"][0]["offset"] = 0.5
    got = import_logs(paths, from_dict(ImportMap, mapping))
    np.testing.assert_allclose(got.q[:, 1], -rig.q[:, 1], atol=1e-6)
    np.testing.assert_allclose(got.q[:, 0], rig.q[:, 0] + 0.5, atol=1e-6)


def test_channels_round_trip_npz_csv(rig, tmp_path):
    paths = write_rig_logs(rig, tmp_path / "logs", RigLogStyle(counts_per_rev=2048))
    traj = import_logs(paths, from_dict(ImportMap, rig_log_map(rig)))
    a = read_trajectory(main_write(traj, tmp_path / "a.csv"))
    b = read_trajectory(main_write(a, tmp_path / "b.npz"))
    for x, y in ((traj, a), (a, b)):
        for key in ("t", "trial", "q", "u", "channels"):
            assert getattr(x, key).tobytes() == getattr(y, key).tobytes(), key
        assert x.meta == y.meta
    assert "x:target_theta" in (tmp_path / "a.csv").read_text().splitlines()[2].split(",")
    assert b.channel("saturation").shape == (traj.n_samples,)
    with pytest.raises(ArgumentError, match=r"no channel 'torque'"):
        b.channel("torque")


def main_write(traj, path):
    from bemlearn.data import write_trajectory

    return write_trajectory(traj, path)


def test_slide_joints_are_metres(tmp_path):
    t = np.arange(200) / 100.0
    rows = ["time_us,cart_mm,pole_deg,force"] + [
        f"{round(ti * 1e6)},{500 * math.sin(ti):.3f},{10 * math.cos(ti):.4f},{ti:.3f}" for ti in t
    ]
    (tmp_path / "cp.csv").write_text("\n".join(rows) + "\n")
    mapping = {
        "robot": "cartpole", "time": {"column": "time_us", "unit": "us"},
        "joints": [{"name": "x", "column": "cart_mm", "unit": "mm"},
                   {"name": "phi", "column": "pole_deg", "unit": "deg", "unactuated": True}],
        "inputs": [{"name": "force", "column": "force", "unit": "N"}],
    }
    got = import_logs([tmp_path / "cp.csv"], from_dict(ImportMap, mapping))
    assert got.meta.joint_kinds == ("slide", "hinge")
    assert got.meta.units == {"t": "s", "q": "m|rad", "u": "N"}
    np.testing.assert_allclose(got.q[:, 0], 0.5 * np.sin(t), atol=5e-7)
    np.testing.assert_allclose(got.q[:, 1], np.radians(10 * np.cos(t)), atol=1e-6)
    back = read_trajectory(main_write(got, tmp_path / "cp.npz"))
    assert back.meta.joint_kinds == ("slide", "hinge")


# ------------------------------------------------------------------ jitter and gaps


def logger_file(tmp_path: Path, t_ms: np.ndarray, name: str = "log.csv", episode: np.ndarray | None = None) -> Path:
    cols = "t,ep,theta,alpha,u" if episode is not None else "t,theta,alpha,u"
    lines = ["# logger", cols]
    for i, ti in enumerate(t_ms):
        ep = f"{int(episode[i])}," if episode is not None else ""
        lines.append(f"{ti:.3f},{ep}{0.001 * i:.6f},{-0.002 * i:.6f},{math.sin(i / 50):.6f}")
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def simple_map(**time) -> ImportMap:
    return from_dict(ImportMap, {
        "time": {"column": "t", "unit": "ms", **time},
        "joints": [{"name": "theta", "column": "theta", "unit": "rad"},
                   {"name": "alpha", "column": "alpha", "unit": "rad", "unactuated": True}],
        "inputs": [{"name": "motor", "column": "u"}],
    })


def test_jitter_is_absorbed_and_drops_are_filled_linearly(tmp_path):
    rng = np.random.default_rng(0)
    t_ms = np.arange(400) * 2.0 + rng.normal(scale=0.02, size=400)  # 500 Hz, 20 µs jitter
    keep = np.ones(400, dtype=bool)
    keep[[50, 120, 121]] = False  # one and two dropped samples (max_fill = 2)
    path = logger_file(tmp_path, t_ms)
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:2] + [l for l, k in zip(lines[2:], keep) if k]) + "\n")
    got = import_logs([path], simple_map())
    assert got.meta.sample_rate_hz == 500.0 and got.n_samples == 400
    assert got.meta.extra["import"]["filled_samples"] == 3
    np.testing.assert_allclose(got.q[:, 0], 0.001 * np.arange(400), atol=1e-9)  # linear: exact
    np.testing.assert_allclose(got.t - got.t[0], np.arange(400) / 500.0, atol=1e-5)  # fitted grid, 20 µs jitter


def test_clock_drift_does_not_accumulate(tmp_path):
    """A 100 ppm clock drift moves the 30 000th stamp by 6 ms (3 steps) from the nominal grid."""
    t_ms = np.arange(30_000) * 2.0 * (1 + 100e-6)
    got = import_logs([logger_file(tmp_path, t_ms)], simple_map(rate_hz=500.0))
    assert got.n_samples == 30_000 and got.meta.extra["import"]["filled_samples"] == 0
    assert np.diff(got.t)[0] == pytest.approx(2e-3 * (1 + 100e-6), rel=1e-9)
    fast = np.arange(200) * 2.0 * 1.02  # 2 % off: the map's rate is wrong
    with pytest.raises(TrajectoryFormatError, match=r"row 0 \(line 3\): the time stamps advance by 2\.04 ms per sample, not the 2 ms of 500 Hz"):
        import_logs([logger_file(tmp_path, fast)], simple_map(rate_hz=500.0))


def test_long_gap_splits_or_fails(tmp_path):
    t_ms = np.concatenate([np.arange(100), np.arange(110, 200)]) * 2.0  # 10 samples missing before row 100
    path = logger_file(tmp_path, t_ms)
    got = import_logs([path], simple_map())
    assert got.trial_ids == (0, 1) and [s.n_samples for s in got.trial_slices()] == [100, 90]
    assert got.meta.extra["import"]["split_gaps"] == 1
    assert got.meta.extra["import"]["trials"][1]["first_row"] == 100
    with pytest.raises(TrajectoryFormatError, match=r"log\.csv: column 't', row 100 \(line 103\): 10 missing samples before time 0\.22 s"):
        import_logs([path], simple_map(on_gap="error", rate_hz=500.0))


def test_time_errors_name_file_column_row(tmp_path):
    t_ms = np.arange(100) * 2.0
    t_ms[40] = 77.0  # before row 39's 78 ms
    with pytest.raises(TrajectoryFormatError, match=r"log\.csv: column 't', row 40 \(line 43\): time 0\.077 s does not increase"):
        import_logs([logger_file(tmp_path, t_ms)], simple_map())
    t_ms = np.arange(100) * 2.0
    t_ms[60] += 0.7  # 700 µs off a 2 ms grid: beyond max_jitter = 0.25
    with pytest.raises(TrajectoryFormatError, match=r"row 60 \(line 63\): time 0\.1207 s is \+69\d\.\d µs off the 500 Hz grid"):
        import_logs([logger_file(tmp_path, t_ms)], simple_map(rate_hz=500.0))


def test_episode_column_cuts_trials(tmp_path):
    ep = np.repeat([7, 3, 9], [40, 30, 50])
    t_ms = np.concatenate([np.arange(40), np.arange(30), np.arange(50)]) * 2.0
    path = logger_file(tmp_path, t_ms, episode=ep)
    mapping = yaml.safe_load(yaml.safe_dump({**_plain(simple_map()), "trials": {"column": "ep"}}))
    got = import_logs([path], from_dict(ImportMap, mapping))
    assert [s.n_samples for s in got.trial_slices()] == [40, 30, 50]
    assert [i["episode"] for i in got.meta.extra["import"]["trials"]] == [7, 3, 9]
    ep[100:] = 7
    with pytest.raises(TrajectoryFormatError, match=r"column 'ep', row 100 \(line 103\): episode 7 resumes after another"):
        import_logs([logger_file(tmp_path, t_ms, episode=ep)], from_dict(ImportMap, mapping))


def _plain(imap: ImportMap) -> dict:
    from bemlearn.config import to_dict

    return to_dict(imap)


# ------------------------------------------------------------------ bad files and maps


def test_bad_cells_and_columns_are_named(tmp_path):
    path = logger_file(tmp_path, np.arange(50) * 2.0)
    lines = path.read_text().splitlines()
    bad = list(lines)
    cells = bad[2 + 17].split(",")
    cells[2] = "abc"
    bad[2 + 17] = ",".join(cells)
    path.write_text("\n".join(bad) + "\n")
    with pytest.raises(TrajectoryFormatError, match=r"log\.csv: column 'alpha', row 17 \(line 20\): 'abc' is not a number"):
        import_logs([path], simple_map())
    cells[2] = ""
    bad[2 + 17] = ",".join(cells)
    path.write_text("\n".join(bad) + "\n")
    with pytest.raises(TrajectoryFormatError, match=r"column 'alpha', row 17 \(line 20\): an empty cell"):
        import_logs([path], simple_map())
    path.write_text("\n".join([lines[0], lines[1].replace("alpha", "beta")] + lines[2:]) + "\n")
    with pytest.raises(TrajectoryFormatError, match=r"log\.csv: line 2: column 'alpha' \(map key joints\[1\]\.column\) is not in the header"):
        import_logs([path], simple_map())
    cells = lines[2 + 5].split(",")
    cells[1] = "nan"
    path.write_text("\n".join(lines[:2 + 5] + [",".join(cells)] + lines[2 + 6:]) + "\n")
    with pytest.raises(TrajectoryFormatError, match=r"column 'theta', row 5 \(line 8\): non-finite value nan"):
        import_logs([path], simple_map())
    with pytest.raises(FileNotFoundError, match=r"nope\.csv: log file not found"):
        import_logs([tmp_path / "nope.csv"], simple_map())


def test_map_errors_name_file_and_key(tmp_path):
    good = _plain(simple_map())
    bad = {**good, "joints": [dict(good["joints"][0], unit="furlong"), good["joints"][1]]}
    with pytest.raises(ConfigError, match=r"m\.yaml: map\.joints\[0\]: unit: expected one of .* got 'furlong'"):
        load_import_map(write_map(tmp_path, bad, "m.yaml"))
    with pytest.raises(ConfigError, match=r"m\.yaml: map: unknown key\(s\) \['colour'\]"):
        load_import_map(write_map(tmp_path, {**good, "colour": 1}, "m.yaml"))
    two = {**good, "joints": [dict(j, unactuated=True) for j in good["joints"]]}
    with pytest.raises(ConfigError, match=r"exactly one joint with unactuated: true"):
        load_import_map(write_map(tmp_path, two, "m.yaml"))
    with pytest.raises(ConfigError, match=r"map\.time: give a time column"):
        load_import_map(write_map(tmp_path, {**good, "time": {"unit": "s"}}, "m.yaml"))
    with pytest.raises(ConfigError, match=r"map\.joints\[1\]: sign: expected 1 or -1"):
        load_import_map(write_map(tmp_path, {**good, "joints": [good["joints"][0], dict(good["joints"][1], sign=2)]}, "m.yaml"))
    assert load_import_map(write_map(tmp_path, {**good, "trials": "per_file"}, "m.yaml")).trials == "per_file"


# ------------------------------------------------------------------ CLI


def test_cli_import_refuses_overwrite_and_writes_atomically(rig, tmp_path, capsys):
    paths = write_rig_logs(rig, tmp_path / "logs", RigLogStyle(counts_per_rev=2048))
    mp = write_map(tmp_path, rig_log_map(rig))
    out = tmp_path / "imported.npz"
    argv = ["data", "import", *map(str, paths), "--map", str(mp), "--out", str(out)]
    assert main(argv) == 0
    assert "(= 2π/2048, 2048 counts/rev)" in capsys.readouterr().out
    before = out.read_bytes()
    assert main(argv) == 2
    assert "already exists (use --force to overwrite)" in capsys.readouterr().err
    # a failing import with --force leaves the old file intact and no temporary file behind
    broken = paths[1].read_text().replace("\n10.", "\nxx.", 1)
    paths[1].write_text(broken)
    assert main(argv + ["--force"]) == 2
    assert "episode_001.csv: column 't'" in capsys.readouterr().err
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["imported.npz", "logs", "map.yaml"]
    traj = read_trajectory(out)
    assert traj.meta.robot == "furuta" and traj.meta.channel_names == ("target_theta", "feedforward", "saturation")


def test_write_is_temp_file_then_replace(rig, tmp_path, monkeypatch):
    import os

    from bemlearn import files

    seen = []
    real = os.replace
    monkeypatch.setattr(files.os, "replace", lambda a, b: (seen.append((Path(a).parent.name, Path(b).name)), real(a, b)))
    main_write(dataclasses.replace(rig), tmp_path / "x.npz")
    # written inside a hidden temporary folder beside the target, then renamed into place
    assert len(seen) == 1 and seen[0][1] == "x.npz" and seen[0][0].startswith(".x.npz.tmp")


@pytest.mark.slow
def test_docs_python_api_snippet_runs(rig, tmp_path, monkeypatch):
    """The API example of docs/log-import.md, run as written on an imported rig file."""
    import re

    text = (Path(__file__).parents[1] / "docs" / "log-import.md").read_text()
    snippet = re.findall(r"```python\n(.*?)```", text, re.DOTALL)[0]
    paths = write_rig_logs(rig, tmp_path / "logs", RigLogStyle(counts_per_rev=2048))
    traj = import_logs(paths, from_dict(ImportMap, rig_log_map(rig)))
    main_write(traj, tmp_path / "rig.npz")
    monkeypatch.chdir(tmp_path)
    code = compile(snippet.replace("DatasetConfig()", "DatasetConfig(n_points=150)"), "log-import.md", "exec")
    exec(code, {})  # the documented example, run as written
    assert (tmp_path / "bem_slices.png").stat().st_size > 10_000


def test_byte_order_mark_crlf_and_semicolons(tmp_path):
    lines = ["t;theta;alpha;u"] + [f"{i * 0.002:.4f};{0.01 * i:.4f};{0.1 * math.sin(i / 9):.4f};{i / 10:.2f}" for i in range(50)]
    path = tmp_path / "win.csv"
    path.write_bytes(b"\xef\xbb\xbf" + "\r\n".join(lines).encode() + b"\r\n")
    mapping = {**_plain(simple_map()), "delimiter": ";", "time": {"column": "t", "unit": "s"}}
    got = import_logs([path], from_dict(ImportMap, mapping))
    assert got.n_samples == 50 and got.meta.sample_rate_hz == 500.0
    np.testing.assert_allclose(got.q[:, 1], [float(f"{0.1 * math.sin(i / 9):.4f}") for i in range(50)], rtol=0, atol=0)


def test_bench_import_speed_counts_rows(rig, capsys):
    from bemlearn.bench.import_bench import bench_import_speed

    r = bench_import_speed(rig, rows=3000, trials=3, repeats=2)
    assert r["rows_written"] == 3000 and r["rows_imported"] == 3000 and len(r["seconds_all"]) == 2
    assert 0 < r["filled_samples"] < 30
