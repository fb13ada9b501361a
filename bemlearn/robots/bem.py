"""Vectorized bracketed root finding for the model-based BEM (eq. 6, 7, 9).

    E = { q_u^e : Γ_0(q_u^e; q_a) = 0 },   Γ_0 = Γ|_{q̇_u = q̈_u = 0}          (6), (7)

For each batch element the admissible range [lo, hi] is scanned on a grid, the
sign-change cell nearest the nominal q_u is chosen (a grid node where Γ_0 is exactly
zero counts as a root), and the root is refined by Chandrupatla's method (bracketed
inverse quadratic interpolation with a bisection safeguard; T. R. Chandrupatla, Adv.
Eng. Softw. 28, 1997), which never leaves its bracket and converges superlinearly.
Elements without a sign change in the range get NaN and ``valid = False``.

:func:`find_roots` is the NumPy implementation (the derivation of defaults calls it without torch);
:func:`solve_bem` is its interface for residuals written in torch.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from bemlearn._lazy import lazy_module
from bemlearn.errors import ArgumentError

if TYPE_CHECKING:
    import torch
else:
    torch = lazy_module("torch")

__all__ = ["BEMResult", "solve_bem", "find_roots", "hinge_basis"]

_EPS = sys.float_info.epsilon  # float64 machine epsilon, as torch.finfo(torch.float64).eps


@dataclass(frozen=True)
class BEMResult:
    """The model-based BEM for a batch.

    Attributes:
        qu: ``(B,)`` q_u^e in q_u's unit (rad for a hinge, m for a slide); NaN where no root was found in the range.
        valid: ``(B,)`` bool, True where a root was found.
        residual: ``(B,)`` |Γ_0(q_u^e)| (N·m, or N for a slide q_u); NaN where invalid.
        iterations: refinement iterations used (max over the batch).
    """

    qu: torch.Tensor
    valid: torch.Tensor
    residual: torch.Tensor
    iterations: int


def solve_bem(
    fun: Callable[..., torch.Tensor],
    batch: int,
    *,
    lo: float,
    hi: float,
    nominal: float = 0.0,
    n_grid: int = 73,
    xtol: float = 1e-14,
    ftol: float = 1e-10,
    max_iter: int = 100,
) -> BEMResult:
    """Find, per batch element, the root of ``fun`` in ``[lo, hi]`` nearest ``nominal`` (torch interface of :func:`find_roots`).

    Args:
        fun: maps candidate roots ``(R, K)`` to residuals ``(R, K)`` (float64 tensors); with a keyword
            argument ``rows`` (``(R,)`` int64) row r uses the ``rows[r]``-th problem's parameters, so only
            unresolved problems are evaluated; without it ``R = B`` and row b is problem b.
        batch: B.
        lo: lower end of the admissible range.
        hi: upper end, ``lo < hi``.
        nominal: preferred value; among bracketed roots the one nearest it is returned.
        n_grid: grid nodes for bracketing (≥ 3).
        xtol: absolute tolerance on the root.
        ftol: a returned root must satisfy |fun| ≤ ftol, else it is marked invalid.
        max_iter: refinement iteration cap.

    Returns:
        :class:`BEMResult` (float64 tensors), computed by :func:`find_roots`.
    """
    import inspect

    if "rows" in inspect.signature(fun).parameters:
        def call(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
            return fun(torch.from_numpy(x), rows=torch.from_numpy(rows)).detach().cpu().numpy()
    else:
        def call(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
            full = np.zeros((batch, x.shape[1]))
            full[rows] = x
            return fun(torch.from_numpy(full)).detach().cpu().numpy()[rows]

    qu, valid, residual, it = find_roots(call, batch, lo=lo, hi=hi, nominal=nominal, n_grid=n_grid, xtol=xtol, ftol=ftol,
                                         max_iter=max_iter)
    return BEMResult(qu=torch.from_numpy(qu), valid=torch.from_numpy(valid), residual=torch.from_numpy(residual), iterations=it)


def find_roots(
    fun: Callable[[np.ndarray, np.ndarray], np.ndarray],
    batch: int,
    *,
    lo: float,
    hi: float,
    nominal: float = 0.0,
    n_grid: int = 73,
    xtol: float = 1e-14,
    ftol: float = 1e-10,
    max_iter: int = 100,
    basis: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Find, per problem, the root of ``fun`` in ``[lo, hi]`` nearest ``nominal`` (module docstring), in NumPy.

    Args:
        fun: ``fun(x, rows)`` maps candidate roots ``x (R, K)`` of the problems ``rows (R,)`` (int64
            indices into the batch) to residuals ``(R, K)``; only unresolved problems are evaluated.
        batch: B, the number of problems.
        lo: lower end of the admissible range.
        hi: upper end, ``lo < hi``.
        nominal: preferred value; among bracketed roots the one nearest it is returned.
        n_grid: grid nodes for bracketing (≥ 3).
        xtol: absolute tolerance on the root.
        ftol: a returned root must satisfy |fun| ≤ ftol, else it is marked invalid.
        max_iter: refinement iteration cap.
        basis: functions ``basis(x) -> (…, P)`` of which each problem's residual is known to be a linear
            combination (:func:`hinge_basis`: Γ_0 of a hinge q_u, eq. 7).  The grid scan then evaluates
            P nodes, fits the combination and reads the other nodes from it, checked against evaluations
            halfway between the fit nodes and at the chosen cell's ends; a problem whose check fails, or whose
            fitted residuals near ``nominal`` are too small to trust their signs, is scanned node by node.
            It picks the cell the node-by-node scan picks, with the same residuals at its ends, so the
            roots are the same.

    Returns:
        ``(root (B,), valid (B,) bool, |fun(root)| (B,), iterations)``: NaN root and residual where invalid.
    """
    if not lo < hi:
        raise ArgumentError(f"solve_bem: need lo < hi, got lo={lo}, hi={hi}")
    if n_grid < 3:
        raise ArgumentError(f"solve_bem: n_grid must be ≥ 3, got {n_grid}")
    nodes = np.linspace(lo, hi, n_grid)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        br = _bracket(fun, nodes, nominal, batch) if basis is None else _bracket_fitted(fun, nodes, nominal, batch, basis)
        exact = br.valid & (br.fa == 0)
        root = np.where(exact, br.a, np.nan)
        froot = np.where(exact, br.fa, np.nan)
        root, froot, it = _chandrupatla(fun, br, root, froot, active=br.valid & ~exact, xtol=xtol, max_iter=max_iter)
    # a last-node exact zero is a root only if nothing else was found
    use_last = br.last_zero & ~br.valid
    root = np.where(use_last, nodes[-1], root)
    froot = np.where(use_last, 0.0, froot)
    valid = br.valid | use_last
    residual = np.abs(froot)
    good = valid & (residual <= ftol)
    return np.where(good, root, np.nan), good, np.where(good, residual, np.nan), it


#: The window of :func:`_bracket` whose cells are taken when no farther than its edges (see there).
_HALF = 4


@dataclass(frozen=True, eq=False)
class _Bracket:
    """Per problem ``(B,)``: the sign-change cell [a, b] nearest the nominal value with its residuals
    ``fa``, ``fb`` (NaN where none), ``valid`` where one was found, and ``last_zero`` where the residual
    is exactly zero on the last grid node (not covered by the cells)."""

    a: np.ndarray
    b: np.ndarray
    fa: np.ndarray
    fb: np.ndarray
    valid: np.ndarray
    last_zero: np.ndarray


def _bracket(call: Callable[[np.ndarray, np.ndarray], np.ndarray], nodes: np.ndarray, nominal: float, batch: int) -> _Bracket:
    """Scan the grid ``nodes`` for the sign-change cell nearest ``nominal`` (:func:`_scan` to the whole grid)."""
    return _scan(call, nodes, nominal, batch)[0]


def _scan(call: Callable[[np.ndarray, np.ndarray], np.ndarray], nodes: np.ndarray, nominal: float, batch: int, *,
          windows: int | None = None) -> tuple[_Bracket, np.ndarray]:
    """Scan the grid ``nodes`` for the sign-change cell nearest ``nominal`` (a node where the residual is
    exactly zero counts as a root).

    Windows of 1, 2, 3, 4, 6, 9, … nodes either side of the nominal value (BEMs lie near it; each half again as
    wide as the last), up to the whole grid, each for the problems whose nearest root may lie outside the
    narrower one, each evaluating only the nodes the narrower one did not.  The
    window of ``_HALF`` nodes either side takes a sign-change cell no farther than its edges; every other
    window one nearer than its edges, which is the cell the scan of the whole grid (and of the ``_HALF``
    window) would choose: the nearest, the leftmost of equally near ones.

    ``windows``: stop after that many windows; returns the bracket and the problems still pending (their
    nearest cell lies beyond the last window's edges).
    """
    n_grid = nodes.size
    a = np.full(batch, np.nan)
    b, fa, fb = a.copy(), a.copy(), a.copy()
    valid = np.zeros(batch, dtype=bool)
    last_zero = np.zeros(batch, dtype=bool)
    k0 = int(np.clip(np.searchsorted(nodes, nominal), 0, n_grid - 1))
    pending = np.arange(batch)
    f_all = np.empty((batch, 0))   # residuals of the pending problems on nodes[p0 : p1 + 1]
    p0, p1 = k0, k0 - 1            # the nodes evaluated so far (none)
    half = 0
    passes = 0
    while half < n_grid and (windows is None or passes < windows):
        passes += 1
        half += max(1, half // 2)   # 1, 2, 3, 4, 6, 9, 13, …: few passes, at most half again the nodes needed
        i0, i1 = max(0, k0 - half), min(n_grid - 1, k0 + half)
        if i1 - i0 < 1 or pending.size == 0:
            continue
        parts = []
        if p1 < p0:  # nothing evaluated yet
            grid = np.broadcast_to(nodes[i0 : i1 + 1], (pending.size, i1 - i0 + 1)).copy()
            f = np.asarray(call(grid, pending), dtype=np.float64)
        else:
            if i0 < p0:
                left = np.broadcast_to(nodes[i0:p0], (pending.size, p0 - i0)).copy()
                parts.append(np.asarray(call(left, pending), dtype=np.float64))
            parts.append(f_all)
            if i1 > p1:
                right = np.broadcast_to(nodes[p1 + 1 : i1 + 1], (pending.size, i1 - p1)).copy()
                parts.append(np.asarray(call(right, pending), dtype=np.float64))
            f = np.concatenate(parts, axis=1) if len(parts) > 1 else f_all
            grid = np.broadcast_to(nodes[i0 : i1 + 1], (pending.size, i1 - i0 + 1))
        p0, p1 = i0, i1
        fl, fr = f[:, :-1], f[:, 1:]
        change = (np.sign(fl) * np.sign(fr) < 0) | (fl == 0)
        xl, xr = grid[:, :-1], grid[:, 1:]
        dist = np.where(nominal < xl, xl - nominal, np.where(nominal > xr, nominal - xr, 0.0))
        dist = np.where(change, dist, np.inf)
        k = dist.argmin(axis=1)
        r = np.arange(pending.size)
        d = dist[r, k]
        whole = i0 == 0 and i1 == n_grid - 1
        edge = min(nominal - float(nodes[i0]) if i0 > 0 else float("inf"), float(nodes[i1]) - nominal if i1 < n_grid - 1 else float("inf"))
        found = np.isfinite(d) & (((d <= edge) if half == _HALF else (d < edge)) | whole)
        rows = pending[found]
        a[rows], b[rows], fa[rows], fb[rows] = xl[r, k][found], xr[r, k][found], fl[r, k][found], fr[r, k][found]
        valid[rows] = True
        if whole:  # exact zero on the last node is not covered by the cells above
            last_zero[pending] = f[:, -1] == 0
            break
        pending, f_all = pending[~found], f[~found]
    else:
        return _Bracket(a, b, fa, fb, valid, last_zero), pending
    return _Bracket(a, b, fa, fb, valid, last_zero), np.arange(0)


def hinge_basis(x: np.ndarray) -> np.ndarray:
    """``(…, 5)``: 1, cos x, sin x, cos 2x, sin 2x of ``x (…)`` (rad).

    Γ_0 (eq. 7) of a rigid multibody as a function of a hinge q_u, the other coordinates and the rates
    fixed (q̇_u = q̈_u = 0), is a combination of these: in the frame of the body q_u turns, only the
    parent's motion and gravity depend on q_u, through one rotation (affine in cos q_u, sin q_u); the
    joint torque is at most quadratic in it (D_ua(q) q̈_a, the Coriolis and centrifugal terms) and gravity
    linear.  Forces outside that form (a spring on q_u, fluid drag) fail :func:`find_roots`' check.
    """
    x = np.asarray(x, dtype=np.float64)
    return np.stack([np.ones_like(x), np.cos(x), np.sin(x), np.cos(2 * x), np.sin(2 * x)], axis=-1)


#: :func:`_bracket_fitted`: the largest fit error at the checked nodes, relative to the largest |residual| fitted.
_FIT_CHECK = 1e-8
#: :func:`_bracket_fitted`: a fitted residual smaller than this (relative) near the chosen cell is not trusted.
_FIT_MARGIN = 1e-6


def _nearest_cell(f: np.ndarray, nodes: np.ndarray, nominal: float) -> tuple[np.ndarray, np.ndarray]:
    """The whole-grid choice of :func:`_bracket` on residuals ``f (B, N)``: the cell index ``(B,)`` and its
    distance to ``nominal`` ``(B,)`` (inf: no sign change)."""
    fl, fr = f[:, :-1], f[:, 1:]
    change = (np.sign(fl) * np.sign(fr) < 0) | (fl == 0)
    xl, xr = nodes[:-1], nodes[1:]
    dist = np.where(nominal < xl, xl - nominal, np.where(nominal > xr, nominal - xr, 0.0))
    dist = np.where(change, dist[None, :], np.inf)
    k = dist.argmin(axis=1)
    return k, dist[np.arange(f.shape[0]), k]


def _bracket_fitted(call: Callable[[np.ndarray, np.ndarray], np.ndarray], nodes: np.ndarray, nominal: float, batch: int,
                    basis: Callable[[np.ndarray], np.ndarray]) -> _Bracket:
    """:func:`_bracket` for residuals in the span of ``basis`` (:func:`find_roots`).

    The first window (the nodes beside ``nominal``) is scanned as :func:`_bracket` does; each problem still
    pending then costs P fitted and 4 checked nodes instead of the wider windows' nodes; the problems that
    fail the checks are scanned node by node.
    """
    n_grid = nodes.size
    V = basis(nodes)                                              # (N, P)
    P = V.shape[1]
    fit = np.unique(np.round(np.linspace(0, n_grid - 1, P)).astype(np.int64))
    if P < 5 or n_grid < 2 * P + 3 or fit.size < P or not np.linalg.cond(V[fit]) < 1e8:   # P ≥ 5: four checks between fit nodes
        return _bracket(call, nodes, nominal, batch)
    br, pending = _scan(call, nodes, nominal, batch, windows=1)
    a, b, fa, fb, valid, last_zero = (x.copy() for x in (br.a, br.b, br.fa, br.fb, br.valid, br.last_zero))
    if pending.size == 0:
        return br
    W = V @ np.linalg.inv(V[fit])                                 # (N, P): residuals at every node from those at the fit nodes
    n = pending.size
    problems = np.arange(n)
    F = np.asarray(call(np.broadcast_to(nodes[fit], (n, P)).copy(), pending), dtype=np.float64)   # (n, P)
    f = F @ W.T                                                   # (n, N) fitted
    known = np.zeros((n, n_grid), dtype=bool)
    f[:, fit], known[:, fit] = F, True
    scale = np.abs(F).max(axis=1)
    k, d = _nearest_cell(f, nodes, nominal)
    # checked: nodes halfway between the fit nodes (the two nearest nominal, the two others where no cell was
    # chosen) and the chosen cell's ends (its residuals go to the refinement as evaluated)
    mid = (fit[:-1] + fit[1:]) // 2
    mid = mid[np.argsort(np.abs(nodes[mid] - nominal), kind="stable")]
    found = np.isfinite(d)
    check = np.stack([np.full(n, mid[0]), np.full(n, mid[1]), np.where(found, k, mid[2]), np.where(found, k + 1, mid[3])], axis=1)
    T = np.asarray(call(nodes[check], pending), dtype=np.float64)                                   # (n, 4)
    r = problems[:, None]
    error = np.abs(T - f[r, check]).max(axis=1)
    f[r, check], known[r, check] = T, True
    k2, d2 = _nearest_cell(f, nodes, nominal)
    # the signs that decide the choice: every node as near as the chosen cell (all of them without one)
    spacing = float(np.max(np.diff(nodes)))
    near = np.abs(nodes[None, :] - nominal) <= np.where(found, d, np.inf)[:, None] + spacing
    doubtful = near & ~known & ~(np.abs(f) > _FIT_MARGIN * scale[:, None])
    same = (np.isfinite(d2) == found) & (~found | ((k2 == k) & (d2 == d)))   # the checked nodes kept the choice
    ok = np.isfinite(scale) & (scale > 0) & (error <= _FIT_CHECK * scale) & ~doubtful.any(axis=1) & same
    got = problems[ok & found]
    rows = pending[got]
    a[rows], b[rows], fa[rows], fb[rows] = nodes[k[got]], nodes[k[got] + 1], f[got, k[got]], f[got, k[got] + 1]
    valid[rows] = True
    none = problems[ok & ~found]
    last_zero[pending[none]] = f[none, -1] == 0
    rest = pending[~ok]
    if rest.size:   # node by node, as without a basis
        br = _bracket(lambda x, rows: call(x, rest[rows]), nodes, nominal, rest.size)
        a[rest], b[rest], fa[rest], fb[rest] = br.a, br.b, br.fa, br.fb
        valid[rest], last_zero[rest] = br.valid, br.last_zero
    return _Bracket(a, b, fa, fb, valid, last_zero)


def _chandrupatla(call: Callable[[np.ndarray, np.ndarray], np.ndarray], br: _Bracket, root: np.ndarray, froot: np.ndarray,
                  *, active: np.ndarray, xtol: float, max_iter: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Chandrupatla's iteration on the brackets ``br`` of the ``active`` problems (evaluated on those only).

    Returns ``(root, froot, iterations)``: ``root``/``froot`` updated where a problem converged, and
    at the iteration cap the better end of each bracket still active.
    """
    a, b, fa, fb = br.a.copy(), br.b.copy(), br.fa.copy(), br.fb.copy()
    c, fc = a.copy(), fa.copy()
    t = np.full_like(a, 0.5)
    active = active.copy()
    it = 0
    while bool(active.any()) and it < max_iter:
        it += 1
        idx = np.flatnonzero(active)
        A, B_, C, FA, FB, FC, T = a[idx], b[idx], c[idx], fa[idx], fb[idx], fc[idx], t[idx]
        xt = A + T * (B_ - A)
        ft = np.asarray(call(xt[:, None], idx), dtype=np.float64)[:, 0]
        same = np.sign(ft) == np.sign(FA)
        C, FC = np.where(same, A, B_), np.where(same, FA, FB)
        B_, FB = np.where(same, B_, A), np.where(same, FB, FA)
        A, FA = xt, ft
        use_a = np.abs(FA) < np.abs(FB)
        xm = np.where(use_a, A, B_)
        fm = np.where(use_a, FA, FB)
        tol = 2 * _EPS * np.abs(xm) + xtol
        width = np.abs(B_ - C)
        tl = tol / np.where(width > 0, width, 1.0)
        done = (tl > 0.5) | (fm == 0) | (width == 0)
        # next t: inverse quadratic interpolation when safe, else bisection
        xi = (A - B_) / (C - B_)
        phi = (FA - FB) / (FC - FB)
        iqi = (phi**2 < xi) & ((1 - phi) ** 2 < 1 - xi)
        t_iqi = FA / (FB - FA) * FC / (FB - FC) + (C - A) / (B_ - A) * FA / (FC - FA) * FB / (FC - FB)
        T = np.where(iqi, t_iqi, 0.5)
        T = np.minimum(np.maximum(T, tl), 1 - tl)
        T = np.where(np.isfinite(T), T, 0.5)
        a[idx], b[idx], c[idx], fa[idx], fb[idx], fc[idx], t[idx] = A, B_, C, FA, FB, FC, T
        root[idx[done]], froot[idx[done]] = xm[done], fm[done]
        active[idx[done]] = False
    if bool(active.any()):  # iteration cap: take the best point so far
        use_a = np.abs(fa) < np.abs(fb)
        root = np.where(active, np.where(use_a, a, b), root)
        froot = np.where(active, np.where(use_a, fa, fb), froot)
    return root, froot, it
