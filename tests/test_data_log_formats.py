"""Logs as loggers write them (issue 21 item 4, issue 22): no header line, whitespace or other
separators, a loop that overruns or a clock that drifts (``time.resample: linear``), a last
line cut mid-write, and error messages that name the map key that fixes them."""

from __future__ import annotations

import dataclasses
import logging
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from bemlearn.cli.main import main
from bemlearn.config import ConfigError, from_dict, to_dict
from bemlearn.data import TrajectoryFormatError, detect_quantization_step, read_trajectory, write_trajectory
from bemlearn.data.import_map import ImportMap, load_import_map
from bemlearn.data.log_import import import_logs
from bemlearn.data.log_table import detect_delimiter
from bemlearn.data.rig_logs import RigLogStyle, log_columns, rig_log_map, write_rig_logs

DATA = Path(__file__).resolve().parents[1] / "data" / "furuta_excitation.npz"
STEP = 2 * math.pi / 4096  # the shipped Furuta data's encoder


@pytest.fixture(scope="module")
def rig():
    """Three trials of the shipped Furuta excitation data (400 Hz, 4096-count encoders)."""
    traj = read_trajectory(DATA)
    longest = sorted(traj.trial_slices(), key=lambda s: -s.n_samples)[:3]
    return traj.select_trials([s.trial_id for s in longest])


def imap_of(mapping: dict) -> ImportMap:
    return from_dict(ImportMap, yaml.safe_load(yaml.safe_dump(mapping)))


def write_map(path: Path, mapping: dict) -> Path:
    path.write_text(yaml.safe_dump(mapping, sort_keys=False))
    return path


def same_arrays(a, b) -> None:
    for key in ("t", "trial", "q", "u", "channels"):
        x, y = getattr(a, key), getattr(b, key)
        assert (x is None and y is None) or x.tobytes() == y.tobytes(), key


# ------------------------------------------------------------------ header-less, other separators


@pytest.mark.parametrize("style", [
    RigLogStyle(header=False, delimiter=" "),
    RigLogStyle(header=False, delimiter=" ", aligned=True),
    RigLogStyle(header=False, delimiter="\t", angle_unit="counts"),
    RigLogStyle(header=True, delimiter=" ", aligned=True),
    RigLogStyle(header=True, delimiter="\t"),
    RigLogStyle(header=False, delimiter=";"),
], ids=["space", "aligned", "tab-counts", "aligned-header", "tab-header", "semicolon"])
def test_other_layouts_give_the_identical_trajectory_as_csv_with_header(rig, tmp_path, style):
    reference = dataclasses.replace(style, header=True, delimiter=",", aligned=False)
    csv = import_logs(write_rig_logs(rig, tmp_path / "csv", reference), imap_of(rig_log_map(rig, reference)))
    paths = write_rig_logs(rig, tmp_path / "other", style)
    first = paths[0].read_text().splitlines()[0]
    assert first.startswith("#") == style.header
    mapping = rig_log_map(rig, style)
    assert ("columns" in mapping) == (not style.header)
    got = import_logs(paths, imap_of(mapping))  # delimiter detected
    same_arrays(csv, got)
    expected = {" ": "whitespace", "\t": "tab", ";": "semicolon"}[style.delimiter]
    assert got.meta.extra["import"]["delimiters"] == [expected] * 3
    explicit = import_logs(paths, imap_of({**mapping, "delimiter": "whitespace" if style.delimiter == " " else style.delimiter}))
    same_arrays(csv, explicit)


def test_home_built_furuta_space_separated_counts_without_header(rig, tmp_path, capsys):
    """`t theta_counts alpha_counts voltage`, no header line: the map names the columns; no hand conversion."""
    style = RigLogStyle(header=False, delimiter=" ", minimal=True, angle_unit="counts", flip=(), drop_prob=0.0, jitter_s=0.0)
    paths = write_rig_logs(rig, tmp_path / "logs", style)
    line = paths[0].read_text().splitlines()[0].split(" ")
    assert len(line) == 4 and line[1].lstrip("-").isdigit()  # t theta_counts alpha_counts voltage
    mapping = {
        "robot": "home-furuta",
        "time": {"column": "t", "unit": "ms"},
        "header": False,
        "columns": ["t", "theta_counts", "alpha_counts", "voltage"],
        "joints": [{"name": "theta", "column": "theta_counts", "unit": "counts:4096"},
                   {"name": "alpha", "column": "alpha_counts", "unit": "counts:4096", "unactuated": True}],
        "inputs": [{"name": "voltage", "column": "voltage", "unit": "V"}],
    }
    mp = write_map(tmp_path / "map.yaml", mapping)
    out = tmp_path / "rig.npz"
    assert main(["data", "import", *map(str, paths), "--map", str(mp), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "(= 2π/4096, 4096 counts/rev)" in printed and "3 trials at 400 Hz" in printed
    got = read_trajectory(out)
    assert got.n_samples == rig.n_samples
    np.testing.assert_allclose(got.q, rig.q, rtol=0, atol=1e-9)  # counts are exact
    np.testing.assert_allclose(got.u, rig.u, rtol=0, atol=5e-7)  # %.6f
    np.testing.assert_allclose(np.diff(got.t[:50]), 1 / 400, rtol=1e-9)


def test_columns_rename_a_header_and_must_match_its_field_count(rig, tmp_path):
    paths = write_rig_logs(rig, tmp_path / "logs", RigLogStyle(drop_prob=0.0))
    base = rig_log_map(rig, RigLogStyle())
    names = [c.upper() for c in log_columns(rig)]
    renamed = {**base, "columns": names,
               "time": {**base["time"], "column": "T"},
               "joints": [dict(j, column=j["column"].upper()) for j in base["joints"]],
               "inputs": [dict(base["inputs"][0], column="PLANT_INPUT")],
               "keep": [k.upper() for k in base["keep"]]}
    same_arrays(import_logs(paths, imap_of(base)), import_logs(paths, imap_of(renamed)))
    with pytest.raises(TrajectoryFormatError, match=r"episode_\d+\.csv: line 3: the header has 9 fields .* the map's columns: names 10"):
        import_logs(paths, imap_of({**renamed, "columns": [*names, "EXTRA"]}))


def test_every_line_must_have_the_files_field_count(tmp_path):
    rows = [f"{i * 2.0:.3f} {0.001 * i:.6f} {-0.002 * i:.6f} {math.sin(i / 50):.6f}" for i in range(60)]
    rows[33] += " 7"
    (tmp_path / "log.txt").write_text("\n".join(rows) + "\n")
    mapping = {"time": {"column": "t", "unit": "ms"}, "header": False, "columns": ["t", "theta", "alpha", "u"],
               "joints": [{"name": "theta", "column": "theta", "unit": "rad"},
                          {"name": "alpha", "column": "alpha", "unit": "rad", "unactuated": True}],
               "inputs": [{"name": "motor", "column": "u"}]}
    with pytest.raises(TrajectoryFormatError, match=r"log\.txt: row 33 \(line 34\): 5 fields, the map's columns: names 4"):
        import_logs([tmp_path / "log.txt"], imap_of(mapping))
    rows[33] = rows[33][:-2]
    rows[20] = "  ".join(rows[20].split(" "))  # runs of spaces are one separator
    (tmp_path / "log.txt").write_text("# preamble\n\n" + "\n".join(rows) + "\n")
    got = import_logs([tmp_path / "log.txt"], imap_of(mapping))
    assert got.n_samples == 60
    np.testing.assert_allclose(got.q[:, 1], [-0.002 * i for i in range(60)], atol=1e-9)
    with_header = ["t,theta,alpha,u"] + [r.replace(" ", ",") for r in rows]
    with_header[10] += ",1"
    (tmp_path / "log.csv").write_text("\n".join(with_header) + "\n")
    plain = {k: v for k, v in mapping.items() if k not in ("header", "columns")}
    with pytest.raises(TrajectoryFormatError, match=r"log\.csv: row 9 \(line 11\): 5 fields, the header \(line 1\) has 4$"):
        import_logs([tmp_path / "log.csv"], imap_of(plain))


# ------------------------------------------------------------------ error hints naming the map key


def _headerless(tmp_path: Path, sep: str = " ") -> Path:
    rows = [sep.join([f"{i * 2.0:.3f}", f"{0.001 * i:.6f}", f"{-0.002 * i:.6f}", f"{math.sin(i / 50):.6f}"]) for i in range(60)]
    path = tmp_path / "noheader.txt"
    path.write_text("\n".join(rows) + "\n")
    return path


PLAIN = {"time": {"column": "t", "unit": "ms"},
         "joints": [{"name": "theta", "column": "theta", "unit": "rad"},
                    {"name": "alpha", "column": "alpha", "unit": "rad", "unactuated": True}],
         "inputs": [{"name": "motor", "column": "u"}]}


def test_error_hints_name_the_map_key_that_fixes_them(tmp_path):
    path = _headerless(tmp_path)
    with pytest.raises(TrajectoryFormatError, match=r"noheader\.txt: line 1: column 't' \(map key time\.column\) is not in the "
                       r"header .*line 1 is data, not a header .*set header: false and columns: \[name, …\] naming the file's 4 columns"):
        import_logs([path], imap_of(PLAIN))
    cols = {**PLAIN, "header": False, "columns": ["t", "theta", "alpha", "u"]}
    with pytest.raises(TrajectoryFormatError, match=r"row 0 \(line 1\): 1 field, but the map's columns: names 4 .*splits into 4 fields "
                       r"at whitespace, not at comma: set delimiter: whitespace"):
        import_logs([path], imap_of({**cols, "delimiter": ","}))
    with pytest.raises(TrajectoryFormatError, match=r"row 0 \(line 1\): 4 fields, but the map's columns: names 5"):
        import_logs([path], imap_of({**cols, "columns": ["t", "theta", "alpha", "u", "v"]}))
    csv = tmp_path / "h.csv"
    csv.write_text("t,theta,alpha,u\n" + path.read_text().replace(" ", ","))
    with pytest.raises(TrajectoryFormatError, match=r"h\.csv: line 1 \('t,theta,alpha,u'\) is not numbers, yet the map says header: "
                       r"false: if it is the header, set header: true"):
        import_logs([csv], imap_of(cols))
    with pytest.raises(TrajectoryFormatError, match=r"h\.csv: line 1: column 't' .* not in the header \['t,theta,alpha,u'\]; the line "
                       r"splits into 4 fields at comma, not at semicolon: set delimiter: ','"):
        import_logs([csv], imap_of({**PLAIN, "delimiter": ";"}))
    with pytest.raises(TrajectoryFormatError, match=r"column 'alpha' \(map key joints\[1\]\.column\) is not in the header .*did you mean 'Alpha'"):
        csv.write_text(csv.read_text().replace("alpha", "Alpha", 1))
        import_logs([csv], imap_of(PLAIN))
    pipes = tmp_path / "pipes.txt"
    pipes.write_text(path.read_text().replace(" ", "|"))
    with pytest.raises(TrajectoryFormatError, match=r"pipes\.txt: cannot tell how the fields are separated: neither comma, semicolon, "
                       r"tab nor whitespace .*set delimiter: in the map"):
        import_logs([pipes], imap_of(cols))
    assert import_logs([pipes], imap_of({**cols, "delimiter": "|"})).n_samples == 60
    dup = tmp_path / "dup.csv"
    dup.write_text("t,theta,theta,u\n" + path.read_text().replace(" ", ","))
    with pytest.raises(TrajectoryFormatError, match=r"column 'theta' \(map key joints\[0\]\.column\) appears 2 times; name the "
                       r"columns with columns: \[name, …\]"):
        import_logs([dup], imap_of({**PLAIN, "joints": [PLAIN["joints"][0], dict(PLAIN["joints"][1], column="theta")]}))
    fixed = {**PLAIN, "columns": ["t", "theta", "alpha", "u"]}
    assert import_logs([dup], imap_of(fixed)).n_samples == 60


def test_detect_delimiter():
    assert detect_delimiter("f", ["t;a;b", "0.1;2;3"], header=True) == ";"
    assert detect_delimiter("f", ["0.1\t2\t3", "0.2\t2\t4"], header=False) == "\t"
    assert detect_delimiter("f", ["0.1   2 3", " 0.2 2\t4"], header=False) == "whitespace"
    assert detect_delimiter("f", ["t, a, b", "0.1, 2, 3"], header=True) == ","
    assert detect_delimiter("f", ["t,a,b", "s,rad,V"], header=True) == ","  # a units row: named when it fails to parse
    with pytest.raises(TrajectoryFormatError, match=r"f: the field separator is ambiguous: comma and whitespace each split line 1 "
                       r"\('a,b c'\) .*set delimiter: in the map"):
        detect_delimiter("f", ["a,b c"], header=True)
    with pytest.raises(TrajectoryFormatError, match=r"f: cannot tell how the fields are separated: .* line 3 \('1\|2'\)"):
        detect_delimiter("f", ["1|2", "3|4"], header=False, first_line=3)


def test_a_units_row_is_named(tmp_path):
    path = tmp_path / "units.csv"
    path.write_text("t,theta,alpha,u\nms,rad,rad,V\n" + "\n".join(f"{2.0 * i},{0.1 * i},{0.2 * i},{i}" for i in range(50)) + "\n")
    with pytest.raises(TrajectoryFormatError, match=r"units\.csv: column 't', row 0 \(line 2\): 'ms' is not a number"):
        import_logs([path], imap_of(PLAIN))


def test_time_error_hints(tmp_path):
    h = 2.0
    late = np.arange(400) * h
    late[150:] += 0.9  # a 0.9 ms overrun at row 150, never caught up
    path = tmp_path / "late.txt"
    path.write_text("\n".join(f"{t:.4f} {0.001 * i:.6f} {-0.002 * i:.6f} {i / 400:.6f}" for i, t in enumerate(late)) + "\n")
    cols = {**PLAIN, "header": False, "columns": ["t", "theta", "alpha", "u"]}
    with pytest.raises(TrajectoryFormatError, match=r"time 0\.\d+ s is [+-]\d+\.\d µs off the 500 Hz grid .*if the logger's loop "
                       r"overran or its clock drifts, set time\.resample: linear .* raise time\.max_jitter"):
        import_logs([path], imap_of(cols))
    late_at = np.arange(400) % 5 == 0
    late_at[0] = False
    overrun = np.arange(400) * h + np.cumsum(np.where(late_at, 0.3, 0.0))  # every 5th sample 0.3 ms late, never caught up
    path.write_text("\n".join(f"{t:.4f} {0.001 * i:.6f} {-0.002 * i:.6f} {i / 400:.6f}" for i, t in enumerate(overrun)) + "\n")
    with pytest.raises(TrajectoryFormatError, match=r"advance by 2\.0599\d* ms per sample, not the 2 ms of 500 Hz \(more than 1% apart\): "
                       r"most steps are 2 ms, but 79 of 399 are longer \(up to 2\.3 ms\) and the stamps never catch up: the "
                       r"logger's loop overran\. Set time\.resample: linear"):
        import_logs([path], imap_of({**cols, "time": {**cols["time"], "rate_hz": 500.0}}))
    drift = np.arange(400) * h * 1.02
    path.write_text("\n".join(f"{t:.4f} {0.001 * i:.6f} {-0.002 * i:.6f} {i / 400:.6f}" for i, t in enumerate(drift)) + "\n")
    with pytest.raises(TrajectoryFormatError, match=r"the steps are a steady 2\.04 ms\. If that is the logger's rate, set "
                       r"time\.rate_hz: 490\.196 .*if its clock drifts against 500 Hz, set time\.resample: linear"):
        import_logs([path], imap_of({**cols, "time": {**cols["time"], "rate_hz": 500.0}}))


def test_map_keys_are_checked(tmp_path):
    good = {**PLAIN, "header": False, "columns": ["t", "theta", "alpha", "u"]}
    cases = [
        ({**PLAIN, "header": False}, r"map: header: false needs columns: \[name, …\]"),
        ({**good, "columns": ["t", "theta", "alpha"]}, r"map: inputs\[0\]\.column: 'u' is not one of columns: \['t', 'theta', 'alpha'\]"),
        ({**good, "columns": ["t", "theta", "theta", "alpha", "u"]}, r"columns: duplicate names \['theta'\]"),
        ({**good, "delimiter": " "}, r"delimiter: expected one character .* got ' ' \(for fields separated by spaces write delimiter: whitespace\)"),
        ({**good, "delimiter": "\\t"}, r'got \'\\\\t\' \(a tab is written "\\t" in double quotes, or tab\)'),
        ({**good, "time": {"rate_hz": 500.0, "resample": "linear"}}, r"map\.time: resample: linear needs the time stamps"),
        ({**good, "time": {"column": "t", "resample": "cubic"}}, r"map\.time\.resample: expected one of \['none', 'linear'\], got 'cubic'"),
    ]
    for mapping, message in cases:
        with pytest.raises(ConfigError, match=message):
            load_import_map(write_map(tmp_path / "m.yaml", mapping))
    assert load_import_map(write_map(tmp_path / "m.yaml", {**good, "delimiter": "tab"})).delimiter == "\t"


# ------------------------------------------------------------------ a last line cut mid-write


@pytest.mark.parametrize("style, reason", [
    (RigLogStyle(cut_tail_chars=1), None),  # no final line end, but the line is whole: imported
    (RigLogStyle(cut_tail_chars=2), r"its last field '' is not a number"),  # cut after the last comma
    (RigLogStyle(cut_tail_chars=9), r"8 of 9 fields"),
    (RigLogStyle(header=False, delimiter=" ", minimal=True, cut_tail_chars=3), r"its last field '-?\d+\.\d{4}' \(column "
     r"'plant_input'\) is printed with other digits than on the lines before it"),
], ids=["no-line-end", "empty-field", "missing-fields", "short-digits"])
def test_a_last_line_cut_mid_write_is_named_and_left_out(rig, tmp_path, style, reason, caplog, capsys):
    whole = dataclasses.replace(style, cut_tail_chars=0)
    full = import_logs(write_rig_logs(rig, tmp_path / "whole", whole), imap_of(rig_log_map(rig, whole)))
    paths = write_rig_logs(rig, tmp_path / "cut", style)
    assert not paths[-1].read_bytes().endswith(b"\n")
    mp = write_map(tmp_path / "map.yaml", rig_log_map(rig, style))
    with caplog.at_level(logging.WARNING):
        got = import_logs(paths, load_import_map(mp))
    cut = got.meta.extra["import"]["cut_last_lines"]
    if reason is None:
        same_arrays(full, got)
        assert cut == [] and "cut mid-write" not in caplog.text
        return
    assert got.n_samples == full.n_samples - 3  # one line per file, each file a trial
    for s_full, s_got in zip(full.trial_slices(), got.trial_slices()):
        np.testing.assert_array_equal(full.q[s_full.rows][:-1], got.q[s_got.rows])
    n_lines = [len(p.read_text().splitlines()) for p in paths]
    assert [c["line"] for c in cut] == n_lines and all(c["file"] == str(p) for c, p in zip(cut, paths))
    assert all(re.search(reason, c["reason"]) for c in cut)
    assert re.search(rf"{paths[0].name}: line {n_lines[0]}, the last \(no line end\), looks cut mid-write \({reason}", caplog.text)
    out = tmp_path / "cut.npz"
    assert main(["data", "import", *map(str, paths), "--map", str(mp), "--out", str(out)]) == 0
    assert re.search(rf"warning: .*{paths[2].name}: line {n_lines[2]}, the last \(no line end\), looks cut mid-write", capsys.readouterr().out)


def test_cut_exponent_of_a_scientific_last_line(tmp_path):
    """A DFKI-like logger printing %.18e: a cut in the exponent still parses, to the wrong magnitude."""
    rows = [",".join(f"{v:.18e}" for v in (i * 2e-3, 0.01 * math.sin(i / 9), 0.02 * math.cos(i / 7), 0.3 * math.sin(i / 5)))
            for i in range(1, 80)]
    path = tmp_path / "sci.csv"
    path.write_text("time,q1,q2,tau\n" + "\n".join(rows) + "\n" + rows[-1][:-1].replace(rows[-1][:12], f"{0.16:.18e}"[:12], 1))
    mapping = {"time": {"column": "time", "unit": "s"},
               "joints": [{"name": "a", "column": "q1", "unit": "rad"}, {"name": "b", "column": "q2", "unit": "rad", "unactuated": True}],
               "inputs": [{"name": "tau", "column": "tau", "unit": "N*m"}]}
    got = import_logs([path], imap_of(mapping))
    assert got.n_samples == 79
    (cut,) = got.meta.extra["import"]["cut_last_lines"]
    assert cut["line"] == 81 and "printed with other digits" in cut["reason"]


# ------------------------------------------------------------------ time.resample: linear


def overrun_stamps(n: int, rate: float, prob: float, late_ms: tuple[float, float], seed: int) -> np.ndarray:
    """True sample times, s, of a loop at ``rate`` that is late by U(late_ms) with probability ``prob``, never catching up."""
    rng = np.random.default_rng(seed)
    late = np.where(rng.random(n) < prob, rng.uniform(*late_ms, n), 0.0) * 1e-3
    late[0] = 0.0
    return np.arange(n) / rate + np.cumsum(late)


def signals(t: np.ndarray) -> np.ndarray:
    """The analytic channels: θ = 0.3 sin(2π·1.3 t), α = 0.05 cos(2π·0.7 t), u = sin(2π·2 t), kept = t²."""
    return np.column_stack([0.3 * np.sin(2 * np.pi * 1.3 * t), 0.05 * np.cos(2 * np.pi * 0.7 * t),
                            np.sin(2 * np.pi * 2.0 * t), t**2])


#: |f''| bounds of :func:`signals`' channels on t ∈ [0, 5] s.
CURVATURE = np.array([0.3 * (2 * np.pi * 1.3) ** 2, 0.05 * (2 * np.pi * 0.7) ** 2, (2 * np.pi * 2.0) ** 2, 2.0])

RESAMPLE_MAP = {
    "time": {"column": "t", "unit": "s", "rate_hz": 500.0, "resample": "linear"},
    "header": False, "columns": ["t", "theta", "alpha", "u", "extra"],
    "joints": [{"name": "theta", "column": "theta", "unit": "rad"},
               {"name": "alpha", "column": "alpha", "unit": "rad", "unactuated": True}],
    "inputs": [{"name": "motor", "column": "u"}],
    "keep": ["extra"],
}


def write_analytic(path: Path, stamps: np.ndarray, true_t: np.ndarray | None = None) -> Path:
    true_t = stamps if true_t is None else true_t
    rows = np.column_stack([stamps, signals(true_t)])
    np.savetxt(path, rows, fmt="%.10f", delimiter=" ")
    return path


def test_resample_linear_interpolates_every_channel_onto_the_grid(tmp_path, caplog):
    rate = 500.0
    tau = overrun_stamps(2500, rate, prob=0.05, late_ms=(0.1, 4.0), seed=1)  # overruns of up to 2 steps
    tau = tau[tau <= 5.0]
    path = write_analytic(tmp_path / "overrun.txt", tau)
    with pytest.raises(TrajectoryFormatError, match=r"set time\.resample: linear"):
        import_logs([path], imap_of({**RESAMPLE_MAP, "time": {"column": "t", "rate_hz": 500.0}}))
    with caplog.at_level(logging.INFO):
        got = import_logs([path], imap_of(RESAMPLE_MAP))
    # the grid: t0 + k/f_s from the first stamp, up to (not past) the last stamp
    n = int(np.floor((tau[-1] - tau[0]) * rate + 1e-9)) + 1
    assert got.n_samples == n and got.trial_ids == (0,)
    np.testing.assert_allclose(got.t, tau[0] + np.arange(n) / rate, rtol=0, atol=1e-12)
    assert got.t[-1] <= tau[-1] + 1e-12
    # every channel vs the analytic signal, within the linear-interpolation bound h_max² / 8 · max|f''| (+ printing)
    steps = np.diff(tau)
    bound = steps.max() ** 2 / 8 * CURVATURE + 1e-9
    truth = signals(got.t)
    err = np.abs(np.column_stack([got.q, got.u, got.channels]) - truth).max(axis=0)
    assert np.all(err <= bound), (err, bound)
    assert err[0] > 1e-7  # the samples were interpolated, not copied
    # the report: stamps moved off the grid (> 0.25 step), the largest overrun, the stamps' mean rate
    res = got.meta.extra["import"]["resample"]
    frac = (tau - tau[0]) * rate
    assert res["moved"] == int(np.sum(np.abs(frac - np.round(frac)) > 0.25)) > 100
    assert res["stamps"] == len(tau) and res["samples"] == n and res["tolerance_steps"] == 0.25
    assert res["largest_overrun_s"] == pytest.approx(steps.max() - 1 / rate, abs=1e-9)
    assert res["stamp_rate_hz"] == pytest.approx((len(tau) - 1) / (tau[-1] - tau[0]), rel=1e-9)
    assert got.meta.extra["import"]["quantization_step"] == {"theta": None, "alpha": None}
    assert "resampled (time.resample: linear) onto 500 Hz" in caplog.text
    assert "leave their encoder grid" not in caplog.text  # nothing was quantized
    back = read_trajectory(write_trajectory(got, tmp_path / "r.csv"))
    assert back.meta.extra["import"]["resample"] == res


def test_drifting_clock_is_resampled_onto_the_nominal_rate(tmp_path):
    """Stamps from a clock 2 % fast: the grid path refuses them; resampling puts the values at the stamps' times."""
    true_t = np.arange(1500) / 500.0
    stamps = true_t * 1.02
    path = write_analytic(tmp_path / "drift.txt", stamps, true_t)
    got = import_logs([path], imap_of(RESAMPLE_MAP))
    assert got.meta.sample_rate_hz == 500.0
    np.testing.assert_allclose(np.diff(got.t), 1 / 500.0, rtol=1e-9)
    # the logger's clock is the time base: a value logged at stamp s is the signal at s / 1.02
    truth = signals(got.t / 1.02)
    bound = (2.04e-3) ** 2 / 8 * CURVATURE + 1e-9
    assert np.all(np.abs(np.column_stack([got.q, got.u, got.channels]) - truth).max(axis=0) <= bound)
    assert got.n_samples == int(np.floor(stamps[-1] * 500 + 1e-9)) + 1
    # without rate_hz the median step sets f_s: the stamps' own 490.196 Hz, rounded to 490 (within 0.1 %)
    free = import_logs([path], imap_of({**RESAMPLE_MAP, "time": {"column": "t", "resample": "linear"}}))
    assert free.meta.sample_rate_hz == 490.0


def test_resample_gaps_split_or_fail_like_the_grid(tmp_path):
    rate = 500.0
    tau = np.concatenate([np.arange(300), np.arange(302.4, 600), np.arange(608.3, 900)]) / rate
    path = write_analytic(tmp_path / "gaps.txt", tau)
    # max_fill 2: a step of 3.4 nominal steps (2 missing) is bridged, one of 8.9 (8 missing) splits the trial
    got = import_logs([path], imap_of(RESAMPLE_MAP))
    info = got.meta.extra["import"]
    assert got.trial_ids == (0, 1) and info["split_gaps"] == 1
    assert [s.n_samples for s in got.trial_slices()] == [600, 292]  # 0 … 599.4 and 608.3 … 899.3 steps, no extrapolation
    assert info["trials"][1]["first_row"] == 300 + 298
    assert got.t[got.trial_slices()[1].rows][0] == pytest.approx(608.3 / rate, abs=1e-12)
    assert info["filled_samples"] == 2  # grid points 300 and 301 lie more than ½ step from the stamps 299 and 302.4
    assert info["resample"]["largest_overrun_s"] == pytest.approx(2.4 / rate, abs=1e-9)
    bridged = import_logs([path], imap_of({**RESAMPLE_MAP, "time": {**RESAMPLE_MAP["time"], "max_fill": 8}}))
    assert bridged.trial_ids == (0,) and bridged.meta.extra["import"]["split_gaps"] == 0
    with pytest.raises(TrajectoryFormatError, match=r"gaps\.txt: column 't', row 598 \(line 599\): 8 missing samples before time "
                       r"1\.2166 s .*raise time\.max_fill to bridge it, or set time\.on_gap: split"):
        import_logs([path], imap_of({**RESAMPLE_MAP, "time": {**RESAMPLE_MAP["time"], "on_gap": "error"}}))


def test_resampled_rig_logs_keep_the_encoder_step_detected_before(rig, tmp_path, caplog, capsys):
    """Counts from an overrunning loop: the angles leave the 4096-count grid, the stored step stays."""
    style = RigLogStyle(angle_unit="counts", overrun_prob=0.05, overrun_max_s=4e-3, jitter_s=0.0, drop_prob=0.0, seed=2)
    paths = write_rig_logs(rig, tmp_path / "logs", style)
    mapping = rig_log_map(rig, style)
    assert mapping["time"]["resample"] == "linear"
    mp = write_map(tmp_path / "map.yaml", mapping)
    with caplog.at_level(logging.WARNING):
        got = import_logs(paths, load_import_map(mp))
    assert "the interpolated angles of theta (step 0.00153398 (2π/4096)), alpha (step 0.00153398 (2π/4096)) leave their encoder grid" in caplog.text
    stored = got.meta.extra["import"]["quantization_step"]
    assert stored == {"theta": pytest.approx(STEP, rel=1e-9), "alpha": pytest.approx(STEP, rel=1e-9)}
    assert detect_quantization_step(got.q[:, 1]) is None  # off the grid after interpolation
    for path in (tmp_path / "r.npz", tmp_path / "r.csv"):
        back = read_trajectory(write_trajectory(got, path))
        assert back.quantization_steps() == {"theta": pytest.approx(STEP, rel=1e-9), "alpha": pytest.approx(STEP, rel=1e-9)}
        assert back.summary()["quantization_step_rad"] == back.quantization_steps() and back.summary()["resampled"]
    # values vs the simulated trajectory at the grid times: two linear interpolations of one encoder step each side
    for s_true, s_got in zip(rig.trial_slices(), got.trial_slices()):
        q_true = rig.q[s_true.rows][: s_got.n_samples]
        jump = np.abs(np.diff(rig.q[s_true.rows], axis=0)).max(axis=0)
        assert np.all(np.abs(got.q[s_got.rows] - q_true).max(axis=0) <= 2 * jump + STEP)
    out = tmp_path / "rig.npz"
    assert main(["data", "import", *map(str, paths), "--map", str(mp), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert re.search(r"resampled \(time\.resample: linear\) onto 400 Hz: \d+ logged samples -> \d+; \d+ \(\d+\.\d %\) had moved "
                     r"more than 0\.25 step off the grid; largest overrun \d\.\d+ ms", text)
    assert "quantization step (rad) — detected in the logged values, before resampling:" in text
    assert "alpha        0.001533980788 (= 2π/4096, 4096 counts/rev)" in text


def test_quantization_steps_detects_when_nothing_is_stored(rig):
    assert rig.quantization_steps() == {"theta": pytest.approx(STEP, rel=1e-6), "alpha": pytest.approx(STEP, rel=1e-6)}
    meta = dataclasses.replace(rig.meta, extra={"import": {"quantization_step": {"alpha": None}}})
    steps = dataclasses.replace(rig, meta=meta).quantization_steps()
    assert steps["alpha"] is None and steps["theta"] == pytest.approx(STEP, rel=1e-6)


def test_import_map_round_trips_through_its_yaml(tmp_path):
    mapping = {**RESAMPLE_MAP, "delimiter": "whitespace"}
    imap = imap_of(mapping)
    assert imap_of(to_dict(imap)) == imap

