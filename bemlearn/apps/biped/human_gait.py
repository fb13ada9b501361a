"""Human walking data for the biped's human-derived gait (paper Section IV-B, Fig. 5).

Source: the sagittal right-side marker and force-plate recording shipped with
GaitAnalysisToolKit 0.2.0 (``gaitanalysis/octave/2d_inverse_dynamics/test/rawdata.txt``,
Apache-2.0, see ``data/human_gait/README.md``): 3 s at 100 Hz, X forward, Y up (m), force
plate FP2 under the right foot (N).  :func:`convert_raw` turns it into joint angles with
the robot's sign conventions (:mod:`bemlearn.apps.biped.model`, rotations about +y, a link's
pitch φ taken so that +φ tips an upward link's far end towards +x):

    trunk  q_1 = atan2(x_SHO − x_GTRO, y_SHO − y_GTRO)            (shoulder–trochanter vs vertical)
    thigh  φ_t = atan2(−(x_LEK − x_GTRO), −(y_LEK − y_GTRO))      (downward link)
    shank  φ_s = atan2(−(x_LM − x_LEK), −(y_LM − y_LEK))
    hip    q_hip = φ_t − q_1,   knee  q_knee = φ_s − φ_t           (knee flexion > 0)

Marker drop-outs (NaN) of at most ``max_gap`` samples are filled by linear interpolation
and flagged per row (``interpolated``); longer gaps are an error.  The shipped CSV
(``data/human_gait/human_gait_right.csv``) is produced by ``scripts/convert_human_gait.py``.

Only the right side was measured.  **Assumption** (documented, as the paper's
transfer needs both legs): the left leg moves like the right one shifted by half a gait
cycle.  One robot step (single support of the paper's n = 5 model, leg 1 = stance) is
then half a cycle: the stance leg is the right leg over cycle phase [0, ½] after its heel
strike, the swing leg the right leg over [½, 1].

The paper maps the human angles linearly into the walker's joint ranges
(:class:`JointRangeMap`, :func:`fit_joint_range_map`): q_robot = a q_human + b per joint
type (hips share one map, knees another, so both legs stay alike).
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bemlearn.errors import ArgumentError, DataError, MissingFileError, TrajectoryFormatError

__all__ = [
    "HUMAN_GAIT_CSV",
    "RAW_COLUMNS",
    "CSV_COLUMNS",
    "HumanGait",
    "HumanGaitConfig",
    "JointRangeMap",
    "convert_raw",
    "format_csv",
    "load_human_gait",
    "fit_joint_range_map",
    "human_step_profile",
]

log = logging.getLogger(__name__)

#: The shipped converted dataset (present in a source checkout).
HUMAN_GAIT_CSV = Path(__file__).resolve().parents[2] / "examples" / "data" / "human_gait" / "human_gait_right.csv"
#: Marker / force columns read from the raw file.
RAW_COLUMNS = ("RSHO.PosX", "RSHO.PosY", "RGTRO.PosX", "RGTRO.PosY", "RLEK.PosX", "RLEK.PosY",
               "RLM.PosX", "RLM.PosY", "FP2.ForY")
#: Columns of the converted CSV: s, rad, rad, rad, N, 0/1.
CSV_COLUMNS = ("t", "trunk", "hip", "knee", "grf_y", "interpolated")
_MAGIC = "# bemlearn human gait v1"


def _parse_raw(text: str, source: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    lines = text.splitlines()
    if not lines or not lines[0].startswith("%"):
        raise TrajectoryFormatError(f"{source}: line 1: expected a '%'-prefixed header of column names")
    names = lines[0].lstrip("%").split()
    if not names or names[0] != "TimeStamp":
        raise TrajectoryFormatError(f"{source}: line 1: first column must be 'TimeStamp', got {names[:1]}")
    missing = [c for c in RAW_COLUMNS if c not in names]
    if missing:
        raise TrajectoryFormatError(f"{source}: line 1: missing column(s) {missing}; found {names}")
    rows = []
    for i, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        fields = line.split()
        if len(fields) != len(names):
            raise TrajectoryFormatError(f"{source}: line {i}: {len(fields)} fields, expected {len(names)}")
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            raise TrajectoryFormatError(f"{source}: line {i}: a field is not a number: {line.strip()[:80]!r}") from None
    table = np.asarray(rows, dtype=np.float64)
    if table.shape[0] < 2:
        raise TrajectoryFormatError(f"{source}: fewer than two data rows")
    t = table[:, 0]
    if not np.all(np.isfinite(t)) or not np.all(np.diff(t) > 0):
        raise TrajectoryFormatError(f"{source}: column 'TimeStamp' must be finite and strictly increasing")
    return t, {c: table[:, names.index(c)] for c in RAW_COLUMNS}


def _fill_gaps(x: np.ndarray, *, max_gap: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    bad = ~np.isfinite(x)
    if not bad.any():
        return x.copy(), bad
    idx = np.flatnonzero(bad)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    for r in runs:
        if r[0] == 0 or r[-1] == len(x) - 1:
            raise TrajectoryFormatError(f"{where}: missing values at the start/end (rows {r[0]}..{r[-1]}) cannot be interpolated")
        if len(r) > max_gap:
            raise TrajectoryFormatError(f"{where}: gap of {len(r)} samples at rows {r[0]}..{r[-1]} exceeds max_gap = {max_gap}")
    good = np.flatnonzero(~bad)
    out = x.copy()
    out[bad] = np.interp(idx, good, x[good])
    return out, bad


def convert_raw(text: str, *, source: str = "<raw>", max_gap: int = 5) -> np.ndarray:
    """Raw marker text → table ``(T, 6)`` with columns :data:`CSV_COLUMNS` (module docstring).

    Raises:
        ValueError: naming ``source``, the line or column, for a malformed file or a gap
            longer than ``max_gap`` samples.
    """
    t, cols = _parse_raw(text, source)
    filled, flag = {}, np.zeros(len(t), dtype=bool)
    for c in RAW_COLUMNS:
        filled[c], bad = _fill_gaps(cols[c], max_gap=max_gap, where=f"{source}: column {c!r}")
        flag |= bad
        if bad.any():
            log.info("%s: column %s: %d missing sample(s) interpolated", source, c, int(bad.sum()))
    p = {m: np.stack([filled[f"{m}.PosX"], filled[f"{m}.PosY"]], 1) for m in ("RSHO", "RGTRO", "RLEK", "RLM")}
    up = p["RSHO"] - p["RGTRO"]
    thigh = p["RLEK"] - p["RGTRO"]
    shank = p["RLM"] - p["RLEK"]
    trunk = np.arctan2(up[:, 0], up[:, 1])
    phi_t = np.arctan2(-thigh[:, 0], -thigh[:, 1])
    phi_s = np.arctan2(-shank[:, 0], -shank[:, 1])
    return np.stack([t, trunk, phi_t - trunk, phi_s - phi_t, filled["FP2.ForY"], flag.astype(np.float64)], 1)


def format_csv(table: np.ndarray, *, provenance: str) -> str:
    """Deterministic CSV text of a :func:`convert_raw` table (angles to 1e-7 rad)."""
    lines = [_MAGIC, f"# {provenance}", ",".join(CSV_COLUMNS)]
    for r in table:
        lines.append(f"{r[0]:.2f},{r[1]:.7f},{r[2]:.7f},{r[3]:.7f},{r[4]:.5f},{int(r[5])}")
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class HumanGait:
    """The converted right-side recording.

    Attributes:
        t: (T,) time, s.  trunk, hip, knee: (T,) rad (robot conventions, module docstring).
        grf_y: (T,) vertical force under the right foot, N.  interpolated: (T,) bool.
        source: file it was read from.
    """

    t: np.ndarray
    trunk: np.ndarray
    hip: np.ndarray
    knee: np.ndarray
    grf_y: np.ndarray
    interpolated: np.ndarray
    source: str = "<memory>"

    def heel_strikes(self, *, threshold: float = 20.0) -> np.ndarray:
        """Times (s) where the right foot's vertical force rises through ``threshold`` N (linear interpolation)."""
        f = self.grf_y - threshold
        k = np.flatnonzero((f[:-1] < 0) & (f[1:] >= 0))
        return self.t[k] + (self.t[k + 1] - self.t[k]) * (-f[k]) / (f[k + 1] - f[k])

    def mean_cycle(self, n: int = 100, *, threshold: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
        """The right leg's gait cycle averaged over all complete cycles.

        Returns:
            ``phase (n,)`` in [0, 1) from right heel strike and ``angles (n, 3)`` rad,
            columns [trunk, hip, knee].
        """
        hs = self.heel_strikes(threshold=threshold)
        if len(hs) < 2:
            raise DataError(f"{self.source}: need two right heel strikes for a gait cycle, found {len(hs)}")
        phase = np.arange(n) / n
        ang = np.stack([self.trunk, self.hip, self.knee], 1)
        cycles = [np.stack([np.interp(a + phase * (b - a), self.t, ang[:, j]) for j in range(3)], 1)
                  for a, b in itertools.pairwise(hs)]
        return phase, np.mean(cycles, axis=0)

    def cycle_period(self, *, threshold: float = 20.0) -> float:
        """Mean time between right heel strikes, s."""
        return float(np.mean(np.diff(self.heel_strikes(threshold=threshold))))

    def step_profile(self, n: int = 51, *, threshold: float = 20.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One step (half a cycle) in the stance-relative order of the pinned model.

        Returns:
            ``s (n,)`` in [0, 1], ``qa (n, 4)`` rad, columns [stance hip, stance knee, swing
            hip, swing knee] (right leg over cycle phase [0, ½] as stance, over [½, 1] as
            swing: the half-cycle assumption), and ``trunk (n,)`` rad.
        """
        phase, ang = self.mean_cycle(400, threshold=threshold)
        def wrap(p: np.ndarray, j: int) -> np.ndarray:
            return np.interp(p, np.r_[phase, 1.0], np.r_[ang[:, j], ang[0, j]])

        s = np.linspace(0.0, 1.0, n)
        qa = np.stack([wrap(s / 2, 1), wrap(s / 2, 2), wrap(0.5 + s / 2, 1), wrap(0.5 + s / 2, 2)], 1)
        return s, qa, wrap(s / 2, 0)


def load_human_gait(path: str | Path | None = None) -> HumanGait:
    """Read the converted CSV (default: the shipped :data:`HUMAN_GAIT_CSV`).

    Raises:
        MissingFileError: (a FileNotFoundError) no such file.
        TrajectoryFormatError: (a ValueError) a malformed file (naming line and column).
    """
    path = Path(path) if path is not None else HUMAN_GAIT_CSV
    if not path.is_file():
        raise MissingFileError(f"{path}: human gait CSV not found (run scripts/convert_human_gait.py)")
    lines = path.read_text(encoding="utf-8").splitlines()
    if not lines or lines[0] != _MAGIC:
        raise TrajectoryFormatError(f"{path}: line 1: expected {_MAGIC!r}")
    header_at = next((i for i, ln in enumerate(lines) if not ln.startswith("#")), None)
    if header_at is None or lines[header_at].split(",") != list(CSV_COLUMNS):
        raise TrajectoryFormatError(f"{path}: expected the header {','.join(CSV_COLUMNS)}")
    body = lines[header_at + 1:]
    try:
        table = np.loadtxt(body, delimiter=",", dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise TrajectoryFormatError(f"{path}: data rows from line {header_at + 2}: {exc}") from None
    if table.shape[1] != len(CSV_COLUMNS):
        raise TrajectoryFormatError(f"{path}: expected {len(CSV_COLUMNS)} columns, got {table.shape[1]}")
    bad = np.argwhere(~np.isfinite(table))
    if len(bad):
        r, c = bad[0]
        raise TrajectoryFormatError(f"{path}: line {header_at + 2 + r}, column {CSV_COLUMNS[c]!r}: non-finite value")
    return HumanGait(table[:, 0], table[:, 1], table[:, 2], table[:, 3], table[:, 4], interpolated=table[:, 5] != 0, source=str(path))


@dataclass(frozen=True)
class JointRangeMap:
    """q_robot = scale · q_human + offset, one map for both hips and one for both knees."""

    hip_scale: float
    hip_offset: float
    knee_scale: float
    knee_offset: float

    def apply(self, qa: np.ndarray) -> np.ndarray:
        """``qa (..., 4)`` rad [hip, knee, hip, knee] → robot angles, same shape."""
        a = np.array([self.hip_scale, self.knee_scale] * 2)
        b = np.array([self.hip_offset, self.knee_offset] * 2)
        return np.asarray(qa) * a + b


def fit_joint_range_map(
    qa: np.ndarray, *, hip_range: tuple[float, float], knee_range: tuple[float, float]
) -> JointRangeMap:
    """The affine map taking the human hip / knee ranges (over both legs) onto the targets.

    Args:
        qa: ``(n, 4)`` human step profile, rad, columns [hip, knee, hip, knee].
        hip_range, knee_range: target ``(lo, hi)`` of the robot joints, rad.
    """
    qa = np.asarray(qa, dtype=np.float64)
    if qa.ndim != 2 or qa.shape[1] != 4:
        raise ArgumentError(f"fit_joint_range_map: qa must have shape (n, 4), got {qa.shape}")
    out = []
    for cols, (lo, hi), name in (((0, 2), hip_range, "hip_range"), ((1, 3), knee_range, "knee_range")):
        if not lo < hi:
            raise ArgumentError(f"fit_joint_range_map: {name} must satisfy lo < hi, got {(lo, hi)}")
        x = qa[:, cols]
        span = float(x.max() - x.min())
        if span <= 0:
            raise DataError(f"fit_joint_range_map: the human {name.split('_')[0]} angle is constant")
        a = (hi - lo) / span
        out += [a, lo - a * float(x.min())]
    return JointRangeMap(*out)


@dataclass(frozen=True)
class HumanGaitConfig:
    """Where the human gait comes from and how it is mapped onto the robot.

    Attributes:
        path: converted CSV (``null``: the shipped file).
        hip_range: target range of the robot hips, rad.
        knee_range: target range of the robot knees, rad (knee flexion > 0).
        samples: points of the step profile the gait is fitted to.
        heel_strike_threshold: vertical force defining right heel strike, N.
    """

    path: str | None = None
    hip_range: tuple[float, float] = (-0.3, 0.05)
    knee_range: tuple[float, float] = (0.1, 0.9)
    samples: int = 101
    heel_strike_threshold: float = 20.0


def human_step_profile(config: HumanGaitConfig = HumanGaitConfig()) -> tuple[np.ndarray, np.ndarray, JointRangeMap]:
    """The human step mapped into the robot's joint ranges.

    Returns:
        ``s (n,)``, ``qa (n, 4)`` robot angles (rad, stance-relative order) and the map used.
    """
    gait = load_human_gait(config.path)
    s, qa, _ = gait.step_profile(config.samples, threshold=config.heel_strike_threshold)
    jmap = fit_joint_range_map(qa, hip_range=config.hip_range, knee_range=config.knee_range)
    return s, jmap.apply(qa), jmap
