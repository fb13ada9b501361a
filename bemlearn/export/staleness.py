"""A run folder's predictor matches its checkpoint: the checkpoint's SHA-256 in the predictor.

:func:`~bemlearn.export.export_run.export_run` records the SHA-256 of the checkpoint file
it exported from as ``checkpoint_sha256`` in the predictor's metadata JSON (``metadata()``
and the archive's ``extra/metadata.json``).  :func:`check_predictor_matches` compares it
with the checkpoint beside the predictor and raises
:class:`~bemlearn.errors.StalePredictorError` when they differ; :func:`remove_stale_predictors`
deletes the predictor files of a run folder that no longer match (``train --force``).
"""

from __future__ import annotations

import json
import logging
import os
import zipfile
from pathlib import Path

from bemlearn.errors import CheckpointError, StalePredictorError
from bemlearn.files import file_sha256

__all__ = [
    "file_sha256",
    "predictor_metadata",
    "predictor_checkpoint_sha256",
    "check_predictor_matches",
    "check_run_predictors",
    "stale_predictors",
    "remove_stale_predictors",
    "PREDICTOR_NAMES",
]

log = logging.getLogger(__name__)

#: Predictor files :func:`export_run` writes into a run folder by default.
PREDICTOR_NAMES = ("bem_predictor.pt", "bem_predictor.pt2", "bem_predictor_aoti.pt2")
_CHECKPOINT = "checkpoint.pt"



def predictor_metadata(path: str | os.PathLike[str]) -> dict:
    """The metadata JSON of a ``.pt`` or ``.pt2`` predictor, read from its zip archive (no torch load).

    Raises:
        CheckpointError: not a zip archive, or no ``extra/metadata.json`` that parses as a JSON object.
    """
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as zf:
            names = [n for n in zf.namelist() if n.endswith("extra/metadata.json")]
            if not names:
                raise CheckpointError(f"{path}: no extra/metadata.json; expected a bemlearn predictor (.pt or .pt2)")
            text = zf.read(names[0]).decode("utf-8")
    except (zipfile.BadZipFile, OSError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"{path}: not a predictor archive ({type(exc).__name__}: {exc})") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CheckpointError(f"{path}: extra/metadata.json is not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise CheckpointError(f"{path}: extra/metadata.json must hold a JSON object")
    return doc


def predictor_checkpoint_sha256(path: str | os.PathLike[str]) -> str | None:
    """The ``checkpoint_sha256`` recorded in a predictor (``None`` for files exported before it existed)."""
    doc = predictor_metadata(path)
    return doc.get("checkpoint_sha256") or (doc.get("extra") or {}).get("checkpoint_sha256")


def check_predictor_matches(predictor: str | os.PathLike[str], checkpoint: str | os.PathLike[str]) -> None:
    """Raise :class:`StalePredictorError` if ``predictor`` was not exported from ``checkpoint``.

    A predictor without a recorded hash (exported by an older bemlearn) counts as stale.
    """
    predictor, checkpoint = Path(predictor), Path(checkpoint)
    recorded = predictor_checkpoint_sha256(predictor)
    actual = file_sha256(checkpoint)
    if recorded != actual:
        what = "records no checkpoint hash" if recorded is None else f"was exported from checkpoint sha256 {recorded[:12]}…"
        raise StalePredictorError(
            f"{predictor}: stale predictor: it {what}, but {checkpoint} has sha256 {actual[:12]}…; "
            f"re-export with `bemlearn export {checkpoint.parent} --format both --force`"
        )


def stale_predictors(run_dir: str | os.PathLike[str]) -> list[Path]:
    """The default predictor files of ``run_dir`` that do not match its ``checkpoint.pt``
    (all of them when the checkpoint is missing)."""
    run_dir = Path(run_dir)
    ck = run_dir / _CHECKPOINT
    stale = []
    for name in PREDICTOR_NAMES:
        p = run_dir / name
        if not p.is_file():
            continue
        try:
            if not ck.is_file():
                raise StalePredictorError(f"{p}: no checkpoint beside it")
            check_predictor_matches(p, ck)
        except (StalePredictorError, CheckpointError):
            stale.append(p)
    return stale


def check_run_predictors(run_dir: str | os.PathLike[str]) -> None:
    """Raise :class:`StalePredictorError` naming every predictor file of ``run_dir`` that does not match."""
    run_dir = Path(run_dir)
    stale = stale_predictors(run_dir)
    if not stale:
        return
    names = ", ".join(map(str, stale))
    try:
        check_predictor_matches(stale[0], run_dir / _CHECKPOINT)
    except StalePredictorError as exc:
        raise StalePredictorError(f"{exc} (stale: {names})") from None
    except (CheckpointError, OSError):
        pass
    raise StalePredictorError(
        f"{names}: stale predictor(s) beside {run_dir / _CHECKPOINT}; re-export with `bemlearn export {run_dir} --format both --force`"
    )


def remove_stale_predictors(run_dir: str | os.PathLike[str]) -> list[Path]:
    """Delete the predictor files of ``run_dir`` that no longer match its checkpoint; returns them."""
    removed = stale_predictors(run_dir)
    for p in removed:
        p.unlink()
        log.warning("removed %s: it no longer matches %s", p, Path(run_dir) / _CHECKPOINT)
    return removed
