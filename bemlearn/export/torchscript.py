"""TorchScript artifact ``bem_predictor.pt``: loads with ``torch.jit.load`` alone, no bemlearn.

The file holds a frozen (``torch.jit.freeze``) script module with ``forward``, ``bem_mean``,
``predict_full`` and ``metadata`` (see :mod:`bemlearn.export.bem_predictor`), and the metadata
JSON again as the extra file ``metadata.json`` (readable without running the module).
torch ≥ 2.10 marks the ``torch.jit`` API deprecated; these helpers silence that one warning
(the artifact is still the lowest-latency, C++-loadable form, see docs/predictor-contract.md).
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import warnings
from collections.abc import Iterator
from pathlib import Path

import torch

from bemlearn.errors import CheckpointError
from bemlearn.export.bem_predictor import EXPORTED_METHODS, LATENT_METHODS, BEMPredictor
from bemlearn.files import atomic_write_files

__all__ = ["quiet_jit", "script_predictor", "save_torchscript", "torchscript_bytes", "load_torchscript", "METADATA_FILE"]

log = logging.getLogger(__name__)

#: Name of the extra file holding the metadata JSON inside the artifact.
METADATA_FILE = "metadata.json"


@contextlib.contextmanager
def quiet_jit() -> Iterator[None]:
    """Silence exactly torch's "`torch.jit.<name>` is deprecated" DeprecationWarning (torch ≥ 2.10) inside the block."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*torch\.jit\..* is deprecated", category=DeprecationWarning)
        yield


def script_predictor(predictor: BEMPredictor, *, freeze: bool = True) -> torch.jit.ScriptModule:
    """Compile ``predictor`` with ``torch.jit.script`` (and ``torch.jit.freeze`` it: buffers
    become constants, submodule calls are inlined; the exported methods are preserved)."""
    with quiet_jit():
        scripted = torch.jit.script(predictor.eval())
        if freeze:
            scripted = torch.jit.freeze(scripted, preserved_attrs=list(EXPORTED_METHODS))
    return scripted


def torchscript_bytes(predictor: BEMPredictor, *, freeze: bool = True) -> bytes:
    """The TorchScript file of ``predictor``, serialized in memory (torch's C++ file writer aborts the
    process on a full disk; the bytes are written by :mod:`bemlearn.files`, which reports it)."""
    buf = io.BytesIO()
    with quiet_jit():
        torch.jit.save(script_predictor(predictor, freeze=freeze), buf, _extra_files={METADATA_FILE: predictor.metadata_json})
    return buf.getvalue()


def save_torchscript(predictor: BEMPredictor, path: str | os.PathLike[str], *, freeze: bool = True) -> Path:
    """Script ``predictor`` and write it to ``path`` atomically (parent directories are created).

    Raises:
        EnvironmentProblem: no room on the disk, or it is read-only (nothing written).
    """
    path = Path(path)
    atomic_write_files({path: torchscript_bytes(predictor, freeze=freeze)})
    log.info("wrote TorchScript BEM predictor %s", path)
    return path


def _read_predictor_file(path: Path) -> bytes:
    from bemlearn.errors import MissingFileError

    if not path.is_file():
        raise MissingFileError(f"{path}: no such TorchScript predictor file")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise CheckpointError(f"{path}: cannot be read ({exc.strerror or exc})") from None


def load_torchscript(path: str | os.PathLike[str] | bytes, *, where: str | os.PathLike[str] | None = None) -> torch.jit.ScriptModule:
    """``torch.jit.load(path)`` with a clear error for a missing, foreign or tampered file (:mod:`bemlearn.safe_load`).

    The archive is first checked without running it
    (:func:`bemlearn.export.archive_check.check_torchscript_archive`): code other than what this
    version's exporter writes is refused, and torch is handed the very bytes that were checked.

    Raises:
        MissingFileError: (a FileNotFoundError) no such file.
        CheckpointError: not a TorchScript file, or not a bemlearn predictor.
    """
    from bemlearn.export.archive_check import check_torchscript_archive
    from bemlearn.safe_load import load_script_module

    if isinstance(path, bytes):
        data, path = path, where or "<TorchScript bytes>"
    else:
        data = _read_predictor_file(Path(path))
        path = where or Path(path)
    # the code in the file is compiled by torch.jit.load: only the exporter's own code is let through
    check_torchscript_archive(data, where=path, export=torchscript_bytes)
    extra = {METADATA_FILE: ""}
    module = load_script_module(data, extra, where=path)  # C++ loader: no Python unpickling (bemlearn.safe_load)
    missing = [m for m in EXPORTED_METHODS if not hasattr(module, m) and m not in LATENT_METHODS]
    if missing or not extra[METADATA_FILE]:
        raise CheckpointError(f"{path}: not a bemlearn BEM predictor (missing {missing or [METADATA_FILE]})")
    return module
