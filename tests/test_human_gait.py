"""The shipped human gait data: checksum, reproducible conversion, angle conventions, loader, linear map."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np
import pytest

from bemlearn.apps.biped.human_gait import (
    HUMAN_GAIT_CSV,
    JointRangeMap,
    convert_raw,
    fit_joint_range_map,
    format_csv,
    load_human_gait,
)
from tests.file_module import load_file_module

ROOT = Path(__file__).resolve().parents[1]
SHIPPED_SHA256 = "30ebdb42d975a412ac4ab029ccc3a56b0583a2b29652c26c092744a35480e34a"
RAW_MEMBER = "gaitanalysis/octave/2d_inverse_dynamics/test/rawdata.txt"
HEADER = ("% TimeStamp\tRSHO.PosX\tRSHO.PosY\tRGTRO.PosX\tRGTRO.PosY\tRLEK.PosX\tRLEK.PosY\tRLM.PosX\tRLM.PosY"
          "\tRHEE.PosX\tRHEE.PosY\tRMT5.PosX\tRMT5.PosY\tFP2.ForX\tFP2.ForY\tFP2.MomZ")


def _source() -> Path | None:
    """The GaitAnalysisToolKit source: $BEMLEARN_GAT_SOURCE, or the sdist unpacked/downloaded in /tmp/gat."""
    candidates = [os.environ.get("BEMLEARN_GAT_SOURCE", ""), f"/tmp/gat/GaitAnalysisToolKit-0.2.0/{RAW_MEMBER}",
                  "/tmp/gat/GaitAnalysisToolKit-0.2.0.tar.gz"]
    return next((Path(c) for c in candidates if c and Path(c).is_file()), None)


def test_shipped_file_checksum():
    assert hashlib.sha256(HUMAN_GAIT_CSV.read_bytes()).hexdigest() == SHIPPED_SHA256


def test_conversion_reproduces_the_shipped_file(tmp_path):
    src = _source()
    if src is None:
        pytest.skip("GaitAnalysisToolKit 0.2.0 source not available: set BEMLEARN_GAT_SOURCE to its rawdata.txt or "
                    "sdist (pip download --no-deps -d /tmp/gat gaitanalysistoolkit==0.2.0)")
    script = load_file_module(ROOT / "scripts" / "convert_human_gait.py")
    out = tmp_path / "hg.csv"
    assert script.main(["--source", str(src), "--out", str(out)]) == 0
    assert out.read_bytes() == HUMAN_GAIT_CSV.read_bytes()
    assert script.main(["--source", str(tmp_path / "nope.txt"), "--out", str(out)]) == 2


def _markers(trunk, hip, knee, *, hip_xy=(0.5, 0.9), L=(0.5, 0.42, 0.43)):
    """Marker rows (SHO, GTRO, LEK, LM) built from known angles with the robot's conventions."""
    phi_t, phi_s = trunk + hip, trunk + hip + knee
    g = np.array(hip_xy)
    sho = g + L[0] * np.array([np.sin(trunk), np.cos(trunk)])
    lek = g + L[1] * np.array([-np.sin(phi_t), -np.cos(phi_t)])
    lm = lek + L[2] * np.array([-np.sin(phi_s), -np.cos(phi_s)])
    return np.r_[sho, g, lek, lm]


def _raw_text(rows):
    lines = [HEADER]
    for i, m in enumerate(rows):
        vals = [7.0 + 0.01 * i, *m, 0.0, 0.0, 0.0, 0.0, 0.0, 100.0 * i, 0.0]
        lines.append("\t".join("NaN" if np.isnan(v) else repr(float(v)) for v in vals))
    return "\n".join(lines) + "\n"


def test_convert_recovers_known_angles_and_fills_gaps():
    angles = [(0.05, -0.3, 0.2), (-0.02, 0.1, 0.6), (0.0, 0.25, 0.05), (0.03, -0.1, 1.0)]
    rows = [_markers(*a) for a in angles]
    table = convert_raw(_raw_text(rows))
    np.testing.assert_allclose(table[:, 1:4], np.array(angles), atol=1e-12)
    np.testing.assert_allclose(table[:, 4], [0.0, 100.0, 200.0, 300.0])
    assert not table[:, 5].any()
    gap = [r.copy() for r in rows]
    gap[1][6:8] = np.nan  # the malleolus (LM) lost for one sample
    t2 = convert_raw(_raw_text(gap))
    np.testing.assert_array_equal(t2[:, 5], [0, 1, 0, 0])
    lm = (rows[0][6:8] + rows[2][6:8]) / 2
    expect_knee = np.arctan2(-(lm - rows[1][4:6])[0], -(lm - rows[1][4:6])[1]) - (angles[1][0] + angles[1][1])
    assert t2[1, 3] == pytest.approx(expect_knee, abs=1e-12)


def test_convert_errors_name_the_problem():
    rows = [_markers(0.0, 0.1 * i, 0.2) for i in range(8)]
    with pytest.raises(ValueError, match=r"missing column\(s\) \['RLM.PosX'\]"):
        convert_raw(_raw_text(rows).replace("RLM.PosX", "RLM.X"), source="raw.txt")
    bad = [r.copy() for r in rows]
    for i in (2, 3, 4):
        bad[i][0] = np.nan
    with pytest.raises(ValueError, match=r"raw.txt: column 'RSHO.PosX': gap of 3 samples at rows 2..4"):
        convert_raw(_raw_text(bad), source="raw.txt", max_gap=2)
    with pytest.raises(ValueError, match="raw.txt: line 2: 15 fields, expected 16"):
        convert_raw(_raw_text(rows).replace("\t0.0\n", "\n", 1), source="raw.txt")


def test_loaded_recording_cycle_and_half_cycle_step():
    g = load_human_gait()
    assert g.t.shape == (301,) and int(g.interpolated.sum()) == 11
    hs = g.heel_strikes()
    assert len(hs) == 3 and g.cycle_period() == pytest.approx(1.1957, abs=1e-3)
    _s, qa, _trunk = g.step_profile(21)
    # half-cycle assumption: the swing leg starts where the stance leg ends and vice versa
    np.testing.assert_allclose(qa[0, 2:], qa[-1, :2], atol=1e-12)
    np.testing.assert_allclose(qa[-1, 2:], qa[0, :2], atol=1e-12)
    # knee flexion positive, stance thigh moves backwards (hip angle increases) over the step
    assert qa[:, [1, 3]].min() > 0 and qa[-1, 0] > qa[0, 0] + 0.3


def test_csv_round_trip_and_loader_errors(tmp_path):
    table = np.array([[7.0, 0.1, -0.2, 0.3, 10.0, 0.0], [7.01, 0.1000001, -0.2, 0.31, 25.0, 1.0]])
    p = tmp_path / "g.csv"
    p.write_text(format_csv(table, provenance="test"))
    g = load_human_gait(p)
    np.testing.assert_allclose(g.knee, [0.3, 0.31])
    np.testing.assert_array_equal(g.interpolated, [False, True])
    with pytest.raises(FileNotFoundError, match="not found"):
        load_human_gait(tmp_path / "missing.csv")
    p.write_text(format_csv(table, provenance="test").replace("grf_y", "grf"))
    with pytest.raises(ValueError, match="expected the header"):
        load_human_gait(p)


def test_joint_range_map_hits_the_target_ranges():
    qa = np.array([[-0.4, 0.1, 0.05, 0.8], [0.1, 0.3, -0.2, 1.2], [0.0, 0.2, -0.1, 0.0]])
    m = fit_joint_range_map(qa, hip_range=(-0.3, 0.05), knee_range=(0.1, 0.9))
    out = m.apply(qa)
    assert out[:, [0, 2]].min() == pytest.approx(-0.3) and out[:, [0, 2]].max() == pytest.approx(0.05)
    assert out[:, [1, 3]].min() == pytest.approx(0.1) and out[:, [1, 3]].max() == pytest.approx(0.9)
    np.testing.assert_allclose(JointRangeMap(1.0, 0.0, 1.0, 0.0).apply(qa), qa)
    with pytest.raises(ValueError, match="hip_range must satisfy lo < hi"):
        fit_joint_range_map(qa, hip_range=(0.1, 0.1), knee_range=(0.0, 1.0))
