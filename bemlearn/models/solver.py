"""The explicit linear-solver policy of every bemlearn GP: dense Cholesky with logged jitter.

GPyTorch switches from Cholesky to conjugate gradients above
``gpytorch.settings.max_cholesky_size`` (800 by default) with a loose tolerance, and with
small noise the posterior mean of eq. (12) then drifts visibly (docs/design.md, "Solver
policy").  bemlearn therefore solves K v = b by Cholesky, K = L Lᵀ, at every size, in training and in
prediction (:func:`cholesky_policy`).

A Cholesky that fails (K only positive semi-definite in floating point, e.g. duplicated
inputs with tiny noise) is retried on K + j I with j = j₀, 10 j₀, 100 j₀, … ; each retry
is issued as a :class:`bemlearn.warnings.NumericalWarning` and logged, never printed and never turned into NaN.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from contextvars import ContextVar

import gpytorch
import linear_operator
import torch
from linear_operator.utils.warnings import NumericalWarning as GPyTorchNumericalWarning

from bemlearn.errors import NumericalError
from bemlearn.warnings import NumericalWarning, warn

__all__ = ["cholesky_policy", "robust_cholesky", "DEFAULT_JITTER", "DEFAULT_MAX_TRIES"]

logger = logging.getLogger(__name__)

#: First jitter j₀ (absolute, normalized output units squared) for float64 matrices.
DEFAULT_JITTER = 1e-8
#: Number of retries: the last one adds j₀ · 10^(max_tries − 1) (1e-1 by default).
DEFAULT_MAX_TRIES = 8

#: (j₀, max_tries) of the innermost active :func:`cholesky_policy`; what :func:`robust_cholesky` uses when
#: it is not given them.
_POLICY: ContextVar[tuple[float, int]] = ContextVar("cholesky_policy", default=(DEFAULT_JITTER, DEFAULT_MAX_TRIES))


@contextmanager
def cholesky_policy(*, jitter: float = DEFAULT_JITTER, max_tries: int = DEFAULT_MAX_TRIES) -> Iterator[None]:
    """Run GPyTorch with dense Cholesky solves at every size and log jitter warnings.

    Sets ``max_cholesky_size(10**9)``, turns ``fast_computations`` (CG / Lanczos) off,
    sets the float64 Cholesky jitter j₀ and the number of retries, and re-issues GPyTorch's
    ``NumericalWarning`` (jitter added, variance clamped) as a :class:`bemlearn.warnings.NumericalWarning`
    logged on this module's logger.  Inside it,
    :func:`robust_cholesky` follows the same j₀ and retries unless given others.

    Args:
        jitter: first jitter j₀ added to the diagonal when a Cholesky fails (float64).
        max_tries: retries with j₀, 10 j₀, … before ``NotPSDError`` is raised.
    """
    with ExitStack() as stack:
        stack.enter_context(gpytorch.settings.max_cholesky_size(10**9))
        stack.enter_context(
            gpytorch.settings.fast_computations(covar_root_decomposition=False, log_prob=False, solves=False)
        )
        stack.enter_context(linear_operator.settings.cholesky_jitter(float_value=jitter * 100, double_value=jitter))
        stack.enter_context(linear_operator.settings.cholesky_max_tries(max_tries))
        token = _POLICY.set((jitter, max_tries))
        stack.callback(_POLICY.reset, token)
        stack.enter_context(warnings.catch_warnings())
        warnings.filterwarnings("always", category=GPyTorchNumericalWarning)
        previous = warnings.showwarning

        def _show(message, category, filename, lineno, file=None, line=None):
            if issubclass(category, GPyTorchNumericalWarning):  # re-issued as bemlearn's, at GPyTorch's line
                warnings.warn_explicit(NumericalWarning(str(message)), NumericalWarning, filename, lineno)
                logger.warning("%s", message)
            else:
                previous(message, category, filename, lineno, file, line)

        warnings.showwarning = _show
        yield


def robust_cholesky(
    A: torch.Tensor, *, what: str, jitter: float | None = None, max_tries: int | None = None
) -> tuple[torch.Tensor, float]:
    """Lower Cholesky factor L of A (A = L Lᵀ), adding diagonal jitter if A is not numerically PD.

    Tries A, then A + j I with j = j₀·10^i, i = 0 … max_tries − 1 (the same sequence as
    GPyTorch under :func:`cholesky_policy`), logging a warning that names ``what``.

    Args:
        A: ``(M, M)`` symmetric matrix (e.g. K_ZZ), normalized output units squared.
        what: what A is, for the log and error messages, e.g. ``"K_ZZ"``.
        jitter: first jitter j₀ (``None``: that of the active :func:`cholesky_policy`, else :data:`DEFAULT_JITTER`).
        max_tries: number of jittered retries (``None``: the active policy's, else :data:`DEFAULT_MAX_TRIES`).

    Returns:
        ``(L, j)``: the ``(M, M)`` lower factor of A + j I and the jitter j actually added (0.0 if none).

    Raises:
        NumericalError: (a RuntimeError) A contains NaN/inf, or is still not PD after the last retry.
    """
    if not bool(torch.isfinite(A).all()):
        raise NumericalError(f"{what}: matrix contains NaN or inf; cannot factorize")
    policy_jitter, policy_tries = _POLICY.get()
    jitter = policy_jitter if jitter is None else jitter
    max_tries = policy_tries if max_tries is None else max_tries
    L, info = torch.linalg.cholesky_ex(A)
    if not bool(info.any()):
        return L, 0.0
    eye = torch.eye(A.shape[-1], dtype=A.dtype, device=A.device)
    for i in range(max_tries):
        j = jitter * 10**i
        warn(NumericalWarning, logger, "%s not positive definite; added jitter of %.1e to the diagonal", what, j)
        L, info = torch.linalg.cholesky_ex(A + j * eye)
        if not bool(info.any()):
            return L, j
    raise NumericalError(f"{what}: not positive definite even after adding jitter {jitter * 10 ** (max_tries - 1):.1e}")
