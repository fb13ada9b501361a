"""Loading files a user may have received (predictors, checkpoints, trajectories) without running code in them.

Python's ``pickle`` runs any callable a file names (``__reduce__``), so a shared ``.pt``,
``.pt2`` or ``.npz`` could run code the moment it is loaded.  Every bemlearn reader goes
through this module, which refuses pickled code by one rule per format:

- **torch.save files** (checkpoints, and the pickles inside a ``.pt2``):
  :func:`torch_load_weights` is ``torch.load(weights_only=True)``, whose unpickler
  builds tensors, containers and numbers only; anything else is a
  :class:`~bemlearn.errors.CheckpointError` that says so.
- **``.pt2`` archives** (``torch.export``): torch's own loader falls back to
  ``weights_only=False`` when the sample inputs do not load safely, unpickles "pickled"
  weights and constants without restriction, ``pickle.loads`` opaque objects and loads
  AOTInductor shared libraries.  :func:`read_pt2_archive` therefore checks the archive first
  (:func:`check_pt2_archive`): only the members a bemlearn predictor consists of (program
  JSON, raw tensor payloads, payload configs without ``use_pickle``, sample inputs that load
  with ``weights_only=True``, extra files); then it hands torch the very bytes it checked.
- **TorchScript ``.pt``**: ``torch.jit.load`` is C++ only; its unpickler resolves
  TorchScript classes and tensors and never calls Python (a pickled callable is an error).
  :func:`load_script_module` maps its errors to :class:`~bemlearn.errors.CheckpointError`.
- **``.npz``**: :func:`open_npz` is ``np.load(allow_pickle=False)``: object arrays are refused.

``tests/test_safe_load.py`` feeds each reader a tampered file whose pickle would create a
folder, and checks that the reader refuses it and the folder was not created.
"""

from __future__ import annotations

import io
import json
import os
import re
import zipfile
from pathlib import Path
from typing import Any

from bemlearn.errors import CheckpointError, MissingFileError

__all__ = ["torch_load_weights", "check_pt2_archive", "read_pt2_archive", "load_script_module", "open_npz",
           "PT2_MEMBERS"]

#: The members a bemlearn ``.pt2`` predictor consists of (paths below the archive's root folder).
PT2_MEMBERS: tuple[re.Pattern[str], ...] = tuple(re.compile(p) for p in (
    r"archive_format", r"archive_version", r"byteorder", r"version", r"\.data/version", r"\.data/serialization_id",
    r"models/[\w.-]+\.json",
    r"data/weights/[\w.-]+_weights_config\.json", r"data/weights/weight_\d+",
    r"data/constants/[\w.-]+_constants_config\.json", r"data/constants/tensor_\d+",
    r"data/sample_inputs/[\w.-]+\.pt",
    r"extra/[\w.-]+",
))


def torch_load_weights(source: str | os.PathLike[str] | bytes, *, where: str | os.PathLike[str], what: str = "a torch file") -> Any:
    """``torch.load(source, weights_only=True, map_location="cpu")``: tensors, containers and numbers only.

    Args:
        source: a file path or the bytes of a ``torch.save`` file.
        where: names the file in errors.
        what: what the file should be, for the error message (e.g. ``"a bemlearn checkpoint"``).

    Raises:
        CheckpointError: the file holds pickled objects other than tensors, containers and
            numbers (e.g. a ``__reduce__`` that would call a function), or is not a torch file.
    """
    import pickle

    import torch

    try:
        return torch.load(io.BytesIO(source) if isinstance(source, bytes) else source, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        named = re.search(r"GLOBAL (\S+)", str(exc))
        what_it_is = f"it names {named.group(1)[:120]}" if named else str(exc).strip().splitlines()[0][:200]
        raise CheckpointError(f"{where}: refused: the file holds pickled objects other than tensors, containers and numbers "
                              f"(loading it would run code; {what_it_is})") from None
    except Exception as exc:  # torch raises many types for a corrupt or foreign file
        raise CheckpointError(f"{where}: cannot be read as {what} ({type(exc).__name__}: {str(exc)[:300]})") from exc


def _pt2_payload_config(data: bytes, where: str) -> dict[str, Any]:
    try:
        doc = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"{where}: not a JSON payload config ({exc})") from None
    config = doc.get("config") if isinstance(doc, dict) else None
    if not isinstance(config, dict):
        raise CheckpointError(f"{where}: expected a JSON object with a 'config' mapping")
    return config


def check_pt2_archive(data: bytes, *, where: str | os.PathLike[str]) -> None:
    """Refuse a ``.pt2`` archive from which ``torch.export`` would run pickled code or native libraries.

    Raises:
        CheckpointError: not a zip archive; members outside :data:`PT2_MEMBERS` (e.g.
            ``data/aotinductor/`` shared libraries, legacy pickled weight files, custom or
            opaque objects); a weight or constant marked ``use_pickle``; sample inputs that do
            not load with ``weights_only=True``.
    """
    try:
        zf = zipfile.ZipFile(io.BytesIO(data))
        names = zf.namelist()
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise CheckpointError(f"{where}: not a torch.export .pt2 archive ({exc})") from None
    with zf:
        roots = {n.split("/", 1)[0] for n in names}
        if len(roots) != 1 or any("/" not in n for n in names):
            raise CheckpointError(f"{where}: not a torch.export .pt2 archive (expected one root folder, got {sorted(roots)[:5]})")
        root = roots.pop() + "/"
        for name in names:
            rel = name[len(root):]
            if not rel or rel.endswith("/"):
                continue
            if not any(p.fullmatch(rel) for p in PT2_MEMBERS):
                raise CheckpointError(f"{where}: refused: unexpected member {rel[:200]!r} (a bemlearn predictor holds only "
                                      "program JSON, raw tensors, sample inputs and extra files; torch would load this one "
                                      "as pickled code or a native library)")
            if rel.endswith(("_weights_config.json", "_constants_config.json")):
                for key, meta in _pt2_payload_config(zf.read(name), f"{where}: {rel}").items():
                    path = meta.get("path_name", "") if isinstance(meta, dict) else ""
                    if not isinstance(meta, dict) or meta.get("use_pickle") or not re.fullmatch(r"(weight|tensor)_\d+", str(path)):
                        raise CheckpointError(f"{where}: refused: {rel} loads {str(key)[:100]!r} as a pickled object "
                                              f"({str(meta)[:200]}); a bemlearn predictor stores raw tensors only")
            elif rel.startswith("data/sample_inputs/"):
                torch_load_weights(zf.read(name), where=f"{where}: {rel}", what="torch.export sample inputs")


def read_pt2_archive(source: str | os.PathLike[str] | bytes, *, where: str | os.PathLike[str] | None = None):
    """``torch.export``'s ``load_pt2`` of the bytes of ``source`` (a path, or the archive's bytes) after
    :func:`check_pt2_archive` passed on them.

    Raises:
        MissingFileError: (a FileNotFoundError) no such file.
        CheckpointError: refused by :func:`check_pt2_archive`, or torch cannot read it.
    """
    from torch.export.pt2_archive._package import load_pt2

    if isinstance(source, bytes):
        data, path = source, where or "<.pt2 bytes>"
    else:
        path = Path(source)
        if not path.is_file():
            raise MissingFileError(f"{path}: no such .pt2 predictor file")
        data = path.read_bytes()
    check_pt2_archive(data, where=path)
    try:
        return load_pt2(io.BytesIO(data))
    except Exception as exc:  # torch raises several types for foreign archives
        raise CheckpointError(f"{path}: not a torch.export .pt2 archive ({type(exc).__name__}: {str(exc)[:300]})") from exc


def load_script_module(source: str | os.PathLike[str] | bytes, extra_files: dict[str, Any] | None = None, *,
                       where: str | os.PathLike[str] | None = None):
    """``torch.jit.load(source, map_location="cpu")`` (C++ only: no Python unpickling) with named errors;
    ``source`` is a path or the bytes of a TorchScript file (``where`` names it in errors).

    Raises:
        MissingFileError: (a FileNotFoundError) no such file.
        CheckpointError: not a TorchScript archive, or its pickles name anything but
            TorchScript classes and tensors.
    """
    import warnings

    import torch

    f: io.BytesIO | str
    if isinstance(source, bytes):
        path, f = where or "<TorchScript bytes>", io.BytesIO(source)
    else:
        path = Path(source)
        if not path.is_file():
            raise MissingFileError(f"{path}: no such TorchScript predictor file")
        f = str(path)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*torch\.jit\..* is deprecated", category=DeprecationWarning)
            return torch.jit.load(f, map_location="cpu", _extra_files=extra_files if extra_files is not None else {})
    except Exception as exc:  # torch raises RuntimeError and others for foreign or truncated files
        raise CheckpointError(f"{path}: not a TorchScript file ({type(exc).__name__}: {str(exc)[:300]})") from exc


def open_npz(path: str | os.PathLike[str]):
    """``np.load(path, allow_pickle=False)``: an ``NpzFile`` whose object arrays are refused when read."""
    import numpy as np

    return np.load(path, allow_pickle=False)
