"""Export a trained run: checkpoint → BEM predictor file(s), checked against the posterior.

``export_run(RUN_DIR)`` reads ``RUN_DIR/checkpoint.pt``, builds the
:class:`~bemlearn.export.bem_predictor.BEMPredictor`, writes ``RUN_DIR/bem_predictor.pt``
(TorchScript) and/or ``RUN_DIR/bem_predictor.pt2`` (torch.export), loads each file back and
compares it on random inputs with a slow dense evaluation of eq. (12)
(:func:`~bemlearn.export.verify.verify_predictor`), so a file that does not reproduce the
model is never left behind.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from pathlib import Path
from typing import Literal

from bemlearn.export.bem_predictor import BEMPredictor
from bemlearn.export.checkpoint import load_checkpoint
from bemlearn.export.pt2 import load_pt2_predictor, save_pt2
from bemlearn.export.torchscript import load_torchscript, save_torchscript
from bemlearn.export.staleness import file_sha256
from bemlearn.export.verify import verify_predictor
from bemlearn.files import check_outputs

__all__ = ["export_run", "ExportFormat", "DEFAULT_NAME"]

log = logging.getLogger(__name__)

ExportFormat = Literal["torchscript", "pt2", "both"]
DEFAULT_NAME = "bem_predictor"


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
        out: output file; default ``<run dir>/bem_predictor.pt`` (``.pt2`` for ``fmt="pt2"``).
            With ``fmt="both"`` it names the TorchScript file and the ``.pt2`` goes next to it.
        fmt: ``"torchscript"``, ``"pt2"`` or ``"both"``.
        verify: load each file back and check it with :func:`verify_predictor`.
        force: replace existing files; ``False`` raises
            :class:`~bemlearn.errors.OutputExistsError` naming them (the CLI's default).

    The SHA-256 of the checkpoint file is recorded as ``checkpoint_sha256`` in each file's
    metadata (see :mod:`bemlearn.export.staleness`).

    Returns:
        The files written.
    """
    if fmt not in ("torchscript", "pt2", "both"):
        raise ValueError(f"fmt: expected 'torchscript', 'pt2' or 'both', got {fmt!r}")
    ckpt = load_checkpoint(run_dir_or_file)
    state = ckpt.predictor_state
    meta = ckpt.metadata
    meta = dataclasses.replace(meta, extra={**meta.extra, "checkpoint_sha256": file_sha256(ckpt.path)})
    predictor = BEMPredictor(state, meta)
    base = Path(out) if out is not None else ckpt.path.parent / f"{DEFAULT_NAME}.pt"
    targets = []
    if fmt in ("torchscript", "both"):
        targets.append((base, save_torchscript, load_torchscript))
    if fmt in ("pt2", "both"):
        targets.append((base if (out is not None and fmt == "pt2") else base.with_suffix(".pt2"), save_pt2, load_pt2_predictor))
    check_outputs([t[0] for t in targets], force, what="export")
    written = []
    for path, save, load in targets:
        save(predictor, path)
        if verify:
            try:
                dm, ds = verify_predictor(load(path), state, where=str(path))
            except Exception:
                path.unlink(missing_ok=True)
                raise
            log.info("%s: max |Δmean| %.2g rad, max rel |Δvar| %.2g vs the dense posterior", path, dm, ds)
        written.append(path)
    return written
