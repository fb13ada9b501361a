"""Export a trained run: checkpoint → BEM predictor file(s), checked against the posterior.

``export_run(RUN_DIR)`` reads ``RUN_DIR/checkpoint.pt``, builds the
:class:`~bemlearn.export.bem_predictor.BEMPredictor`, writes ``RUN_DIR/bem_predictor.pt``
(TorchScript) and/or ``RUN_DIR/bem_predictor.pt2`` (torch.export), or
``RUN_DIR/bem_predictor_aoti.pt2`` (AOTInductor, :mod:`bemlearn.export.aoti`): each is serialized in
memory, loaded back from those bytes and compared on random inputs with a slow dense
evaluation of eq. (12) (:func:`~bemlearn.export.verify.verify_predictor`), and only then are
the files written, all or none, after checking the disk has room for them
(:func:`~bemlearn.files.atomic_write_files`): a file that does not reproduce the model is never
written, and a full or read-only disk is one clear error with nothing left behind.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from pathlib import Path
from typing import Literal

from bemlearn.errors import ArgumentError
from bemlearn.export.aoti import aoti_bytes, load_aoti_predictor
from bemlearn.export.bem_predictor import BEMPredictor
from bemlearn.export.checkpoint import Checkpoint, load_checkpoint
from bemlearn.export.pt2 import load_pt2_predictor, pt2_bytes
from bemlearn.export.staleness import file_sha256
from bemlearn.export.torchscript import load_torchscript, torchscript_bytes
from bemlearn.export.verify import verification_cases, verify_predictor
from bemlearn.files import atomic_write_files, check_outputs, check_writable

__all__ = ["export_run", "export_files", "write_exported", "export_targets", "ExportFormat", "DEFAULT_NAME", "AOTI_NAME"]

log = logging.getLogger(__name__)

ExportFormat = Literal["torchscript", "pt2", "both", "aoti"]
DEFAULT_NAME = "bem_predictor"
#: Default file of ``fmt="aoti"`` (an AOTInductor package is a ``.pt2`` too: a distinct name keeps both).
AOTI_NAME = f"{DEFAULT_NAME}_aoti.pt2"


def export_targets(run_dir_or_file: str | os.PathLike[str], *, out: str | os.PathLike[str] | None = None,
                   fmt: ExportFormat = "torchscript") -> list[Path]:
    """The files :func:`export_run` writes for these arguments (TorchScript first)."""
    if fmt not in ("torchscript", "pt2", "both", "aoti"):
        raise ArgumentError(f"fmt: expected 'torchscript', 'pt2', 'both' or 'aoti', got {fmt!r}")
    src = Path(run_dir_or_file)
    if fmt == "aoti":
        if out is not None and Path(out).suffix != ".pt2":
            raise ArgumentError(f"--out {out}: an AOTInductor package must end in .pt2")
        return [Path(out) if out is not None else (src if src.is_dir() else src.parent) / AOTI_NAME]
    base = Path(out) if out is not None else (src if src.is_dir() else src.parent) / f"{DEFAULT_NAME}.pt"
    targets = []
    if fmt in ("torchscript", "both"):
        targets.append(base)
    if fmt in ("pt2", "both"):
        targets.append(base if (out is not None and fmt == "pt2") else base.with_suffix(".pt2"))
    return targets


def export_run(
    run_dir_or_file: str | os.PathLike[str],
    *,
    out: str | os.PathLike[str] | None = None,
    fmt: ExportFormat = "torchscript",
    verify: bool = True,
    force: bool = True,
) -> list[Path]:
    """Write the BEM predictor of a trained run.

    Args:
        run_dir_or_file: the run directory (or its ``checkpoint.pt``).
        out: output file; default ``<run dir>/bem_predictor.pt`` (``.pt2`` for ``fmt="pt2"``,
            ``bem_predictor_aoti.pt2`` for ``fmt="aoti"``). With ``fmt="both"`` it names the
            TorchScript file and the ``.pt2`` goes next to it.
        fmt: ``"torchscript"``, ``"pt2"``, ``"both"`` or ``"aoti"`` (AOTInductor package,
            :mod:`bemlearn.export.aoti`: compiled with the system C++ compiler, ≈ 1–2 min).
        verify: load each file back and check it with :func:`verify_predictor`.
        force: replace existing files; ``False`` raises
            :class:`~bemlearn.errors.OutputExistsError` naming them (the CLI's default).

    The SHA-256 of the checkpoint file is recorded as ``checkpoint_sha256`` in each file's
    metadata (see :mod:`bemlearn.export.staleness`).

    Returns:
        The files written.
    """
    paths = export_targets(run_dir_or_file, out=out, fmt=fmt)
    ckpt = load_checkpoint(run_dir_or_file)
    _check_targets(paths, force)
    return write_exported(_serialized(ckpt, paths, fmt, verify=verify), force=force)


def _check_targets(paths: list[Path], force: bool) -> None:
    check_outputs(paths, force, what="export")
    for folder in {p.parent for p in paths}:
        check_writable(folder, what="export")


def write_exported(files: dict[Path, bytes], *, force: bool = True) -> list[Path]:
    """Write the checked predictor files of :func:`export_files` (all or none, room checked first); the paths.

    ``force=False`` raises :class:`~bemlearn.errors.OutputExistsError` for a file that exists.
    """
    _check_targets(list(files), force)
    written = atomic_write_files(files)
    for path in written:
        log.info("wrote BEM predictor %s", path)
    return written


def export_files(run_dir_or_file: str | os.PathLike[str], *, out: str | os.PathLike[str] | None = None,
                 fmt: ExportFormat = "torchscript", verify: bool = True) -> dict[Path, bytes]:
    """The files :func:`export_run` would write, serialized and checked in memory: ``{path: bytes}``.

    Nothing is written: a run exports its predictors this way beside its evaluation (the ``.pt2`` in a
    worker process) and writes them with :func:`write_exported` when it reaches its export stage.
    Arguments as :func:`export_run`'s.
    """
    paths = export_targets(run_dir_or_file, out=out, fmt=fmt)
    return _serialized(load_checkpoint(run_dir_or_file), paths, fmt, verify=verify)


def _serialized(ckpt: Checkpoint, paths: list[Path], fmt: ExportFormat, *, verify: bool) -> dict[Path, bytes]:
    """Each of ``paths`` (:func:`export_targets` of ``fmt``) serialized from checkpoint ``ckpt`` and, with
    ``verify``, loaded back from its bytes and checked against the dense posterior."""
    state = ckpt.predictor_state
    meta = ckpt.metadata
    meta = dataclasses.replace(meta, extra={**meta.extra, "checkpoint_sha256": file_sha256(ckpt.path)})
    predictor = BEMPredictor(state, meta)
    kinds = {"torchscript": ["torchscript"], "pt2": ["pt2"], "both": ["torchscript", "pt2"], "aoti": ["aoti"]}[fmt]
    tools = {"torchscript": (torchscript_bytes, load_torchscript), "pt2": (pt2_bytes, load_pt2_predictor),
             "aoti": (aoti_bytes, load_aoti_predictor)}
    files: dict[Path, bytes] = {}
    cases = verification_cases(state) if verify else ()   # the dense references, computed once for every file
    for path, kind in zip(paths, kinds):   # serialized and checked in memory: nothing is written unless all pass
        serialize, load = tools[kind]
        data = serialize(predictor)
        if verify:
            dm, ds = verify_predictor(load(data, where=path), state, where=str(path), cases=cases)
            log.info("%s: max |Δmean| %.2g rad, max rel |Δvar| %.2g vs the dense posterior", path, dm, ds)
        files[path] = data
    return files
