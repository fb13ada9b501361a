"""Reading and writing trajectory files (NPZ and CSV, format in ``docs/trajectory-format.md``).

The suffix chooses the format: ``.npz`` (arrays ``meta``, ``t``, ``trial``, ``q``, ``u``
and, in ground-truth files, ``qd``, ``qdd``; ``channels`` when the file carries extra
logged channels; ``tau`` when it carries logged torques) or ``.csv`` (two ``#`` metadata lines, a header
``t,trial,q:<joint>...,u:<actuator>...[,qd:<joint>...,qdd:<joint>...][,tau:<joint>...][,x:<channel>...]``, one row
per sample, floats written with ``%.17g`` so CSV ↔ NPZ is lossless).  Every read is
validated (:func:`bemlearn.data.validation.validate`); nothing is dropped or repaired.
"""

from __future__ import annotations

import json
import logging
import math
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from bemlearn.data.text_extent import text_extent
from bemlearn.data.trajectory import Trajectory, TrajectoryMeta, check_names
from bemlearn.data.validation import JITTER_RTOL, MIN_TRIAL_SAMPLES, RATE_RTOL, RobotLike, column_names, validate
from bemlearn.errors import MissingFileError, TrajectoryFormatError
from bemlearn.files import atomic_path
from bemlearn.safe_load import open_npz

#: Largest uncompressed / compressed size ratio deflate can reach (about 1032:1).
_DEFLATE_RATIO = 1100

__all__ = ["read_trajectory", "read_ground_truth", "write_trajectory", "ground_truth_path", "CSV_MAGIC", "SUFFIXES"]

logger = logging.getLogger(__name__)

#: First line of every CSV trajectory file.
CSV_MAGIC = "# bemlearn-trajectory v1"
_CSV_META_PREFIX = "# meta: "
#: Supported file suffixes.
SUFFIXES = (".npz", ".csv")
_NPZ_REQUIRED = ("meta", "t", "trial", "q", "u")
_NPZ_OPTIONAL = ("qd", "qdd", "channels", "tau")


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise TrajectoryFormatError(
            f"{path}: unsupported trajectory file suffix {path.suffix!r}; expected one of {list(SUFFIXES)}"
        )
    return suffix


def _resolve_robot(robot: str | RobotLike | None) -> RobotLike | None:
    if robot is None or not isinstance(robot, str):
        return robot
    from bemlearn.robots import load  # lazy: robots is heavier than data

    return load(robot)


def ground_truth_path(path: str | Path) -> Path:
    """Where the ground truth of data file ``path`` lives by convention: ``<stem>.truth<suffix>``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.truth{path.suffix}")


def read_trajectory(
    path: str | Path,
    *,
    robot: str | RobotLike | None = None,
    min_trial_samples: int = MIN_TRIAL_SAMPLES,
    rate_rtol: float = RATE_RTOL,
    jitter_rtol: float = JITTER_RTOL,
) -> Trajectory:
    """Read and validate a trajectory file (``.npz`` or ``.csv``).

    Args:
        path: the file.
        robot: a registry name (``bemlearn.robots.load``) or robot object to match joint names against.
        min_trial_samples: shortest accepted trial, samples.
        rate_rtol: accepted relative deviation of each trial's median time step from 1 / sample_rate_hz.
        jitter_rtol: accepted relative deviation of every single time step from 1 / sample_rate_hz.

    Returns:
        The trajectory (with ``qd``/``qdd`` when the file holds ground truth, and the
        extra channels of ``meta.channel_names``).

    Raises:
        MissingFileError: (a FileNotFoundError) no such file.
        ValueError: unsupported suffix.
        TrajectoryFormatError: malformed file, naming file, column and row.
    """
    path = Path(path)
    suffix = _suffix(path)
    if not path.is_file():
        raise MissingFileError(f"{path}: trajectory file not found")
    if suffix == ".npz":
        traj, first_line = _read_npz(path), None
    else:
        traj, first_line = _read_csv(path)
    validate(
        traj, source=str(path), min_trial_samples=min_trial_samples, rate_rtol=rate_rtol,
        robot=_resolve_robot(robot), first_line=first_line, jitter_rtol=jitter_rtol,
    )
    logger.debug("read %s: %d samples, %d trials", path, traj.n_samples, len(traj.meta.trial_failed))
    return traj


def read_ground_truth(path: str | Path, **kwargs: Any) -> Trajectory:
    """Like :func:`read_trajectory`, but the file must hold the true ``qd`` and ``qdd``."""
    traj = read_trajectory(path, **kwargs)
    if not traj.has_ground_truth:
        what = "arrays" if Path(path).suffix.lower() == ".npz" else "columns"
        raise TrajectoryFormatError(f"{path}: not a ground-truth file (no qd/qdd {what})")
    return traj


def write_trajectory(
    traj: Trajectory,
    path: str | Path,
    *,
    min_trial_samples: int = MIN_TRIAL_SAMPLES,
    rate_rtol: float = RATE_RTOL,
    jitter_rtol: float = JITTER_RTOL,
) -> Path:
    """Validate ``traj`` and write it to ``path`` (format from the suffix; replaces an existing file).

    Ground truth (``qd``, ``qdd``) and extra channels are written when present.  The file is
    written to a temporary name next to ``path`` and moved into place (``os.replace``).

    Returns:
        ``path`` as a :class:`~pathlib.Path`.
    """
    path = Path(path)
    suffix = _suffix(path)
    validate(
        traj, source=f"write {path}", min_trial_samples=min_trial_samples, rate_rtol=rate_rtol, jitter_rtol=jitter_rtol
    )
    with atomic_path(path) as tmp:
        if suffix == ".npz":
            _write_npz(traj, tmp)
        else:
            _write_csv(traj, tmp)
    logger.debug("wrote %s: %d samples", path, traj.n_samples)
    return path


# ---------------------------------------------------------------- NPZ


def _write_npz(traj: Trajectory, path: Path) -> None:
    arrays: dict[str, np.ndarray] = {
        "meta": np.array(traj.meta.to_json()),
        "t": traj.t, "trial": traj.trial, "q": traj.q, "u": traj.u,
    }
    if traj.has_ground_truth:
        assert traj.qd is not None and traj.qdd is not None
        arrays["qd"], arrays["qdd"] = traj.qd, traj.qdd
    if traj.meta.channel_names:
        assert traj.channels is not None  # Trajectory.__post_init__ fills it
        arrays["channels"] = traj.channels
    if traj.meta.torque_joints:
        assert traj.tau is not None  # Trajectory.__post_init__ fills it
        arrays["tau"] = traj.tau
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]  # mypy also matches the ** dict against the bool allow_pickle


def _check_npz_sizes(path: Path) -> None:
    """Each array's header (shape × item size) against the bytes the archive holds for it, before
    numpy allocates what the header declares (a forged 10¹¹ × 2 header asked for 1.46 TiB).

    Raises:
        TrajectoryFormatError: an array declaring more bytes than its member holds, or a member
            declaring an uncompressed size deflate cannot reach from its compressed bytes.
    """
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            name = info.filename.removesuffix(".npy")
            stored = info.compress_type == zipfile.ZIP_STORED
            if (stored and info.file_size != info.compress_size) or info.file_size > _DEFLATE_RATIO * info.compress_size + 4096:
                raise TrajectoryFormatError(f"{path}: array {name!r} declares {info.file_size} bytes in {info.compress_size} "
                                            "stored bytes: a forged archive")
            if not info.filename.endswith(".npy"):
                continue
            with zf.open(info) as fh:
                version = np.lib.format.read_magic(fh)
                if version == (1, 0):
                    shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
                elif version == (2, 0):
                    shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
                else:
                    raise TrajectoryFormatError(f"{path}: array {name!r}: .npy format version {version} is not supported")
            declared = math.prod(int(d) for d in shape) * dtype.itemsize
            if declared > info.file_size:
                raise TrajectoryFormatError(f"{path}: array {name!r}: its header declares shape {tuple(shape)} of {dtype} "
                                            f"({declared} bytes), but the file holds {info.file_size} bytes for it")


def _read_npz(path: Path) -> Trajectory:
    try:
        _check_npz_sizes(path)
        with open_npz(path) as npz:  # allow_pickle=False: object arrays are refused
            arrays = {k: npz[k] for k in npz.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, zlib.error) as exc:
        raise TrajectoryFormatError(f"{path}: not a readable NPZ file ({exc})") from None
    check_names(arrays, _NPZ_REQUIRED, _NPZ_OPTIONAL, where=str(path), what="array",
                valid=f"a trajectory NPZ holds {list(_NPZ_REQUIRED)} and may hold {list(_NPZ_OPTIONAL)}")
    if ("qd" in arrays) != ("qdd" in arrays):
        raise TrajectoryFormatError(f"{path}: ground truth needs both arrays 'qd' and 'qdd', found only one")
    raw = arrays["meta"]
    if raw.dtype.kind != "U" or raw.size != 1:
        raise TrajectoryFormatError(
            f"{path}: array 'meta' must hold one JSON string, got dtype {raw.dtype} shape {raw.shape}"
        )
    meta = _parse_meta(str(raw.reshape(())), path)
    n = meta.n_joints
    if ("channels" in arrays) != bool(meta.channel_names):
        raise TrajectoryFormatError(
            f"{path}: meta.channel_names lists {list(meta.channel_names)} but the array 'channels' is "
            f"{'present' if 'channels' in arrays else 'missing'}"
        )
    if ("tau" in arrays) != bool(meta.torque_joints):
        raise TrajectoryFormatError(
            f"{path}: meta.torque_joints lists {list(meta.torque_joints)} but the array 'tau' is "
            f"{'present' if 'tau' in arrays else 'missing'}"
        )
    names = {
        "q": meta.joint_names, "qd": meta.joint_names, "qdd": meta.joint_names, "u": meta.actuator_names,
        "channels": meta.channel_names, "tau": meta.torque_joints,
    }
    if arrays["t"].ndim != 1:
        raise TrajectoryFormatError(f"{path}: array 't' must be 1-D (T,), got shape {arrays['t'].shape}")
    T = arrays["t"].shape[0]
    for key in ("t", "trial", "q", "u", "qd", "qdd", "channels", "tau"):
        if key not in arrays:
            continue
        arr = arrays[key]
        if key == "trial" and arr.dtype.kind not in "iu":
            raise TrajectoryFormatError(
                f"{path}: column 'trial' (array 'trial') must be integer, got dtype {arr.dtype}"
            )
        if arr.dtype.kind not in "fiu":
            raise TrajectoryFormatError(f"{path}: array {key!r} must be real numbers, got dtype {arr.dtype}")
        if key in ("t", "trial"):
            want: tuple[int, ...] = (T,)
        else:
            want = (T, len(names[key]))
        if arr.shape != want:
            prefix = "x" if key == "channels" else key
            cols = "" if key in ("t", "trial") else f" (columns {[f'{prefix}:{j}' for j in names[key]]})"
            raise TrajectoryFormatError(
                f"{path}: array {key!r} has shape {arr.shape}, expected {want}{cols} for {n} joints"
            )
    return Trajectory(
        t=arrays["t"], trial=arrays["trial"], q=arrays["q"], u=arrays["u"], meta=meta,
        qd=arrays.get("qd"), qdd=arrays.get("qdd"), channels=arrays.get("channels"), tau=arrays.get("tau"),
    )


def _parse_meta(text: str, path: Path) -> TrajectoryMeta:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise TrajectoryFormatError(f"{path}: metadata is not valid JSON ({exc})") from None
    return TrajectoryMeta.from_json_dict(data, source=str(path))


# ---------------------------------------------------------------- CSV


def _write_csv(traj: Trajectory, path: Path) -> None:
    cols = column_names(traj.meta, ground_truth=traj.has_ground_truth)
    blocks = [traj.t[:, None], traj.trial[:, None].astype(np.float64), traj.q, traj.u]
    if traj.has_ground_truth:
        assert traj.qd is not None and traj.qdd is not None
        blocks += [traj.qd, traj.qdd]
    assert traj.channels is not None and traj.tau is not None  # Trajectory.__post_init__ fills them
    blocks += [traj.tau, traj.channels]
    table = np.concatenate(blocks, axis=1) if traj.n_samples else np.zeros((0, len(cols)))
    if traj.n_samples and np.abs(traj.trial).max() >= 2**53:
        raise TrajectoryFormatError(f"{path}: trial ids must be below 2**53 in magnitude to be written as CSV")
    fmt = ["%.17g", "%d"] + ["%.17g"] * (len(cols) - 2)
    with open(path, "w", newline="\n", encoding="utf-8") as fh:
        fh.write(f"{CSV_MAGIC}\n{_CSV_META_PREFIX}{traj.meta.to_json()}\n{','.join(cols)}\n")
        np.savetxt(fh, table, fmt=fmt, delimiter=",")


def _read_csv(path: Path) -> tuple[Trajectory, int]:
    """The trajectory and the file line (1-based) of its first data row."""
    n_text, _ = text_extent(path, what="a bemlearn trajectory CSV")   # binary files refused before reading
    try:
        with open(path, "rb") as fh:
            lines = fh.read(n_text).decode("utf-8").splitlines()
    except UnicodeDecodeError as exc:
        raise TrajectoryFormatError(f"{path}: not a UTF-8 text file (byte {exc.start}); expected a bemlearn trajectory CSV") from None
    if not lines or lines[0].strip() != CSV_MAGIC:
        first = lines[0][:60] if lines else "<empty file>"
        raise TrajectoryFormatError(
            f"{path}: line 1: expected {CSV_MAGIC!r}, found {first!r} (not a bemlearn trajectory CSV)"
        )
    if len(lines) < 2 or not lines[1].startswith(_CSV_META_PREFIX):
        raise TrajectoryFormatError(f"{path}: line 2: expected the metadata line '{_CSV_META_PREFIX}{{json}}'")
    meta = _parse_meta(lines[1][len(_CSV_META_PREFIX):], path)
    if len(lines) < 3:
        raise TrajectoryFormatError(f"{path}: line 3: missing the header row")
    header = [h.strip() for h in lines[2].split(",")]
    gt = any(h.startswith(("qd:", "qdd:")) for h in header)  # x:<channel> columns come from meta.channel_names
    expected = column_names(meta, ground_truth=gt)
    want = ",".join(expected)
    check_names(header, expected, where=f"{path}: line 3", what="column", valid=f"expected header {want}")
    if header != expected:
        raise TrajectoryFormatError(
            f"{path}: line 3: columns out of order ({','.join(header)}); expected {','.join(expected)}"
        )
    first_line = 4
    body = lines[3:]
    table = _parse_rows(body, expected, path, first_line)
    trial_col = table[:, 1]
    frac = np.flatnonzero((trial_col != np.round(trial_col)) | ~np.isfinite(trial_col))
    if len(frac):
        i = int(frac[0])
        raise TrajectoryFormatError(
            f"{path}: column 'trial', row {i} (line {first_line + i}): trial id must be an integer, "
            f"got {body[i].split(',')[1]!r}"
        )
    n, m = meta.n_joints, meta.n_joints - 1
    k, p = len(meta.channel_names), len(meta.torque_joints)
    kw: dict[str, Any] = {"channels": table[:, table.shape[1] - k:], "tau": table[:, table.shape[1] - k - p:table.shape[1] - k]}
    if gt:
        kw.update(qd=table[:, 2 + n + m: 2 + 2 * n + m], qdd=table[:, 2 + 2 * n + m: 2 + 3 * n + m])
    traj = Trajectory(
        t=table[:, 0], trial=trial_col.astype(np.int64), q=table[:, 2:2 + n], u=table[:, 2 + n:2 + n + m],
        meta=meta, **kw,
    )
    return traj, first_line


def _parse_rows(body: list[str], cols: list[str], path: Path, first_line: int) -> np.ndarray:
    if not body:
        return np.zeros((0, len(cols)))
    try:
        table = np.loadtxt(body, delimiter=",", dtype=np.float64, comments=None, ndmin=2)
    except ValueError:
        table = None
    if table is not None and table.shape == (len(body), len(cols)):
        return table
    # Slow path, only to name the first offending row/column.
    for i, line in enumerate(body):
        where = f"{path}: row {i} (line {first_line + i})"
        fields = line.split(",")
        if not line.strip():
            raise TrajectoryFormatError(f"{where}: blank line inside the data")
        if len(fields) != len(cols):
            raise TrajectoryFormatError(f"{where}: {len(fields)} fields, expected {len(cols)} ({','.join(cols)})")
        for name, value in zip(cols, fields):
            try:
                float(value)
            except ValueError:
                raise TrajectoryFormatError(f"{where}: column {name!r}: {value.strip()!r} is not a number") from None
    raise TrajectoryFormatError(f"{path}: could not parse the data rows")  # pragma: no cover
