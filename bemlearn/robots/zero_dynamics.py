"""Zero dynamics S_0 (eq. 4), its bounded solution q_u^d(t), and Lemma 1 (eq. 10).

Under perfect tracking q_a = q_a^d(t) the unactuated coordinate obeys

    Γ(q_u; q_a^d) = D_uu q̈_u + D_ua q̈_a^d + C_uu q̇_u + C_ua q̇_a^d + G_u − τ_p,u = 0      (4), (5)

For a balance robot this is unstable (non-minimum phase), so integrating it forward
diverges; the *bounded* solution is a boundary-value problem:

* periodic q_a^d (period T): the T-periodic orbit, by Fourier (pseudo-spectral)
  collocation — q_u at N equispaced nodes, q̇_u, q̈_u by exact differentiation of the
  trigonometric interpolant, Newton's method on Γ(t_k) = 0 (:func:`periodic_zero_dynamics`);
* finite horizon [t0, t1] (stable inversion on a window): ``scipy.integrate.solve_bvp``
  with q_u pinned to the BEM at both ends (:func:`finite_zero_dynamics`).  Because the
  dynamics are a saddle, the influence of these end conditions decays exponentially
  away from the ends; trust the interior.

Lemma 1 (:func:`lemma1`).  Along q_a^d let q_u^e(t) be the BEM (eq. 9) and q_u^d(t) the
bounded solution.  Since Γ_0(q_u^e) = 0 and Γ(q_u^d) = 0,

    ΔΓ = Γ(q_u^e; q_a^d) − Γ(q_u^d; q_a^d) = D_uu q̈_u^e + Ḋ_uu q̇_u^e − Δτ_p,u = Ḣ_u − Δτ_p,u    (10)

with H_u = D_uu q̇_u^e.  The identity ΔΓ = Ḣ_u is exact when (i) D_uu does not depend on
q_u itself (true for any hinge or slide in a kinematic tree: a subtree's inertia about its
own joint axis is invariant to motion about that axis) and (ii) no passive force depends
on q̇_u; joint damping b_u on the unactuated joint adds Δτ_p,u = −b_u q̇_u^e, reported
separately as ``damping`` (ΔΓ = Ḣ_u + b_u q̇_u^e).  Everything else (Coriolis structure)
is exact, so the numerical gap measures only discretization and solver error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from bemlearn.errors import ArgumentError, NumericalError
from bemlearn.robots.protocol import BalanceRobot, ControlRobot
from bemlearn.robots.reference import CompositeSinusoid

__all__ = [
    "ZeroDynamicsSolution",
    "LemmaOneResult",
    "periodic_zero_dynamics",
    "finite_zero_dynamics",
    "lemma1",
    "spectral_derivative",
    "scaled_references",
    "lemma1_relative_gap",
]


def spectral_derivative(y: np.ndarray, period: float, order: int = 1) -> np.ndarray:
    """d^order y/dt^order of samples ``y (N, ...)`` of a smooth T-periodic function on t_k = kT/N."""
    N = y.shape[0]
    k = np.fft.fftfreq(N, d=1.0 / N)
    if N % 2 == 0 and order % 2 == 1:
        k[N // 2] = 0.0  # drop the Nyquist mode for odd derivatives (keeps the result real)
    mult = (2j * np.pi * k / period) ** order
    Y = np.fft.fft(y, axis=0)
    return np.real(np.fft.ifft(Y * mult.reshape((N,) + (1,) * (y.ndim - 1)), axis=0))


def _diff_matrix(N: int, period: float, order: int) -> np.ndarray:
    return spectral_derivative(np.eye(N), period, order)


@dataclass(frozen=True)
class ZeroDynamicsSolution:
    """The bounded solution of S_0 on a time grid.

    Attributes:
        t: ``(N,)`` s.
        qa, qad, qadd: ``(N, m)`` the desired actuated trajectory and its derivatives.
        qu, qud, qudd: ``(N,)`` q_u^d and its derivatives (rad, rad/s, rad/s²; m, m/s, m/s² for a slide).
        residual: ``(N,)`` Γ(q_u^d; q_a^d) at the grid (N·m), the eq. (4) residual.
        iterations: Newton / BVP iterations used.
    """

    t: np.ndarray
    qa: np.ndarray
    qad: np.ndarray
    qadd: np.ndarray
    qu: np.ndarray
    qud: np.ndarray
    qudd: np.ndarray
    residual: np.ndarray
    iterations: int


def _gamma(robot: BalanceRobot, qa, qad, qadd, qu, qud, qudd) -> np.ndarray:
    T = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64))  # noqa: E731
    q = robot.join(T(qa), T(qu))
    qd = robot.join(T(qad), T(qud))
    qdd = robot.join(T(qadd), T(qudd))
    return robot.gamma(q, qd, qdd).numpy()


def periodic_zero_dynamics(
    robot: BalanceRobot,
    reference: CompositeSinusoid,
    *,
    n_nodes: int = 256,
    tol: float = 1e-11,
    max_iter: int = 30,
    fd_step: float = 1e-6,
) -> ZeroDynamicsSolution:
    """The periodic orbit q_u^d(t) of S_0 (eq. 4) for a periodic q_a^d, by Fourier collocation.

    Args:
        robot: the robot (any :class:`~bemlearn.robots.BalanceRobot`).
        reference: a T-periodic composite sinusoid for the m actuated joints.
        n_nodes: collocation nodes over one period.
        tol: stop when max |Γ| at the nodes ≤ tol (N·m).
        max_iter: Newton iteration cap; ``RuntimeError`` if not converged.
        fd_step: finite-difference step of the Jacobian's partial derivatives.
    """
    if reference.m != robot.m:
        raise ArgumentError(f"periodic_zero_dynamics: reference has {reference.m} actuated joints, robot {robot.name!r} has {robot.m}")
    T = reference.period
    if not np.isfinite(T):
        raise ArgumentError("periodic_zero_dynamics: the reference is not periodic (use finite_zero_dynamics)")
    t = np.arange(n_nodes) * T / n_nodes
    qa, qad, qadd = (x.numpy() for x in reference(t))
    bem = robot.bem(qa, qad, qadd)
    if not bool(bem.valid.all()):
        raise ArgumentError("periodic_zero_dynamics: the BEM does not exist along the whole reference (needed as initial guess)")
    u = bem.qu.numpy().copy()
    D1, D2 = _diff_matrix(n_nodes, T, 1), _diff_matrix(n_nodes, T, 2)
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 - the count reached is returned
        ud, udd = D1 @ u, D2 @ u
        r = _gamma(robot, qa, qad, qadd, u, ud, udd)
        if np.max(np.abs(r)) <= tol:
            break
        h = fd_step
        dq = (_gamma(robot, qa, qad, qadd, u + h, ud, udd) - _gamma(robot, qa, qad, qadd, u - h, ud, udd)) / (2 * h)
        dqd = (_gamma(robot, qa, qad, qadd, u, ud + h, udd) - _gamma(robot, qa, qad, qadd, u, ud - h, udd)) / (2 * h)
        duu = _gamma(robot, qa, qad, qadd, u, ud, udd + 1.0) - r  # Γ is affine in q̈_u
        J = np.diag(dq) + dqd[:, None] * D1 + duu[:, None] * D2
        u = u - np.linalg.solve(J, r)
    else:
        raise NumericalError(f"periodic_zero_dynamics: no convergence in {max_iter} Newton steps (max |Γ| = {np.max(np.abs(r)):.3e})")
    ud, udd = D1 @ u, D2 @ u
    r = _gamma(robot, qa, qad, qadd, u, ud, udd)
    return ZeroDynamicsSolution(t, qa, qad, qadd, u, ud, udd, r, it)


def finite_zero_dynamics(
    robot: BalanceRobot,
    reference: CompositeSinusoid,
    t0: float,
    t1: float,
    *,
    n_nodes: int = 400,
    tol: float = 1e-8,
) -> ZeroDynamicsSolution:
    """Bounded solution of S_0 on ``[t0, t1]`` (stable inversion on a window, module docstring).

    Uses ``scipy.integrate.solve_bvp`` on y = [q_u, q̇_u] with q_u(t0), q_u(t1) set to the BEM.
    """
    from scipy.integrate import solve_bvp

    if reference.m != robot.m:
        raise ArgumentError(f"finite_zero_dynamics: reference has {reference.m} actuated joints, robot has {robot.m}")
    if not t1 > t0:
        raise ArgumentError(f"finite_zero_dynamics: need t1 > t0, got t0={t0}, t1={t1}")

    def rhs(t, y):
        qa, qad, qadd = (x.numpy() for x in reference(t))
        g0 = _gamma(robot, qa, qad, qadd, y[0], y[1], np.zeros_like(t))
        duu = _gamma(robot, qa, qad, qadd, y[0], y[1], np.ones_like(t)) - g0
        return np.vstack([y[1], -g0 / duu])

    ends = robot.bem(*(x.numpy() for x in reference(np.array([t0, t1])))).qu.numpy()
    if not np.all(np.isfinite(ends)):
        raise ArgumentError("finite_zero_dynamics: the BEM does not exist at the window ends")
    t = np.linspace(t0, t1, n_nodes)
    qa, qad, qadd = (x.numpy() for x in reference(t))
    guess = robot.bem(qa, qad, qadd).qu.numpy()
    guess = np.where(np.isfinite(guess), guess, 0.0)
    y0 = np.vstack([guess, np.gradient(guess, t)])
    sol = solve_bvp(rhs, lambda ya, yb: np.array([ya[0] - ends[0], yb[0] - ends[1]]), t, y0, tol=tol, max_nodes=100000)
    if not sol.success:
        raise NumericalError(f"finite_zero_dynamics: solve_bvp failed: {sol.message}")
    y = sol.sol(t)
    qudd = rhs(t, y)[1]
    r = _gamma(robot, qa, qad, qadd, y[0], y[1], qudd)
    return ZeroDynamicsSolution(t, qa, qad, qadd, y[0], y[1], qudd, r, int(sol.niter))


@dataclass(frozen=True)
class LemmaOneResult:
    """Lemma 1 along a periodic reference (module docstring), all arrays ``(N,)``.

    Attributes:
        t: s.  qu_e, qud_e, qudd_e: the BEM and its time derivatives.
        qu_d: the bounded zero-dynamics solution.
        delta_gamma: ΔΓ = Γ(q_u^e) − Γ(q_u^d), N·m.
        hdot: Ḣ_u = d/dt(D_uu q̇_u^e), N·m.
        damping: b_u q̇_u^e, the passive-force term (0 without damping), N·m.
        gap: ΔΓ − Ḣ_u − damping (should vanish), N·m.
        max_distance: max |q_u^d − q_u^e|, in q_u's unit (rad or m).
    """

    t: np.ndarray
    qu_e: np.ndarray
    qud_e: np.ndarray
    qudd_e: np.ndarray
    qu_d: np.ndarray
    delta_gamma: np.ndarray
    hdot: np.ndarray
    damping: np.ndarray
    gap: np.ndarray
    max_distance: float
    zero_dynamics: ZeroDynamicsSolution


def lemma1(robot: BalanceRobot, reference: CompositeSinusoid, *, n_nodes: int = 256) -> LemmaOneResult:
    """Evaluate ΔΓ and Ḣ_u of eq. (10) along a periodic reference (see module docstring)."""
    zd = periodic_zero_dynamics(robot, reference, n_nodes=n_nodes)
    T = reference.period
    qa, qad, qadd = zd.qa, zd.qad, zd.qadd
    qu_e = robot.bem(qa, qad, qadd).qu.numpy()
    qud_e = spectral_derivative(qu_e, T, 1)
    qudd_e = spectral_derivative(qu_e, T, 2)
    g_e = _gamma(robot, qa, qad, qadd, qu_e, qud_e, qudd_e)
    delta = g_e - zd.residual
    Tt = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64))  # noqa: E731
    q_e = robot.join(Tt(qa), Tt(qu_e))
    u = robot.unactuated_index
    duu = robot.mass_matrix(q_e)[:, u, u].numpy()
    hdot = spectral_derivative(duu * qud_e, T, 1)
    tp_moving = robot.passive(q_e, robot.join(Tt(qad), Tt(qud_e)))[:, u].numpy()
    tp_still = robot.passive(q_e, robot.join(Tt(qad), Tt(np.zeros_like(qu_e))))[:, u].numpy()
    damping = -(tp_moving - tp_still)
    gap = delta - hdot - damping
    return LemmaOneResult(
        t=zd.t,
        qu_e=qu_e,
        qud_e=qud_e,
        qudd_e=qudd_e,
        qu_d=zd.qu,
        delta_gamma=delta,
        hdot=hdot,
        damping=damping,
        gap=gap,
        max_distance=float(np.max(np.abs(zd.qu - qu_e))),
        zero_dynamics=zd,
    )


def scaled_references(robot: ControlRobot, *, design_qu: float = 0.2) -> dict[str, CompositeSinusoid]:
    """Periodic composite sinusoids scaled to ``robot`` for Lemma 1 (labels → references).

    Base frequency f_0 = 0.1 λ/2π (λ = √(Γ_q/D_uu), :func:`bemlearn.robots.scales.instability_rate`)
    rounded to 1e-3 Hz so that the components (f_0, 2f_0), (f_0, 3f_0), (2f_0, 3f_0) and
    (4f_0) share a period; amplitudes (3 : 2 for two components) so that the linearised BEM
    peaks at ``design_qu``/2 (never more than half a limited actuated joint's range).
    """
    from bemlearn.robots.scales import UNLIMITED_HALF_RANGE, bem_gain, bem_slopes, instability_rate, qa_half_ranges

    lam = instability_rate(robot)
    f0 = max(round(0.1 * lam / (2 * np.pi), 3), 1e-3)
    slopes = bem_slopes(robot)
    half = qa_half_ranges(robot)
    cap = float(np.min(np.where(half == UNLIMITED_HALF_RANGE, np.inf, 0.5 * half)))
    out = {}
    for ks, w in (((1, 2), (0.6, 0.4)), ((1, 3), (0.6, 0.4)), ((2, 3), (0.5, 0.5)), ((4,), (1.0,))):
        f = np.array(ks, dtype=float) * f0
        g = np.max(bem_gain(slopes, 2 * np.pi * f), axis=0)
        scale = min(0.5 * design_qu / max(float(np.dot(w, g)), 1e-12), cap)
        A = [float(f"{scale * x:.4g}") for x in w]
        ph = [0.0, 0.7][: len(ks)]
        label = " + ".join(f"{a:g} sin(2π·{fk:g} t{'' if p == 0 else f' + {p:g}'})" for a, fk, p in zip(A, f, ph))
        out[label] = CompositeSinusoid((tuple(A),) * robot.m, (tuple(float(x) for x in f),) * robot.m, (tuple(ph),) * robot.m, (0.0,) * robot.m)
    return out


def lemma1_relative_gap(result: LemmaOneResult) -> float:
    """max|ΔΓ − Ḣ_u − b_u q̇_u^e| / max|ΔΓ|: Lemma 1's residual relative to the term it explains."""
    scale = float(np.abs(result.delta_gamma).max())
    return float(np.abs(result.gap).max()) / scale if scale > 0 else float("inf")
