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
from pathlib import Path
from typing import Any

import torch
from torch import nn

from bemlearn.errors import ArgumentError, CheckpointError, MissingFileError, PredictorInputError
from bemlearn.export.bem_predictor import BEMPredictor
from bemlearn.files import atomic_write_files

__all__ = ["save_pt2", "pt2_bytes", "load_pt2_predictor", "Pt2Predictor", "PT2_PROGRAMS", "PT2_METADATA_FILE"]

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


def _export_programs(predictor: BEMPredictor) -> dict[str, torch.export.ExportedProgram]:
    predictor = predictor.eval()
    batch = torch.export.Dim("batch", min=1)
    programs = {}
    for name, method in PT2_PROGRAMS.items():
        width = predictor.n_full if method in ("predict_full", "full_mean", "predict_full_latent") else predictor.n_bem
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

    programs = _export_programs(predictor)
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


class Pt2Predictor:
    """The loaded ``.pt2`` predictor: callables with the BEMPredictor contract.

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
        self.metadata_json = metadata_json
        doc = json.loads(metadata_json)
        units = doc.get("units", {})
        self._columns = {
            False: (len(doc["inputs"]), ", ".join(f"{n} [{units.get(n, '?')}]" for n in doc["inputs"])),
            True: (len(doc["full_inputs"]), ", ".join(f"{n} [{units.get(n, '?')}]" for n in doc["full_inputs"])),
        }
        self._forward = self.programs["model"].module()
        self._bem_mean = self.programs["bem_mean"].module()
        self._predict_full = self.programs["predict_full"].module()
        self._full_mean = self.programs["full_mean"].module() if "full_mean" in self.programs else None
        self._forward_latent = self.programs["forward_latent"].module() if "forward_latent" in self.programs else None
        self._predict_full_latent = (
            self.programs["predict_full_latent"].module() if "predict_full_latent" in self.programs else None
        )

    def _call(self, program, x: torch.Tensor, method: str, full: bool):
        """Check ``x`` as the TorchScript module does (same messages), then run ``program``."""
        n, columns = self._columns[full]
        if not isinstance(x, torch.Tensor) or x.dim() != 2 or x.size(1) != n or x.size(0) == 0 or x.dtype != torch.float64:
            shape = list(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
            dtype = x.dtype if isinstance(x, torch.Tensor) else "-"
            raise PredictorInputError(
                f"BEMPredictor.{method}: expected x of shape (B, {n}), B >= 1, and dtype torch.float64 with columns "
                f"[{columns}]; got shape {shape} and dtype {dtype}"
            )
        bad = torch.nonzero(~torch.isfinite(x))
        if bad.size(0) > 0:
            r, c = int(bad[0, 0]), int(bad[0, 1])
            raise PredictorInputError(
                f"BEMPredictor.{method}: x[{r}, {c}] is {float(x[r, c])}; inputs must be finite ({bad.size(0)} non-finite entries)"
            )
        try:
            if x.size(0) <= self.chunk:
                return program(x)
            # row blocks: the program holds (B, M + 1) kernel blocks, several of them, for the whole batch;
            # each block's results are copied out at once (a program's output keeps its block's buffers alive)
            outs: tuple[torch.Tensor, ...] | None = None
            single = False
            for i in range(0, x.size(0), self.chunk):
                got = program(x[i : i + self.chunk])
                single = isinstance(got, torch.Tensor)
                parts = (got,) if single else tuple(got)
                if outs is None:
                    outs = tuple(torch.empty((x.size(0), *p.shape[1:]), dtype=p.dtype) for p in parts)
                for out, part in zip(outs, parts):
                    out[i : i + part.size(0)].copy_(part)
                del got, parts
            assert outs is not None  # x has at least one row
            return outs[0] if single else outs
        except RuntimeError as exc:  # the program's own finite check: entries too large to evaluate
            if "BEMPredictor." in str(exc):
                raise PredictorInputError(
                    f"BEMPredictor.{method}: x has finite entries too large to evaluate: the kernel cannot be evaluated in "
                    "float64 (||(x - x_mean) / (x_std * lengthscale)|| above 1e150)"
                ) from None
            raise

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(μ(x_0^e), σ(x_0^e)) for ``x: (B, 3m)`` float64, each ``(B,)`` in q_u's unit (eq. 12, 14).

        Raises:
            PredictorInputError: (a ValueError) wrong rank, width or dtype, B = 0, or non-finite entries.
        """
        return self._call(self._forward, x, "forward", False)

    def __call__(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward(x)

    def bem_mean(self, x: torch.Tensor) -> torch.Tensor:
        """μ(x_0^e) ``(B,)`` in q_u's unit for ``x: (B, 3m)`` float64."""
        return self._call(self._bem_mean, x, "bem_mean", False)

    def predict_full(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, std) of f(x) (eq. 11) for ``x: (B, 3m + 2)`` float64."""
        return self._call(self._predict_full, x, "predict_full", True)

    def full_mean(self, x: torch.Tensor) -> torch.Tensor:
        """Mean of the full learned map only (eq. 11), ``(B,)`` in q_u's unit."""
        if self._full_mean is None:
            return self._call(self._predict_full, x, "full_mean", True)[0]
        return self._call(self._full_mean, x, "full_mean", True)

    def forward_latent(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(μ(x_0^e), latent σ(x_0^e)) (eq. 12, 14); archives without the program return ``forward``
        (written before the calibrated band, when ``std`` was the latent std)."""
        program = self._forward if self._forward_latent is None else self._forward_latent
        return self._call(program, x, "forward_latent", False)

    def predict_full_latent(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, latent std) of f(x) (eq. 11, 12); see :meth:`forward_latent` for old archives."""
        program = self._predict_full if self._predict_full_latent is None else self._predict_full_latent
        return self._call(program, x, "predict_full_latent", True)

    def metadata(self) -> str:
        """The metadata JSON document."""
        return self.metadata_json


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
