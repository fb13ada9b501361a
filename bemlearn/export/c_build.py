"""Compile an exported C predictor with the system C compiler and call it through ctypes.

For tests, benchmarks and the examples; a controller links ``<prefix>_predictor.c`` into its
own build instead.  ``PORTABLE_FLAGS`` are the build flags docs/c-export.md recommends.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bemlearn.errors import EnvironmentProblem

__all__ = ["find_cc", "compile_shared", "CPredictorLibrary", "PORTABLE_FLAGS", "STRICT_FLAGS"]

#: Recommended, portable build flags (no -march, no -ffast-math: results independent of the CPU).
PORTABLE_FLAGS = ("-std=c99", "-O2")
#: Warnings the tests demand (issue 17; -Wextra -pedantic: issue 22, what docs/c-export.md promises).
STRICT_FLAGS = ("-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror")


def find_cc() -> str | None:
    """The system C compiler (``$CC``, else ``cc``, ``gcc``, ``clang`` on PATH), or None."""
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def compile_shared(sources: Sequence[str | os.PathLike[str]], out: str | os.PathLike[str], *,
                   flags: Sequence[str] = (*STRICT_FLAGS, "-O2"), cc: str | None = None) -> Path:
    """``cc FLAGS -fPIC -shared SOURCES -o OUT -lm``; RuntimeError with the compiler output on failure."""
    cc = cc or find_cc()
    if cc is None:
        raise EnvironmentProblem("compile_shared: no C compiler found (set $CC or install cc)")
    out = Path(out)
    cmd = [cc, *flags, "-fPIC", "-shared", *map(str, sources), "-o", str(out), "-lm"]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise EnvironmentProblem(f"compile_shared: {' '.join(cmd)} failed:\n{res.stderr}")
    return out


class CPredictorLibrary:
    """ctypes binding of a compiled ``<prefix>_predictor.c``.

    Args:
        path: the shared library.
        prefix: the export prefix.
        dtype: ``"float64"`` or ``"float32"`` (the C ``<prefix>_real``).
    """

    def __init__(self, path: str | os.PathLike[str], *, prefix: str = "bem", dtype: str = "float64") -> None:
        self.lib = ctypes.CDLL(str(path))
        self.np_dtype = np.float64 if dtype == "float64" else np.float32
        real = ctypes.c_double if dtype == "float64" else ctypes.c_float
        ptr = ctypes.POINTER(real)
        self._ptr, self._real = ptr, real
        self._mean = getattr(self.lib, f"{prefix}_mean")
        self._full_mean = getattr(self.lib, f"{prefix}_full_mean")
        for f in (self._mean, self._full_mean):
            f.restype, f.argtypes = real, [ptr]
        self._forward = getattr(self.lib, f"{prefix}_forward")
        self._predict_full = getattr(self.lib, f"{prefix}_predict_full")
        self._forward_latent = getattr(self.lib, f"{prefix}_forward_latent")
        self._predict_full_latent = getattr(self.lib, f"{prefix}_predict_full_latent")
        for f in (self._forward, self._predict_full, self._forward_latent, self._predict_full_latent):
            f.restype, f.argtypes = ctypes.c_int, [ptr, ptr, ptr]
        meta = getattr(self.lib, f"{prefix}_metadata")
        meta.restype, meta.argtypes = ctypes.c_char_p, []
        self.metadata_json = meta().decode()

    def _rows(self, x: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(np.atleast_2d(x), dtype=self.np_dtype)

    def mean(self, x: np.ndarray, *, full: bool = False) -> np.ndarray:
        """``<prefix>_mean`` (or ``_full_mean``) row by row: ``x (B, n)`` → ``(B,)``."""
        fn, x = (self._full_mean if full else self._mean), self._rows(x)
        return np.array([fn(row.ctypes.data_as(self._ptr)) for row in x])

    def forward(self, x: np.ndarray, *, full: bool = False, latent: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``<prefix>_forward`` (or ``_predict_full``; with ``latent`` their ``_latent`` forms) row by row
        → (mean, std, codes), each ``(B,)``; std the calibrated band, or the latent std with ``latent``."""
        fns = ((self._forward, self._predict_full), (self._forward_latent, self._predict_full_latent))[latent]
        fn, x = fns[full], self._rows(x)
        mean, std, codes = np.empty(len(x)), np.empty(len(x)), np.empty(len(x), dtype=np.int64)
        m, s = self._real(), self._real()
        for i, row in enumerate(x):
            codes[i] = fn(row.ctypes.data_as(self._ptr), ctypes.byref(m), ctypes.byref(s))
            mean[i], std[i] = m.value, s.value
        return mean, std, codes
