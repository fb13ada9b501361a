"""Trajectory files: lossless NPZ ↔ CSV round trips and a named error for every bad input."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from test_data_helpers import QSTEP, make_trajectory

from bemlearn.data import (
    Trajectory,
    TrajectoryFormatError,
    TrajectoryMeta,
    counts_per_revolution,
    detect_quantization_step,
    ground_truth_path,
    read_ground_truth,
    read_trajectory,
    validate,
    write_trajectory,
)

ARRAYS = ("t", "trial", "q", "u")
HYP = settings(
    max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def assert_bit_identical(a: Trajectory, b: Trajectory) -> None:
    for key in (*ARRAYS, "qd", "qdd"):
        x, y = getattr(a, key), getattr(b, key)
        if x is None:
            assert y is None, key
            continue
        assert x.dtype == y.dtype and x.shape == y.shape, key
        assert x.tobytes() == y.tobytes(), f"{key} differs"
    assert a.meta == b.meta


def csv_lines(tmp_path: Path, traj: Trajectory, name: str = "a.csv") -> tuple[Path, list[str]]:
    path = write_trajectory(traj, tmp_path / name)
    return path, path.read_text().splitlines()


def write_lines(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


def npz_with(tmp_path: Path, traj: Trajectory, **changes) -> Path:
    """An NPZ of ``traj`` with arrays replaced (value) or removed (None)."""
    arrays = {"meta": np.array(traj.meta.to_json()), "t": traj.t, "trial": traj.trial, "q": traj.q, "u": traj.u}
    for k, v in changes.items():
        if v is None:
            arrays.pop(k)
        else:
            arrays[k] = v
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    return path


# ------------------------------------------------------------------ round trips


def test_npz_csv_npz_is_bit_identical(tmp_path):
    traj = make_trajectory(quantize=True, ground_truth=True)
    a = read_trajectory(write_trajectory(traj, tmp_path / "a.npz"))
    b = read_trajectory(write_trajectory(a, tmp_path / "b.csv"))
    c = read_trajectory(write_trajectory(b, tmp_path / "c.npz"))
    assert_bit_identical(traj, a)
    assert_bit_identical(a, b)
    assert_bit_identical(a, c)
    assert c.has_ground_truth


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@HYP
@given(
    q=hnp.arrays(np.float64, (23, 3), elements=finite),
    u=hnp.arrays(np.float64, (23, 2), elements=finite),
    rate=st.floats(1.0, 5000.0),
    t0=st.floats(-1e4, 1e4),
)
def test_round_trip_arbitrary_floats(tmp_path, q, u, rate, t0):
    """Any finite float64 (subnormals, -0.0, 1e308) survives NPZ → CSV → NPZ exactly."""
    t = t0 + np.arange(23) / rate
    t[12:] = np.arange(11) / rate  # second trial restarts its clock
    meta = TrajectoryMeta(
        robot="biped3", joint_names=("q1", "q2", "q3"), unactuated="q1", actuator_names=("hip", "knee"),
        sample_rate_hz=rate, trial_failed={7: True, -2: False}, extra={"rate": rate, "note": "ünïcode"},
    )
    traj = Trajectory(t=t, trial=np.r_[np.full(12, 7), np.full(11, -2)], q=q, u=u, meta=meta)
    a = read_trajectory(write_trajectory(traj, tmp_path / "a.npz"), rate_rtol=1e-6)
    b = read_trajectory(write_trajectory(a, tmp_path / "b.csv"), rate_rtol=1e-6)
    c = read_trajectory(write_trajectory(b, tmp_path / "c.npz"), rate_rtol=1e-6)
    assert_bit_identical(traj, c)
    assert_bit_identical(a, b)


def test_csv_layout(tmp_path):
    traj = make_trajectory((12, 10), ground_truth=True)
    _, lines = csv_lines(tmp_path, traj)
    assert lines[0] == "# bemlearn-trajectory v1"
    meta = json.loads(lines[1].removeprefix("# meta: "))
    assert meta["joint_names"] == ["theta", "alpha"] and meta["trial_failed"] == {"0": False, "1": True}
    assert lines[2] == "t,trial,q:theta,q:alpha,u:m_theta,qd:theta,qd:alpha,qdd:theta,qdd:alpha"
    assert len(lines) == 3 + 22
    assert lines[3].split(",")[1] == "0" and lines[-1].split(",")[1] == "1"


def test_ground_truth_reader(tmp_path):
    plain = write_trajectory(make_trajectory((20, 20)), tmp_path / "d.npz")
    truth = write_trajectory(make_trajectory((20, 20), ground_truth=True), ground_truth_path(plain))
    assert truth.name == "d.truth.npz"
    assert read_ground_truth(truth).qdd.shape == (40, 2)
    with pytest.raises(TrajectoryFormatError, match=r"d\.npz: not a ground-truth file"):
        read_ground_truth(plain)


def test_summary_numbers():
    traj = make_trajectory((40, 60, 80), quantize=True, failed=(0, 2))
    s = traj.summary()
    assert (s["trials"], s["failed_trials"], s["failed_trial_ids"], s["samples"]) == (3, 2, [0, 2], 180)
    assert s["duration_s"] == pytest.approx(180 / 400.0, rel=1e-15)
    assert s["trial_samples_min_median_max"] == [40, 60.0, 80]
    assert s["angle_ranges_rad"]["alpha"] == [traj.q[:, 1].min(), traj.q[:, 1].max()]
    for step in s["quantization_step_rad"].values():
        assert step == pytest.approx(QSTEP, rel=1e-12)
    assert all(v is None for v in make_trajectory((40, 60)).summary()["quantization_step_rad"].values())


def test_quantization_detection():
    rng = np.random.default_rng(3)
    step = 2 * np.pi / 4096
    q = 0.37 + step * rng.integers(-3000, 3000, size=2000)  # offset grid
    assert detect_quantization_step(q) == pytest.approx(step, rel=1e-10)
    assert counts_per_revolution(detect_quantization_step(q)) == 4096
    assert detect_quantization_step(q + rng.normal(scale=1e-5, size=q.shape)) is None
    assert detect_quantization_step(rng.normal(size=500)) is None
    assert detect_quantization_step(np.zeros(10)) is None


# ------------------------------------------------------------------ bad inputs


def test_unsupported_suffix_and_missing_file(tmp_path):
    with pytest.raises(ValueError, match=r"x\.txt: unsupported trajectory file suffix '\.txt'"):
        read_trajectory(tmp_path / "x.txt")
    with pytest.raises(ValueError, match="unsupported"):
        write_trajectory(make_trajectory((20,)), tmp_path / "x.parquet")
    with pytest.raises(FileNotFoundError, match=r"nope\.npz: trajectory file not found"):
        read_trajectory(tmp_path / "nope.npz")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda h: h.replace(",u:m_theta", ""), r"missing column\(s\) \['u:m_theta'\]"),
        (lambda h: h + ",q:extra", r"unknown column\(s\) \['q:extra'\]"),
        (lambda h: h.replace("q:alpha", "q:beta"), r"missing column\(s\) \['q:alpha'\]"),
        (lambda h: "trial,t" + h[len("t,trial"):], r"columns out of order"),
    ],
)
def test_csv_missing_unknown_columns(tmp_path, edit, message):
    path, lines = csv_lines(tmp_path, make_trajectory((20, 20)))
    lines[2] = edit(lines[2])
    with pytest.raises(TrajectoryFormatError, match=rf"a\.csv: line 3: {message}"):
        read_trajectory(write_lines(path, lines))


def test_npz_missing_unknown_arrays(tmp_path):
    traj = make_trajectory((20, 20))
    with pytest.raises(TrajectoryFormatError, match=r"bad\.npz: missing array\(s\) \['u'\]"):
        read_trajectory(npz_with(tmp_path, traj, u=None))
    with pytest.raises(TrajectoryFormatError, match=r"bad\.npz: unknown array\(s\) \['x'\]"):
        read_trajectory(npz_with(tmp_path, traj, x=np.zeros(3)))
    with pytest.raises(TrajectoryFormatError, match=r"array 'q' has shape \(40, 3\), expected \(40, 2\)"):
        read_trajectory(npz_with(tmp_path, traj, q=np.zeros((40, 3))))
    with pytest.raises(TrajectoryFormatError, match=r"column 'trial' \(array 'trial'\) must be integer"):
        read_trajectory(npz_with(tmp_path, traj, trial=traj.trial.astype(float)))
    with pytest.raises(TrajectoryFormatError, match=r"ground truth needs both arrays"):
        read_trajectory(npz_with(tmp_path, traj, qd=traj.q))


@HYP
@given(data=st.data())
def test_non_finite_value_named(tmp_path, data):
    traj = make_trajectory((30, 25), ground_truth=True)
    cols = ["t", "q:theta", "q:alpha", "u:m_theta", "qd:theta", "qd:alpha", "qdd:theta", "qdd:alpha"]
    col = data.draw(st.sampled_from(cols))
    row = data.draw(st.integers(0, traj.n_samples - 1))
    bad = data.draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    # CSV: edit the text cell.
    path, lines = csv_lines(tmp_path, traj)
    header = lines[2].split(",")
    cells = lines[3 + row].split(",")
    cells[header.index(col)] = repr(float(bad))
    lines[3 + row] = ",".join(cells)
    with pytest.raises(TrajectoryFormatError, match=rf"a\.csv: column '{col}', row {row} \(line {row + 4}\): non-finite"):
        read_trajectory(write_lines(path, lines))
    # NPZ: edit the array.
    key, _, joint = col.partition(":")
    arr = getattr(traj, key).copy()
    if key == "t":
        arr[row] = bad
    else:
        names = traj.meta.actuator_names if key == "u" else traj.meta.joint_names
        arr[row, list(names).index(joint)] = bad
    arrays = {k: getattr(traj, k) for k in ("t", "trial", "q", "u", "qd", "qdd")}
    arrays[key] = arr
    npz = tmp_path / "b.npz"
    np.savez(npz, meta=np.array(traj.meta.to_json()), **arrays)
    with pytest.raises(TrajectoryFormatError, match=rf"b\.npz: column '{col}', row {row}: non-finite"):
        read_trajectory(npz)


@HYP
@given(row=st.integers(1, 59).filter(lambda r: r != 30), shift=st.sampled_from([0.0, -1.0, -3.5]))
def test_non_increasing_time_named(tmp_path, row, shift):
    traj = make_trajectory((30, 30))
    t = traj.t.copy()
    t[row] = t[row - 1] + shift * traj.meta.dt
    bad = dataclasses.replace(traj, t=t)
    with pytest.raises(TrajectoryFormatError, match=rf"column 't', row {row} \(line {row + 4}\): time .* does not increase"):
        _, lines = csv_lines(tmp_path, traj)
        lines[3 + row] = ",".join([repr(float(t[row]))] + lines[3 + row].split(",")[1:])
        read_trajectory(write_lines(tmp_path / "a.csv", lines))
    with pytest.raises(TrajectoryFormatError, match=rf"column 't', row {row}: time"):
        validate(bad)


def test_empty_file_rejected(tmp_path):
    path, lines = csv_lines(tmp_path, make_trajectory((20,)))
    meta = json.loads(lines[1].removeprefix("# meta: "))
    meta["trial_failed"] = {}
    with pytest.raises(TrajectoryFormatError, match=r"a\.csv: no samples"):
        read_trajectory(write_lines(path, [lines[0], "# meta: " + json.dumps(meta), lines[2]]))


def test_timestamp_jitter_accepted_and_median_rate_checked():
    traj = make_trajectory((300, 200))
    rng = np.random.default_rng(5)
    jittered = traj.t + rng.normal(scale=0.008 * traj.meta.dt, size=traj.t.shape)  # 20 µs at 400 Hz
    validate(dataclasses.replace(traj, t=jittered))
    slow = dataclasses.replace(traj, t=traj.t * 1.02)  # every step 2 % long: the rate is wrong, not jittered
    with pytest.raises(TrajectoryFormatError, match=r"median time step .* of trial 0 is inconsistent with sample_rate_hz"):
        validate(slow)
    validate(slow, rate_rtol=0.03)


def test_time_may_restart_between_trials():
    traj = make_trajectory((30, 30))
    assert traj.t[30] < traj.t[29]
    validate(traj)


def test_inconsistent_sample_rate_named(tmp_path):
    traj = make_trajectory((30, 30))
    t = traj.t.copy()
    t[45:] += 0.15 * traj.meta.dt  # one step 15 % too long: beyond the 10 % jitter tolerance
    with pytest.raises(TrajectoryFormatError, match=r"column 't', row 45: time step .* inconsistent with sample_rate_hz = 400\.0 .*jitter"):
        validate(dataclasses.replace(traj, t=t))
    validate(dataclasses.replace(traj, t=t), jitter_rtol=0.2)  # tolerance is an option
    dropped = np.concatenate([traj.t[:40], traj.t[41:]])  # one dropped sample: a step of 2 Δt
    with pytest.raises(TrajectoryFormatError, match=r"row 40: time step 0\.005.*data import"):
        validate(dataclasses.replace(traj.select_rows(np.arange(59)), t=dropped))
    wrong_rate = dataclasses.replace(traj, meta=dataclasses.replace(traj.meta, sample_rate_hz=500.0))
    path = tmp_path / "r.npz"
    np.savez(path, meta=np.array(wrong_rate.meta.to_json()), t=traj.t, trial=traj.trial, q=traj.q, u=traj.u)
    with pytest.raises(TrajectoryFormatError, match=r"r\.npz: column 't', row 0: median time step 0\.0025\d* s of trial 0 is inconsistent"):
        read_trajectory(path)


def test_too_short_trial_named(tmp_path):
    path = write_trajectory(make_trajectory((30, 12, 30)), tmp_path / "s.csv")
    read_trajectory(path)  # default minimum is 10
    with pytest.raises(TrajectoryFormatError, match=r"s\.csv: column 'trial', row 30 \(line 34\): trial 1 has 12 samples, fewer than the minimum 20"):
        read_trajectory(path, min_trial_samples=20)


def test_non_contiguous_trial_and_outcomes():
    traj = make_trajectory((20, 20, 20), trial_ids=(0, 1, 0), failed=())
    with pytest.raises(TrajectoryFormatError, match=r"column 'trial', row 40: trial 0 resumes after another trial"):
        validate(traj)
    ok = make_trajectory((20, 20))
    missing = dataclasses.replace(ok, meta=dataclasses.replace(ok.meta, trial_failed={0: False}))
    with pytest.raises(TrajectoryFormatError, match=r"trial_failed has no outcome for trial\(s\) \[1\]"):
        validate(missing)
    extra = dataclasses.replace(ok, meta=dataclasses.replace(ok.meta, trial_failed={0: False, 1: True, 5: True}))
    with pytest.raises(TrajectoryFormatError, match=r"lists trial\(s\) \[5\] that have no samples"):
        validate(extra)


def test_csv_bad_cells_named(tmp_path):
    path, lines = csv_lines(tmp_path, make_trajectory((20, 20)))
    edited = list(lines)
    edited[3 + 25] = edited[3 + 25].replace(",1,", ",1.5,", 1)
    with pytest.raises(TrajectoryFormatError, match=r"column 'trial', row 25 \(line 29\): trial id must be an integer, got '1.5'"):
        read_trajectory(write_lines(path, edited))
    edited = list(lines)
    cells = edited[3 + 7].split(",")
    cells[3] = "abc"
    edited[3 + 7] = ",".join(cells)
    with pytest.raises(TrajectoryFormatError, match=r"row 7 \(line 11\): column 'q:alpha': 'abc' is not a number"):
        read_trajectory(write_lines(path, edited))
    edited = list(lines)
    edited[3 + 9] = ",".join(edited[3 + 9].split(",")[:-1])
    with pytest.raises(TrajectoryFormatError, match=r"row 9 \(line 13\): 4 fields, expected 5"):
        read_trajectory(write_lines(path, edited))
    edited = list(lines)
    edited.insert(3 + 4, "")
    with pytest.raises(TrajectoryFormatError, match=r"row 4 \(line 8\): blank line"):
        read_trajectory(write_lines(path, edited))


def test_csv_bad_preamble(tmp_path):
    path, lines = csv_lines(tmp_path, make_trajectory((20, 20)))
    with pytest.raises(TrajectoryFormatError, match=r"line 1: expected '# bemlearn-trajectory v1'"):
        read_trajectory(write_lines(path, lines[1:]))
    with pytest.raises(TrajectoryFormatError, match=r"metadata is not valid JSON"):
        read_trajectory(write_lines(path, [lines[0], "# meta: {oops", *lines[2:]]))
    meta = json.loads(lines[1].removeprefix("# meta: "))
    meta["colour"] = "red"
    with pytest.raises(TrajectoryFormatError, match=r"unknown metadata key\(s\) \['colour'\]"):
        read_trajectory(write_lines(path, [lines[0], "# meta: " + json.dumps(meta), *lines[2:]]))
    del meta["colour"], meta["sample_rate_hz"]
    with pytest.raises(TrajectoryFormatError, match=r"missing metadata key\(s\) \['sample_rate_hz'\]"):
        read_trajectory(write_lines(path, [lines[0], "# meta: " + json.dumps(meta), *lines[2:]]))
    meta["sample_rate_hz"], meta["unactuated"] = 400.0, "gamma"
    with pytest.raises(TrajectoryFormatError, match=r"meta\.unactuated: 'gamma' is not one of the joints"):
        read_trajectory(write_lines(path, [lines[0], "# meta: " + json.dumps(meta), *lines[2:]]))


def test_units_must_be_rad_and_seconds():
    traj = make_trajectory((20,))
    deg = dataclasses.replace(traj, meta=dataclasses.replace(traj.meta, units={"t": "s", "q": "deg", "u": "V"}))
    with pytest.raises(TrajectoryFormatError, match=r"meta\.units\['q'\] must be 'rad', got 'deg'"):
        validate(deg)


def test_write_refuses_invalid_and_leaves_no_file(tmp_path):
    traj = make_trajectory((20, 20))
    q = traj.q.copy()
    q[3, 0] = np.nan
    with pytest.raises(TrajectoryFormatError, match=r"write .*x\.npz: column 'q:theta', row 3: non-finite"):
        write_trajectory(dataclasses.replace(traj, q=q), tmp_path / "x.npz")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ robot match


def robot(name="furuta", joints=("theta", "alpha"), unactuated="alpha"):
    return SimpleNamespace(
        name=name, joint_names=joints, unactuated_name=unactuated,
        actuated_names=tuple(j for j in joints if j != unactuated),
    )


@pytest.mark.parametrize(
    ("stand_in", "message"),
    [
        (robot(joints=("arm", "alpha")), r"meta\.joint_names is \['theta', 'alpha'\] but robot 'furuta' has \['arm', 'alpha'\]"),
        (robot(joints=("alpha", "theta")), r"meta\.joint_names is \['theta', 'alpha'\] but robot 'furuta' has \['alpha', 'theta'\]"),
        (robot(unactuated="theta"), r"meta\.unactuated is 'alpha' but robot 'furuta' has 'theta'"),
        (robot(name="biped"), r"meta\.robot is 'furuta' but robot is 'biped'"),
    ],
)
def test_joint_names_must_match_robot(tmp_path, stand_in, message):
    path = write_trajectory(make_trajectory((20, 20)), tmp_path / "j.npz")
    read_trajectory(path, robot=robot())
    with pytest.raises(TrajectoryFormatError, match=re.escape(str(path)) + ": " + message):
        read_trajectory(path, robot=stand_in)


def test_robot_by_name_uses_registry(tmp_path, monkeypatch):
    import bemlearn.robots

    calls = []
    monkeypatch.setattr(bemlearn.robots, "load", lambda name: calls.append(name) or robot(joints=("x", "alpha")), raising=False)
    path = write_trajectory(make_trajectory((20, 20)), tmp_path / "j.npz")
    with pytest.raises(TrajectoryFormatError, match="joint_names"):
        read_trajectory(path, robot="furuta")
    assert calls == ["furuta"]
