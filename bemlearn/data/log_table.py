"""One logger CSV file: its header and the columns an :class:`ImportMap` names, read fast.

A file is optional comment lines (starting with ``imap.comment``), one header line and one
row per sample.  The named columns are parsed by NumPy's C reader (``np.loadtxt`` with
``usecols``: about 0.5 s per 10⁶ rows × 9 columns here); only when that fails is the file
scanned row by row, to name the first bad cell.  A byte-order mark, CRLF line ends,
quoted header names and spaces around fields are accepted.  Errors name the file, the
column (and the map key naming it) and the row: the 0-based data row and the 1-based file
line (blank and comment lines are not rows).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bemlearn.data.import_map import ImportMap
from bemlearn.data.trajectory import TrajectoryFormatError

__all__ = ["LogTable", "check_finite", "read_log_table"]


@dataclass(frozen=True)
class LogTable:
    """The mapped columns of one logger file.

    Attributes:
        path: the file.
        columns: column name → (R,) float64 raw values (as written, before unit conversion).
        header_line: 1-based file line of the header.
        comment: the comment prefix of the file's map.
    """

    path: Path
    columns: dict[str, np.ndarray]
    header_line: int
    comment: str = "#"

    @property
    def n_rows(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def where(self, column: str, row: int) -> str:
        """``"<file>: column '<c>', row <r> (line <l>)"`` for error messages."""
        return f"{self.path}: column {column!r}, row {row} (line {_data_lines(self.path, self.header_line, self.comment)[row]})"


def _split(line: str, delimiter: str) -> list[str]:
    line = line.lstrip("\ufeff")  # a byte-order mark some tools write before the header
    return [f.strip().strip('"').strip("'").strip() for f in line.rstrip("\r\n").split(delimiter)]


def _is_skipped(line: str, comment: str) -> bool:
    s = line.strip()
    return not s or (bool(comment) and s.startswith(comment))


def _data_lines(path: Path, header_line: int, comment: str) -> np.ndarray:
    """1-based file line of each data row (blank and comment lines are not rows)."""
    lines = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for n, line in enumerate(fh, start=1):
            if n > header_line and not _is_skipped(line, comment):
                lines.append(n)
    return np.asarray(lines, dtype=np.int64)


def _header(path: Path, imap: ImportMap) -> tuple[list[str], int]:
    with open(path, encoding="utf-8", errors="replace") as fh:
        for n, line in enumerate(fh, start=1):
            if not _is_skipped(line, imap.comment):
                return _split(line, imap.delimiter), n
    raise TrajectoryFormatError(f"{path}: no header line (the file is empty or holds only comments)")


def read_log_table(path: str | Path, imap: ImportMap) -> LogTable:
    """Read the columns ``imap`` names from one logger file (module docstring).

    Raises:
        FileNotFoundError: no such file.
        TrajectoryFormatError: a missing or duplicated column, a non-numeric or missing cell,
            naming the file, the column (and its map key) and the row / line.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: log file not found")
    header, header_line = _header(path, imap)
    wanted = imap.columns()
    index: dict[str, int] = {}
    for col, key in wanted.items():
        hits = [i for i, h in enumerate(header) if h == col]
        if not hits:
            raise TrajectoryFormatError(
                f"{path}: line {header_line}: column {col!r} (map key {key}) is not in the header {header}"
            )
        if len(hits) > 1:
            raise TrajectoryFormatError(f"{path}: line {header_line}: column {col!r} (map key {key}) appears {len(hits)} times")
        index[col] = hits[0]
    names = list(index)
    usecols = [index[c] for c in names]
    try:
        table = np.loadtxt(
            path, delimiter=imap.delimiter, comments=imap.comment or None, skiprows=header_line,
            usecols=usecols, ndmin=2, dtype=np.float64, encoding="utf-8",
        )
    except ValueError:
        _scan_for_bad_cell(path, imap, header, header_line, names, usecols)
        raise  # pragma: no cover - the scan raises
    if table.shape[0] == 0:
        raise TrajectoryFormatError(f"{path}: no data rows after the header (line {header_line})")
    columns = {c: np.ascontiguousarray(table[:, j]) for j, c in enumerate(names)}
    return LogTable(path=path, columns=columns, header_line=header_line, comment=imap.comment)


def _scan_for_bad_cell(
    path: Path, imap: ImportMap, header: list[str], header_line: int, names: list[str], usecols: list[int]
) -> None:
    row = 0
    need = max(usecols) + 1
    with open(path, encoding="utf-8", errors="replace") as fh:
        for n, line in enumerate(fh, start=1):
            if n <= header_line or _is_skipped(line, imap.comment):
                continue
            fields = _split(line, imap.delimiter)
            if len(fields) < need:
                raise TrajectoryFormatError(
                    f"{path}: row {row} (line {n}): {len(fields)} fields, the header has {len(header)} "
                    f"(column {header[len(fields)]!r} is missing)"
                )
            for c, i in zip(names, usecols):
                try:
                    float(fields[i])
                except ValueError:
                    what = "an empty cell" if not fields[i] else f"{fields[i]!r} is not a number"
                    raise TrajectoryFormatError(f"{path}: column {c!r}, row {row} (line {n}): {what}") from None
            row += 1
    raise TrajectoryFormatError(f"{path}: could not parse the data rows")  # pragma: no cover


def check_finite(table: LogTable, cols: Sequence[str]) -> None:
    """Raise naming the first non-finite value of ``cols`` (file, column, row, line)."""
    for c in cols:
        bad = np.flatnonzero(~np.isfinite(table.columns[c]))
        if len(bad):
            raise TrajectoryFormatError(f"{table.where(c, int(bad[0]))}: non-finite value {float(table.columns[c][bad[0]])!r}")


