"""Learned vs model-based BEM over the whole design region, not only along a few references.

The held-out references of :mod:`bemlearn.pipeline.evaluation` reach the BEM values their
amplitudes happen to produce; a bias that grows with |q_u^e| (a slope error) hides there.
This evaluation looks where a user will use the BEM: every actuated motion whose model BEM
(eq. 9) lies in the design region |q_u^e − nominal| ≤ d (d = 0.2 rad or the q_u half range,
:func:`~bemlearn.pipeline.derive.design_region`).

The actuated motions are a scrambled Sobol set (``scipy.stats.qmc``) in the box, per actuated
coordinate j,

    |q_a,j| ≤ max(Q_j, min(d / |s_p,j|, 0.8 h_j)),    |q̇_a,j| ≤ Q_j ω,    |q̈_a,j| ≤ max(Q_j ω², 1.3 d / |s_a,j|)   (D1)

widened to the excitation's own extents where it has them (m ≥ 2, ``collect.excursion``: :func:`design_grid`; its
velocities to those of a motion on the balance's time scale 1/λ that reaches the box's accelerations)

with Q_j = min(Σ|A| of the held-out references, the joint's half range), ω = 2π × their top
frequency (``evaluate:``), h_j the joint's half range, and s_p,j = ∂q_u^e/∂q_a,j, s_a,j = ∂q_u^e/∂q̈_a,j at upright
(:func:`~bemlearn.robots.scales.bem_slopes`; a term with a slope of rounding size, below 10⁻⁹, is left out): the
position and acceleration ranges reach the design bound whatever the references' amplitudes.  The
points whose model BEM lies outside the design region (or has no root) are left out.  On them,
with e = μ(x_0^e) − q_u^e (eq. 14 vs 9):

    RMSE, max |e|, and the gain: the least-squares slope of μ on q_u^e (with an intercept);   (D2)

a gain below 1 is a learned BEM that under-reacts (e.g. derivatives that attenuate q̈), above
1 one that over-reacts.

The sample's max |e| is a lower bound of the region's sup, and in 3m dimensions a loose one (a turntable,
3m = 9: the sample's 0.039 rad where the error reaches 0.047).  With the robot at hand the max is refined
(:func:`refine_max`): a pattern search of |e| in the box from the :data:`REFINE_STARTS` worst points of the
sample, each step trying ± a step along every coordinate of the actuated motion, moving to the best
improvement and halving the step where none improves, over points whose model BEM stays in the region:

    max |e| = max(sample max, refined max),                                                     (D3)

and ``worst`` is where it was found.  RMSE and gain stay those of the sample (unbiased estimates over the
region); the max is what the check of the region's worst case needs.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from bemlearn.models.band import band_reference
from bemlearn.models.predictor_state import PredictorState

if TYPE_CHECKING:
    from bemlearn.pipeline.evaluation import EvaluationConfig
    from bemlearn.robots.protocol import ControlRobot

__all__ = ["DesignGrid", "DesignRegionResult", "DesignRegionCurve", "REFINE_STARTS", "design_grid", "evaluate_design_region",
           "least_squares_gain", "design_region_figure", "pattern_search_max", "refine_max"]

#: Starts of (D3)'s pattern search: the sample's worst points (distinct local maxima of |e| are few in practice).
REFINE_STARTS = 8
#: (D3)'s first step, a fraction of each half width of the box; the search ends after this many halvings.
REFINE_STEP, REFINE_HALVINGS = 0.05, 6


@dataclass(frozen=True)
class DesignGrid:
    """Queries of (D1) and their model BEM.

    Attributes:
        x: ``(N, 3m + 2)`` BEM queries x_0^e = [q̈_a, q̇_a, q_a, 0, 0] (joint units per s², per s, units).
        qu: ``(N,)`` model-based BEM q_u^e (eq. 9), q_u's unit.
        bound: d, q_u's unit.
        box: per actuated coordinate, the half widths ``{"q", "qd", "qdd"}`` of (D1).
        n_drawn: points drawn before leaving out those outside the design region.
    """

    x: torch.Tensor
    qu: np.ndarray
    bound: float
    box: dict
    n_drawn: int


def design_grid(robot: ControlRobot, evaluate_config: EvaluationConfig, *, n_points: int = 4096, seed: int = 0, bound: float | None = None,
                excursion: tuple[float, ...] | None = None) -> DesignGrid:
    """The queries of (D1) for ``robot`` (module docstring).

    Args:
        robot: a robot with a model BEM (``robot.bem``) and :func:`~bemlearn.robots.scales.bem_slopes`.
        evaluate_config: the run's :class:`~bemlearn.pipeline.evaluation.EvaluationConfig` (derived or
            given ``amplitude_max`` and ``frequency_hz``).
        n_points: Sobol points drawn (rounded to a power of two).
        seed: the Sobol scrambling seed.
        bound: d (default :func:`~bemlearn.pipeline.derive.design_region`).
        excursion: the excitation's per-direction extents (``collect.excursion``: P_j, then a_j; m ≥ 2): the box
            then reaches them too, |q_a,j| ≤ max(Q_j, P_j), |q̈_a,j| ≤ A_j = max(A_j, a_j) and
            |q̇_a,j| ≤ max(V_j, min(√(a_j P_j), A_j / (1.3 λ), v_j)) — the velocity of the excited motions that the
            balance performs on its own time scale 1/λ (λ the instability rate): a motion reaching the design
            acceleration A_j/1.3 moves at A_j/(1.3 λ), none faster than v_j, the speed that doubles the upright's
            stiffness (the robot family's oracle defines its region's velocities the same way, a_i/ω_u and v_tip),
            so that the check covers the motions the run claims to have excited (a turntable's yaw over ±π), not only
            the held-out references' amplitude.  A hinge the excitation sweeps is checked over its whole design region:
            poses to 0.8 × its half range (a half turn where unlimited), rates to its stiffening speed v_j
            (:func:`~bemlearn.robots.scales.velocity_stiffening_speed`) and accelerations to λ·v_j (λ the instability
            rate: a motion on the balance's own time scale that reaches v_j).
    """
    from scipy.stats import qmc

    from bemlearn.pipeline.derive import design_region
    from bemlearn.robots.scales import bem_slopes, qa_half_ranges

    d = float(design_region(robot).value if bound is None else bound)
    m = robot.m
    if evaluate_config.amplitude_max is None or evaluate_config.frequency_hz is None:
        from bemlearn.errors import ConfigError

        raise ConfigError("design_grid: evaluate.amplitude_max and evaluate.frequency_hz are not set; resolve the config "
                          "first (bemlearn.pipeline.resolve_pipeline_config derives them from the model)")
    w = 2 * math.pi * float(evaluate_config.frequency_hz[1])
    s_a = np.abs(bem_slopes(robot)[2])
    Q = np.minimum(float(evaluate_config.amplitude_max), qa_half_ranges(robot))
    V = Q * w
    # an s_a of rounding size (a turntable's yaw: 1e-18 rad per rad/s², where it is 0) is 0, as in the excitation's
    # extents (derive.excitation_directions): else the box asks for yaw accelerations of 1e17 rad/s²
    A = np.maximum(Q * w * w, np.where(s_a > 1e-9, 1.3 * d / np.maximum(s_a, 1e-300), 0.0))
    # a coordinate whose position moves the BEM (s_p ≠ 0: a pendubot's shoulder, an arm's joints) is checked to the
    # offset at which it alone moves the BEM by d, within 0.8 × its half range, as its acceleration is checked to
    # 1.3 d/|s_a|: the references' amplitude reached a third of that on a two-link arm of the robot family, whose
    # learned BEM was off by 0.046 rad beyond it and said ok; the velocities stay the references' (Q ω from before)
    s_p = np.abs(bem_slopes(robot)[0])
    Q = np.maximum(Q, np.where(s_p > 1e-9, np.minimum(d / np.maximum(s_p, 1e-300), 0.8 * qa_half_ranges(robot)), 0.0))
    if excursion:
        ext = np.asarray(excursion, dtype=np.float64)
        P, a = ext[:m], ext[m:2 * m]
        from bemlearn.robots.scales import instability_rate, velocity_stiffening_speed

        lam = instability_rate(robot)
        v = velocity_stiffening_speed(robot)
        Q, A = np.maximum(Q, P), np.maximum(A, a)
        # the velocities of the excitation's motions that the balance performs on its own time scale 1/λ: a motion
        # whose acceleration reaches the design extent A_j / 1.3 (the box's acceleration without its margin) moves at
        # A_j / (1.3 λ), and no joint faster than the speed v_j that doubles the upright's stiffness (the family
        # oracle's a_i / ω_u and v_tip).  √(a_j P_j), the speed of a sine that fills both extents, is slower than λ
        # where P_j > a_j / λ²: a quasi-static sweep whose velocity the balance never meets at its accelerations
        # (fam1_028: the shoulder's box to 2.4× the oracle's velocity, degraded on a max the oracle's box does not have)
        V = np.maximum(V, np.minimum.reduce([np.sqrt(a * P), A / (1.3 * lam), v]))   # v: inf where a velocity does not stiffen
        # a hinge the excitation sweeps (its pose turns the BEM's slopes over ≥ SWEEP_SPAN, sim.collect._sweep_components)
        # is checked over its whole design region: the poses to 0.8 × its half range (a half turn where unlimited) and
        # the rates to the speed that doubles the upright's stiffness, not only as far as the sweep's effort-scaled
        # extents went (fam0_053: yaw to 1.55 rad and 4.6 rad/s of 1.89 and 5.6; ok by its own box, RMSE 0.011 by
        # the oracle's)
        from bemlearn.robots.mujoco_robot import MujocoRobot
        from bemlearn.robots.scales import qa_limited
        from bemlearn.sim.collect import SWEEP_SPAN

        kinds = tuple(getattr(robot, "coordinate_kinds", ()))
        ia = list(getattr(robot, "actuated_index", range(m)))
        swept = np.array([len(kinds) == robot.n and kinds[ia[j]] == "hinge" and P[j] >= SWEEP_SPAN for j in range(m)], dtype=bool)
        if swept.any():
            limited = qa_limited(robot) if isinstance(robot, MujocoRobot) else np.ones(m, dtype=bool)
            whole = np.where(limited, 0.8 * qa_half_ranges(robot), math.pi)
            vf = np.where(np.isfinite(v), v, 0.0)
            Q = np.where(swept, np.maximum(Q, whole), Q)
            V = np.where(swept & np.isfinite(v), np.maximum(V, vf), V)
            # and the accelerations of a motion on the balance's own time scale that reaches that speed, λ·v_j (the
            # same extent as a flat joint's in the family oracle): fam0_017's yaw was checked to 9.2 rad/s² of λ·v =
            # 29; ok by its own box (max 0.039 rad), max 0.055 by the oracle's
            A = np.where(swept & np.isfinite(v), np.maximum(A, lam * vf), A)
    k = max(4, int(math.ceil(math.log2(max(n_points, 16)))))
    u = qmc.Sobol(3 * m, scramble=True, seed=seed).random_base2(k) * 2.0 - 1.0
    qadd, qad, qa = u[:, :m] * A, u[:, m:2 * m] * V, u[:, 2 * m:] * Q
    res = robot.bem(torch.from_numpy(qa), torch.from_numpy(qad), torch.from_numpy(qadd))
    qu = res.qu.numpy()
    keep = res.valid.numpy() & (np.abs(qu - robot.qu_nominal) <= d)
    x = np.concatenate([qadd, qad, qa, np.zeros((len(u), 2))], axis=1)[keep]
    names = robot.actuated_names if hasattr(robot, "actuated_names") else [f"q_a{j}" for j in range(m)]
    box = {str(nm): {"q": float(Q[j]), "qd": float(V[j]), "qdd": float(A[j])} for j, nm in enumerate(names)}
    return DesignGrid(torch.from_numpy(np.ascontiguousarray(x)), qu[keep], d, box, len(u))


def least_squares_gain(model: np.ndarray, learned: np.ndarray) -> tuple[float, float]:
    """(slope, intercept) of the least-squares line learned ≈ slope · model + intercept (D2)."""
    model = np.asarray(model, dtype=np.float64)
    learned = np.asarray(learned, dtype=np.float64)
    mc = model - model.mean()
    den = float(mc @ mc)
    if not den > 0:
        return math.nan, math.nan
    slope = float(mc @ (learned - learned.mean())) / den
    return slope, float(learned.mean() - slope * model.mean())


@dataclass(frozen=True)
class DesignRegionCurve:
    """The points of (D2), for the figure: model BEM, learned μ(x_0^e) and the exported band's σ, ``(N,)`` each, q_u's unit."""

    model: np.ndarray
    learned: np.ndarray
    band: np.ndarray


@dataclass(frozen=True)
class DesignRegionResult:
    """What :func:`evaluate_design_region` measured: (D2) of a learned BEM over a :class:`DesignGrid`.

    Errors are learned minus model BEM, in q_u's unit (NaN when the grid is empty).

    Attributes:
        rmse: RMSE of the error.
        max_abs: largest |error|.
        gain: slope of the least-squares line of learned on model BEM (1 for a faithful BEM).
        intercept: its intercept, q_u's unit.
        n_points: points of the grid whose model BEM is in the design region.
        n_drawn: points drawn for the grid.
        bound: the design bound d, q_u's unit.
        box: per actuated coordinate, the half widths ``{"q", "qd", "qdd"}`` of (D1).
        coverage_2sigma_band: share of the model BEM inside the exported band's ±2σ.
        worst: the query ``x0e`` and both BEMs where |error| is largest (``None`` for an empty grid).
        curve: the points, for :func:`design_region_figure` (not serialized).
        max_sampled: the sample's max |error| before (D3) refined it (``None``: not refined).
        refine_evaluations: model BEMs evaluated by (D3)'s search (0: not refined).
    """

    rmse: float
    max_abs: float
    gain: float
    intercept: float
    n_points: int
    n_drawn: int
    bound: float
    box: dict
    coverage_2sigma_band: float
    worst: dict[str, Any] | None
    curve: DesignRegionCurve
    max_sampled: float | None = None
    refine_evaluations: int = 0

    def as_dict(self) -> dict[str, Any]:
        """The JSON-ready summary (``metrics.json`` → ``bem_design_region``), without ``curve``."""
        return {"rmse": self.rmse, "max_abs": self.max_abs, "gain": self.gain, "intercept": self.intercept,
                "n_points": self.n_points, "n_drawn": self.n_drawn, "bound": self.bound, "box": self.box,
                "coverage_2sigma_band": self.coverage_2sigma_band, "worst": self.worst, "max_sampled": self.max_sampled,
                "refine_evaluations": self.refine_evaluations}


def evaluate_design_region(state: PredictorState, grid: DesignGrid, robot: ControlRobot | None = None) -> DesignRegionResult:
    """(D2) of ``state``'s learned BEM on ``grid`` (module docstring); with ``robot`` (the model the grid's BEM came
    from) the max refined by (D3), :func:`refine_max`."""
    if len(grid.qu) == 0:
        empty = np.zeros(0)
        return DesignRegionResult(math.nan, math.nan, math.nan, math.nan, 0, grid.n_drawn, grid.bound, grid.box, math.nan, None,
                                  DesignRegionCurve(empty, empty, empty))
    mean, band, _ = (v.numpy() for v in band_reference(state, grid.x, n_inputs=state.dim - 2))
    e = mean - grid.qu
    gain, icpt = least_squares_gain(grid.qu, mean)
    i = int(np.argmax(np.abs(e)))
    result = DesignRegionResult(
        rmse=float(np.sqrt(np.mean(e**2))), max_abs=float(np.abs(e).max()), gain=gain, intercept=icpt, n_points=int(e.size),
        n_drawn=grid.n_drawn, bound=grid.bound, box=grid.box, coverage_2sigma_band=float(np.mean(np.abs(e) <= 2 * band)),
        worst={"x0e": [float(v) for v in grid.x[i, :-2]], "model": float(grid.qu[i]), "learned": float(mean[i])},
        curve=DesignRegionCurve(grid.qu, mean, band))
    return result if robot is None else refine_max(state, robot, grid, result)


def refine_max(state: PredictorState, robot: ControlRobot, grid: DesignGrid, result: DesignRegionResult, *,
               starts: int = REFINE_STARTS, step: float = REFINE_STEP, halvings: int = REFINE_HALVINGS) -> DesignRegionResult:
    """(D3): ``result`` with its max |e| refined by a pattern search in ``grid``'s box (module docstring).

    Args:
        state: the learned BEM.
        robot: the model whose BEM (eq. 9) ``grid`` holds (``robot.bem`` on batches of actuated motions).
        grid: the sample of (D1), its box and bound.
        result: (D2) on ``grid``.
        starts: the sample's worst points the search starts from.
        step: the first step, a fraction of each half width of the box.
        halvings: the search at a start ends after this many halvings of its step.

    Returns:
        ``result`` with ``max_abs``, ``worst``, ``max_sampled`` and ``refine_evaluations`` set (``result`` as it is for
        an empty grid).
    """
    if len(grid.qu) == 0 or starts < 1:
        return result
    m = robot.m
    half = np.array([[grid.box[k]["qdd"] for k in grid.box], [grid.box[k]["qd"] for k in grid.box],
                     [grid.box[k]["q"] for k in grid.box]], dtype=np.float64).reshape(-1)        # (3m,) [A, V, Q]
    nominal, d = float(robot.qu_nominal), float(grid.bound)
    found: dict[str, np.ndarray] = {}

    def error(u: np.ndarray) -> np.ndarray:
        """|e| at box coordinates u (B, 3m); −1 outside the region or without a root."""
        x = u * half
        res = robot.bem(torch.from_numpy(x[:, 2 * m:]), torch.from_numpy(x[:, m:2 * m]), torch.from_numpy(x[:, :m]))
        qu = res.qu.numpy()
        ok = res.valid.numpy() & (np.abs(qu - nominal) <= d)
        mu = band_reference(state, torch.from_numpy(np.concatenate([x, np.zeros((len(x), 2))], axis=1)), n_inputs=state.dim - 2)[0].numpy()
        found["qu"], found["mu"] = qu, mu
        return np.where(ok, np.abs(mu - qu), -1.0)

    e_all = np.abs(result.curve.learned - result.curve.model)
    order = np.argsort(-e_all)[:starts]
    live = half > 0
    u0 = np.where(live, grid.x[:, :3 * m].numpy()[order] / np.where(live, half, 1.0), 0.0)
    u, best, evaluations = pattern_search_max(error, u0, e_all[order], step=step, halvings=halvings, live=live)
    top = int(np.argmax(best))
    if best[top] <= result.max_abs:
        return dataclasses.replace(result, max_sampled=result.max_abs, refine_evaluations=evaluations)
    error(u[top:top + 1])                                                   # the two BEMs at the worst point found
    return dataclasses.replace(result, max_abs=float(best[top]), max_sampled=result.max_abs, refine_evaluations=evaluations,
                               worst={"x0e": [float(v) for v in u[top] * half], "model": float(found["qu"][0]),
                                      "learned": float(found["mu"][0])})


def pattern_search_max(f, u0: np.ndarray, f0: np.ndarray, *, step: float = REFINE_STEP, halvings: int = REFINE_HALVINGS,
                       live: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Local maxima of ``f`` over the box [−1, 1]^k from each start, by compass search (D3).

    At each start, every step tries u ± h e_i along the ``live`` coordinates (all by default), moves to the best
    candidate when it improves on the current value and halves h otherwise, until h < ``step`` · 2^−``halvings``.
    The starts step together: ``f`` is called once per step on all of their candidates.

    Args:
        f: ``f(U)`` for ``U (B, k)`` in the box → ``(B,)`` values to maximise (a value below every start's marks a
            point outside the feasible set).
        u0: ``(S, k)`` starts in the box.
        f0: ``(S,)`` ``f`` at the starts.
        step: the first h.
        halvings: halvings of h before a start stops.
        live: ``(k,)`` bool, the coordinates that move.

    Returns:
        ``(u (S, k), f(u) (S,), evaluations)``: where each start ended, its value, and the points ``f`` was given.
    """
    u, best = np.array(u0, dtype=np.float64), np.array(f0, dtype=np.float64)
    k = u.shape[1]
    live = np.ones(k, dtype=bool) if live is None else np.asarray(live, dtype=bool)
    directions = np.concatenate([np.eye(k)[live], -np.eye(k)[live]])                        # (2k', k)
    h = np.full(len(u), float(step))
    floor = step * 0.5**halvings
    evaluations = 0
    while len(directions) and np.any(h >= floor):
        active = np.flatnonzero(h >= floor)
        cand = np.clip(u[active, None, :] + h[active, None, None] * directions[None], -1.0, 1.0)   # (S', 2k', k)
        val = np.asarray(f(cand.reshape(-1, k)), dtype=np.float64).reshape(len(active), -1)
        evaluations += cand.shape[0] * cand.shape[1]
        j = np.argmax(val, axis=1)
        for r, s in enumerate(active):
            if val[r, j[r]] > best[s]:
                u[s], best[s] = cand[r, j[r]], val[r, j[r]]
            else:
                h[s] *= 0.5
    return u, best, evaluations


def design_region_figure(result: DesignRegionResult, qu_name: str, unit: str = "rad"):
    """Learned vs model BEM over the design region: μ(x_0^e) against q_u^e with ±2σ of the band
    and the identity line (left), and the error against q_u^e (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    model, learned, band = result.curve.model, result.curve.learned, result.curve.band
    order = np.argsort(model)
    fig, ax = plt.subplots(1, 2, figsize=(10, 4.2))
    d = result.bound
    ax[0].plot([-d, d], [-d, d], "k", lw=1, label="identity (learned = model)")
    ax[0].scatter(model, learned, s=3, c="C1", alpha=0.5, label=f"learned μ(x₀ᵉ), {result.n_points} motions")
    if len(model):
        ax[0].fill_between(model[order], (learned - 2 * band)[order], (learned + 2 * band)[order], color="C1", alpha=0.15,
                           label="±2σ (calibrated band)")
    ax[0].set_xlabel(f"model-based BEM q_u^e (eq. 9), {unit}")
    ax[0].set_ylabel(f"learned BEM (eq. 14), {unit}")
    ax[0].set_title(f"{qu_name}: gain {result.gain:.3f}, RMSE {result.rmse:.4f} {unit}", fontsize=10)
    ax[0].legend(fontsize=8)
    ax[1].scatter(model, learned - model, s=3, c="C3", alpha=0.5)
    ax[1].axhline(0.0, color="k", lw=0.8)
    ax[1].set_xlabel(f"model-based BEM q_u^e, {unit}")
    ax[1].set_ylabel(f"learned − model, {unit}")
    ax[1].set_title(f"max |error| {result.max_abs:.4f} {unit} over |q_u^e| ≤ {d:g}", fontsize=10)
    fig.tight_layout()
    return fig
