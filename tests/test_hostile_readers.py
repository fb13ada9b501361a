"""Readers check what a file declares against what it holds before allocating (issue 29, item 6).

The 2 GB files are sparse (``truncate``): they cost no disk, and reading them costs what a real
one would.  Memory is measured in a child process (``resource.getrusage`` max RSS).
"""

import io
import json
import subprocess
import sys
import textwrap
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from bemlearn.config import from_dict
from bemlearn.data import TrajectoryFormatError, read_trajectory
from bemlearn.data.import_map import ImportMap
from bemlearn.data.log_import import import_logs
from bemlearn.data.rig_logs import RigLogStyle, rig_log_map, write_rig_logs

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "data" / "furuta_excitation.npz"
TWO_GB = 2 * 1024**3


@pytest.fixture(scope="module")
def rig():
    traj = read_trajectory(DATA)
    return traj.select_trials([traj.trial_slices()[0].trial_id])


def _imap(rig, style) -> ImportMap:
    return from_dict(ImportMap, yaml.safe_load(yaml.safe_dump(rig_log_map(rig, style))))


def _forged_npz(path: Path, shape: tuple[int, ...]) -> Path:
    """A trajectory NPZ whose ``q`` header declares ``shape`` but holds 16 bytes."""
    ok = io.BytesIO()
    np.savez(ok, meta=np.array("{}"), t=np.zeros(2), trial=np.zeros(2, dtype=np.int64), q=np.zeros((2, 2)), u=np.zeros((2, 1)))
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(io.BytesIO(ok.getvalue())) as zin, zipfile.ZipFile(path, "w") as zout:
        for info in zin.infolist():
            data = b"\x93NUMPY\x01\x00" + header.getvalue()[8:] + b"\0" * 16 if info.filename == "q.npy" else zin.read(info)
            zout.writestr(info.filename, data)
    return path


def test_an_npz_header_declaring_more_than_the_file_holds_is_refused(tmp_path):
    """A header declaring 10¹¹ × 2 float64 ended in MemoryError ("Unable to allocate 1.46 TiB")."""
    bad = _forged_npz(tmp_path / "forged.npz", (10**11, 2))
    t0 = time.perf_counter()
    with pytest.raises(TrajectoryFormatError, match=r"forged.npz: array 'q': its header declares shape \(100000000000, 2\) "
                                                    r"of float64 \(1600000000000 bytes\), but the file holds \d+ bytes"):
        read_trajectory(bad)
    assert time.perf_counter() - t0 < 1.0


def test_a_zip_member_declaring_an_impossible_size_is_refused(tmp_path):
    bad = tmp_path / "bomb.npz"
    np.savez(bad, t=np.zeros(3))
    data = bytearray(bad.read_bytes())
    # the central directory's uncompressed size of the stored member: 2⁳¹ bytes
    cd = data.rfind(b"PK\x01\x02")
    data[cd + 24:cd + 28] = (2**31).to_bytes(4, "little")
    bad.write_bytes(bytes(data))
    with pytest.raises(TrajectoryFormatError, match=r"bomb.npz: array 't' declares 2147483648 bytes in \d+ stored bytes"):
        read_trajectory(bad)


_MEASURE = textwrap.dedent("""
    import json, resource, sys, time
    import yaml
    from bemlearn.config import from_dict
    from bemlearn.data.import_map import ImportMap
    from bemlearn.data.log_import import import_logs
    from bemlearn.errors import BemlearnError
    imap = from_dict(ImportMap, yaml.safe_load(open(sys.argv[2])))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    try:
        traj = import_logs([sys.argv[1]], imap)
        result = {"rows": traj.n_samples}
    except BemlearnError as exc:
        result = {"error": str(exc)}
    result["s"] = time.perf_counter() - t0
    result["rss_growth_mb"] = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    print(json.dumps(result))
""")


def _measure(log: Path, imap_file: Path) -> dict:
    res = subprocess.run([sys.executable, "-c", _MEASURE, str(log), str(imap_file)], capture_output=True, text=True, timeout=600,
                         env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_a_2gb_nul_file_is_refused_within_a_second(rig, tmp_path):
    """A 2 GB file of NUL bytes took 53 s and 4.2 GB of memory to reject its first line."""
    style = RigLogStyle(header=True, delimiter=",")
    imap_file = tmp_path / "map.yaml"
    imap_file.write_text(yaml.safe_dump(rig_log_map(rig, style)))
    nul = tmp_path / "zeros.csv"
    subprocess.run(["truncate", "-s", str(TWO_GB), str(nul)], check=True)
    got = _measure(nul, imap_file)
    assert "zeros.csv: a NUL byte at offset 0, in the first line: a binary file, not a text log" in got.get("error", ""), got
    assert got["s"] <= 1.0 and got["rss_growth_mb"] < 100, got


def test_a_valid_log_with_a_2gb_nul_tail_imports_in_bounded_memory(rig, tmp_path):
    """A valid log followed by a 2 GB NUL tail imported correctly but peaked at 6.3 GB."""
    style = RigLogStyle(header=True, delimiter=",")
    (log,) = write_rig_logs(rig, tmp_path / "logs", style)
    whole = import_logs([log], _imap(rig, style))
    imap_file = tmp_path / "map.yaml"
    imap_file.write_text(yaml.safe_dump(rig_log_map(rig, style)))
    size = log.stat().st_size
    subprocess.run(["truncate", "-s", str(size + TWO_GB), str(log)], check=True)
    got = _measure(log, imap_file)
    assert got.get("rows") == whole.n_samples, got
    assert got["rss_growth_mb"] < 300, got   # the text is ~1 MB; the tail is never held in memory
    tailed = import_logs([log], _imap(rig, style))
    np.testing.assert_array_equal(tailed.q, whole.q)


def test_binary_data_after_a_nul_run_is_refused(rig, tmp_path):
    style = RigLogStyle(header=True, delimiter=",")
    (log,) = write_rig_logs(rig, tmp_path / "logs", style)
    with open(log, "ab") as fh:
        fh.write(b"\0" * 100 + b"\x7fELF")
    with pytest.raises(TrajectoryFormatError, match=r"NUL bytes from offset \d+, then data again at offset \d+: binary data"):
        import_logs([log], _imap(rig, style))


def test_a_trajectory_csv_of_nul_bytes_is_refused_at_once(tmp_path):
    nul = tmp_path / "zeros.csv"
    subprocess.run(["truncate", "-s", str(TWO_GB), str(nul)], check=True)
    t0 = time.perf_counter()
    with pytest.raises(TrajectoryFormatError, match=r"zeros.csv: a NUL byte at offset 0, in the first line: a binary file, "
                                                    r"not a bemlearn trajectory CSV"):
        read_trajectory(nul)
    assert time.perf_counter() - t0 < 1.0
