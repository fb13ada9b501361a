"""The upright of the unactuated coordinate, found from the physics (not from a convention).

At rest (q̇ = q̈ = 0) with the actuated coordinates at their zero, the unactuated row of the
dynamics (eq. 5) is the generalized gravity-and-spring force

    Γ_0(q_u) = G_u(q_u) − τ_p,u(q_u) = ∂V/∂q_u,

the derivative of the potential energy V (gravity and joint springs).  Its roots are the
equilibria of q_u with the actuated joints held; a root is *unstable* where the restoring
stiffness is negative,

    Γ_q = −∂Γ_0/∂q_u > 0    (D_uu δq̈_u = Γ_q δq_u grows like e^{λt}, λ = √(Γ_q/D_uu)),

i.e. where V has a maximum.  A balance robot is balanced at an unstable equilibrium; the
*upright* is the one of highest potential energy (a pendulum's top, never its bottom):

    V(q_u) − V(q_u,0) = ∫_{q_u,0}^{q_u} Γ_0(s) ds.

For a hinge the search covers one turn (−π, π] (or the joint range when it is limited), so a
pendulum whose angle reads 0 hanging down and π upright — by its geometry or by MuJoCo's
joint ``ref`` — gets q_u,upright = π.  Nothing is assumed about where the zero is.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["Equilibrium", "UprightSearch", "find_upright"]


@dataclass(frozen=True)
class Equilibrium:
    """A root of Γ_0(q_u) with the actuated joints held at their zero.

    Attributes:
        qu: the equilibrium, in q_u's unit (rad or m).
        stiffness: Γ_q = −∂Γ_0/∂q_u there (N·m/rad or N/m); > 0: unstable (balanced only by control).
        potential: V(qu) − V(start of the search), J.
    """

    qu: float
    stiffness: float
    potential: float

    @property
    def unstable(self) -> bool:
        """True where gravity (and springs) push q_u away: the equilibrium a balance controller holds."""
        return self.stiffness > 0


@dataclass(frozen=True)
class UprightSearch:
    """Result of :func:`find_upright`.

    Attributes:
        upright: the unstable equilibrium of highest potential energy, or ``None`` if q_u has none.
        equilibria: every equilibrium found, in increasing q_u.
        interval: the searched interval of q_u.
    """

    upright: Equilibrium | None
    equilibria: tuple[Equilibrium, ...]
    interval: tuple[float, float]

    def describe(self, unit: str = "rad") -> str:
        """One line: where the upright is and why (for ``config show`` and messages)."""
        if self.upright is None:
            kinds = ", ".join(f"{e.qu:.4g} ({'unstable' if e.unstable else 'stable'})" for e in self.equilibria) or "none"
            return (f"no unstable equilibrium of q_u in [{self.interval[0]:.4g}, {self.interval[1]:.4g}] {unit} "
                    f"with the actuated joints at 0 (equilibria: {kinds})")
        u = self.upright
        return (f"{u.qu:.6g} {unit}: the unstable equilibrium of highest potential energy with the actuated joints at 0 "
                f"(stiffness Γ_q = {u.stiffness:.4g}, {len(self.equilibria)} equilibri{'um' if len(self.equilibria) == 1 else 'a'} "
                f"in [{self.interval[0]:.4g}, {self.interval[1]:.4g}] {unit})")


def _bisect(f: Callable[[float], float], a: float, b: float, fa: float, *, tol: float) -> float:
    for _ in range(80):
        c = 0.5 * (a + b)
        fc = f(c)
        if fc == 0.0 or b - a < tol:
            return c
        if (fc > 0) == (fa > 0):
            a, fa = c, fc
        else:
            b = c
    return 0.5 * (a + b)


def find_upright(gamma0: Callable[[float], float], *, kind: str, limits: tuple[float, float] | None = None,
                 n_grid: int = 720, prefer: float = 0.0) -> UprightSearch:
    """The equilibria of q_u and its upright (module docstring).

    Args:
        gamma0: q_u ↦ Γ_0 at rest with the actuated joints at 0 (N·m or N).
        kind: ``"hinge"`` or ``"slide"``.
        limits: the joint's range when it is limited (q_u's unit), else ``None``: a hinge searches
            (−π, π], a slide ±1 m.
        n_grid: grid cells of the sign scan.
        prefer: among unstable equilibria of equal potential (to 1e-9 relative), the one nearest this.

    Returns:
        :class:`UprightSearch`.
    """
    periodic = kind == "hinge" and not (limits is not None and all(math.isfinite(v) for v in limits))
    if not periodic and limits is not None:
        lo, hi = float(limits[0]), float(limits[1])
        if kind == "hinge" and hi - lo > 2 * math.pi:  # a multi-turn range: one turn around the middle holds every pose
            mid = 0.5 * (lo + hi)
            lo, hi = mid - math.pi, mid + math.pi
    elif periodic:
        lo, hi = -math.pi, math.pi
    else:
        lo, hi = -1.0, 1.0
    # a hinge without limits is periodic: scan a little past ±π so a root at π is bracketed
    pad = 3 * (hi - lo) / n_grid if periodic else 0.0
    grid = np.linspace(lo - pad, hi + pad, n_grid + 1 + (6 if periodic else 0))
    g = np.array([gamma0(float(x)) for x in grid])
    scale = float(np.max(np.abs(g))) if g.size else 0.0
    if not np.all(np.isfinite(g)) or scale == 0.0:
        return UprightSearch(None, (), (lo, hi))
    # potential by the trapezoid rule on the grid, V(grid[0]) = 0
    V = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(grid))])
    tol = 1e-12 * max(1.0, hi - lo)
    roots: list[float] = []
    for k in range(len(grid) - 1):
        a, b = grid[k], grid[k + 1]
        fa, fb = g[k], g[k + 1]
        if fa == 0.0:
            roots.append(float(a))
        elif (fa > 0) != (fb > 0) and fb != 0.0:
            roots.append(_bisect(gamma0, float(a), float(b), float(fa), tol=tol))
    if g[-1] == 0.0:
        roots.append(float(grid[-1]))
    eqs: list[Equilibrium] = []
    h = 1e-6 * max(1.0, hi - lo)
    for r in roots:
        pot = float(np.interp(r, grid, V))
        if periodic:  # one representative per pose, in (−π, π]
            r = float(math.remainder(r, 2 * math.pi))
            r = math.pi if r <= -math.pi + 1e-9 else r
        elif not lo - 1e-12 <= r <= hi + 1e-12:
            continue
        if any(abs(r - e.qu) < 1e-7 for e in eqs):
            continue
        stiff = -(gamma0(r + h) - gamma0(r - h)) / (2 * h)
        eqs.append(Equilibrium(float(r), float(stiff), pot))
    unstable = [e for e in eqs if e.stiffness > 1e-9 * scale]
    if not unstable:
        return UprightSearch(None, tuple(eqs), (lo, hi))
    top = max(e.potential for e in unstable)
    span = max(float(np.max(V) - np.min(V)), 1e-300)
    best = [e for e in unstable if top - e.potential <= 1e-9 * span + 1e-12]
    up = min(best, key=lambda e: abs(e.qu - prefer))
    return UprightSearch(up, tuple(sorted(eqs, key=lambda e: e.qu)), (lo, hi))
