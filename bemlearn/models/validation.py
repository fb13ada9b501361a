"""Input checks shared by the GP models: shapes, dtypes and finiteness, with named errors."""

from __future__ import annotations

import torch

from bemlearn.errors import ArgumentError, DataError

__all__ = ["check_inputs", "check_targets"]


def check_inputs(x: object, *, name: str, dim: int | None = None, dtype: torch.dtype | None = None) -> torch.Tensor:
    """Check that ``x`` is a finite ``(N, d)`` floating tensor and return it.

    Args:
        x: the candidate ``(N, d)`` tensor (normalized GP inputs).
        name: the argument name used in error messages, e.g. ``"train_x"``.
        dim: the required number of columns d, if known.
        dtype: the required dtype, if known (GP work is float64).

    Raises:
        TypeError: ``x`` is not a tensor or has the wrong dtype.
        ValueError: wrong shape, no rows, or non-finite entries (the first bad row is named).
    """
    x = _check_float_tensor(x, name, "(N, d)", dtype)
    if x.ndim != 2:
        raise ArgumentError(f"{name}: expected shape (N, d), got {tuple(x.shape)}")
    if x.shape[0] == 0:
        raise ArgumentError(f"{name}: expected at least one row, got shape {tuple(x.shape)}")
    if dim is not None and x.shape[1] != dim:
        raise ArgumentError(f"{name}: expected {dim} columns, got shape {tuple(x.shape)}")
    _check_finite(x, name)
    return x


def check_targets(y: object, *, name: str, n: int, dtype: torch.dtype | None = None) -> torch.Tensor:
    """Check that ``y`` is a finite ``(n,)`` floating tensor and return it.

    Args:
        y: the candidate ``(n,)`` tensor (normalized GP outputs).
        name: the argument name used in error messages, e.g. ``"train_y"``.
        n: the required length (the number of input rows).
        dtype: the required dtype, if known.

    Raises:
        TypeError: ``y`` is not a tensor or has the wrong dtype.
        ValueError: wrong shape or non-finite entries (the first bad row is named).
    """
    y = _check_float_tensor(y, name, f"({n},)", dtype)
    if tuple(y.shape) != (n,):
        raise ArgumentError(f"{name}: expected shape ({n},), got {tuple(y.shape)}")
    _check_finite(y, name)
    return y


def _check_float_tensor(t: object, name: str, shape: str, dtype: torch.dtype | None) -> torch.Tensor:
    """TypeError naming ``name`` unless ``t`` is a floating tensor (of ``dtype`` if given)."""
    if not isinstance(t, torch.Tensor):
        raise ArgumentError(f"{name}: expected a torch.Tensor of shape {shape}, got {type(t).__name__}")
    if not t.is_floating_point():
        raise ArgumentError(f"{name}: expected a floating-point tensor, got dtype {t.dtype}")
    if dtype is not None and t.dtype != dtype:
        raise ArgumentError(f"{name}: expected dtype {dtype}, got {t.dtype}")
    return t


def _check_finite(t: torch.Tensor, name: str) -> None:
    bad = ~torch.isfinite(t)
    if bool(bad.any()):
        rows = bad.reshape(t.shape[0], -1).any(dim=1).nonzero().flatten()
        raise DataError(
            f"{name}: {int(rows.numel())} row(s) contain NaN or inf, first at row {int(rows[0])}"
        )
