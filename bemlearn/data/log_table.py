"""One logger file: its column names and the columns an :class:`ImportMap` names, read fast.

A file is optional comment lines (starting with ``imap.comment``), one header line (unless
the map says ``header: false`` and names the columns by ``columns:``) and one row per
sample.  Fields are separated by the map's ``delimiter``; without one it is detected from the
file's first two lines (:func:`detect_delimiter`: comma, semicolon, tab or whitespace, the
one that splits them into the same number of numeric fields).  Every line must have as many
fields as the header (or ``columns:``) names.

The named columns are parsed by NumPy's C reader (``np.loadtxt`` with ``usecols``; import
speed: ``bemlearn bench import``); the field counts are checked by counting delimiters over the
whole file, and only when a count or a cell is wrong is the file scanned row by
row, to name the first bad line.  A byte-order mark, CRLF line ends, quoted header names and
spaces around fields are accepted.

A last line without a line end whose field count differs from the file's, whose last field
is not a number, or whose last field has other digits than that column's previous lines
(all printed alike) was cut mid-write: it is not imported, and is named in a warning and in
:attr:`LogTable.cut_line`.

Errors name the file, the column (and the map key naming it) and the row: the 0-based data
row and the 1-based file line (blank and comment lines are not rows), and the map key that
fixes the problem where there is one.
"""

from __future__ import annotations

import difflib
import io
import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bemlearn.data.import_map import DELIMITERS, WHITESPACE, ImportMap, delimiter_name
from bemlearn.data.text_extent import text_extent
from bemlearn.data.trajectory import TrajectoryFormatError
from bemlearn.errors import MissingFileError
from bemlearn.warnings import DataWarning, warn

__all__ = ["LogTable", "check_finite", "detect_delimiter", "read_log_table"]

logger = logging.getLogger(__name__)

#: Lines before a cut last line whose last field's digits it is compared with.
_SHAPE_LINES = 20


@dataclass(frozen=True)
class LogTable:
    """The mapped columns of one logger file.

    Attributes:
        path: the file.
        columns: column name → (R,) float64 raw values (as written, before unit conversion).
        header_line: 1-based file line of the header (0: the file has no header line).
        comment: the comment prefix of the file's map.
        delimiter: the field separator used (the map's, or detected): ``","``, ``";"``,
            ``"\\t"``, … or ``"whitespace"``.
        cut_line: ``None``, or the last line that was left out because it was cut mid-write:
            ``{"line": 1-based line, "reason": text, "text": its first 80 characters}``.
        window: ``None`` (every row is imported), or (R,) bool: the rows inside the map's time
            window (``time.window``, ``windows``), set by the import.
    """

    path: Path
    columns: dict[str, np.ndarray]
    header_line: int
    comment: str = "#"
    delimiter: str = ","
    cut_line: dict | None = None
    window: np.ndarray | None = None

    @property
    def n_rows(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def where(self, column: str, row: int) -> str:
        """``"<file>: column '<c>', row <r> (line <l>)"`` for error messages."""
        return f"{self.path}: column {column!r}, row {row} (line {_data_lines(self.path, self.header_line, self.comment)[row]})"


def _split(line: str, delimiter: str) -> list[str]:
    line = line.lstrip("\ufeff")  # a byte-order mark some tools write before the header
    if delimiter == WHITESPACE:
        return [f.strip('"').strip("'") for f in line.split()]
    return [f.strip().strip('"').strip("'").strip() for f in line.rstrip("\r\n").split(delimiter)]


def _is_skipped(line: str, comment: str) -> bool:
    s = line.strip().lstrip("\ufeff")
    return not s or (bool(comment) and s.startswith(comment))


def _uncomment(line: str, comment: str) -> str:
    """The line without a trailing comment (as ``np.loadtxt`` reads it)."""
    return line.split(comment, 1)[0] if comment else line


def _data_lines(path: Path, header_line: int, comment: str) -> np.ndarray:
    """1-based file line of each data row (blank and comment lines are not rows)."""
    lines = []
    n_text, _ = text_extent(path)
    with open(path, "rb") as fh:
        text = fh.read(n_text).decode("utf-8", errors="replace")
    for n, line in enumerate(io.StringIO(text, newline=None), start=1):   # universal newlines, as open() reads

        if n > header_line and not _is_skipped(line, comment):
            lines.append(n)
    return np.asarray(lines, dtype=np.int64)


def _is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


def _first_lines(raw: bytes, comment: str, count: int) -> list[tuple[int, str, int, int]]:
    """The first ``count`` lines that are neither blank nor comments: (1-based line, text, byte offsets of its start and end)."""
    out: list[tuple[int, str, int, int]] = []
    pos, n = 0, 0
    while pos < len(raw) and len(out) < count:
        end = raw.find(b"\n", pos)
        stop = len(raw) if end < 0 else end + 1
        n += 1
        text = raw[pos:stop].decode("utf-8", errors="replace")
        if not _is_skipped(text, comment):
            out.append((n, text.rstrip("\r\n"), pos, stop))
        pos = stop
    return out


def detect_delimiter(path: Path | str, lines: Sequence[str], *, header: bool, first_line: int = 1) -> str:
    """The field separator of a file from its first (non-comment) lines.

    Each of comma, semicolon, tab and whitespace (:data:`~bemlearn.data.import_map.DELIMITERS`)
    is tried: it fits when it splits every line into the same number (≥ 2) of fields and
    every field of the data lines (all lines when ``header`` is false, all but the first
    otherwise) is a number.  Tab and whitespace splitting alike count as one (tab).  When
    none fits, the one separator that splits the lines into the same number of fields is
    taken (a first data line that is not numbers then fails to parse, naming its cell).

    Args:
        path: the file (for messages).
        lines: its first lines that are neither blank nor comments (one or two).
        header: whether the first of them is the header line.
        first_line: 1-based file line of ``lines[0]`` (for messages).

    Raises:
        TrajectoryFormatError: none fits, or more than one does (naming the file and the
            candidates, and the map key ``delimiter``).
    """
    fits: dict[str, list[list[str]]] = {}
    data = lines[1:] if header and len(lines) > 1 else lines if not header else []
    for cand in DELIMITERS:
        split = [_split(line, cand) for line in lines]
        if len(split[0]) < 2 or any(len(f) != len(split[0]) for f in split):
            continue
        if any(not _is_number(f) for line in data for f in _split(line, cand)):
            continue
        fits[cand] = split
    if "\t" in fits and fits.get(WHITESPACE) == fits["\t"]:
        del fits[WHITESPACE]
    if len(fits) == 1:
        return next(iter(fits))
    shown = f"line {first_line} ({lines[0][:80]!r})"
    if not fits and not header and len(lines) > 1:
        try:
            found = detect_delimiter(path, lines, header=True, first_line=first_line)
        except TrajectoryFormatError:
            found = None
        if found is not None:
            raise TrajectoryFormatError(
                f"{path}: line {first_line} ({lines[0][:80]!r}) is not numbers, yet the map says header: false: if it "
                f"is the header, set header: true (columns: then renames its fields); if it is a preamble, mark it "
                f"with comment:"
            )
    if not fits:  # a first data line that is not numbers (a units row?): the one separator that splits alike
        loose = {c: [_split(line, c) for line in lines] for c in DELIMITERS}
        loose = {c: f for c, f in loose.items() if len(f[0]) >= 2 and all(len(x) == len(f[0]) for x in f)}
        if "\t" in loose and loose.get(WHITESPACE) == loose["\t"]:
            del loose[WHITESPACE]
        if len(loose) == 1 and len(lines) > 1:
            return next(iter(loose))
        raise TrajectoryFormatError(
            f"{path}: cannot tell how the fields are separated: neither comma, semicolon, tab nor whitespace splits "
            f"{shown}{' and the line after it' if len(lines) > 1 else ''} into the same number (≥ 2) of "
            f"{'numeric ' if data else ''}fields; set delimiter: in the map"
            + ("" if header else " (and check header: false: the first line is read as data)")
        )
    names = " and ".join(delimiter_name(c) for c in fits)
    raise TrajectoryFormatError(
        f"{path}: the field separator is ambiguous: {names} each split {shown} into numeric fields; "
        f"set delimiter: in the map (e.g. delimiter: {next(iter(fits))!r})"
    )


def _fields(n: int) -> str:
    return f"{n} field{'' if n == 1 else 's'}"


def _yaml_delimiter(delimiter: str) -> str:
    """How to write ``delimiter`` in the map: ``','``, ``"\\t"``, ``whitespace``."""
    return {"\t": '"\\t"', WHITESPACE: WHITESPACE}.get(delimiter, repr(delimiter))


def _delimiter_hint(line: str, used: str, want: int | None) -> str:
    """``"; it splits into k fields at tab: set delimiter: …"`` when another delimiter fits ``line`` (else "")."""
    for cand in DELIMITERS:
        k = len(_split(line, cand))
        if cand != used and k >= 2 and (want is None or k == want):
            return (f"; the line splits into {_fields(k)} at {delimiter_name(cand)}, not at {delimiter_name(used)}: "
                    f"set delimiter: {_yaml_delimiter(cand)} in the map")
    return ""


def _shape(field: str) -> tuple[int, int]:
    """(decimals, exponent digits) of a printed number, −1 where there is no '.' or exponent."""
    m = re.fullmatch(r"[+-]?(\d*)(?:\.(\d*))?(?:[eE][+-]?(\d*))?", field.strip())
    if m is None:
        return (-2, -2)
    return (-1 if m.group(2) is None else len(m.group(2)), -1 if m.group(3) is None else len(m.group(3)))


def _previous_lines(raw: bytes, before: int, comment: str, count: int, stop_at: int) -> list[str]:
    """Up to ``count`` non-skipped lines ending before byte ``before``, not before byte ``stop_at``."""
    out: list[str] = []
    end = before
    while end > stop_at and len(out) < count:
        start = raw.rfind(b"\n", stop_at, end - 1) + 1
        start = max(start, stop_at)
        text = raw[start:end].decode("utf-8", errors="replace")
        if not _is_skipped(text, comment):
            out.append(text.rstrip("\r\n"))
        end = start
    return out


def _cut_last_line(raw: bytes, data_start: int, imap: ImportMap, delimiter: str, n_fields: int,
                   names: list[str]) -> tuple[int, dict] | None:
    """(byte offset of the last line, description) when the file ends in a line cut mid-write, else ``None``."""
    if raw.endswith(b"\n") or len(raw) <= data_start:
        return None
    start = max(raw.rfind(b"\n", data_start) + 1, data_start)
    text = raw[start:].decode("utf-8", errors="replace")
    if _is_skipped(text, imap.comment) or start == data_start:
        return None  # a comment, or the only data line: nothing to compare it with
    fields = _split(_uncomment(text, imap.comment), delimiter)
    line = raw.count(b"\n", 0, start) + 1
    reason = None
    if len(fields) != n_fields:
        reason = f"{len(fields)} of {n_fields} fields"
    elif not _is_number(fields[-1]):
        reason = f"its last field {fields[-1]!r} is not a number"
    else:
        before = [_split(_uncomment(p, imap.comment), delimiter) for p in
                  _previous_lines(raw, start, imap.comment, _SHAPE_LINES, data_start)]
        shapes = {_shape(f[-1]) for f in before if len(f) == n_fields}
        if len(shapes) == 1 and _shape(fields[-1]) != next(iter(shapes)):
            reason = (f"its last field {fields[-1]!r} (column {names[-1]!r}) is printed with other digits than on "
                      f"the lines before it ({before[0][-1]!r})")
    if reason is None:
        return None
    return start, {"line": line, "reason": reason, "text": text[:80]}


def _count_ok(raw: bytes, start: int, stop: int, delimiter: str, n_fields: int, comment: str) -> bool:
    """Fast check that every line of ``raw[start:stop]`` has ``n_fields`` fields (False: scan to find out)."""
    if start >= stop:
        return True
    if comment and raw.find(comment.encode(), start, stop) >= 0:
        return False
    n_lines = raw.count(b"\n", start, stop) + (0 if raw[stop - 1:stop] == b"\n" else 1)
    if delimiter == WHITESPACE:
        if raw.count(b" ", start, stop) + raw.count(b"\t", start, stop) == n_lines * (n_fields - 1):
            return True
        return len(raw[start:stop].split()) == n_lines * n_fields
    return raw.count(delimiter.encode(), start, stop) == n_lines * (n_fields - 1)


def _where_names(imap: ImportMap, header_line: int, n_fields: int) -> str:
    if imap.header and imap.columns is None:
        return f"the header (line {header_line}) has {n_fields}"
    return f"the map's columns: names {n_fields}"


def _check_field_counts(path: Path, raw: bytes, start: int, stop: int, imap: ImportMap, delimiter: str,
                        n_fields: int, header_line: int, first_data_line: int) -> None:
    """Raise naming the first line in ``raw[start:stop]`` whose field count is not ``n_fields``."""
    if _count_ok(raw, start, stop, delimiter, n_fields, imap.comment):
        return
    text = raw[start:stop].decode("utf-8", errors="replace")
    row = 0
    for n, line in enumerate(text.split("\n"), start=first_data_line):
        if _is_skipped(line, imap.comment):
            continue
        fields = _split(_uncomment(line, imap.comment), delimiter)
        if len(fields) != n_fields:
            hint = _delimiter_hint(_uncomment(line, imap.comment), delimiter, n_fields)
            if not hint and imap.delimiter is None and row == 0:
                hint = f"; the fields were split at {delimiter_name(delimiter)} (detected): set delimiter: if that is wrong"
            raise TrajectoryFormatError(
                f"{path}: row {row} (line {n}): {_fields(len(fields))}, {_where_names(imap, header_line, n_fields)}{hint}"
            )
        row += 1


def _column_hint(col: str, header: list[str], header_text: str, delimiter: str) -> str:
    """What to change in the map when ``col`` is not among the header's names."""
    if header and all(_is_number(h) for h in header):
        return (f"; line {{line}} is data, not a header (all {len(header)} fields are numbers): set header: false "
                f"and columns: [name, …] naming the file's {len(header)} columns in order")
    if len(header) == 1:
        return _delimiter_hint(header_text, delimiter, None) or (
            f"; the header line has a single field (split at {delimiter_name(delimiter)}): set delimiter:")
    close = difflib.get_close_matches(col, header, n=1, cutoff=0.6)
    folded = [h for h in header if h.lower() == col.lower()]
    if folded or close:
        return f"; did you mean {(folded or close)[0]!r}?"
    return ""


def read_log_table(path: str | Path, imap: ImportMap) -> LogTable:
    """Read the columns ``imap`` names from one logger file (module docstring).

    Raises:
        MissingFileError: (a FileNotFoundError) no such file.
        TrajectoryFormatError: a missing or duplicated column, a line with another field
            count, a non-numeric or missing cell, naming the file, the column (and its map
            key) and the row / line, and the map key that fixes it where one does.
    """
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"{path}: log file not found")
    n_text, size = text_extent(path, what="a text log")   # binary files refused before anything is read
    if n_text < size:
        warn(DataWarning, logger, "%s: %d NUL bytes after byte %d (padding a logger left): not imported", path, size - n_text, n_text)
    with open(path, "rb") as fh:
        raw = fh.read(n_text)
    first = _first_lines(raw, imap.comment, 2)
    if not first:
        raise TrajectoryFormatError(
            f"{path}: no {'header line' if imap.header else 'data'} (the file is empty or holds only comments)"
        )
    delimiter = imap.delimiter or detect_delimiter(path, [f[1] for f in first], header=imap.header,
                                                   first_line=first[0][0])
    if imap.header:
        header_line, header_text, _, data_start = first[0]
        header = _split(header_text, delimiter)
        first_data_line = header_line + 1
    else:  # the data start at the first line that is not a comment
        header_line, header, data_start, first_data_line = 0, list(imap.columns or ()), first[0][2], first[0][0]
        header_text = ""
    names = list(header)
    if imap.columns is not None:
        if imap.header and len(header) != len(imap.columns):
            raise TrajectoryFormatError(
                f"{path}: line {header_line}: the header has {len(header)} fields ({header}) and the map's columns: "
                f"names {len(imap.columns)}: give one name per field, in order"
            )
        names = list(imap.columns)
    wanted = imap.used_columns()
    index: dict[str, int] = {}
    for col, key in wanted.items():
        hits = [i for i, h in enumerate(names) if h == col]
        if not hits:
            hint = _column_hint(col, header, header_text, delimiter).replace("{line}", str(header_line))
            raise TrajectoryFormatError(
                f"{path}: line {header_line}: column {col!r} (map key {key}) is not in the header {header}{hint}"
            )
        if len(hits) > 1:
            raise TrajectoryFormatError(
                f"{path}: line {header_line}: column {col!r} (map key {key}) appears {len(hits)} times; name the columns "
                f"with columns: [name, …] (one per field, in order) to tell them apart"
            )
        index[col] = hits[0]
    n_fields = len(names)
    if imap.header and len(first) < 2:
        raise TrajectoryFormatError(f"{path}: no data rows after the header (line {header_line})")
    if not imap.header:
        line = _uncomment(first[0][1], imap.comment)
        got = len(_split(line, delimiter))
        if got != n_fields:
            raise TrajectoryFormatError(
                f"{path}: row 0 (line {first[0][0]}): {_fields(got)}, but the map's columns: names {n_fields} "
                f"({list(imap.columns or ())})"
                + (_delimiter_hint(line, delimiter, n_fields) or ": give one name per field, in order")
            )
    cut = _cut_last_line(raw, data_start, imap, delimiter, n_fields, names)
    stop = len(raw) if cut is None else cut[0]
    cut_info = None
    if cut is not None:
        cut_info = cut[1]
        warn(DataWarning, logger, "%s: line %d, the last (no line end), looks cut mid-write (%s): not imported",
                                  path, cut_info["line"], cut_info["reason"])
    _check_field_counts(path, raw, data_start, stop, imap, delimiter, n_fields, header_line, first_data_line)
    names_used = list(index)
    usecols = [index[c] for c in names_used]
    bom_data = not imap.header and raw.startswith(b"\xef\xbb\xbf")
    source: Any = path  # a path or the cleaned text
    if cut is not None or bom_data or n_text < size:
        source = io.StringIO(raw[:stop].decode("utf-8", errors="replace").lstrip("\ufeff"))
    try:
        table = np.loadtxt(
            source, delimiter=None if delimiter == WHITESPACE else delimiter, comments=imap.comment or None,
            skiprows=header_line, usecols=usecols, ndmin=2, dtype=np.float64, encoding="utf-8",
        )
    except ValueError:
        _scan_for_bad_cell(path, raw[:stop], imap, delimiter, header_line, names_used, usecols)
        raise  # pragma: no cover - the scan raises
    if table.shape[0] == 0:
        raise TrajectoryFormatError(f"{path}: no data rows after the header (line {header_line})")
    columns = {c: np.ascontiguousarray(table[:, j]) for j, c in enumerate(names_used)}
    return LogTable(path=path, columns=columns, header_line=header_line, comment=imap.comment,
                    delimiter=delimiter, cut_line=cut_info)


def _scan_for_bad_cell(path: Path, raw: bytes, imap: ImportMap, delimiter: str, header_line: int,
                       names: list[str], usecols: list[int]) -> None:
    row = 0
    text = raw.decode("utf-8", errors="replace")
    for n, line in enumerate(text.split("\n"), start=1):
        if n <= header_line or _is_skipped(line, imap.comment):
            continue
        fields = _split(_uncomment(line, imap.comment), delimiter)
        for c, i in zip(names, usecols):
            try:
                float(fields[i])
            except (ValueError, IndexError):
                what = "an empty cell" if i < len(fields) and not fields[i] else (
                    f"{fields[i]!r} is not a number" if i < len(fields) else "the field is missing")
                hint = ""
                if i < len(fields) and "," in fields[i] and delimiter != "," and _is_number(fields[i].replace(",", ".")):
                    hint = " (a decimal comma: write the file with decimal points)"
                elif not imap.header and row == 0:
                    hint = " (header: false, yet the first line is not data: set header: true, or comment: for a preamble)"
                raise TrajectoryFormatError(f"{path}: column {c!r}, row {row} (line {n}): {what}{hint}") from None
        row += 1
    raise TrajectoryFormatError(f"{path}: could not parse the data rows")  # pragma: no cover


def check_finite(table: LogTable, cols: Sequence[str]) -> None:
    """Raise naming the first non-finite value of ``cols`` (file, column, row, line)."""
    for c in cols:
        bad = np.flatnonzero(~np.isfinite(table.columns[c]))
        if len(bad):
            raise TrajectoryFormatError(f"{table.where(c, int(bad[0]))}: non-finite value {float(table.columns[c][bad[0]])!r}")
