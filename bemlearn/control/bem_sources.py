"""Where the controller gets its BEM q_u^e from, chosen by name (``BEM_SOURCES``).

Every source maps a batch of BEM inputs ``x (B, 3m)`` = [q̈_a, q̇_a, q_a] (rad/s², rad/s,
rad; m/s², m/s, m for slides; the exported predictor's column order, eq. 14) to ``q_u^e (B,)``
in q_u's unit (rad for a hinge, m for a slide).

* ``predictor`` — the exported TorchScript file (``bem_predictor.pt``), its ``bem_mean``
  called every control tick: the learned BEM μ(x_0^e) of eq. (14).
* ``model`` — the model-based BEM of the *nominal* robot (eq. 9), by a warm-started,
  safeguarded Newton iteration on Γ_0 per row (falls back to the bracketed solver).
* ``zero`` — q_u^e ≡ nominal (plain balancing), a baseline.

All three satisfy :class:`BEMSource`, the interface :class:`~bemlearn.control.EICController`
and :func:`~bemlearn.pipeline.lemma.learned_lemma1` call.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from bemlearn._lazy import lazy_module
from bemlearn.errors import ArgumentError, ConfigError, MissingFileError
from bemlearn.robots.protocol import BalanceRobot, ControlRobot

if TYPE_CHECKING:
    import torch
else:
    torch = lazy_module("torch")

__all__ = ["BEM_SOURCES", "BEMSource", "PredictorBEM", "ModelBEM", "ZeroBEM", "make_bem_source"]


@runtime_checkable
class BEMSource(Protocol):
    """A BEM the controller can call: the learned BEM μ(x_0^e) (eq. 14) and the full learned map
    f (eq. 11), or their model-based counterparts (eq. 9, 5).

    ``__call__``: ``x (B, 3m)`` = [q̈_a, q̇_a, q_a] → q_u^e ``(B,)``.
    ``full``: ``x (B, 3m + 2)`` = [q̈_a, q̇_a, q_a, q̈_u, q̇_u] → q_u ``(B,)``.
    Units follow the joints (q_a in rad or m and its rates; q_u in rad or m); float64 numpy arrays.
    """

    @property
    def name(self) -> str:
        """The source's name in :data:`BEM_SOURCES` (or another label)."""
        ...

    def __call__(self, x: np.ndarray) -> np.ndarray: ...

    def full(self, x: np.ndarray) -> np.ndarray: ...


class PredictorBEM:
    """The exported TorchScript predictor's ``bem_mean`` (module docstring)."""

    name = "predictor"

    def __init__(self, path: str | Path, *, robot: BalanceRobot | None = None) -> None:
        from bemlearn.export.torchscript import load_torchscript

        path = Path(path)
        if not path.is_file():
            raise MissingFileError(f"BEM predictor file {path} not found (run `bemlearn export RUN_DIR` first)")
        # CheckpointError (a ValueError) for a foreign or tampered file, before any of its code is loaded
        self.module = load_torchscript(path)
        self.meta = json.loads(self.module.metadata())
        if robot is not None and (self.meta.get("robot") != robot.name or int(self.meta.get("m", -1)) != robot.m):
            raise ArgumentError(
                f"{path}: predictor is for robot {self.meta.get('robot')!r} (m = {self.meta.get('m')}), "
                f"but the controller runs {robot.name!r} (m = {robot.m})"
            )
        self.path = path

    def __call__(self, x: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.module.bem_mean(torch.from_numpy(x)).numpy()

    def full(self, x: np.ndarray) -> np.ndarray:
        """The full learned map f of eq. (11): ``x (B, 3m + 2)`` = [q̈_a, q̇_a, q_a, q̈_u, q̇_u] → q_u (B,)."""
        with torch.no_grad():
            return self.module.full_mean(torch.from_numpy(x)).numpy()

    def mean_std(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and posterior std (q_u's unit) for logging/plots (slower than ``__call__``)."""
        with torch.no_grad():
            mean, std = self.module(torch.from_numpy(np.ascontiguousarray(x)))
        return mean.numpy(), std.numpy()


class ModelBEM:
    """Model-based BEM of a nominal robot with a ``gamma0_scalar`` fast path (eq. 6–9).

    Each row is solved by Newton's iteration on Γ_0 (Γ for :meth:`full`) in q_u with a central-difference
    slope (step 1e-7), to |Γ| ≤ 1e-12 or a step ≤ 1e-14, at most 30 iterations, never leaving the admissible
    range; the rows of a call iterate together (their Γ evaluated by the robot's ``gamma_rows`` in one loop when
    it has one).  Starts: :meth:`__call__` from the previous call's roots when it had as many rows (the nominal
    value otherwise), :meth:`full` from the first root of the last :meth:`__call__`.  A row that does not
    converge falls back to the bracketed solver (:meth:`__call__`) or is NaN (:meth:`full`).

    Starting :meth:`full` from the previous tick's root instead saves few evaluations and moves the closed
    loop's numbers (measured in docs/timings.md), so it is not done.
    """

    name = "model"

    def __init__(self, robot: ControlRobot) -> None:
        self.robot = robot
        self.m = robot.m
        self.lo, self.hi = robot.qu_range
        self._last: np.ndarray | None = None

    def _gamma(self, x: np.ndarray, qa: np.ndarray, qad: np.ndarray, qadd: np.ndarray, qud: np.ndarray, qudd: np.ndarray) -> np.ndarray:
        """Γ of rows ``x (R,)`` (q_u) with ``qa, qad, qadd (R, m)``, ``qud, qudd (R,)``."""
        rows = getattr(self.robot, "gamma_rows", None)
        if rows is not None:
            return np.asarray(rows(x, qa, qad, qadd, qud, qudd), dtype=np.float64)
        g = self.robot.gamma0_scalar
        return np.array([g(float(x[r]), qa[r], qad[r], qadd[r], float(qud[r]), float(qudd[r])) for r in range(x.shape[0])], dtype=np.float64)

    def _newton_one(self, x0: float, qa: np.ndarray, qad: np.ndarray, qadd: np.ndarray, qud: float, qudd: float) -> float:
        """:meth:`_newton` of one row through ``gamma0_scalar`` (the per-tick call: no array bookkeeping)."""
        g = self.robot.gamma0_scalar
        x = x0
        h = 1e-7
        for _ in range(30):
            f = g(x, qa, qad, qadd, qud, qudd)
            if abs(f) <= 1e-12:
                return x
            df = (g(x + h, qa, qad, qadd, qud, qudd) - g(x - h, qa, qad, qadd, qud, qudd)) / (2 * h)
            if df == 0 or not math.isfinite(df):
                return math.nan
            x_new = x - f / df
            if not (self.lo <= x_new <= self.hi):
                return math.nan
            if abs(x_new - x) <= 1e-14:
                return x_new
            x = x_new
        return math.nan

    def _newton(self, x0: np.ndarray, qa: np.ndarray, qad: np.ndarray, qadd: np.ndarray, qud: np.ndarray, qudd: np.ndarray) -> np.ndarray:
        """Newton roots of Γ per row from ``x0 (R,)`` (class docstring); NaN where a row did not converge."""
        if np.shape(x0)[0] == 1:
            return np.array([self._newton_one(float(x0[0]), qa[0], qad[0], qadd[0], float(qud[0]), float(qudd[0]))])
        h = 1e-7
        x = np.array(x0, dtype=np.float64)
        out = np.full(x.shape[0], np.nan)
        act = np.arange(x.shape[0])
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for _ in range(30):
                if act.size == 0:
                    break
                xa = x[act]
                f = self._gamma(xa, qa[act], qad[act], qadd[act], qud[act], qudd[act])
                done = np.abs(f) <= 1e-12
                out[act[done]] = xa[done]
                act, xa, f = act[~done], xa[~done], f[~done]
                if act.size == 0:
                    break
                k = act.size
                two = np.concatenate([act, act])
                fpm = self._gamma(np.concatenate([xa + h, xa - h]), qa[two], qad[two], qadd[two], qud[two], qudd[two])
                df = (fpm[:k] - fpm[k:]) / (2 * h)
                x_new = xa - f / df
                fail = (df == 0) | ~np.isfinite(df) | ~((self.lo <= x_new) & (x_new <= self.hi))
                small = ~fail & (np.abs(x_new - xa) <= 1e-14)
                out[act[small]] = x_new[small]
                keep = ~fail & ~small
                x[act[keep]] = x_new[keep]
                act = act[keep]
        return out

    def __call__(self, x: np.ndarray) -> np.ndarray:
        m, B = self.m, x.shape[0]
        start = self._last if self._last is not None and self._last.shape[0] == B else np.full(B, self.robot.qu_nominal)
        zeros = np.zeros(B)
        qadd, qad, qa = x[:, :m], x[:, m : 2 * m], x[:, 2 * m : 3 * m]
        out = self._newton(start, qa, qad, qadd, zeros, zeros)
        miss = np.flatnonzero(np.isnan(out))
        if miss.size:  # no convergence from the warm start: bracket from scratch
            res = self.robot.bem(torch.from_numpy(np.ascontiguousarray(qa[miss])), torch.from_numpy(np.ascontiguousarray(qad[miss])),
                                 torch.from_numpy(np.ascontiguousarray(qadd[miss])))
            out[miss] = res.qu.numpy()
        self._last = out.copy()
        return out

    def full(self, x: np.ndarray) -> np.ndarray:
        """Root of Γ(q_u; q_a, with q̈_u, q̇_u given) = 0 (eq. 5): ``x (B, 3m + 2)`` → (B,)."""
        m, B = self.m, x.shape[0]
        start = np.full(B, float(self._last[0]) if self._last is not None else self.robot.qu_nominal)
        return self._newton(start, x[:, 2 * m : 3 * m], x[:, m : 2 * m], x[:, :m], x[:, 3 * m + 1], x[:, 3 * m])


class ZeroBEM:
    """q_u^e ≡ nominal (upright): plain balancing without a balance manifold."""

    name = "zero"

    def __init__(self, nominal: float = 0.0) -> None:
        self.nominal = nominal

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return np.full(x.shape[0], self.nominal)

    full = __call__


BEM_SOURCES = ("predictor", "model", "zero")


def make_bem_source(name: str, *, robot: ControlRobot, predictor: str | Path | None = None) -> BEMSource:
    """Build a BEM source by name for ``robot`` (the nominal robot for ``model``)."""
    if name == "predictor":
        if predictor is None:
            raise ConfigError("BEM source 'predictor' needs a predictor file (simulate.predictor or --predictor)")
        return PredictorBEM(predictor, robot=robot)
    if name == "model":
        return ModelBEM(robot)
    if name == "zero":
        return ZeroBEM(robot.qu_nominal)
    raise ConfigError(f"unknown BEM source {name!r}; choose one of {list(BEM_SOURCES)}")
