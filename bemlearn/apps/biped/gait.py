"""Periodic biped gaits as virtual constraints q_a = h(ϑ) on a phase variable (Section III-C).

Coordinates are those of the pinned model (:mod:`bemlearn.apps.biped.model`) *relative to the
stance leg*: q = [q1, q2, q3, q4, q5] = [torso, stance hip, stance knee, swing hip, swing
knee] (rad).  When the walker's leg 2 is in stance its joints are swapped
(:data:`LEG_SWAP`, :func:`stance_frame`); at each impact the legs exchange roles, so one
step of the gait describes the whole periodic walk.

The phase is linear in q, as in the paper (ϑ = c q, Section III-C):

    ϑ = cᵀ q,    s = (ϑ − ϑ⁺) / (ϑ⁻ − ϑ⁺) ∈ [0, 1]     (ϑ⁺, ϑ⁻: start and end of a step)

and the virtual constraints are Bézier polynomials of degree M in s,

    h(s) = Σ_k α_k b_k(s),   b_k(s) = C(M, k) s^k (1 − s)^(M−k),
    h'(s) = M Σ_k (α_{k+1} − α_k) b_k^{M−1}(s),   h''(s) = M (M − 1) Σ_k Δ²α_k b_k^{M−2}(s),

so along the motion q̇_a^d = h'(s) ṡ and q̈_a^d = h''(s) ṡ² + h'(s) s̈.  The default
c = [1, 1, ½, 0, 0] is the stance leg's absolute angle (thigh plus half the knee ≈ the
hip–foot line), which increases monotonically as the body vaults over the stance foot.

Two gaits are built here (:func:`build_gait`): an engineered one from a Cartesian design
(:class:`GaitDesign`: hip path over the stance foot and a swing-foot arc, converted by the
leg's inverse kinematics) and the human-derived one (:mod:`bemlearn.apps.biped.human_gait`,
linearly mapped into the robot's joint ranges, its swing-foot path raised to a clearance
arc because the robot has point feet — a documented adaptation beyond the paper's linear map).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from bemlearn.apps.biped.human_gait import HumanGaitConfig, human_step_profile
from bemlearn.apps.biped.model import BipedParameters
from bemlearn.errors import ArgumentError, ConfigError, DataError

__all__ = [
    "LEG_SWAP",
    "stance_frame",
    "BezierGait",
    "GaitDesign",
    "GaitConfig",
    "leg_ik",
    "leg_fk",
    "design_gait",
    "human_gait",
    "build_gait",
]

#: Index map q_stance = q_walker[LEG_SWAP] when leg 2 is the stance leg (its own inverse).
LEG_SWAP = (0, 3, 4, 1, 2)


def stance_frame(q: np.ndarray, stance_leg: int) -> np.ndarray:
    """Walker coordinates ``(..., 5)`` [q1..q5] → stance-relative ones (and back: same map).

    Args:
        q: ``(..., 5)`` rad (or rad/s, rad/s², N·m on the same columns).
        stance_leg: 1 or 2.
    """
    if stance_leg == 1:
        return np.array(q, dtype=np.float64, copy=True)
    if stance_leg == 2:
        return np.asarray(q, dtype=np.float64)[..., list(LEG_SWAP)]
    raise ArgumentError(f"stance_frame: stance_leg must be 1 or 2, got {stance_leg!r}")


def _bernstein(s: float, M: int) -> np.ndarray:
    k = np.arange(M + 1)
    return np.array([math.comb(M, int(i)) for i in k]) * s**k * (1.0 - s) ** (M - k)


@dataclass(frozen=True)
class BezierGait:
    """Virtual constraints q_a = h(s(ϑ)) of one step (module docstring).

    Attributes:
        coefficients: ``(4, M + 1)`` Bézier coefficients α, rad, rows [stance hip, stance
            knee, swing hip, swing knee].
        phase_weights: c, ``(5,)``, ϑ = cᵀ q on stance-relative q.
        theta_start, theta_end: ϑ⁺ and ϑ⁻, rad.
        torso: the torso angle q1 the gait was designed with, rad (hip references are
            applied relative to the world through it, see :mod:`bemlearn.apps.biped.controller`).
        name: a label.
    """

    coefficients: tuple[tuple[float, ...], ...]
    phase_weights: tuple[float, ...]
    theta_start: float
    theta_end: float
    torso: float = 0.0
    name: str = "gait"
    # numpy caches set in __post_init__: coefficients, their first and second differences, c
    _a: np.ndarray = field(init=False, repr=False, compare=False)
    _d1: np.ndarray = field(init=False, repr=False, compare=False)
    _d2: np.ndarray = field(init=False, repr=False, compare=False)
    _c: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        a = np.asarray(self.coefficients, dtype=np.float64)
        if a.ndim != 2 or a.shape[0] != 4 or a.shape[1] < 3:
            raise ArgumentError(f"BezierGait.coefficients: expected shape (4, M + 1) with M >= 2, got {a.shape}")
        if len(self.phase_weights) != 5:
            raise ArgumentError(f"BezierGait.phase_weights: expected 5 weights, got {len(self.phase_weights)}")
        if not self.theta_end > self.theta_start:
            raise ArgumentError(f"BezierGait: theta_end ({self.theta_end}) must exceed theta_start ({self.theta_start})")
        M = a.shape[1] - 1
        object.__setattr__(self, "_a", a)
        object.__setattr__(self, "_d1", M * np.diff(a, axis=1))
        object.__setattr__(self, "_d2", M * (M - 1) * np.diff(a, n=2, axis=1))
        object.__setattr__(self, "_c", np.asarray(self.phase_weights, dtype=np.float64))

    @property
    def degree(self) -> int:
        return self._a.shape[1] - 1

    @property
    def c(self) -> np.ndarray:
        """Phase weights c, ``(5,)``."""
        return self._c.copy()

    def phase(self, q: np.ndarray, qd: np.ndarray) -> tuple[float, float]:
        """``(s, ṡ)`` (–, 1/s) of stance-relative ``q (5,)`` rad and ``qd (5,)`` rad/s (s may leave [0, 1])."""
        span = self.theta_end - self.theta_start
        return float((self._c @ q - self.theta_start) / span), float(self._c @ qd / span)

    def evaluate(self, s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``h(s), h'(s), h''(s)``, each ``(4,)`` rad; s is clamped to [0, 1]."""
        s = min(max(float(s), 0.0), 1.0)
        M = self.degree
        return self._a @ _bernstein(s, M), self._d1 @ _bernstein(s, M - 1), self._d2 @ _bernstein(s, M - 2)

    def reference(self, s: float, sd: float, sdd: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``q_a^d (4,)`` rad, ``q̇_a^d = h' ṡ`` rad/s, ``q̈_a^d = h'' ṡ² + h' s̈`` rad/s²."""
        h, h1, h2 = self.evaluate(s)
        return h, h1 * sd, h2 * sd * sd + h1 * sdd

    def posture(self, s: float) -> np.ndarray:
        """Stance-relative q ``(5,)`` on the gait at phase s: [q1, h(s)] with cᵀq = ϑ(s)."""
        h = self.evaluate(s)[0]
        theta = self.theta_start + s * (self.theta_end - self.theta_start)
        c = self._c
        if c[0] == 0:
            raise ArgumentError("BezierGait.posture: the phase weight of q1 is 0, q1 is not determined by the phase")
        return np.r_[(theta - c[1:] @ h) / c[0], h]

    @classmethod
    def fit(cls, q: np.ndarray, *, degree: int, phase_weights, name: str = "gait") -> BezierGait:
        """Least-squares Bézier fit of stance-relative samples of one step.

        The end coefficients are pinned to the first and last sample (so a gait whose last
        posture is the leg-swapped first one stays impact-consistent); s is recomputed
        from ϑ = cᵀq of the samples, which must increase strictly.

        Args:
            q: ``(n, 5)`` rad, samples from the start to the end of the step.
            degree: M ≥ 2.
            phase_weights: c ``(5,)``.
        """
        q = np.asarray(q, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != 5 or q.shape[0] < degree + 1:
            raise ArgumentError(f"BezierGait.fit: q must have shape (n, 5) with n > degree = {degree}, got {q.shape}")
        if degree < 2:
            raise ArgumentError(f"BezierGait.fit: degree must be >= 2, got {degree}")
        c = np.asarray(phase_weights, dtype=np.float64)
        theta = q @ c
        bad = np.flatnonzero(np.diff(theta) <= 0)
        if len(bad):
            raise DataError(
                f"BezierGait.fit: the phase ϑ = cᵀq (c = {c.tolist()}) must increase along the step; "
                f"it does not between samples {bad[0]} and {bad[0] + 1}"
            )
        s = (theta - theta[0]) / (theta[-1] - theta[0])
        B = np.stack([_bernstein(float(v), degree) for v in s])
        qa = q[:, 1:]
        rhs = qa - np.outer(B[:, 0], qa[0]) - np.outer(B[:, -1], qa[-1])
        inner = np.linalg.lstsq(B[:, 1:-1], rhs, rcond=None)[0]
        alpha = np.c_[qa[0], inner.T, qa[-1]]
        return cls(tuple(map(tuple, alpha.tolist())), tuple(c.tolist()), float(theta[0]), float(theta[-1]),
                   torso=float(np.mean(q[:, 0])), name=name)


# ---------------------------------------------------------------- leg kinematics

def leg_fk(thigh: np.ndarray, knee: np.ndarray, *, L_t: float, L_s: float) -> np.ndarray:
    """Foot position relative to the hip ``(..., 2)`` [x, z] m for absolute thigh pitch and knee angle (rad).

    A downward link of pitch φ points along (−sin φ, −cos φ); the shank's pitch is thigh + knee.
    """
    thigh, knee = np.asarray(thigh, dtype=np.float64), np.asarray(knee, dtype=np.float64)
    shank = thigh + knee
    return np.stack([-(L_t * np.sin(thigh) + L_s * np.sin(shank)), -(L_t * np.cos(thigh) + L_s * np.cos(shank))], -1)


def leg_ik(dx: np.ndarray, dz: np.ndarray, *, L_t: float, L_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Absolute thigh pitch and knee flexion (rad, knee ≥ 0) placing the foot at (dx, dz) m from the hip.

    r² = L_t² + L_s² + 2 L_t L_s cos κ;  the hip–foot line has pitch ψ = atan2(−dx, −dz);
    thigh = ψ − atan2(L_s sin κ, L_t + L_s cos κ).

    Raises:
        ValueError: a point out of reach (r > L_t + L_s or r < |L_t − L_s|).
    """
    dx, dz = np.asarray(dx, dtype=np.float64), np.asarray(dz, dtype=np.float64)
    r = np.hypot(dx, dz)
    cosk = (r**2 - L_t**2 - L_s**2) / (2 * L_t * L_s)
    if np.any(np.abs(cosk) > 1 + 1e-12):
        i = int(np.argmax(np.abs(cosk)))
        raise ArgumentError(f"leg_ik: foot at distance {float(np.ravel(r)[i]):.4f} m is out of the leg's reach "
                         f"[{abs(L_t - L_s):.3f}, {L_t + L_s:.3f}] m")
    knee = np.arccos(np.clip(cosk, -1.0, 1.0))
    psi = np.arctan2(-dx, -dz)
    return psi - np.arctan2(L_s * np.sin(knee), L_t + L_s * np.cos(knee)), knee


# ---------------------------------------------------------------- gait construction

@dataclass(frozen=True)
class GaitDesign:
    """The engineered default gait, in Cartesian terms relative to the stance foot.

    Hip: x from −L/2 to +L/2 (linear in the design parameter u ∈ [0, 1]),
    z = hip_height − hip_lift · sin(2πu) (lower early, higher late: the zero dynamics
    gains energy over a step).  Swing foot: x from −L to +L along a quintic smoothstep,
    z = clearance · 4u(1 − u) − touchdown_depth · u³ (it strikes while still descending).

    Attributes:
        step_length: L, m.  hip_height: m.  hip_lift: m.  clearance: m.
        touchdown_depth: m below the ground at the end of the step.  torso: q1, rad.
    """

    step_length: float = 0.15
    hip_height: float = 0.38
    hip_lift: float = 0.01
    clearance: float = 0.04
    touchdown_depth: float = 0.005
    torso: float = 0.0


@dataclass(frozen=True)
class GaitConfig:
    """Which gait to walk (``walk.gait`` section).

    Attributes:
        kind: ``"default"`` (:class:`GaitDesign`) or ``"human"`` (:mod:`bemlearn.apps.biped.human_gait`).
        degree: Bézier degree M.
        phase_weights: c of ϑ = cᵀq (stance-relative q1..q5).
        samples: posture samples the Bézier polynomials are fitted to.
        design: the default gait's design.
        human: the human data and its linear map into the robot's joint ranges.
        human_clearance: peak of the clearance arc the human swing-foot path is raised to, m.
        human_torso: torso angle the human-derived hip angles are referred to, rad.
    """

    kind: Literal["default", "human"] = "default"
    degree: int = 6
    phase_weights: tuple[float, float, float, float, float] = (1.0, 1.0, 0.5, 0.0, 0.0)
    samples: int = 201
    design: GaitDesign = field(default_factory=GaitDesign)
    human: HumanGaitConfig = field(default_factory=HumanGaitConfig)
    human_clearance: float = 0.05
    human_torso: float = 0.0


def design_gait(design: GaitDesign = GaitDesign(), *, degree: int = 6, phase_weights=(1.0, 1.0, 0.5, 0.0, 0.0),
                samples: int = 201, params: BipedParameters = BipedParameters()) -> BezierGait:
    """The engineered gait of :class:`GaitDesign`, fitted as a :class:`BezierGait`."""
    u = np.linspace(0.0, 1.0, samples)
    L = design.step_length
    xh = -L / 2 + L * u
    zh = design.hip_height - design.hip_lift * np.sin(2 * np.pi * u)
    sm = 10 * u**3 - 15 * u**4 + 6 * u**5
    xf = -L + 2 * L * sm
    zf = design.clearance * 4 * u * (1 - u) - design.touchdown_depth * u**3
    kw = dict(L_t=params.L_t, L_s=params.L_s)
    th_st, k_st = leg_ik(-xh, -zh, **kw)
    th_sw, k_sw = leg_ik(xf - xh, zf - zh, **kw)
    q1 = np.full_like(u, design.torso)
    q = np.stack([q1, th_st - q1, k_st, th_sw - q1, k_sw], 1)
    return BezierGait.fit(q, degree=degree, phase_weights=phase_weights, name="default")


def human_gait(human: HumanGaitConfig = HumanGaitConfig(), *, clearance: float = 0.05, torso: float = 0.0,
               degree: int = 6, phase_weights=(1.0, 1.0, 0.5, 0.0, 0.0),
               params: BipedParameters = BipedParameters()) -> BezierGait:
    """The human-derived gait: linear map into the joint ranges, swing-foot clearance, Bézier fit.

    The stance leg keeps the mapped human angles.  The swing foot's height above the
    stance foot, z(s), is corrected linearly so that both feet are level at s = 0 and 1,
    raised to at least ``clearance · 4s(1 − s)``, and turned back into swing hip / knee
    angles by :func:`leg_ik` (its horizontal path is the human one).
    """
    s, qa, _ = human_step_profile(human)
    kw = dict(L_t=params.L_t, L_s=params.L_s)
    st = leg_fk(qa[:, 0] + torso, qa[:, 1], **kw)
    sw = leg_fk(qa[:, 2] + torso, qa[:, 3], **kw)
    ground = st[:, 1]
    h = sw[:, 1] - ground
    h = h - (h[0] * (1 - s) + h[-1] * s)
    h = np.maximum(h, clearance * 4 * s * (1 - s))
    thigh, knee = leg_ik(sw[:, 0], ground + h, **kw)
    q = np.c_[np.full_like(s, torso), qa[:, 0], qa[:, 1], thigh - torso, knee]
    return BezierGait.fit(q, degree=degree, phase_weights=phase_weights, name="human")


def build_gait(config: GaitConfig = GaitConfig(), *, params: BipedParameters = BipedParameters()) -> BezierGait:
    """The gait selected by ``config.kind``."""
    if config.kind == "default":
        return design_gait(config.design, degree=config.degree, phase_weights=config.phase_weights,
                           samples=config.samples, params=params)
    if config.kind == "human":
        return human_gait(config.human, clearance=config.human_clearance, torso=config.human_torso,
                          degree=config.degree, phase_weights=config.phase_weights, params=params)
    raise ConfigError(f"gait.kind must be 'default' or 'human', got {config.kind!r}")
