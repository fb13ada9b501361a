"""How much of a text file is text: binary files are refused at once, a NUL tail is cut off.

A logger that crashed or preallocated its file leaves NUL bytes after the last line it wrote;
a wrong file (a binary, an image, a sparse 2 GB file of NULs) has them near the start.  Reading
either whole before looking costs the file's size in memory (and a 2 GB "first line").
:func:`text_extent` looks without reading the file into memory (one 16 MiB block at a time):

* a NUL byte before the first line end, or a first line longer than :data:`MAX_FIRST_LINE`:
  not a text file, refused after reading at most that much;
* text followed by NUL bytes up to the end of the file: the text is the file (the tail is
  reported by the caller);
* text, NULs, then other bytes again: binary data inside the file, refused naming the offset.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bemlearn.errors import TrajectoryFormatError

__all__ = ["text_extent", "MAX_FIRST_LINE"]

#: The longest first line (header or first row) accepted, bytes.
MAX_FIRST_LINE = 1 << 20
_BLOCK = 1 << 24


def text_extent(path: str | os.PathLike[str], *, what: str = "a text log") -> tuple[int, int]:
    """``(text_bytes, file_bytes)``: the length of the text at the start of ``path`` and of the file.

    ``text_bytes < file_bytes`` only when the rest of the file is NUL bytes.  Memory stays at
    one block (16 MiB) whatever the file's size.

    Raises:
        TrajectoryFormatError: a NUL byte or no line end in the first line (not a text file), or
            NUL bytes followed by other data (binary data inside the file).
    """
    path = Path(path)
    size = path.stat().st_size
    if size == 0:
        return 0, 0
    buf = bytearray(min(_BLOCK, size))
    view = memoryview(buf)
    with open(path, "rb", buffering=0) as fh:
        n = fh.readinto(view[:min(MAX_FIRST_LINE, size)])
        head = bytes(view[:n])
        nul = head.find(b"\0")
        line_end = head.find(b"\n")
        if nul >= 0 and (line_end < 0 or nul < line_end):
            raise TrajectoryFormatError(f"{path}: a NUL byte at offset {nul}, in the first line: a binary file, not {what}")
        if line_end < 0 and size > MAX_FIRST_LINE:
            raise TrajectoryFormatError(f"{path}: no line end in the first {MAX_FIRST_LINE} bytes: not {what}")
        fh.seek(0)
        first_nul, pos = -1, 0
        while pos < size:   # one block in memory at a time (a memory map would count the file in the RSS)
            n = fh.readinto(view)
            if not n:
                break
            block = np.frombuffer(buf, dtype=np.uint8, count=n)
            if first_nul < 0:
                zeros = np.flatnonzero(block == 0)
                if zeros.size:
                    first_nul = pos + int(zeros[0])
                    rest = block[int(zeros[0]):]
                    if rest.any():
                        raise _data_after(path, first_nul, first_nul + int(np.flatnonzero(rest)[0]), what)
            elif block.any():
                raise _data_after(path, first_nul, pos + int(np.flatnonzero(block)[0]), what)
            pos += n
        return (size, size) if first_nul < 0 else (first_nul, size)


def _data_after(path: Path, first_nul: int, offset: int, what: str) -> TrajectoryFormatError:
    return TrajectoryFormatError(f"{path}: NUL bytes from offset {first_nul}, then data again at offset {offset}: "
                                 f"binary data inside the file, not {what}")
