"""``torch.export`` artifact ``bem_predictor.pt2``: the same contract as the TorchScript file.

A ``.pt2`` archive (the format ``torch.export.save`` writes) with one ExportedProgram per
method and the metadata JSON as an extra file:

    models/model.json          forward(x: (B, 3m)) -> (mean (B,), std (B,))   [torch.export.load]
    models/bem_mean.json       bem_mean(x: (B, 3m)) -> mean (B,)
    models/predict_full.json   predict_full(x: (B, 3m + 2)) -> (mean, std)
    models/forward_latent.json, models/predict_full_latent.json   the same with the latent std
    extra/metadata.json        the metadata() JSON document

``torch.export.load(path)`` returns the ``forward`` program (the archive's default ``model``);
``torch.export.pt2_archive._package.load_pt2(path).exported_programs[name]`` returns any of them
(:func:`load_pt2_predictor` wraps that).  B is dynamic (B ≥ 1).  :class:`Pt2Predictor`
checks inputs exactly as the TorchScript module (rank, width, dtype, B = 0, non-finite) and
raises :class:`~bemlearn.errors.PredictorInputError` with the same message.  A raw program
(plain ``torch.export.load``) raises torch's exceptions: a wrong width fails the input guard
(AssertionError), a wrong dtype ``aten._assert_tensor_metadata`` (RuntimeError), B = 0 and
non-finite inputs ``aten._assert_async`` with a BEMPredictor message (RuntimeError); see
docs/predictor-contract.md.
"""

from __future__ import annotations

import io
import json
import logging
import os
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import torch
from torch import nn

from bemlearn.errors import ArgumentError, CheckpointError, MissingFileError
from bemlearn.export.bem_predictor import BEMPredictor
from bemlearn.export.checked_predictor import FULL_METHODS, CheckedPredictor
from bemlearn.files import atomic_write_files

__all__ = ["save_pt2", "pt2_bytes", "export_programs", "load_pt2_predictor", "Pt2Predictor", "PT2_PROGRAMS", "PT2_METADATA_FILE"]

log = logging.getLogger(__name__)

#: Program name in the archive → BEMPredictor method it exports.
PT2_PROGRAMS = {"model": "forward", "bem_mean": "bem_mean", "predict_full": "predict_full", "full_mean": "full_mean",
                "forward_latent": "forward_latent", "predict_full_latent": "predict_full_latent"}
#: Programs that archives written before the calibrated band lack.
_OPTIONAL_PROGRAMS = ("forward_latent", "predict_full_latent")
PT2_METADATA_FILE = "metadata.json"
#: Rows per block of a large batch (FoldedPosterior's default chunk, the TorchScript module's).
PT2_CHUNK = 1024


class _Method(nn.Module):
    """One method of a BEMPredictor as a module's forward, with a runtime dtype assertion."""

    def __init__(self, predictor: BEMPredictor, method: str) -> None:
        super().__init__()
        self.predictor = predictor
        self.method = method

    def forward(self, x: torch.Tensor) -> Any:
        torch.ops.aten._assert_tensor_metadata.default(x, dtype=torch.float64)
        # B is a dynamic dimension with min 1, but torch.export does not guard it at run time:
        # a tensor-valued assertion keeps an empty batch from returning a (1,) mean
        torch._assert_async(x.new_ones(x.shape[0]).sum() > 0.5, f"BEMPredictor.{self.method}: x is an empty batch (B = 0); expected B >= 1")
        return getattr(self.predictor, self.method)(x)


def export_programs(predictor: BEMPredictor, *, names: Iterable[str] = tuple(PT2_PROGRAMS)) -> dict[str, torch.export.ExportedProgram]:
    """``torch.export`` of each method named in ``names`` (archive names, :data:`PT2_PROGRAMS`), batch dimension dynamic (B ≥ 1)."""
    predictor = predictor.eval()
    batch = torch.export.Dim("batch", min=1)
    programs = {}
    for name in names:
        method = PT2_PROGRAMS[name]
        width = predictor.n_full if method in FULL_METHODS else predictor.n_bem
        example = torch.zeros(4, width, dtype=torch.float64)
        with torch.no_grad():
            programs[name] = torch.export.export(
                _Method(predictor, method), (example,), dynamic_shapes={"x": {0: batch}}, strict=False
            )
    return programs


def pt2_bytes(predictor: BEMPredictor) -> bytes:
    """The ``.pt2`` archive of ``predictor``'s methods (``torch.export``), serialized in memory (torch's
    C++ archive writer aborts the process on a full disk; :mod:`bemlearn.files` writes the bytes)."""
    from torch.export.pt2_archive._package import package_pt2

    programs = export_programs(predictor)
    buf = io.BytesIO()
    with warnings.catch_warnings():
        # bem and full share their weight/factor tensors; torch warns about the shared group,
        # harmless for CPU weights (the test suite checks every program's numbers after loading)
        warnings.filterwarnings("ignore", message="No complete tensor found in the group")
        package_pt2(buf, exported_programs=programs, extra_files={PT2_METADATA_FILE: predictor.metadata_json})
    return buf.getvalue()


def save_pt2(predictor: BEMPredictor, path: str | os.PathLike[str]) -> Path:
    """Export ``predictor``'s methods with ``torch.export`` and write one ``.pt2`` atomically.

    Raises:
        EnvironmentProblem: no room on the disk, or it is read-only (nothing written).
    """
    path = Path(path)
    atomic_write_files({path: pt2_bytes(predictor)})
    log.info("wrote torch.export BEM predictor %s", path)
    return path


class Pt2Predictor(CheckedPredictor):
    """The loaded ``.pt2`` predictor: callables with the BEMPredictor contract, inputs checked as the
    TorchScript module checks them (:class:`~bemlearn.export.checked_predictor.CheckedPredictor`).

    Args:
        programs: the ExportedPrograms by archive name (``model`` is ``forward``).
        metadata_json: the metadata document.
        chunk: batches larger than this run in row blocks of this size (as the TorchScript
            module does): peak memory stays that of one block, whatever B.
    """

    def __init__(self, programs: dict[str, torch.export.ExportedProgram], metadata_json: str, *,
                 chunk: int = PT2_CHUNK) -> None:
        if chunk < 1:
            raise ArgumentError(f"chunk: expected a positive row count, got {chunk}")
        self.chunk = chunk
        self.programs = dict(programs)
        super().__init__(metadata_json, {PT2_PROGRAMS[name]: _in_chunks(program.module(), chunk)
                                         for name, program in self.programs.items() if name in PT2_PROGRAMS})


def _in_chunks(program, chunk: int):
    """``program`` evaluated in row blocks of ``chunk`` when the batch is larger: an exported program holds
    several (B, M + 1) kernel blocks for the whole batch, so peak memory then stays that of one block."""

    def run(x: torch.Tensor):
        if x.size(0) <= chunk:
            return program(x)
        outs: tuple[torch.Tensor, ...] | None = None
        single = False
        for i in range(0, x.size(0), chunk):
            got = program(x[i : i + chunk])
            single = isinstance(got, torch.Tensor)
            parts = (got,) if single else tuple(got)
            if outs is None:
                outs = tuple(torch.empty((x.size(0), *p.shape[1:]), dtype=p.dtype) for p in parts)
            for out, part in zip(outs, parts):
                out[i : i + part.size(0)].copy_(part)   # copied out at once: an output keeps its block's buffers alive
            del got, parts
        assert outs is not None  # x has at least one row
        return outs[0] if single else outs

    return run


def _program_json(data: bytes) -> dict[str, bytes]:
    """``models/<name>.json`` → bytes of an archive :func:`bemlearn.safe_load.check_pt2_archive` accepted."""
    import re
    import zipfile

    out = {}
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        for name in zf.namelist():
            match = re.fullmatch(r"[^/]+/models/([\w.-]+)\.json", name)
            if match:
                out[match.group(1)] = zf.read(name)
    return out


def load_pt2_predictor(path: str | os.PathLike[str] | bytes, *, where: str | os.PathLike[str] | None = None) -> Pt2Predictor:
    """Load a ``.pt2`` written by :func:`save_pt2`, refusing archives that would run pickled code
    or native libraries (:func:`bemlearn.safe_load.read_pt2_archive`).

    Raises:
        MissingFileError: (a FileNotFoundError) no such file.
        CheckpointError: a foreign or tampered archive, or not a bemlearn predictor.
    """
    from bemlearn.export.archive_check import check_pt2_programs
    from bemlearn.safe_load import check_pt2_archive, read_pt2_archive

    if isinstance(path, bytes):
        data, path = path, where or "<.pt2 bytes>"
    else:
        source = Path(path)
        path = where or source
        if not source.is_file():
            raise MissingFileError(f"{path}: no such .pt2 predictor file")
        try:
            data = source.read_bytes()
        except OSError as exc:
            raise CheckpointError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    check_pt2_archive(data, where=path)
    # the graph names the operators torch will run and holds strings torch evaluates: only the exporter's own
    check_pt2_programs(_program_json(data), where=path, names=PT2_PROGRAMS, method_module=_Method)
    contents = read_pt2_archive(data, where=path)
    missing = [k for k in PT2_PROGRAMS if k not in contents.exported_programs and k not in _OPTIONAL_PROGRAMS]
    meta = contents.extra_files.get(PT2_METADATA_FILE)
    if missing or not meta:
        raise CheckpointError(f"{path}: not a bemlearn BEM predictor (missing {missing or [PT2_METADATA_FILE]})")
    try:
        meta_text = meta.decode() if isinstance(meta, bytes) else str(meta)
        doc = json.loads(meta_text)
    except ValueError as exc:  # UnicodeDecodeError and JSONDecodeError
        raise CheckpointError(f"{path}: extra/{PT2_METADATA_FILE} is not the bemlearn predictor metadata ({exc})") from None
    if not isinstance(doc, dict) or not all(isinstance(doc.get(k), list) for k in ("inputs", "full_inputs")):
        raise CheckpointError(f"{path}: extra/{PT2_METADATA_FILE} is not the bemlearn predictor metadata "
                              "(expected a JSON object with lists 'inputs' and 'full_inputs')")
    return Pt2Predictor(programs=dict(contents.exported_programs), metadata_json=meta_text)
