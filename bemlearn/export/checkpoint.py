"""The training checkpoint ``RUN_DIR/checkpoint.pt``: write it, read it back, validated.

``torch.load(path, weights_only=True)`` gives a dict::

    format            "bemlearn-checkpoint-v1"
    kind              "exact" | "sgpr" | "svgp"
    model_state       the model's state dict (tensors)
    predictor_state   PredictorState.to_dict(): the frozen posterior of eq. (12)
    metadata          PredictorMetadata.to_dict(): robot, columns, units, provenance

Export reads only ``predictor_state`` and ``metadata``; ``model_state`` is for resuming.
"""

from __future__ import annotations

import dataclasses
import io
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from bemlearn.config import ConfigError
from bemlearn.errors import CheckpointError, MissingFileError
from bemlearn.export.metadata import PredictorMetadata, artifact_metadata
from bemlearn.files import atomic_write_files
from bemlearn.models.gp_kinds import GP_KINDS
from bemlearn.models.learned_bem import LearnedBEM
from bemlearn.models.predictor_state import GPKind, PredictorState

__all__ = ["CHECKPOINT_FORMAT", "CHECKPOINT_NAME", "Checkpoint", "load_checkpoint", "load_learned_bem", "write_checkpoint"]

log = logging.getLogger(__name__)

CHECKPOINT_FORMAT = "bemlearn-checkpoint-v1"
CHECKPOINT_NAME = "checkpoint.pt"

_TOP_KEYS = ("format", "kind", "model_state", "predictor_state", "metadata")
_STATE_TENSORS = tuple(
    f.name for f in dataclasses.fields(PredictorState) if f.name not in ("kind", "input_names", "n_train")
)
#: Tensors added after v1 checkpoints were first written (calibrated band; the sparse kinds' factored
#: S = L⁻ᵀ C L⁻¹; the plane coefficients' variance of eq. L3); absent → defaults (S used as given, no term).
_OPTIONAL_TENSORS = ("std_scale", "input_std", "estimator_delta", "S_chol", "S_inner", "plane_weights", "plane_cov")


@dataclass(frozen=True)
class Checkpoint:
    """A validated checkpoint.

    Attributes:
        path: the file it was read from.
        kind: GP kind, equal to ``predictor_state.kind``.
        model_state: the model's state dict (opaque to export).
        predictor_state: the frozen posterior (float64 tensors).
        metadata: the validated metadata.
    """

    path: Path
    kind: GPKind
    model_state: dict[str, Any]
    predictor_state: PredictorState
    metadata: PredictorMetadata

    def artifact_metadata(self) -> dict[str, Any]:
        """The JSON document of the exported predictor (see :func:`artifact_metadata`)."""
        return artifact_metadata(self.metadata, self.predictor_state)


def _checkpoint_path(run_dir_or_file: str | os.PathLike[str]) -> Path:
    path = Path(run_dir_or_file)
    if path.is_dir():
        path = path / CHECKPOINT_NAME
        if not path.is_file():
            raise MissingFileError(f"{path}: no checkpoint in run directory {path.parent}")
    elif not path.is_file():
        raise MissingFileError(f"{path}: no such checkpoint file or run directory")
    return path


def _parse_state(data: Any, kind: str, where: str) -> PredictorState:
    if not isinstance(data, dict):
        raise CheckpointError(f"{where}: expected a dict (PredictorState.to_dict()), got {type(data).__name__}")
    missing = [k for k in (*_STATE_TENSORS, "kind", "input_names", "n_train") if k not in data and k not in _OPTIONAL_TENSORS]
    if missing:
        raise CheckpointError(f"{where}: missing key(s) {missing}")
    unknown = sorted(set(data) - {*_STATE_TENSORS, "kind", "input_names", "n_train"})
    if unknown:
        raise CheckpointError(f"{where}: unknown key(s) {unknown}")
    for name in _STATE_TENSORS:
        if name in _OPTIONAL_TENSORS and name not in data:
            continue
        t = data[name]
        if not isinstance(t, torch.Tensor):
            raise CheckpointError(f"{where}.{name}: expected a tensor, got {type(t).__name__}")
        if t.dtype != torch.float64:
            raise CheckpointError(f"{where}.{name}: expected float64 (GP posteriors are stored in float64), got {t.dtype}")
        if not bool(torch.isfinite(t).all()):
            raise CheckpointError(f"{where}.{name}: has non-finite values")
    if data["kind"] != kind:
        raise CheckpointError(f"{where}.kind: {data['kind']!r} differs from the checkpoint's kind {kind!r}")
    if not isinstance(data["n_train"], int) or isinstance(data["n_train"], bool):
        raise CheckpointError(f"{where}.n_train: expected an integer, got {data['n_train']!r}")
    names = data["input_names"]
    if not isinstance(names, (list, tuple)) or not all(isinstance(n, str) for n in names):
        raise CheckpointError(f"{where}.input_names: expected a list of strings, got {names!r}")
    try:
        state = PredictorState.from_dict(data)
    except ValueError as exc:
        raise CheckpointError(f"{where}: {exc}") from exc
    for name in ("lengthscale", "x_std", "y_std", "outputscale"):
        if not bool((getattr(state, name) > 0).all()):
            raise CheckpointError(f"{where}.{name}: expected positive values, got {getattr(state, name).tolist()}")
    if float(state.noise) < 0:
        raise CheckpointError(f"{where}.noise: expected >= 0, got {float(state.noise)}")
    assert state.std_scale is not None and state.input_std is not None  # filled by PredictorState.__post_init__
    if not float(state.std_scale) > 0 or not bool((state.input_std >= 0).all()):
        raise CheckpointError(f"{where}: std_scale must be > 0 and input_std >= 0, got {float(state.std_scale)} and "
                         f"{state.input_std.tolist()}")
    return state


def _content_sha256(data: dict) -> str:
    """SHA-256 over the model and posterior tensors (names, dtypes, shapes, bytes) and the metadata JSON.

    Recorded as ``content_sha256`` at write and checked at load: a flipped byte inside a
    tensor changes values without making the zip unreadable.
    """
    import hashlib
    import json

    h = hashlib.sha256()
    for group in ("model_state", "predictor_state"):
        items = data.get(group)
        if not isinstance(items, dict):
            continue
        for name in sorted(items, key=str):
            v = items[name]
            h.update(f"{group}.{name}".encode())
            if isinstance(v, torch.Tensor):
                t = v.detach().cpu().contiguous()
                h.update(f"{t.dtype}{tuple(t.shape)}".encode())
                h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
            else:
                h.update(repr(v).encode())
    h.update(json.dumps(data.get("metadata"), sort_keys=True, default=str).encode())
    return h.hexdigest()


def load_checkpoint(run_dir_or_file: str | os.PathLike[str]) -> Checkpoint:
    """Read and validate ``RUN_DIR/checkpoint.pt`` (or a checkpoint file given directly).

    Raises:
        MissingFileError: (a FileNotFoundError) no such file, or a run directory without ``checkpoint.pt``.
        CheckpointError: (a ValueError) not loadable with ``weights_only=True``, wrong ``format``, a missing key,
            a bad value, or metadata inconsistent with the posterior; the message names the
            file and the key.
    """
    path = _checkpoint_path(run_dir_or_file)
    from bemlearn.safe_load import torch_load_weights

    data = torch_load_weights(path, where=path, what="a bemlearn checkpoint")  # weights_only: a pickled callable is refused
    if not isinstance(data, dict):
        raise CheckpointError(f"{path}: expected a dict with keys {list(_TOP_KEYS)}, got {type(data).__name__}")
    missing = [k for k in _TOP_KEYS if k not in data]
    if missing:
        raise CheckpointError(f"{path}: missing key(s) {missing}; a checkpoint has keys {list(_TOP_KEYS)}")
    if data["format"] != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: format is {data['format']!r}, expected {CHECKPOINT_FORMAT!r}")
    kind = data["kind"]
    if not isinstance(kind, str) or kind not in GP_KINDS:
        raise CheckpointError(f"{path}: kind is {kind!r}, expected one of {list(GP_KINDS)}")
    if not isinstance(data["model_state"], dict):
        raise CheckpointError(f"{path}: model_state: expected a state dict, got {type(data['model_state']).__name__}")
    state = _parse_state(data["predictor_state"], kind, f"{path}: predictor_state")
    try:
        meta = PredictorMetadata.from_dict(data["metadata"], where=f"{path}: metadata")
        artifact_metadata(meta, state)  # cross-checks columns, n_train, n_inducing
    except (ConfigError, ValueError, TypeError) as exc:
        msg = str(exc)
        raise CheckpointError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from exc
    recorded = data.get("content_sha256")  # last: the specific checks above name the bad key first
    if recorded is not None and recorded != _content_sha256(data):
        raise CheckpointError(f"{path}: the tensors do not match the checkpoint's content_sha256: the file is corrupted; retrain or restore it")
    log.debug("loaded %s: %s GP, %d support points, d = %d", path, kind, state.n_support, state.dim)
    return Checkpoint(path=path, kind=state.kind, model_state=data["model_state"], predictor_state=state, metadata=meta)


def write_checkpoint(
    run_dir_or_file: str | os.PathLike[str],
    *,
    model_state: dict[str, Any],
    predictor_state: PredictorState,
    metadata: PredictorMetadata | dict[str, Any],
    read_back: bool = True,
) -> Path:
    """Validate and write a checkpoint; returns the file written.

    Args:
        run_dir_or_file: a run directory (the file is ``checkpoint.pt`` inside, the directory
            is created) or a ``.pt`` file path.
        model_state: the model's ``state_dict()``.
        predictor_state: the frozen float64 posterior; its ``kind`` is the checkpoint's kind.
        metadata: a :class:`PredictorMetadata` or a dict with its keys.
        read_back: load the written file back with :func:`load_checkpoint` before returning (the
            contents are validated before writing either way; an interrupted fit skips the read-back
            so that Ctrl-C ends promptly).

    The file is written to a temporary name and renamed, so a crash never leaves a
    half-written checkpoint.
    """
    target = Path(run_dir_or_file)
    path = target if target.suffix == ".pt" else target / CHECKPOINT_NAME
    meta = metadata if isinstance(metadata, PredictorMetadata) else PredictorMetadata.from_dict(metadata)
    artifact_metadata(meta, predictor_state)
    data = {
        "format": CHECKPOINT_FORMAT,
        "kind": predictor_state.kind,
        "model_state": dict(model_state),
        "predictor_state": predictor_state.to_dict(),
        "metadata": meta.to_dict(),
    }
    _parse_state(data["predictor_state"], predictor_state.kind, "predictor_state")
    data["content_sha256"] = _content_sha256(data)
    buf = io.BytesIO()   # in memory: torch's C++ file writer aborts the process on a full disk
    torch.save(data, buf)
    atomic_write_files({path: buf.getvalue()})
    if read_back:
        load_checkpoint(path)
    log.info("wrote checkpoint %s (%s GP)", path, predictor_state.kind)
    return path


def load_learned_bem(run_dir_or_file: str | os.PathLike[str]) -> LearnedBEM:
    """The :class:`~bemlearn.models.LearnedBEM` (eq. 12–15) of ``RUN_DIR`` or ``RUN_DIR/checkpoint.pt``."""
    ck = load_checkpoint(run_dir_or_file)
    md = ck.metadata
    return LearnedBEM(ck.predictor_state, robot=md.robot, actuated_names=md.actuated_names, unactuated_name=md.unactuated_name)
