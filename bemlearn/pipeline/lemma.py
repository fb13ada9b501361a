"""Lemma 1 (eq. 10) from the learned model alone, along a periodic reference.

Linearizing Γ about the BEM, Γ(q_u^e + δ, q̇_u, q̈_u) ≈ Γ_q δ + Γ_q̇ q̇_u + D_uu q̈_u, and the GP
f of eq. (11) solves Γ = 0 for q_u, so f(x^e) − f(x_0^e) = δ with Γ_q δ = −ΔΓ, where x^e holds
the BEM's own rates q̇_u^e, q̈_u^e and x_0^e zeros (eq. 14).  The GP also gives
∂f/∂q̈_u = −D_uu / Γ_q, hence

    ΔΓ_learned / D_uu = (f(x^e) − f(x_0^e)) / (∂f/∂q̈_u),

built from GP quantities only; it is scaled by the nominal D_uu for N·m.  The model-based
side (:func:`bemlearn.robots.zero_dynamics.lemma1`) gives ΔΓ and Ḣ_u exactly.

Both sides sample one period T of the reference at N nodes and take q̇_u^e, q̈_u^e by spectral
derivatives, exact for the harmonics k/T with |k| < N/2.  A reference whose frequencies are not
commensurate to the digits they are written with has a period of the least common multiple: the
derived closed-loop reference (0.2, 0.4)·λ/2π written to 4 significant digits, e.g. (0.1971,
0.3941) Hz, repeats after T = 1/gcd = 10⁴ s, and 256 nodes over it are 39 s apart, 8 periods of its
fastest component: the derivatives, ΔΓ and the correlation are then of an aliased sequence (on
the public two-wheeler r = 0.37 there, 0.998 along (0.1971, 0.3942) Hz).  :func:`lemma1_reference`
keeps a reference the nodes resolve (f_max T ≤ N / 16: at least 16 nodes per cycle of the fastest
component, its harmonics to the 8th resolved) and otherwise takes the commensurate frequencies it
was written from, f_k = (p_k/q_k) f_min (small integers, within the written digits' rounding).

The learned ΔΓ is also split by least squares over the model's two parts,

    ΔΓ_learned ≈ a Ḣ_u + b (b_u q̇_u^e),

a = b = 1 where the learned map reproduces both.  The damping part rests on the map's slope in q̇_u
alone, which balanced data often do not fix (q̇_u moves in lockstep with q̇_a); its size in q_u along
the reference, std(b_u q̇_u^e) / |Γ_q| with Γ_q = −D_uu / (∂f/∂q̈_u), says whether a wrong b could be
seen at all at the learned map's accuracy (the verdict compares it with the held-out error).  So does the
model's whole ΔΓ in q_u, std(ΔΓ) / |Γ_q|: how far the zero dynamics along the reference move q_u from the BEM
at rest, f(x^e) − f(x_0^e) for an exact map; where that is below the map's held-out q_u error, the learned
ΔΓ is a difference the map does not resolve, and its correlation with the model's says nothing either way.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction

import numpy as np
import torch

from bemlearn.robots.protocol import BalanceRobot
from bemlearn.robots.reference import CompositeSinusoid
from bemlearn.robots.zero_dynamics import lemma1, spectral_derivative

__all__ = ["LearnedLemma1", "learned_lemma1", "lemma1_reference", "NODES_PER_CYCLE"]

#: Nodes per cycle of a reference's fastest component below which its sampled period is aliased (module docstring).
NODES_PER_CYCLE = 16
#: The relative error within which a frequency ratio is a small fraction (4 significant digits round by ≤ 5e-4 each).
_RATIO_TOL = 1e-3
#: The largest denominator of a frequency ratio taken as commensurate.
_RATIO_DEN = 12


@dataclass(frozen=True, eq=False)
class LearnedLemma1:
    """Learned ΔΓ against the model's along one period of a reference (:func:`learned_lemma1`).

    Generalized forces are in the unactuated row's unit (N·m for a hinge q_u, N for a slide).

    Attributes:
        t: ``(N,)`` sample times over one period, s.
        hdot: ``(N,)`` Ḣ_u of the model's zero dynamics (Lemma 1, eq. 10).
        damping: ``(N,)`` b_u q̇_u^e, the passive part of the model's ΔΓ.
        delta_gamma_model: ``(N,)`` the model's ΔΓ.
        delta_gamma_learned: ``(N,)`` ΔΓ from the learned map alone (module docstring).
        r: Pearson correlation of ``delta_gamma_learned`` with Ḣ_u + b_u q̇_u^e (the model's ΔΓ).
        r_hdot: its correlation with Ḣ_u alone.
        model_gap: max |ΔΓ − Ḣ_u − b_u q̇_u^e| of the model side.
        hdot_coefficient: a of the split (module docstring).
        damping_coefficient: b of the split; NaN where the model's damping part is zero along the
            reference (no passive damping on q_u).
        r_model_damping: the correlation with the model's ΔΓ once the learned damping part is
            replaced by the model's (``delta_gamma_learned − (b − 1) b_u q̇_u^e``); equals ``r`` when
            b is NaN.
        damping_qu: std(b_u q̇_u^e) / |Γ_q| along the reference, in q_u's unit: how far the damping
            part moves q_u (0 without damping).
        delta_gamma_qu: std(ΔΓ) / |Γ_q| of the model's ΔΓ along the reference, in q_u's unit: how far the
            zero dynamics move q_u from the BEM at rest (NaN where Γ_q is not finite and positive).
    """

    t: np.ndarray
    hdot: np.ndarray
    damping: np.ndarray
    delta_gamma_model: np.ndarray
    delta_gamma_learned: np.ndarray
    r: float
    r_hdot: float
    model_gap: float
    hdot_coefficient: float = float("nan")
    damping_coefficient: float = float("nan")
    r_model_damping: float = float("nan")
    damping_qu: float = 0.0
    delta_gamma_qu: float = float("nan")


def learned_lemma1(bem_fn: Callable[[np.ndarray], np.ndarray], full_fn: Callable[[np.ndarray], np.ndarray], robot: BalanceRobot,
                   reference: CompositeSinusoid, *, n_nodes: int = 256, h: float = 1e-3) -> LearnedLemma1:
    """Learned ΔΓ vs model Ḣ_u along a periodic ``reference``.

    Args:
        bem_fn: learned BEM mean, ``x (B, 3m)`` = [q̈_a, q̇_a, q_a] → ``(B,)`` in q_u's unit (eq. 14).
        full_fn: learned map mean, ``x (B, 3m + 2)`` → ``(B,)`` in q_u's unit (eq. 11); e.g. a
            :class:`~bemlearn.control.bem_sources.PredictorBEM` and its ``full``.
        robot: the (nominal) robot, for D_uu and the model-based side.
        reference: a periodic composite sinusoid.
        n_nodes: samples over one period.
        h: finite-difference step in q̈_u (rad/s², m/s² for a slide) for ∂f/∂q̈_u.

    Returns:
        a :class:`LearnedLemma1` (``N = n_nodes`` samples).
    """
    L = lemma1(robot, reference, n_nodes=n_nodes)
    T = reference.period
    qa, qad, qadd = reference.evaluate(L.t)
    mu0 = np.asarray(bem_fn(np.ascontiguousarray(np.concatenate([qadd, qad, qa], axis=1))))
    qud = spectral_derivative(mu0, T, 1)
    qudd = spectral_derivative(mu0, T, 2)
    base = np.concatenate([qadd, qad, qa], axis=1)
    x_e = np.concatenate([base, qudd[:, None], qud[:, None]], axis=1)
    x_0 = np.concatenate([base, np.zeros((L.t.size, 2))], axis=1)
    x_p, x_m = x_0.copy(), x_0.copy()
    x_p[:, -2] += h
    x_m[:, -2] -= h
    f = lambda x: np.asarray(full_fn(np.ascontiguousarray(x)))  # noqa: E731
    dfdqdd = (f(x_p) - f(x_m)) / (2 * h)
    u = robot.unactuated_index
    q_e = robot.join(torch.from_numpy(qa), torch.from_numpy(L.qu_e))
    duu = robot.mass_matrix(q_e)[:, u, u].numpy()
    dg_learned = duu * (f(x_e) - f(x_0)) / dfdqdd
    target = L.hdot + L.damping
    r = float(np.corrcoef(dg_learned, target)[0, 1])
    r_hdot = float(np.corrcoef(dg_learned, L.hdot)[0, 1])
    gamma_q = float(np.median(np.abs(duu / dfdqdd)))
    a, b, r_md, damping_qu = _split(dg_learned, L.hdot, L.damping, gamma_q=gamma_q)
    dg_qu = float(np.std(L.delta_gamma)) / gamma_q if math.isfinite(gamma_q) and gamma_q > 0 else math.nan
    return LearnedLemma1(t=L.t, hdot=L.hdot, damping=L.damping, delta_gamma_model=L.delta_gamma, delta_gamma_learned=dg_learned,
                         r=r, r_hdot=r_hdot, model_gap=float(np.abs(L.gap).max()), hdot_coefficient=a, damping_coefficient=b,
                         r_model_damping=r_md if math.isfinite(r_md) else r, damping_qu=damping_qu, delta_gamma_qu=dg_qu)


def _split(dg: np.ndarray, hdot: np.ndarray, damping: np.ndarray, *, gamma_q: float) -> tuple[float, float, float, float]:
    """``(a, b, r_model_damping, damping_qu)`` of ΔΓ_learned ≈ a Ḣ_u + b (b_u q̇_u^e) (module docstring).

    The damping part counts only where it is above rounding next to Ḣ_u (``1e-9`` of its spread).
    """
    scale = float(np.std(hdot)) + float(np.std(damping))
    has_damping = float(np.std(damping)) > 1e-9 * scale
    damping_qu = float(np.std(damping)) / gamma_q if has_damping and gamma_q > 0 else 0.0
    if not has_damping:
        a = float(np.linalg.lstsq(np.stack([hdot, np.ones_like(hdot)], 1), dg, rcond=None)[0][0])
        return a, math.nan, math.nan, damping_qu
    coef = np.linalg.lstsq(np.stack([hdot, damping, np.ones_like(hdot)], 1), dg, rcond=None)[0]
    a, b = float(coef[0]), float(coef[1])
    r_md = float(np.corrcoef(dg - (b - 1.0) * damping, hdot + damping)[0, 1])
    return a, b, r_md, damping_qu


def lemma1_reference(reference: CompositeSinusoid, *, n_nodes: int = 256) -> tuple[CompositeSinusoid, str]:
    """The reference along which Lemma 1 is checked with ``n_nodes`` samples of one period (module docstring).

    ``reference`` itself when f_max T ≤ n_nodes / :data:`NODES_PER_CYCLE`; otherwise each row's frequencies
    f_k' = (p_k/q_k) f_min with p_k/q_k the fraction of denominator ≤ 12 nearest f_k/f_min, when every one is within
    1e-3 of it (the ratios the reference was derived with, (0.2, 0.4)·λ/2π → 2) and the result is resolved; else
    ``reference`` (the caller's check is then of an aliased sequence, and the note says so).

    Returns:
        ``(reference, note)``: the note is ``""`` when ``reference`` is returned resolved, else one sentence.
    """
    def resolved(ref: CompositeSinusoid) -> bool:
        f_max = max((abs(f) for row in ref.frequencies for f in row), default=0.0)
        return math.isfinite(ref.period) and f_max * ref.period <= n_nodes / NODES_PER_CYCLE

    if resolved(reference):
        return reference, ""
    rows = []
    for row in reference.frequencies:
        f_min = min((abs(f) for f in row if f != 0), default=0.0)
        snapped = []
        for f in row:
            if f == 0 or f_min == 0:
                snapped.append(float(f))
                continue
            ratio = Fraction(abs(f) / f_min).limit_denominator(_RATIO_DEN)
            if abs(float(ratio) * f_min - abs(f)) > _RATIO_TOL * abs(f):
                return reference, (f"its frequencies {list(row)} Hz are not near small-integer ratios: one period "
                                   f"({reference.period:.4g} s) is aliased at {n_nodes} nodes")
            snapped.append(math.copysign(float(ratio) * f_min, f))
        rows.append(tuple(snapped))
    out = CompositeSinusoid(reference.amplitudes, tuple(rows), reference.phases, reference.offsets)
    if not resolved(out):
        return reference, f"one period ({reference.period:.4g} s) is aliased at {n_nodes} nodes"
    return out, (f"along the commensurate frequencies {[list(r) for r in rows]} Hz (the reference's "
                 f"{[list(r) for r in reference.frequencies]} Hz repeat only after {reference.period:.4g} s, which "
                 f"{n_nodes} nodes alias)")
