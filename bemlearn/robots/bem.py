"""Vectorized bracketed root finding for the model-based BEM (eq. 6, 7, 9).

    E = { q_u^e : Γ_0(q_u^e; q_a) = 0 },   Γ_0 = Γ|_{q̇_u = q̈_u = 0}          (6), (7)

For each batch element the admissible range [lo, hi] is scanned on a grid, the
sign-change cell nearest the nominal q_u is chosen (a grid node where Γ_0 is exactly
zero counts as a root), and the root is refined by Chandrupatla's method (bracketed
inverse quadratic interpolation with a bisection safeguard; T. R. Chandrupatla, Adv.
Eng. Softw. 28, 1997), which never leaves its bracket and converges superlinearly.
Elements without a sign change in the range get NaN and ``valid = False``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from bemlearn.errors import ArgumentError

__all__ = ["BEMResult", "solve_bem"]

_EPS = torch.finfo(torch.float64).eps


@dataclass(frozen=True)
class BEMResult:
    """The model-based BEM for a batch.

    Attributes:
        qu: ``(B,)`` q_u^e (rad); NaN where no root was found in the range.
        valid: ``(B,)`` bool, True where a root was found.
        residual: ``(B,)`` |Γ_0(q_u^e)| (N·m); NaN where invalid.
        iterations: refinement iterations used (max over the batch).
    """

    qu: torch.Tensor
    valid: torch.Tensor
    residual: torch.Tensor
    iterations: int


def solve_bem(
    fun: Callable[..., torch.Tensor],  # fun(qu_grid) or fun(qu_grid, rows=...)
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
    """Find, per batch element, the root of ``fun`` in ``[lo, hi]`` nearest ``nominal``.

    Args:
        fun: maps candidate roots ``(R, K)`` to residuals ``(R, K)``; with a keyword argument
            ``rows`` (``(R,)`` int64) row r uses the ``rows[r]``-th problem's parameters, so only
            unresolved problems are evaluated; without it ``R = B`` and row b is problem b.
        batch: B.
        lo, hi: admissible range, ``lo < hi``.
        nominal: preferred value; among bracketed roots the one nearest it is returned.
        n_grid: grid nodes for bracketing (≥ 3).
        xtol: absolute tolerance on the root.
        ftol: a returned root must satisfy |fun| ≤ ftol, else it is marked invalid.
        max_iter: refinement iteration cap.
    """
    if not lo < hi:
        raise ArgumentError(f"solve_bem: need lo < hi, got lo={lo}, hi={hi}")
    if n_grid < 3:
        raise ArgumentError(f"solve_bem: n_grid must be ≥ 3, got {n_grid}")
    import inspect

    takes_rows = "rows" in inspect.signature(fun).parameters

    def call(x: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
        """``fun`` on the problems ``rows`` only (all problems when ``fun`` takes no ``rows``)."""
        if takes_rows:
            return fun(x, rows=rows)
        full = torch.zeros(batch, x.shape[1], dtype=torch.float64)
        full[rows] = x
        return fun(full)[rows]

    nodes = torch.linspace(lo, hi, n_grid, dtype=torch.float64)
    all_rows = torch.arange(batch)
    a = torch.full((batch,), float("nan"), dtype=torch.float64)
    b, fa, fb = a.clone(), a.clone(), a.clone()
    valid = torch.zeros(batch, dtype=torch.bool)
    last_zero = torch.zeros(batch, dtype=torch.bool)
    # bracket: first a window of nodes around the nominal value (BEMs lie near it), then the whole
    # grid for the problems whose nearest root may lie outside the window.  A sign-change cell in a
    # window is the nearest one of the whole grid when it is no farther than the window's edges.
    k0 = int(torch.clamp(torch.searchsorted(nodes, torch.tensor(nominal, dtype=torch.float64)), 0, n_grid - 1))
    pending = all_rows
    for half in (4, n_grid):
        i0, i1 = max(0, k0 - half), min(n_grid - 1, k0 + half)
        if i1 - i0 < 1 or pending.numel() == 0:
            continue
        grid = nodes[i0 : i1 + 1].expand(pending.numel(), i1 - i0 + 1).contiguous()
        f = call(grid, pending)
        fl, fr = f[:, :-1], f[:, 1:]
        change = (torch.sign(fl) * torch.sign(fr) < 0) | (fl == 0)
        xl, xr = grid[:, :-1], grid[:, 1:]
        dist = torch.where(nominal < xl, xl - nominal, torch.where(nominal > xr, nominal - xr, torch.zeros_like(xl)))
        dist = torch.where(change, dist, torch.full_like(dist, float("inf")))
        k = dist.argmin(dim=1)
        r = torch.arange(pending.numel())
        d = dist[r, k]
        whole = i0 == 0 and i1 == n_grid - 1
        edge = min(nominal - float(nodes[i0]) if i0 > 0 else float("inf"), float(nodes[i1]) - nominal if i1 < n_grid - 1 else float("inf"))
        found = torch.isfinite(d) & ((d <= edge) | whole)
        rows = pending[found]
        a[rows], b[rows], fa[rows], fb[rows] = xl[r, k][found], xr[r, k][found], fl[r, k][found], fr[r, k][found]
        valid[rows] = True
        if whole:  # exact zero on the last node is not covered by the cells above
            last_zero[pending] = f[:, -1] == 0
        pending = pending[~found]
    exact = valid & (fa == 0)
    # Chandrupatla iteration on the bracket [a, b], on the problems still active only
    c, fc = a.clone(), fa.clone()
    t = torch.full((batch,), 0.5, dtype=torch.float64)
    active = valid & ~exact
    root = torch.where(exact, a, torch.full_like(a, float("nan")))
    froot = torch.where(exact, fa, torch.full_like(a, float("nan")))
    it = 0
    while bool(active.any()) and it < max_iter:
        it += 1
        idx = active.nonzero()[:, 0]
        A, B_, C, FA, FB, FC, T = a[idx], b[idx], c[idx], fa[idx], fb[idx], fc[idx], t[idx]
        xt = A + T * (B_ - A)
        ft = call(xt[:, None], idx)[:, 0]
        same = torch.sign(ft) == torch.sign(FA)
        C, FC = torch.where(same, A, B_), torch.where(same, FA, FB)
        B_, FB = torch.where(same, B_, A), torch.where(same, FB, FA)
        A, FA = xt, ft
        use_a = FA.abs() < FB.abs()
        xm = torch.where(use_a, A, B_)
        fm = torch.where(use_a, FA, FB)
        tol = 2 * _EPS * xm.abs() + xtol
        width = (B_ - C).abs()
        tl = tol / torch.where(width > 0, width, torch.ones_like(width))
        done = (tl > 0.5) | (fm == 0) | (width == 0)
        # next t: inverse quadratic interpolation when safe, else bisection
        xi = (A - B_) / (C - B_)
        phi = (FA - FB) / (FC - FB)
        iqi = (phi**2 < xi) & ((1 - phi) ** 2 < 1 - xi)
        t_iqi = FA / (FB - FA) * FC / (FB - FC) + (C - A) / (B_ - A) * FA / (FC - FA) * FB / (FC - FB)
        T = torch.where(iqi, t_iqi, torch.full_like(T, 0.5))
        T = torch.minimum(torch.maximum(T, tl), 1 - tl)
        T = torch.where(torch.isfinite(T), T, torch.full_like(T, 0.5))
        a[idx], b[idx], c[idx], fa[idx], fb[idx], fc[idx], t[idx] = A, B_, C, FA, FB, FC, T
        root[idx[done]], froot[idx[done]] = xm[done], fm[done]
        active[idx[done]] = False
    if bool(active.any()):  # iteration cap: take the best point so far
        use_a = fa.abs() < fb.abs()
        root = torch.where(active, torch.where(use_a, a, b), root)
        froot = torch.where(active, torch.where(use_a, fa, fb), froot)
    # a last-node exact zero is a root only if nothing else was found
    use_last = last_zero & ~valid
    root = torch.where(use_last, nodes[-1].expand(batch), root)
    froot = torch.where(use_last, torch.zeros_like(froot), froot)
    valid = valid | use_last
    residual = froot.abs()
    good = valid & (residual <= ftol)
    nan = torch.full_like(root, float("nan"))
    return BEMResult(
        qu=torch.where(good, root, nan),
        valid=good,
        residual=torch.where(good, residual, nan),
        iterations=it,
    )
