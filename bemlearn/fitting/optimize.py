"""Full-batch minimization loops (L-BFGS, Adam) with callbacks, progress bar and failure recovery.

An evaluation whose loss is not finite, or whose Cholesky fails even after jitter, restores
the best parameters evaluated so far; L-BFGS then restarts from them with a fresh curvature
history (a line-search trial far out, such as an overflowing lengthscale, is the usual cause),
up to three times, and otherwise the fit stops with a logged warning.  It never leaves NaN
parameters behind.

:class:`KeptParameters` is that keep-best / Ctrl-C logic on its own: :func:`minimize` and the
minibatch loop of :func:`~bemlearn.fitting.svgp.fit_svgp` both run inside it.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager

import torch
from linear_operator.utils.errors import NanError, NotPSDError
from tqdm.auto import tqdm

from bemlearn.errors import ArgumentError, NumericalError
from bemlearn.fitting.result import Callback, FitResult
from bemlearn.interrupts import check_interrupt, interruptible
from bemlearn.warnings import FitWarning, warn

__all__ = ["minimize", "KeptParameters", "checked_loss", "default_lr", "NumericalFailure"]

logger = logging.getLogger(__name__)


class NumericalFailure(NumericalError):
    """A loss evaluation produced NaN/inf or an unrecoverable Cholesky failure."""


#: What a loss evaluation raises when its numbers fail (and nothing else: a shape bug or a
#: ``ValueError`` in the loss is a bug and propagates).
NUMERICAL_ERRORS: tuple[type[BaseException], ...] = (NotPSDError, NanError, torch.linalg.LinAlgError, NumericalError)


def checked_loss(loss_fn: Callable[[], torch.Tensor]) -> torch.Tensor:
    """``loss_fn()``, raising :class:`NumericalFailure` if it is not finite or its Cholesky failed.

    Only numerical failures (:data:`NUMERICAL_ERRORS`: linear_operator's ``NotPSDError`` and
    ``NanError``, ``torch.linalg.LinAlgError``, :class:`~bemlearn.errors.NumericalError`) become a
    :class:`NumericalFailure`; any other exception of ``loss_fn`` propagates unchanged.
    """
    try:
        loss = loss_fn()
    except NUMERICAL_ERRORS as exc:
        raise NumericalFailure(str(exc)) from exc
    if not bool(torch.isfinite(loss)):
        raise NumericalFailure(f"loss is {float(loss.detach())}")
    return loss


class KeptParameters:
    """The values a fit falls back to, and how a fit ends early (one implementation for every loop).

    ``keep()`` copies the parameters' current values; ``offer(loss)`` keeps them when ``loss`` is the
    lowest seen (keep-best), and ``restore()`` writes the kept values back.  Inside :meth:`guard`:

    * a :class:`NumericalFailure` restores the kept values, logs a warning and ends the block
      (``failed`` is then true: the fit's stop reason is ``"numerical failure"``);
    * Ctrl-C or SIGTERM (:mod:`bemlearn.interrupts`; the loop calls
      :func:`~bemlearn.interrupts.check_interrupt` between evaluations) restores them and re-raises
      :class:`KeyboardInterrupt`, so the caller can save what it has.

    Args:
        params: the parameters to keep (the initial values are kept at the start).
        desc: the fit's name in log messages.
        kept: what the kept values are, for the messages (``"best"`` or ``"last good"``).
        unit: what :attr:`count` counts, for the messages (``"evaluations"``, ``"steps"``).
    """

    def __init__(self, params: Iterable[torch.nn.Parameter], *, desc: str, kept: str = "best", unit: str = "evaluations") -> None:
        self.params = list(params)
        self.values = [p.detach().clone() for p in self.params]
        self.best = math.inf
        self.count = 0
        self.failed = False
        self.desc, self.kept, self.unit = desc, kept, unit

    def keep(self) -> None:
        """Keep the parameters' current values."""
        with torch.no_grad():
            for p, v in zip(self.params, self.values):
                v.copy_(p)

    def offer(self, loss: float) -> None:
        """Keep the current values if ``loss`` is the lowest offered so far."""
        if loss < self.best:
            self.best = loss
            self.keep()

    def restore(self) -> None:
        """Write the kept values back into the parameters."""
        with torch.no_grad():
            for p, v in zip(self.params, self.values):
                p.copy_(v)

    @contextmanager
    def guard(self) -> Iterator[KeptParameters]:
        """The fit loop's block: interruptible, restoring the kept values on a numerical failure or Ctrl-C."""
        with interruptible():
            try:
                yield self
            except NumericalFailure as exc:
                self.restore()
                self.failed = True
                warn(FitWarning, logger, "%s: numerical failure after %d %s (%s); keeping the %s parameters",
                                         self.desc, self.count, self.unit, exc, self.kept)
            except KeyboardInterrupt:
                self.restore()
                loss = f" (loss {self.best:.6g})" if math.isfinite(self.best) else ""
                logger.warning("%s: interrupted after %d %s; keeping the %s parameters%s",
                               self.desc, self.count, self.unit, self.kept, loss)
                raise


def default_lr(optimizer: str, lr: float | None) -> float:
    """``lr``, or 1.0 for L-BFGS (initial step) and 0.05 for Adam when it is ``None``."""
    if lr is not None:
        return lr
    return 1.0 if optimizer == "lbfgs" else 0.05


def minimize(
    loss_fn: Callable[[], torch.Tensor],
    params: Sequence[torch.nn.Parameter],
    *,
    optimizer: str,
    max_iter: int,
    lr: float,
    tol: float,
    metrics_fn: Callable[[], dict[str, float]],
    callback: Callback | None = None,
    progress: bool = False,
    desc: str = "fit",
    kind: str = "fit",
) -> FitResult:
    """Minimize ``loss_fn()`` over ``params`` with L-BFGS (strong Wolfe line search) or Adam.

    The callback is called after every loss evaluation (L-BFGS: every function evaluation,
    including line-search trials; Adam: every step) with the loss at the evaluated point.
    At the end the parameters are those of the lowest loss evaluated.

    Args:
        loss_fn: returns the ``()`` loss for the current parameters (graph attached).
        params: the parameters (those with ``requires_grad`` are optimized).
        optimizer: ``"lbfgs"`` or ``"adam"``.
        max_iter: L-BFGS iterations (≤ 1.5 · max_iter evaluations) or Adam steps.
        lr: learning rate.
        tol: L-BFGS stops when the loss or the parameters change by less than ``tol`` in an
            iteration; Adam stops after 50 steps without an improvement larger than ``tol``
            (0 disables both).
        metrics_fn: extra metrics for the callback (hyperparameters).
        callback: ``callback(step, metrics)``.
        progress: show a tqdm progress bar.
        desc: progress-bar label.
        kind: what is fitted, recorded as :attr:`FitResult.kind` (the GP kind, ``"gpdm"``, ...).

    Returns:
        a :class:`FitResult`: the final loss (at the kept parameters), the loss evaluations, the
        stop reason (``"converged"``, ``"max_iter"`` or ``"numerical failure"``), the seconds and
        the final metrics.
    """
    start = time.perf_counter()
    params = [p for p in params if p.requires_grad]
    if optimizer not in ("lbfgs", "adam"):
        raise ArgumentError(f"optimizer: unknown {optimizer!r}; valid are ['adam', 'lbfgs']")
    kept = KeptParameters(params, desc=desc)
    state = {"since_best": 0, "iter_base": 0}
    max_eval = int(max_iter * 1.5) if optimizer == "lbfgs" else max_iter

    def lbfgs(max_iter: int, max_eval: int) -> torch.optim.LBFGS:
        return torch.optim.LBFGS(params, lr=lr, max_iter=max_iter, max_eval=max_eval, history_size=50,
                                 line_search_fn="strong_wolfe", tolerance_grad=1e-9, tolerance_change=tol)

    opt: torch.optim.Optimizer = lbfgs(max_iter, max_eval) if optimizer == "lbfgs" else torch.optim.Adam(params, lr=lr)

    def closure() -> torch.Tensor:
        check_interrupt()  # between evaluations, also inside one L-BFGS iteration's line search
        opt.zero_grad(set_to_none=True)
        loss = checked_loss(loss_fn)
        loss.backward()
        value = float(loss.detach())
        state["since_best"] = 0 if value < kept.best - tol else state["since_best"] + 1
        kept.offer(value)
        metrics = {"loss": value, **metrics_fn(), "lr": float(opt.param_groups[0]["lr"])}
        if callback is not None:
            callback(kept.count, metrics)
        kept.count += 1
        # the bar counts what max_iter bounds: L-BFGS iterations (an iteration may evaluate several times), Adam steps
        done = state["iter_base"] + _lbfgs_iterations(opt) if optimizer == "lbfgs" else kept.count
        bar.update(max(0, min(done, max_iter) - bar.n))
        bar.set_postfix(loss=f"{value:.5f}", evals=kept.count)
        return loss

    stop = "max_iter"
    with tqdm(total=max_iter, desc=desc, unit="it", disable=not progress, leave=False) as bar, kept.guard():
        if optimizer == "lbfgs":
            # a line-search trial far out (e.g. an overflowing lengthscale) fails numerically:
            # restart from the best point with a fresh curvature history, up to 3 times
            for restart in range(4):
                try:
                    opt.step(closure)  # type: ignore[arg-type]  # torch's stub wants a float closure; LBFGS uses the Tensor
                except NumericalFailure as exc:
                    if restart == 3 or kept.count >= max_eval or not math.isfinite(kept.best):
                        raise
                    logger.info("%s: numerical failure after %d evaluations (%s); restarting L-BFGS from the best "
                                "parameters", desc, kept.count, exc)
                    kept.restore()
                    state["iter_base"] += _lbfgs_iterations(opt)
                    left = max_eval - kept.count
                    opt = lbfgs(max(1, int(left / 1.5)), left)
                    continue
                n_iter = _lbfgs_iterations(opt)
                if n_iter < opt.defaults["max_iter"] and kept.count < max_eval:
                    stop = "converged"
                break
        else:
            for _ in range(max_iter):
                opt.step(closure)  # type: ignore[arg-type]  # torch's stub wants a float closure; a Tensor works
                if tol > 0 and state["since_best"] >= 50:
                    stop = "converged"
                    break
    if kept.failed:
        stop = "numerical failure"
    kept.restore()
    with torch.no_grad():
        final = float(checked_loss(loss_fn))
    metrics = {"loss": final, **metrics_fn(), "lr": float(opt.param_groups[0]["lr"])}
    return FitResult(kind, final, kept.count, time.perf_counter() - start, stop, metrics)


def _lbfgs_iterations(opt: torch.optim.Optimizer) -> int:
    """Iterations an L-BFGS optimizer has completed (its own count, kept in the state of its one
    parameter group's first parameter)."""
    return int(opt.state[opt.param_groups[0]["params"][0]].get("n_iter", 0))
