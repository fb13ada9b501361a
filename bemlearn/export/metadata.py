"""What a trained BEM predictor was trained on: robot, columns, units, provenance.

The learned map is q_u = f(x) with x = [q̈_a (m), q̇_a (m), q_a (m), q̈_u, q̇_u] (eq. 11) and the
BEM is μ(x_0^e) with x_0^e = [q̈_a, q̇_a, q_a, 0, 0] (eq. 14).  :class:`PredictorMetadata`
holds the checkpoint's ``metadata`` dict, checked; :func:`artifact_metadata` turns it (plus
the :class:`~bemlearn.models.predictor_state.PredictorState`) into the JSON document that the
exported predictors return from ``metadata()``.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from bemlearn.config import ConfigError, from_dict
from bemlearn.errors import ArgumentError, CheckpointError
from bemlearn.models.predictor_state import PredictorState

__all__ = ["PredictorMetadata", "artifact_metadata", "ARTIFACT_FORMAT", "jsonable"]

#: Value of the ``format`` key in the exported predictors' metadata JSON.
ARTIFACT_FORMAT = "bemlearn-bem-predictor-v1"

_SHA256 = re.compile(r"^[0-9a-f]{64}$")


@dataclass(frozen=True)
class PredictorMetadata:
    """The checkpoint's ``metadata`` dict, validated (see docs/predictor-contract.md).

    Attributes:
        robot: robot name, e.g. ``"furuta"``.
        joint_names: all joint names of the robot.
        actuated_names: the m actuated joints q_a, in the predictor's column order.
        unactuated_name: the unactuated joint q_u (the GP output, in its joint's unit: rad or m).
        m: number of actuated joints.
        input_names: the 3m + 2 GP input columns [q̈_a, q̇_a, q_a, q̈_u, q̇_u] (eq. 11).
        units: unit of every input column (rad/s², rad/s, rad; m/s², m/s, m for slides), as ``{name: unit}``
            (a list parallel to ``input_names`` is accepted and converted).
        n_train: number of training points.
        n_inducing: number of inducing points, ``None`` for an exact GP.
        hyperparameters: JSON-able hyperparameters (tensors and NumPy values are converted to
            lists / numbers on construction).
        bemlearn_version: version that trained the model.
        data_sha256: SHA-256 (hex) of the training data.
        extra: the checkpoint metadata's ``extra`` mapping plus any unknown top-level keys,
            kept as they are (JSON-able); written back under ``extra``.
    """

    robot: str
    joint_names: tuple[str, ...]
    actuated_names: tuple[str, ...]
    unactuated_name: str
    m: int
    input_names: tuple[str, ...]
    units: dict[str, str]
    n_train: int
    n_inducing: int | None
    hyperparameters: dict[str, Any]
    bemlearn_version: str
    data_sha256: str
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.m < 1:
            raise CheckpointError(f"m: expected an integer >= 1, got {self.m}")
        if len(self.actuated_names) != self.m:
            raise CheckpointError(
                f"actuated_names: expected m = {self.m} names, got {list(self.actuated_names)}"
            )
        missing = [n for n in (*self.actuated_names, self.unactuated_name) if n not in self.joint_names]
        if missing:
            raise CheckpointError(f"joint_names: {list(self.joint_names)} lacks {missing}")
        if self.unactuated_name in self.actuated_names:
            raise CheckpointError(f"unactuated_name: {self.unactuated_name!r} is also actuated")
        if len(self.input_names) != 3 * self.m + 2:
            raise CheckpointError(
                f"input_names: expected 3m + 2 = {3 * self.m + 2} column names "
                f"[q̈_a, q̇_a, q_a, q̈_u, q̇_u], got {len(self.input_names)}: {list(self.input_names)}"
            )
        no_unit = [n for n in self.input_names if n not in self.units]
        if no_unit:
            raise CheckpointError(f"units: no unit for input column(s) {no_unit}")
        if self.n_train < 1:
            raise CheckpointError(f"n_train: expected an integer >= 1, got {self.n_train}")
        if self.n_inducing is not None and self.n_inducing < 1:
            raise CheckpointError(f"n_inducing: expected null or an integer >= 1, got {self.n_inducing}")
        if not _SHA256.match(self.data_sha256):
            raise CheckpointError(f"data_sha256: expected 64 lowercase hex digits, got {self.data_sha256!r}")
        # plain JSON types from here on: no tensors or NumPy scalars, which would also make
        # the checkpoint unreadable with torch.load(weights_only=True)
        object.__setattr__(self, "hyperparameters", jsonable(self.hyperparameters, where="hyperparameters"))
        object.__setattr__(self, "extra", jsonable(self.extra, where="extra"))
        object.__setattr__(self, "units", dict(self.units))

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, where: str = "metadata") -> PredictorMetadata:
        """Parse the checkpoint's metadata dict; unknown keys are kept in :attr:`extra`.

        Raises:
            ConfigError: a required key is missing or has the wrong type (names the key path).
            ValueError: the values are inconsistent (e.g. ``len(actuated_names) != m``).
        """
        if not isinstance(data, dict):
            raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
        known = {f for f in cls.__dataclass_fields__ if f != "extra"}
        parsed = dict(data)
        units = parsed.get("units")
        names = parsed.get("input_names")
        if isinstance(units, (list, tuple)) and isinstance(names, (list, tuple)):
            if len(units) != len(names):
                raise ConfigError(
                    f"{where}.units: a list of units must have one entry per input column "
                    f"({len(names)}), got {len(units)}"
                )
            parsed["units"] = dict(zip(names, units))
        extra = {k: v for k, v in parsed.items() if k not in known and k != "extra"}
        nested = parsed.get("extra", {})
        if not isinstance(nested, dict):
            raise ConfigError(f"{where}.extra: expected a mapping, got {type(nested).__name__}")
        clash = sorted(set(extra) & set(nested))
        if clash:
            raise ConfigError(f"{where}: key(s) {clash} given both at the top level and under 'extra'")
        extra.update(nested)
        core = {k: v for k, v in parsed.items() if k in known}
        meta = from_dict(cls, core, where=where)
        if extra:
            meta = cls(**{**{k: getattr(meta, k) for k in known}, "extra": extra})
        return meta

    def to_dict(self) -> dict[str, Any]:
        """The checkpoint form (``torch.load(weights_only=True)``-safe; extras under ``extra``)."""
        out: dict[str, Any] = {
            "robot": self.robot,
            "joint_names": list(self.joint_names),
            "actuated_names": list(self.actuated_names),
            "unactuated_name": self.unactuated_name,
            "m": self.m,
            "input_names": list(self.input_names),
            "units": dict(self.units),
            "n_train": self.n_train,
            "n_inducing": self.n_inducing,
            "hyperparameters": dict(self.hyperparameters),
            "bemlearn_version": self.bemlearn_version,
            "data_sha256": self.data_sha256,
        }
        if self.extra:
            out["extra"] = dict(self.extra)
        return out


def jsonable(value: Any, *, where: str) -> Any:
    """``value`` with tensors / tuples turned into JSON types; TypeError names the bad key path."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().tolist()
    if isinstance(value, np.generic | np.ndarray):
        return jsonable(value.tolist(), where=where)
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise ArgumentError(f"{where}: keys must be strings for JSON, got {k!r}")
            out[k] = jsonable(v, where=f"{where}.{k}")
        return out
    if isinstance(value, (list, tuple)):
        return [jsonable(v, where=f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, float) and not math.isfinite(value):
        raise ArgumentError(f"{where}: {value} is not valid JSON (non-finite number)")
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    raise ArgumentError(f"{where}: cannot store a {type(value).__name__} in JSON metadata")


def artifact_metadata(meta: PredictorMetadata, state: PredictorState) -> dict[str, Any]:
    """The JSON document returned by the exported predictors' ``metadata()``.

    Args:
        meta: validated checkpoint metadata.
        state: the posterior the predictor evaluates; its kind and input columns must agree
            with ``meta``.

    Raises:
        ValueError: ``state`` and ``meta`` disagree (column names, dimension, n_inducing).
    """
    d = 3 * meta.m + 2
    if state.dim != d:
        raise CheckpointError(f"PredictorState.Z: expected d = 3m + 2 = {d} input columns (m = {meta.m}), got {state.dim}")
    if tuple(state.input_names) != tuple(meta.input_names):
        raise CheckpointError(
            f"PredictorState.input_names {list(state.input_names)} differ from metadata.input_names "
            f"{list(meta.input_names)}"
        )
    if not state.sparse:
        if meta.n_inducing is not None:
            raise CheckpointError(f"metadata.n_inducing: expected null for an exact GP, got {meta.n_inducing}")
    elif meta.n_inducing != state.n_support:
        raise CheckpointError(
            f"metadata.n_inducing: expected {state.n_support} (rows of PredictorState.Z) for a "
            f"{state.kind} GP, got {meta.n_inducing}"
        )
    if state.n_train != meta.n_train:
        raise CheckpointError(f"metadata.n_train = {meta.n_train} but PredictorState.n_train = {state.n_train}")
    n = 3 * meta.m
    noise_std = float(state.y_std) * math.sqrt(max(float(state.noise), 0.0))
    assert state.std_scale is not None and state.input_std is not None  # filled by PredictorState.__post_init__
    # the output q_u is in its joint's unit: the unit of the q̇_u column without "/s" (rad or m)
    rate_unit = meta.units.get(f"qd_{meta.unactuated_name}", "rad/s")
    out_unit = rate_unit[: -len("/s")] if rate_unit.endswith("/s") else "rad"
    doc = {
        "format": ARTIFACT_FORMAT,
        "robot": meta.robot,
        "joint_names": list(meta.joint_names),
        "actuated_names": list(meta.actuated_names),
        "unactuated_name": meta.unactuated_name,
        "m": meta.m,
        "inputs": list(meta.input_names[:n]),
        "full_inputs": list(meta.input_names),
        "units": {name: meta.units[name] for name in meta.input_names} | {"mean": out_unit, "std": out_unit},
        "outputs": {
            "forward": ["mean", "std"],
            "bem_mean": ["mean"],
            "predict_full": ["mean", "std"],
            "forward_latent": ["mean", "latent_std"],
            "predict_full_latent": ["mean", "latent_std"],
            "std": "calibrated band: std² = std_scale² · latent_std² + max(Σ_i (input_std_i · ∂mean/∂x_i)² over the "
                   "method's input columns, mean_k (mean's shift column k)²: the neighbouring derivative estimators' shifts and the mean's deviation "
                   "from other draws of its training rows, their variances summed) "
                   "(docs/uncertainty.md); observation noise excluded",
            "latent_std": "latent posterior std of f (eq. 12), observation noise excluded",
        },
        "uncertainty": {
            "std_scale": float(state.std_scale),
            "input_std": {name: float(v) for name, v in zip(meta.input_names, state.input_std.tolist())},
            "n_estimators": state.n_estimators,
            "calibration": jsonable(meta.extra.get("uncertainty"), where="metadata.extra.uncertainty"),
        },
        "model": state.kind,
        "n_train": meta.n_train,
        "n_inducing": meta.n_inducing,
        "n_support": state.n_support,
        "noise_std": noise_std,
        "hyperparameters": jsonable(meta.hyperparameters, where="metadata.hyperparameters"),
        "normalization": {
            "x_mean": state.x_mean.tolist(),
            "x_std": state.x_std.tolist(),
            "y_mean": float(state.y_mean),
            "y_std": float(state.y_std),
            "lengthscale": state.lengthscale.tolist(),
            "outputscale": float(state.outputscale),
            "noise": float(state.noise),
            "std_scale": float(state.std_scale),
            "input_std": state.input_std.tolist(),
        },
        "bemlearn_version": meta.bemlearn_version,
        "data_sha256": meta.data_sha256,
    }
    if state.linear_mean:   # eq. (L1): the plane under the GP, normalized and per input unit (q_u's unit per column unit)
        assert state.mean_slope is not None
        doc["normalization"]["mean_slope"] = state.mean_slope.tolist()
        doc["prior_mean"] = {"kind": "linear", "slope": {n: float(g) for n, g in zip(meta.input_names, state.prior_mean_gradient().tolist())},
                             # eq. (L3): the coefficients' variance is part of the latent std (and the band)
                             "coefficient_variance": state.plane_variance,
                             # eq. (L4): with the term the plane is the generalized-least-squares one under the kernel
                             "estimate": state.plane_estimate}
    if meta.extra:
        doc["extra"] = jsonable(meta.extra, where="metadata")
        if "checkpoint_sha256" in meta.extra:  # recorded by export_run (bemlearn.export.staleness)
            doc["checkpoint_sha256"] = meta.extra["checkpoint_sha256"]
    json.dumps(doc, allow_nan=False)  # fail here, not in the exported module
    return doc
