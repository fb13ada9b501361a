"""The underactuated balance robot interface shared by every robot model.

A robot with n coordinates q (columns in :attr:`Robot.joint_names` order) has one
unactuated coordinate q_u and m = n − 1 actuated coordinates q_a (eq. 2a/2b):

    D(q) q̈ + C(q, q̇) q̇ + G(q) = B u + τ_p(q, q̇),        B = rows of I for q_a, 0 for q_u   (1)

where τ_p are passive generalized forces (joint damping, springs), which the paper folds
into C.  Implementations supply D (:meth:`Robot.mass_matrix`), C q̇ + G
(:meth:`Robot.bias`) and τ_p (:meth:`Robot.passive`); everything else — the
unactuated-row residual Γ (eq. 5), Γ_0 (eq. 7) and the model-based BEM (eq. 6, 9) — is
defined here once, so every robot (MuJoCo or analytic) shares it.

All tensors are float64; batched arguments have a leading batch dimension B.  Units follow
the joint (:mod:`bemlearn.units`): a hinge coordinate is in rad (rates rad/s, rad/s²; force
N·m), a slide coordinate in m (m/s, m/s²; force N).  "rad" below is short for "rad, or m for
a slide", "N·m" for "N·m, or N for a slide".
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from bemlearn._lazy import lazy_module
from bemlearn.errors import ArgumentError
from bemlearn.robots.bem import BEMResult, find_roots, solve_bem

if TYPE_CHECKING:
    import torch
else:
    torch = lazy_module("torch")

__all__ = ["Robot", "as_batch"]


def as_batch(x, width: int, name: str, *, func: str, units: str = "") -> torch.Tensor:
    """Validate a batched ``(B, width)`` float input and return it as a float64 tensor.

    Raises:
        ValueError: naming ``func``, the argument, the expected shape and what was given,
            or the first non-finite entry.
    """
    t = torch.as_tensor(x, dtype=torch.float64)
    if t.ndim != 2 or t.shape[1] != width:
        raise ArgumentError(
            f"{func}: argument {name!r} must have shape (B, {width}){' [' + units + ']' if units else ''}, "
            f"got {tuple(t.shape)}"
        )
    if not torch.isfinite(t).all():
        bad = (~torch.isfinite(t)).nonzero()[0].tolist()
        raise ArgumentError(f"{func}: argument {name!r} has a non-finite value at index {tuple(bad)}")
    return t


class Robot(abc.ABC):
    """An n-DOF robot with one unactuated coordinate (eq. 1, 2a, 2b).

    Attributes:
        name: registry name or model name.
        joint_names: the n coordinate names, in column order of every ``q`` tensor.
        unactuated_index: column of q_u in ``q``.
        qu_range: ``(lo, hi)`` admissible range of q_u searched for the BEM (rad or m).
        qu_nominal: nominal (upright) value of q_u; the BEM root nearest to it is returned.
    """

    name: str
    joint_names: tuple[str, ...]
    unactuated_index: int
    qu_range: tuple[float, float]
    qu_nominal: float

    # ---- partition -------------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of coordinates."""
        return len(self.joint_names)

    @property
    def m(self) -> int:
        """Number of actuated coordinates, n − 1."""
        return self.n - 1

    @property
    def actuated_index(self) -> tuple[int, ...]:
        return tuple(i for i in range(self.n) if i != self.unactuated_index)

    @property
    def actuated_names(self) -> tuple[str, ...]:
        return tuple(self.joint_names[i] for i in self.actuated_index)

    @property
    def unactuated_name(self) -> str:
        return self.joint_names[self.unactuated_index]

    @property
    def coordinate_kinds(self) -> tuple[str, ...]:
        """``"hinge"`` or ``"slide"`` per coordinate: its units are rad or m (:mod:`bemlearn.units`)."""
        return ("hinge",) * self.n

    def split(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``q (B, n)`` → ``(q_a (B, m), q_u (B,))``."""
        return q[:, list(self.actuated_index)], q[:, self.unactuated_index]

    def join(self, qa: torch.Tensor, qu: torch.Tensor) -> torch.Tensor:
        """``q_a (B, m)``, ``q_u (B,)`` → ``q (B, n)`` in joint order."""
        cols = list(qa.unbind(-1))
        cols.insert(self.unactuated_index, qu)
        return torch.stack(cols, dim=-1)

    # ---- dynamics supplied by implementations ------------------------------------------
    @abc.abstractmethod
    def mass_matrix(self, q: torch.Tensor) -> torch.Tensor:
        """D(q) of eq. (1). ``q: (B, n)`` in each joint's unit (rad or m) → ``(B, n, n)``."""

    @abc.abstractmethod
    def bias(self, q: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """C(q, q̇) q̇ + G(q) of eq. (1). ``q, qd: (B, n)`` rad, rad/s (m, m/s for slides) → ``(B, n)`` N·m (N for slides)."""

    @abc.abstractmethod
    def passive(self, q: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """Passive generalized forces τ_p (damping, springs) acting on the robot, ``(B, n)``."""

    # ---- derived quantities ------------------------------------------------------------
    def inverse_dynamics(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor) -> torch.Tensor:
        """τ = D q̈ + C q̇ + G − τ_p: the generalized force the inputs must supply, ``(B, n)``.

        Its unactuated entry is Γ (eq. 5) and must vanish along any motion of the robot.
        """
        q, qd, qdd = self._states(q, qd, qdd, func="inverse_dynamics")
        return torch.einsum("bij,bj->bi", self.mass_matrix(q), qdd) + self.bias(q, qd) - self.passive(q, qd)

    def gamma(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor) -> torch.Tensor:
        """Γ = D_ua q̈_a + D_uu q̈_u + C_ua q̇_a + C_uu q̇_u + G_u − τ_p,u  (eq. 5), ``(B,)`` N·m.

        Zero along every trajectory of the robot (eq. 2b / 4).
        """
        return self.inverse_dynamics(q, qd, qdd)[:, self.unactuated_index]

    def gamma0(self, qu: torch.Tensor, qa: torch.Tensor, qad: torch.Tensor, qadd: torch.Tensor) -> torch.Tensor:
        """Γ_0(q_u; q_a) = Γ at q̇_u = q̈_u = 0 (eq. 7), ``(B,)`` N·m (N if q_u is a slide).

        Args:
            qu: ``(B,)`` candidate unactuated coordinate, in its joint's unit (rad for a hinge, m for a slide).
            qa: ``(B, m)`` actuated positions q_a, each in its joint's unit (rad or m).
            qad: ``(B, m)`` actuated velocities q̇_a (rad/s or m/s).
            qadd: ``(B, m)`` actuated accelerations q̈_a (rad/s² or m/s²).
        """
        zeros = torch.zeros_like(qu)
        return self.gamma(self.join(qa, qu), self.join(qad, zeros), self.join(qadd, zeros))

    # ---- single-state NumPy path (control loops, the derivation of defaults) ----------------
    def terms(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """D(q) ``(n, n)`` and h = C(q, q̇) q̇ + G(q) − τ_p ``(n,)`` for one state ``q, qd (n,)`` (eq. 1: D q̈ + h = B u).

        This version evaluates the batched torch terms; implementations override it with a faster path.
        """
        qt = torch.as_tensor(np.asarray(q, dtype=np.float64))[None]
        qdt = torch.as_tensor(np.asarray(qd, dtype=np.float64))[None]
        return self.mass_matrix(qt)[0].numpy(), (self.bias(qt, qdt) - self.passive(qt, qdt))[0].numpy()

    def gamma0_scalar(self, qu: float, qa: np.ndarray, qad: np.ndarray, qadd: np.ndarray, qud: float = 0.0, qudd: float = 0.0) -> float:
        """Γ (eq. 5) for one state; Γ_0 (eq. 7) with the default q̇_u = q̈_u = 0 (N·m, N for a slide q_u).

        This version evaluates :meth:`gamma` on a batch of one; implementations override it with a faster path.
        """
        def joined(a: np.ndarray, u: float) -> torch.Tensor:
            return self.join(torch.as_tensor(np.asarray(a, dtype=np.float64).reshape(1, self.m)), torch.tensor([float(u)], dtype=torch.float64))

        return float(self.gamma(joined(qa, qu), joined(qad, qud), joined(qadd, qudd))[0])

    def gamma_rows(self, qu: np.ndarray, qa: np.ndarray, qad: np.ndarray, qadd: np.ndarray,
                   qud: np.ndarray | None = None, qudd: np.ndarray | None = None) -> np.ndarray:
        """Γ (eq. 5) for many states in NumPy; Γ_0 (eq. 7) with the default q̇_u = q̈_u = 0 (N·m, N for a slide q_u).

        Row r is :meth:`gamma0_scalar` of row r; this version calls it row by row, implementations override it
        with a faster loop.

        Args:
            qu: ``(R,)`` q_u in its joint's unit (rad or m).
            qa: ``(R, m)`` q_a (rad; m for slides).
            qad: ``(R, m)`` q̇_a (rad/s; m/s for slides).
            qadd: ``(R, m)`` q̈_a (rad/s²; m/s² for slides).
            qud: ``(R,)`` q̇_u (default 0).
            qudd: ``(R,)`` q̈_u (default 0).
        """
        qu = np.asarray(qu, dtype=np.float64).reshape(-1)
        R = qu.shape[0]
        qa, qad, qadd = (np.asarray(a, dtype=np.float64).reshape(R, self.m) for a in (qa, qad, qadd))
        qud = np.zeros(R) if qud is None else np.asarray(qud, dtype=np.float64).reshape(R)
        qudd = np.zeros(R) if qudd is None else np.asarray(qudd, dtype=np.float64).reshape(R)
        return np.array([self.gamma0_scalar(float(qu[r]), qa[r], qad[r], qadd[r], float(qud[r]), float(qudd[r])) for r in range(R)],
                        dtype=np.float64).reshape(R)

    def momentum_u(self, q: torch.Tensor, qd_u: torch.Tensor) -> torch.Tensor:
        """H_u = D_uu(q) q̇_u (Lemma 1, eq. 19–20). ``q: (B, n)``, ``qd_u: (B,)`` → ``(B,)``."""
        u = self.unactuated_index
        return self.mass_matrix(q)[:, u, u] * qd_u

    def bem(
        self,
        qa,
        qad,
        qadd,
        *,
        qu_range: tuple[float, float] | None = None,
        n_grid: int = 73,
        on_missing: str = "nan",
    ) -> BEMResult:
        """Model-based BEM q_u^e: the root of Γ_0(q_u; q_a) = 0 (eq. 6, 7, 9).

        The root nearest :attr:`qu_nominal` inside the admissible range is returned,
        refined by a bracketed inverse-quadratic (Chandrupatla) iteration to
        |Γ_0| ≤ 1e-10 (N·m, or N for a slide q_u).  See :func:`bemlearn.robots.bem.solve_bem`.

        Args:
            qa: ``(B, m)`` actuated positions q_a, each in its joint's unit (rad or m).
            qad: ``(B, m)`` actuated velocities q̇_a (rad/s or m/s).
            qadd: ``(B, m)`` actuated accelerations q̈_a (rad/s² or m/s²).
            qu_range: admissible ``(lo, hi)``; default :attr:`qu_range`.
            n_grid: grid points used to bracket roots (roots closer together than
                the grid spacing may be missed).
            on_missing: ``"nan"`` (default) returns NaN and ``valid=False`` where no root
                exists in the range; ``"raise"`` raises ``ValueError`` naming the first
                such batch index.

        Returns:
            :class:`BEMResult` with ``qu (B,)`` in q_u's unit (rad or m), ``valid (B,)`` bool and
            ``residual (B,)`` |Γ_0| at the root.
        """
        qa, qad, qadd = self._states(qa, qad, qadd, func="bem", width=self.m, names=("qa", "qad", "qadd"))
        lo, hi = qu_range if qu_range is not None else self.qu_range
        B = qa.shape[0]

        def fun(qu_grid: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:  # (R, K) -> (R, K)
            R, K = qu_grid.shape
            rep = lambda t: t[rows].repeat_interleave(K, dim=0)  # noqa: E731
            return self.gamma0(qu_grid.reshape(-1), rep(qa), rep(qad), rep(qadd)).reshape(R, K)

        residual = self._bem_residual(qa.numpy(), qad.numpy(), qadd.numpy())
        if residual is None:
            result = solve_bem(fun, B, lo=lo, hi=hi, nominal=self.qu_nominal, n_grid=n_grid)
        else:
            qu, valid, res, it = find_roots(residual, B, lo=lo, hi=hi, nominal=self.qu_nominal, n_grid=n_grid,
                                            basis=self._bem_basis())
            result = BEMResult(qu=torch.from_numpy(qu), valid=torch.from_numpy(valid), residual=torch.from_numpy(res), iterations=it)
        if on_missing == "raise" and not bool(result.valid.all()):
            i = int((~result.valid).nonzero()[0])
            raise ArgumentError(
                f"bem: no root of Γ_0 in q_u ∈ [{lo}, {hi}] for batch index {i} "
                f"(qa={qa[i].tolist()}, qad={qad[i].tolist()}, qadd={qadd[i].tolist()})"
            )
        if on_missing not in ("nan", "raise"):
            raise ArgumentError(f"bem: on_missing must be 'nan' or 'raise', got {on_missing!r}")
        return result

    def _bem_residual(self, qa: np.ndarray, qad: np.ndarray, qadd: np.ndarray) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
        """Γ_0 in NumPy for :meth:`bem` (``fun(x (R, K), rows (R,)) -> (R, K)``, :func:`~bemlearn.robots.bem.find_roots`)
        when an implementation evaluates it with the numbers of :meth:`gamma0`; None: :meth:`bem` calls :meth:`gamma0`."""
        return None

    def _bem_basis(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """Functions of q_u whose combination :meth:`_bem_residual`'s Γ_0 is, for its grid scan
        (:func:`~bemlearn.robots.bem.find_roots`'s ``basis``); None: the scan evaluates every node it needs."""
        return None

    # ---- helpers ---------------------------------------------------------------------
    def _states(
        self,
        *args,
        func: str,
        width: int | None = None,
        names: Sequence[str] = ("q", "qd", "qdd"),
    ) -> tuple[torch.Tensor, ...]:
        width = self.n if width is None else width
        units = ("rad", "rad/s", "rad/s²")
        out = tuple(as_batch(a, width, n, func=func, units=u) for a, n, u in zip(args, names, units))
        if len({t.shape[0] for t in out}) != 1:
            raise ArgumentError(f"{func}: arguments {list(names[:len(out)])} have different batch sizes {[t.shape[0] for t in out]}")
        return out

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(name={self.name!r}, joints={list(self.joint_names)}, "
            f"unactuated={self.unactuated_name!r})"
        )
