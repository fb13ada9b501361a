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
    fun: Callable[[torch.Tensor], torch.Tensor],
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
        fun: maps candidate roots ``(B, K)`` to residuals ``(B, K)`` (row b uses the
            b-th problem's parameters).
        batch: B.
        lo, hi: admissible range, ``lo < hi``.
        nominal: preferred value; among bracketed roots the one nearest it is returned.
        n_grid: grid nodes for bracketing (≥ 3).
        xtol: absolute tolerance on the root.
        ftol: a returned root must satisfy |fun| ≤ ftol, else it is marked invalid.
        max_iter: refinement iteration cap.
    """
    if not lo < hi:
        raise ValueError(f"solve_bem: need lo < hi, got lo={lo}, hi={hi}")
    if n_grid < 3:
        raise ValueError(f"solve_bem: n_grid must be ≥ 3, got {n_grid}")
    grid = torch.linspace(lo, hi, n_grid, dtype=torch.float64).expand(batch, n_grid).contiguous()
    f = fun(grid)
    # candidate cells: sign change between node k and k+1 (or an exact zero at node k)
    fl, fr = f[:, :-1], f[:, 1:]
    change = (torch.sign(fl) * torch.sign(fr) < 0) | (fl == 0)
    xl, xr = grid[:, :-1], grid[:, 1:]
    dist = torch.where(nominal < xl, xl - nominal, torch.where(nominal > xr, nominal - xr, torch.zeros_like(xl)))
    dist = torch.where(change, dist, torch.full_like(dist, float("inf")))
    k = dist.argmin(dim=1)
    valid = torch.isfinite(dist.gather(1, k[:, None])[:, 0])
    # exact zero on the last node is not covered by the cells above
    last_zero = f[:, -1] == 0
    rows = torch.arange(batch)
    a = xl[rows, k].clone()
    b = xr[rows, k].clone()
    fa = fl[rows, k].clone()
    fb = fr[rows, k].clone()
    exact = valid & (fa == 0)
    # Chandrupatla iteration on the bracket [a, b]
    c, fc = a.clone(), fa.clone()
    t = torch.full((batch,), 0.5, dtype=torch.float64)
    active = valid & ~exact
    root = torch.where(exact, a, torch.full_like(a, float("nan")))
    froot = torch.where(exact, fa, torch.full_like(a, float("nan")))
    it = 0
    # initialise so that (a, fa) is the newest point and [a, b] brackets
    while bool(active.any()) and it < max_iter:
        it += 1
        xt = a + t * (b - a)
        ft = fun(xt[:, None])[:, 0]
        same = torch.sign(ft) == torch.sign(fa)
        c_new = torch.where(same, a, b)
        fc_new = torch.where(same, fa, fb)
        b_new = torch.where(same, b, a)
        fb_new = torch.where(same, fb, fa)
        upd = active
        c, fc = torch.where(upd, c_new, c), torch.where(upd, fc_new, fc)
        b, fb = torch.where(upd, b_new, b), torch.where(upd, fb_new, fb)
        a, fa = torch.where(upd, xt, a), torch.where(upd, ft, fa)
        use_a = fa.abs() < fb.abs()
        xm = torch.where(use_a, a, b)
        fm = torch.where(use_a, fa, fb)
        tol = 2 * _EPS * xm.abs() + xtol
        width = (b - c).abs()
        tl = tol / torch.where(width > 0, width, torch.ones_like(width))
        done = active & ((tl > 0.5) | (fm == 0) | (width == 0))
        root = torch.where(done, xm, root)
        froot = torch.where(done, fm, froot)
        active = active & ~done
        # next t: inverse quadratic interpolation when safe, else bisection
        with torch.no_grad():
            xi = (a - b) / (c - b)
            phi = (fa - fb) / (fc - fb)
            iqi = (phi**2 < xi) & ((1 - phi) ** 2 < 1 - xi)
            t_iqi = fa / (fb - fa) * fc / (fb - fc) + (c - a) / (b - a) * fa / (fc - fa) * fb / (fc - fb)
            t = torch.where(iqi, t_iqi, torch.full_like(t, 0.5))
            t = torch.minimum(torch.maximum(t, tl), 1 - tl)
            t = torch.where(torch.isfinite(t), t, torch.full_like(t, 0.5))
    if bool(active.any()):  # iteration cap: take the best point so far
        use_a = fa.abs() < fb.abs()
        root = torch.where(active, torch.where(use_a, a, b), root)
        froot = torch.where(active, torch.where(use_a, fa, fb), froot)
    # a last-node exact zero is a root only if nothing else was found
    use_last = last_zero & ~valid
    root = torch.where(use_last, grid[:, -1], root)
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
