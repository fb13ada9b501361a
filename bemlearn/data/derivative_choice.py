"""The Gaussian estimator's width σ, chosen from the data's own motion.

A consistent filter (:mod:`bemlearn.data.gaussian_derivative`, eq. G2) keeps the unactuated
row's relation between the smoothed inputs and the smoothed label at every σ, so σ trades two
errors that do not bias each other's sign: at small σ the quantization noise in S[q̈]
(growing as σ^(−5/2)) attenuates the learned slopes (errors in variables); at large σ the
smoothing takes the motion itself away, the data cover less of the design region and the GP
has to extrapolate, and the smoothing of products and of the nonlinearity grows.  The rule
takes as much smoothing as the motion allows:

    σ = the width at which the smoothed label keeps ρ = 93 % of its motion,
        std(S_σ[q_u] − trial mean) = ρ · std(S_σ₀[q_u] − trial mean)                   (C1)

with σ₀ two samples (std over the rows valid at every σ tried and inside ``qu_window``).  For
a single sine of frequency f, (C1) is σ = √(−2 ln ρ) / (2πf) ≈ 0.06 / f.  The measurements
behind the default ρ = 0.93 are in docs/derivatives.md (``bemlearn bench derivatives``).
No model is used.

The result also states how much quantization noise is left in S[q̈] at that σ: the noise std
δ/√12 · ‖w2‖ of each joint with a detected encoder step δ, as a fraction of the std of S[q̈] in
the data; above :data:`NOISY` the derivatives are noise-dominated and the learned slopes are
attenuated (the run's verdict says so).
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bemlearn.data.gaussian_derivative import GaussianDerivative, apply_kernel, gaussian_kernels
from bemlearn.data.trajectory import Trajectory

__all__ = ["SigmaChoice", "choose_sigma", "resolve_estimator", "estimate_states", "estimate_states_of", "KEPT_MOTION", "NOISY", "TURNING_SPAN", "TURNING_KEPT"]

log = logging.getLogger(__name__)

#: ρ of (C1): the share of the label's motion (std) the smoothing keeps.
KEPT_MOTION = 0.93
#: Quantization noise in S[q̈] above this fraction of its std in the data: noise-dominated
#: (the measurements behind the threshold: docs/derivatives.md).
NOISY = 0.04
#: Ratio between neighbouring widths of the ladder (C1) is evaluated on, interpolated between.
LADDER_RATIO = 1.25
#: The ladder's largest σ, s.
MAX_SIGMA_S = 2.0


@dataclass(frozen=True)
class SigmaChoice:
    """The result of :func:`choose_sigma`.

    Attributes:
        sigma_s: the chosen σ, s.
        ladder: the σ values evaluated, s.
        kept: the share of the label's motion each keeps (C1).
        rows: samples (C1) was evaluated on.
        noise: per joint with a detected encoder step, the quantization noise std in S[q̈] at σ
            as a fraction of S[q̈]'s std in the data (``{joint: fraction}``).
        limited: ``None``, or why σ is not where (C1) would put it (``"short trials"``: the
            trials cannot hold a wider kernel; ``"slow motion"``: the widest σ tried keeps more
            than ρ).
        note: one line for logs and reports.
    """

    sigma_s: float
    ladder: tuple[float, ...]
    kept: tuple[float, ...]
    rows: int
    noise: dict[str, float]
    limited: str | None
    note: str

    @property
    def noisy(self) -> list[str]:
        """Joints whose S[q̈] is noise-dominated (noise fraction above :data:`NOISY`)."""
        return [j for j, v in self.noise.items() if v > NOISY]

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary."""
        return {"sigma_s": self.sigma_s, "ladder": list(self.ladder), "kept_motion": list(self.kept), "rows": self.rows,
                "qdd_noise_fraction": dict(self.noise), "limited": self.limited, "note": self.note,
                "criterion": f"C1: the smoothed label keeps {KEPT_MOTION:.0%} of its motion (docs/derivatives.md)"}


def estimate_states(traj: Trajectory, estimator, *, within: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """q as the estimator passes it, q̇, q̈ and the validity of each row, trial by trial.

    An estimator with ``smooths = True`` (the Gaussian) returns its smoothed q, which then serves
    as the GP's q_a inputs and q_u label alike (eq. G2); others return the recorded q.  Rows are
    invalid within :meth:`edge_samples` of a trial end for estimators with ``edges_valid = False``,
    and throughout trials shorter than :meth:`min_samples`.

    Args:
        traj: the trajectory.
        estimator: a derivative estimator.
        within: ``(T,)`` bool, the rows to use (e.g. |q_u| inside the dataset's window).  For an
            estimator that smooths, each run of consecutive ``True`` rows of a trial is filtered as
            a trial of its own, so that no motion outside them (a swing-up, a fall) is smoothed into
            them; rows outside are invalid.  Other estimators work on whole trials.

    Returns:
        ``q, qd, qdd``: ``(T, n)`` each (joint units, per s, per s²; zeros where invalid) and
        ``valid``: ``(T,)`` bool.  Fresh arrays: the caller may change them.

    A trajectory keeps what was estimated from it, per estimator (its ``repr``) and ``within``: a run
    builds its datasets, calibrates the band and weighs the neighbouring estimators on the same
    estimates, computed once.
    """
    key = (type(estimator), repr(estimator), None if within is None else hashlib.sha1(np.packbits(within).tobytes()).hexdigest())
    memo = traj.__dict__.setdefault("_state_estimates", {})
    if key not in memo:
        memo[key] = _estimate_states(traj, estimator, within)
    return tuple(a.copy() for a in memo[key])


def estimate_states_of(traj: Trajectory, estimators, *, within: np.ndarray | None = None
                       ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """:func:`estimate_states` of each of ``estimators`` (in their order), from the trajectory's memo.

    One call for a caller that needs several estimates of the same rows, e.g. the chosen estimator
    and its neighbours (:func:`~bemlearn.fitting.estimator_sensitivity.estimator_sensitivity`).

    Returns:
        one ``(q, qd, qdd, valid)`` per estimator, as :func:`estimate_states` returns it.
    """
    return [estimate_states(traj, est, within=within) for est in estimators]


def _estimate_states(traj: Trajectory, estimator, within: np.ndarray | None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rate = traj.meta.sample_rate_hz
    q = traj.q.copy()
    qd = np.zeros_like(q)
    qdd = np.zeros_like(q)
    valid = np.zeros(traj.n_samples, dtype=bool)
    need = estimator.min_samples(rate)
    smooths = bool(getattr(estimator, "smooths", False))
    edge = 0 if getattr(estimator, "edges_valid", True) else estimator.edge_samples(rate)
    for r in _segments(traj, within if smooths else None):
        if r.stop - r.start < need:
            continue
        if smooths:
            q[r], qd[r], qdd[r] = estimator.filter(traj.q[r], sample_rate_hz=rate)
        else:
            qd[r], qdd[r] = estimator(traj.q[r], sample_rate_hz=rate)
        valid[r.start + edge:r.stop - edge] = True
    return q, qd, qdd, valid


def _segments(traj: Trajectory, within: np.ndarray | None) -> list[slice]:
    """The row slices filtered as one: each trial, or each run of ``within`` rows inside a trial."""
    out = []
    for s in traj.trial_slices():
        if within is None:
            out.append(s.rows)
            continue
        w = np.asarray(within[s.rows], dtype=np.int8)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], w, [0]])))
        out.extend(slice(s.rows.start + int(a), s.rows.start + int(b)) for a, b in zip(edges[::2], edges[1::2]))
    return out


def _ladder(traj: Trajectory, truncate: float, within: np.ndarray | None = None) -> tuple[float, ...]:
    """σ from two samples up by :data:`LADDER_RATIO` while at least half the samples keep a full kernel."""
    rate = traj.meta.sample_rate_hz
    lengths = np.array([r.stop - r.start for r in _segments(traj, within)], dtype=np.float64)
    total = lengths.sum()
    sig = 2.0 / rate
    out = []
    while sig <= MAX_SIGMA_S:
        K = math.ceil(truncate * sig * rate)
        if np.clip(lengths - 2 * K, 0, None).sum() < 0.5 * total:
            break
        out.append(float(f"{sig:.4g}"))
        sig *= LADDER_RATIO
    return tuple(out)


def _detrended_std(v: np.ndarray, trial: np.ndarray) -> float:
    _, inv = np.unique(trial, return_inverse=True)
    means = np.bincount(inv, weights=v) / np.bincount(inv)
    return float(np.std(v - means[inv]))


def choose_sigma(traj: Trajectory, *, qu_window: float | None = 0.5, truncate: float = 5.0,
                 kept_motion: float = KEPT_MOTION) -> SigmaChoice:
    """σ of the Gaussian estimator for ``traj`` by rule (C1) (module docstring).

    Args:
        traj: the trajectory (uniformly sampled trials).
        qu_window: rows with |q_u| > this are left out (the dataset's ``qu_window``), rad or m.
        truncate: the estimator's ``truncate``.
        kept_motion: ρ of (C1).

    Raises:
        TrajectoryFormatError: the trials are too short for even a two-sample σ.
    """
    from bemlearn.errors import TrajectoryFormatError

    meta = traj.meta
    rate = meta.sample_rate_hz
    iu = meta.unactuated_index
    within = traj.qu_window_mask(qu_window)
    ladder = _ladder(traj, truncate, within)
    where = f"{meta.robot!r} ({traj.n_samples} samples in {len(traj.trial_ids)} trials at {rate:g} Hz)"
    if within is not None and int(within.sum()) < 10:
        raise TrajectoryFormatError(f"choose_sigma: {where}: fewer than 10 samples inside |{meta.qu_from_upright}| ≤ "
                                    f"{qu_window:g} ({int(within.sum())}); widen dataset.qu_window or "
                                    f"check the sign and offset of {meta.unactuated} (the upright must read "
                                    f"{meta.qu_upright:g}, the data's meta.qu_upright)")
    if not ladder:
        raise TrajectoryFormatError(
            f"choose_sigma: the trials of {where} are too short for the Gaussian estimator (a σ of two samples needs "
            f"trials of more than {4 * math.ceil(2 * truncate)} samples); use dataset.derivative: savgol or central")
    edge = GaussianDerivative(sigma_s=ladder[-1], truncate=truncate).edge_samples(rate)
    segments = _segments(traj, within)
    common = np.zeros(traj.n_samples, dtype=bool)
    for r in segments:
        if r.stop - r.start > 2 * edge:
            common[r.start + edge:r.stop - edge] = True
    rows = np.flatnonzero(common)
    if rows.size < 10:
        raise TrajectoryFormatError(f"choose_sigma: {where}: fewer than 10 samples inside |{meta.qu_from_upright}| ≤ "
                                    f"{qu_window} away from the trial ends; nothing to choose σ from")
    trial = traj.trial[rows]
    label = traj.q[:, iu:iu + 1]
    stds = []
    for sig in ladder:
        w0 = gaussian_kernels(sig, rate, truncate)[0]
        smooth = np.empty_like(label)
        for r in segments:
            if r.stop - r.start > 2 * edge:
                smooth[r] = apply_kernel(label[r], w0)
        stds.append(_detrended_std(smooth[rows, 0], trial))
    kept = tuple(float(v / stds[0]) if stds[0] > 0 else math.nan for v in stds)
    limited = None
    if not stds[0] > 0:
        sigma = ladder[len(ladder) // 2]
        note = f"σ = {sigma:g} s: {meta.unactuated} does not move in the data; the middle of the ladder is used"
        limited = "no motion"
    else:
        below = [k for k, v in enumerate(kept) if v < kept_motion]
        if not below:
            sigma = ladder[-1]
            limited = "short trials" if ladder[-1] * LADDER_RATIO <= MAX_SIGMA_S else "slow motion"
            note = (f"σ = {sigma:g} s, the widest the trials allow: it keeps {kept[-1]:.0%} of {meta.unactuated}'s motion "
                    f"(rule: {kept_motion:.0%})")
        else:
            k = below[0]
            lo, hi = math.log(ladder[k - 1]), math.log(ladder[k])
            a, b = kept[k - 1], kept[k]
            sigma = float(f"{math.exp(lo + (hi - lo) * (a - kept_motion) / (a - b)):.4g}")
            note = f"σ = {sigma:g} s chosen from the data: the smoothed {meta.unactuated} keeps {kept_motion:.0%} of its motion"
    steps = traj.quantization_steps()       # detected, or recorded by an import before resampling
    turning = _turning_directions(traj, rows, within, GaussianDerivative(sigma_s=sigma, truncate=truncate))
    for name, (sig_j, span, w95) in turning.items():
        if sig_j < sigma:
            # not into the noise: the quantization noise in S[q̈] grows as σ^(−5/2); where it passes NOISY at the
            # turning bound, σ is raised to where it meets it (never above the label's σ)
            floor = sig_j
            for _ in range(4):   # the law is ‖w2‖'s; S_σ[q̈]'s spread shrinks a little with σ too: a few steps
                worst = max(_noise(traj, steps, floor, rate, truncate, within).values(), default=0.0)
                if worst <= NOISY or floor >= sigma:
                    break
                floor = float(f"{floor * (worst / NOISY) ** 0.4 * 1.001:.4g}")
            chosen = float(f"{min(sigma, floor):.4g}")
            note = (f"σ = {chosen:g} s chosen from the data: {name} turns through {span:.3g} rad at up to {w95:.3g} rad/s "
                    f"(95 %), and the smoothing keeps {TURNING_KEPT:.0%} of its direction's products at {sig_j:g} s"
                    + (f", raised to where q̈'s quantization noise is {NOISY:.0%} of its spread" if chosen > sig_j else "")
                    + f" (the label alone would allow {sigma:g} s)")
            sigma, limited = chosen, None
    noise = _noise(traj, steps, sigma, rate, truncate, within)
    noisy = [j for j, v in noise.items() if v > NOISY]
    if noisy:
        note += "; q̈ noise-dominated in " + ", ".join(f"{j} ({noise[j]:.0%} of its std)" for j in noisy)
    log.info("derivatives: %s", note)
    return SigmaChoice(sigma, ladder, kept, int(rows.size), noise, limited, note)


def _noise(traj: Trajectory, steps: dict, sigma: float, rate: float, truncate: float, within: np.ndarray | None) -> dict[str, float]:
    """Per joint with a detected encoder step δ: δ/√12 · ‖w2‖ as a fraction of the std of S_σ[q̈] in the data."""
    w2 = gaussian_kernels(sigma, rate, truncate)[2]
    _, _, qdd, ok = estimate_states(traj, GaussianDerivative(sigma_s=sigma, truncate=truncate), within=within)
    noise: dict[str, float] = {}
    for j, name in enumerate(traj.meta.joint_names):
        step = steps.get(name)
        sd = float(np.std(qdd[ok, j])) if ok.any() else 0.0
        if step is not None and sd > 0:
            noise[name] = float(step / math.sqrt(12.0) * np.linalg.norm(w2) / sd)
    return noise


#: An actuated hinge whose angle spans more than this (rad, 2.5–97.5 % of the data) bounds σ by its turning rate.
TURNING_SPAN = 1.0
#: The share of a turning direction's products the smoothing keeps at the hinge's 95th-percentile rate.
TURNING_KEPT = 0.99


def _turning_directions(traj: Trajectory, rows: np.ndarray, within: np.ndarray | None, est) -> dict[str, tuple[float, float, float]]:
    """σ bound of each actuated hinge that turns through more than :data:`TURNING_SPAN` and whose pose turns how the
    label depends on the other actuated coordinates' accelerations.

    The unactuated row holds products of the pose's cos and sin with the other motions (a turntable's
    tan θ (m l g + ψ̇² J cos θ) = m l (ẍ cos ψ + ÿ sin ψ)); smoothing keeps the row's relation between the smoothed
    inputs and label only where it is linear (module docstring).  A direction turning at ψ̇ is kept by the kernel as
    S[e^{iψ}] ≈ e^{iψ} exp(−σ² ψ̇² / 2), and its products with it: the slopes the GP learns shrink by that factor.
    So σ ≤ √(−2 ln ρ_t) / ψ̇₉₅ (ρ_t = :data:`TURNING_KEPT`, ψ̇₉₅ the 95th percentile of |ψ̇| by central differences
    of the recorded angle).  On ``fam0_005`` (yaw sweeping ±π at up to 5.6 rad/s) the label's σ = 0.085 s learned
    the BEM with RMSE 0.021 rad and gain 0.87 against the oracle, σ = 0.03 s with RMSE 0.0066.  Within ±0.5 rad cos
    and sin are linear to a few %: such a hinge (a pendubot's shoulder, an arm's joints) keeps the label's σ.

    Whether the pose enters is read from the data (no model): the least-squares fit of the label (smoothed at the
    label's σ, ``est``) on the other actuated accelerations q̈_k leaves residual variance r₀; with the products
    q̈_k cos q_j, q̈_k sin q_j added, r₁.  The pose enters where r₁ < r₀ / 2 (a turntable's yaw: the products explain
    most of what the plain fit leaves).  A hinge with no other actuated coordinate (a reaction wheel, a rotary arm
    with m = 1) and one whose turning does not change the balance keep the label's σ.

    Returns: per such joint ``(σ bound in s, its span in rad, ψ̇₉₅ in rad/s)``."""
    meta = traj.meta
    iu = meta.unactuated_index
    rate = meta.sample_rate_hz
    out: dict[str, tuple[float, float, float]] = {}
    acts = [k for k in range(len(meta.joint_names)) if k != iu]
    smoothed = None
    for j, (name, kind) in enumerate(zip(meta.joint_names, meta.joint_kinds)):
        if j == iu or kind != "hinge" or len(acts) < 2:
            continue
        lo, hi = np.quantile(traj.q[rows, j], [0.025, 0.975])
        span = float(hi - lo)
        if not span > TURNING_SPAN:
            continue
        if smoothed is None:
            smoothed = estimate_states(traj, est, within=within)
        q_s, _, qdd_s, ok = smoothed
        use = np.flatnonzero(ok)
        if use.size < 50:
            continue
        y = q_s[use, iu] - q_s[use, iu].mean()
        others = np.array([k for k in acts if k != j], dtype=np.int64)
        base = np.c_[np.ones(use.size), qdd_s[np.ix_(use, others)]]
        c, sn = np.cos(q_s[use, j])[:, None], np.sin(q_s[use, j])[:, None]
        ext = np.c_[base, qdd_s[np.ix_(use, others)] * c, qdd_s[np.ix_(use, others)] * sn]
        r0 = float(np.sum((y - base @ np.linalg.lstsq(base, y, rcond=None)[0]) ** 2))
        r1 = float(np.sum((y - ext @ np.linalg.lstsq(ext, y, rcond=None)[0]) ** 2))
        if not r1 < 0.5 * r0:
            continue
        speed = np.zeros(traj.n_samples)
        for s in traj.trial_slices():
            if s.rows.stop - s.rows.start > 2:
                speed[s.rows] = np.abs(np.gradient(traj.q[s.rows, j])) * rate
        w95 = float(np.quantile(speed[rows], 0.95))
        if w95 > 0:
            out[name] = (float(f"{math.sqrt(-2.0 * math.log(TURNING_KEPT)) / w95:.4g}"), span, w95)
    return out


def resolve_estimator(estimator, traj: Trajectory, *, qu_window: float | None = 0.5) -> tuple[Any, SigmaChoice | None]:
    """``estimator`` with every option it leaves to the data chosen from ``traj``, and how.

    A :class:`~bemlearn.data.gaussian_derivative.GaussianDerivative` without ``sigma_s`` gets the σ
    of :func:`choose_sigma`; any other estimator is returned as it is (choice ``None``).
    """
    if isinstance(estimator, GaussianDerivative) and not estimator.resolved:
        choice = choose_sigma(traj, qu_window=qu_window, truncate=estimator.truncate)
        return dataclasses.replace(estimator, sigma_s=choice.sigma_s), choice
    return estimator, None
