"""Joint support of BEM queries by training inputs: (S1) and (S2) of docs/verdict.md, NumPy only.

(S1) whitened nearest-neighbour support (:func:`support_of_queries`) and (S2) the leverage t
statistic of the extrapolation along q̈_u (:func:`extrapolation_leverage`); the learned-BEM side
(:func:`bemlearn.pipeline.data_evaluation.design_support`) applies them to a run's training set.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bemlearn.errors import DataError
from bemlearn.pipeline.verdict import EXTRAPOLATION_T

__all__ = ["SUPPORT_RATIO", "LINEAR_R2", "EXTRAPOLATION_T", "support_of_queries", "extrapolation_leverage"]

#: A BEM query is supported when its nearest training sample, in the data's whitened input space,
#: is within this many times the training samples' own median nearest-neighbour spacing ((S1),
#: docs/verdict.md "Joint support").
SUPPORT_RATIO = 3.0

#: (S2) takes the learned BEM as a regressor where the fit linear in the actuated inputs explains less of q_u's
#: variance than this (:func:`extrapolation_leverage`).
LINEAR_R2 = 0.9


def _whitener(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mean (d,), W (d, d)) with z = (x − mean) W of identity covariance: W = V Λ^{-1/2} Vᵀ of the
    data's covariance C = V Λ Vᵀ (eigenvalues floored at 1e-12 · max so a constant column stays finite)."""
    mu = x.mean(0)
    c = np.cov(x - mu, rowvar=False).reshape(x.shape[1], x.shape[1])
    lam, v = np.linalg.eigh(c)
    lam = np.maximum(lam, max(float(lam.max()), 1e-300) * 1e-12)
    return mu, (v / np.sqrt(lam)) @ v.T


def _nearest(a: np.ndarray, b: np.ndarray, *, exclude_self: bool = False, chunk: int = 1024) -> np.ndarray:
    """Euclidean distance of each row of ``a`` to its nearest row of ``b`` (itself excluded when ``a`` is ``b``)."""
    out = np.empty(len(a))
    bb = np.einsum("ij,ij->i", b, b)
    for s in range(0, len(a), chunk):
        p = a[s:s + chunk]
        d2 = np.einsum("ij,ij->i", p, p)[:, None] + bb[None, :] - 2.0 * p @ b.T
        if exclude_self:
            d2[np.arange(len(p)), np.arange(s, s + len(p))] = np.inf
        out[s:s + chunk] = np.sqrt(np.maximum(d2.min(1), 0.0))
    return out


def support_of_queries(x: np.ndarray, queries: np.ndarray, *, ratio: float = SUPPORT_RATIO) -> dict[str, Any]:
    """Joint support of BEM queries by training inputs (eq. 14's x_0^e against eq. 11's x_i).

    With z = (x − x̄) W the training inputs whitened by their own covariance (Mahalanobis
    coordinates, :func:`_whitener`), s = median_i min_{j≠i} ‖z_i − z_j‖ the training samples'
    typical nearest-neighbour spacing, and for each query q

        r(q) = min_i ‖z(q) − z_i‖ / s,      supported ⇔ r(q) ≤ ``ratio``.             (S1)

    Inputs that move together (q̈_u ≈ b q̈_a under a balancing controller) span a thin slab
    in x; whitening stretches the slab's thin direction to unit scale, so a query off the slab
    (q̈_u = 0 at large |q̈_a|) lies many spacings from every sample although each of its inputs
    is inside its own range.

    Args:
        x: ``(N, d)`` training inputs, physical units.
        queries: ``(B, d)`` queries, same columns.
        ratio: the limit of (S1).

    Returns:
        ``{"ratio": (B,) r, "supported": (B,) bool, "share": float, "spacing": s, "limit": ratio,
        "r_median", "r_q90"}``.
    """
    x = np.asarray(x, dtype=np.float64)
    queries = np.asarray(queries, dtype=np.float64)
    if len(x) < 3:
        raise DataError(f"support_of_queries: need at least 3 training inputs, got {len(x)}")
    mu, w = _whitener(x)
    z, zq = (x - mu) @ w, (queries - mu) @ w
    nn = _nearest(z, z, exclude_self=True)
    pos = nn[nn > 0]                       # repeated samples (a rig at rest on its encoder grid) are no spacing
    s = float(np.median(pos)) if len(pos) else 0.0
    r = _nearest(zq, z) / max(s, 1e-300)
    sup = r <= ratio
    return {"ratio": r, "supported": sup, "share": float(sup.mean()) if len(r) else float("nan"), "spacing": s,
            "limit": ratio, "r_median": float(np.median(r)), "r_q90": float(np.quantile(r, 0.9))}


def _lockstep_pairs(x: np.ndarray, names: tuple[str, ...], n_act: int) -> list[dict[str, Any]]:
    """Per unactuated input (q̈_u, q̇_u): the actuated input it moves with most (largest |corr|), the
    correlation and the least-squares ratio b of u ≈ b a + c."""
    pairs = []
    for c in range(n_act, x.shape[1]):
        best = None
        for a in range(n_act):
            sa, sc = x[:, a].std(), x[:, c].std()
            if not (sa > 0 and sc > 0):
                continue
            r = float(np.corrcoef(x[:, a], x[:, c])[0, 1])
            if best is None or abs(r) > abs(best[1]):
                best = (a, r, r * sc / sa)
        if best is not None:
            pairs.append({"input": names[c], "with": names[best[0]], "corr": best[1], "ratio": best[2]})
    pairs.sort(key=lambda p: -abs(p["corr"]))
    return pairs


def extrapolation_leverage(x: np.ndarray, y: np.ndarray, names: tuple[str, ...], *, bem: np.ndarray | None = None) -> dict[str, Any]:
    """(S2): do the data determine q_u's dependence on q̈_u apart from the actuated inputs?

    Linearised at upright, the unactuated row (eq. 5) gives q_u − q_u^e(q̈_a, q̇_a, q_a) = q̈_u / λ²
    (+ a damping term in q̇_u), λ² = Γ_q / D_uu > 0 for an equilibrium that needs balancing.  Moving
    a sample to its BEM query (q̈_u → 0) is therefore an extrapolation along q̈_u by the slope 1/λ².
    The ordinary least-squares fit y ≈ β₀ + Σ β_i x_i on the training points (columns centred and
    scaled) gives that slope's standard error from the leverage matrix (XᵀX)⁻¹,

        se(β_q̈u) = σ̂ √[(XᵀX)⁻¹]_{q̈u,q̈u},   t = β_q̈u / se(β_q̈u),                          (S2)

    σ̂² the residual variance; se grows as 1/√(1 − R²) when q̈_u moves in lockstep with the actuated
    inputs (R² of q̈_u on the other inputs).  The extrapolation is *resolved* when t ≥
    :data:`EXTRAPOLATION_T` (a positive, well-determined 1/λ²); t ≤ −EXTRAPOLATION_T says the data
    were taken about an equilibrium that is stable without control (λ² < 0).

    The fit is linear in the actuated inputs: the BEM linearised at upright.  Where that does not describe the data
    (the fit's own R² below :data:`LINEAR_R2`: a BEM that turns with the pose, a turntable's ẍ cos ψ + ÿ sin ψ over a
    full turn, R² 0.10 on ``fam0_005``'s data against ≥ 0.996 on carts, pendubots and arms), the BEM's nonlinear part
    leaks into the residual and into β_q̈u (there t = −23 said "stable without control" of a balanced upright).
    Then, given ``bem (N,)`` — the learned BEM at each sample's own actuated motion, μ(x_0^e) (eq. 14) — the fit is
    repeated with it as one more regressor: q_u − μ(x_0^e) is what the unactuated row leaves to q̈_u and q̇_u, and
    q̈_u's leverage still counts how far it moves apart from the actuated inputs (lockstep keeps the VIF high).

    Returns:
        ``{"qdd_u": name, "slope": β_q̈u in q_u's unit per q̈_u's, "t": t, "lambda2": 1/β_q̈u (1/s²),
        "vif": 1/(1 − R²), "r2": the fit's R², "with_bem": whether ``bem`` entered (then "r2_linear")}``; an empty dict
        when the fit is degenerate; ``t`` ``None`` where even the fit with ``bem`` leaves R² < :data:`LINEAR_R2` (the
        learned BEM does not describe the data either — ``fam0_041``, 18 of 24 trials fallen: R² 0.76, t = −9.8 —
        and the slope's sign says nothing about the equilibrium).
    """
    out = _leverage(x, y, names)
    if bem is not None and out and out["r2"] < LINEAR_R2:
        again = _leverage(np.c_[np.asarray(bem, dtype=np.float64).reshape(-1), np.asarray(x, dtype=np.float64)], y, names)
        if again:
            out = {**again, "with_bem": True, "r2_linear": out["r2"]}
            if out["r2"] < LINEAR_R2:   # neither fit describes q_u: its slope in q̈_u says nothing either way
                out["t"] = None
    return out


def _leverage(x: np.ndarray, y: np.ndarray, names: tuple[str, ...]) -> dict[str, Any]:
    """The fit (S2) of :func:`extrapolation_leverage` on the columns ``x`` (q̈_u second to last)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    sd = x.std(0)
    if len(x) <= x.shape[1] + 2 or not np.all(sd > 0):
        return {}
    a = np.c_[np.ones(len(x)), (x - x.mean(0)) / sd]
    g = np.linalg.pinv(a.T @ a)
    beta = g @ (a.T @ y)
    res = y - a @ beta
    s2 = float(res @ res) / (len(y) - a.shape[1])
    c = x.shape[1] - 2 + 1                                   # q̈_u's column in a (after the intercept)
    se = math.sqrt(max(s2 * g[c, c], 1e-300))
    slope = float(beta[c] / sd[c - 1])
    others = np.delete(a, c, axis=1)
    coef, *_ = np.linalg.lstsq(others, a[:, c], rcond=None)
    r = a[:, c] - others @ coef
    r2 = 1.0 - float(r @ r) / float(a[:, c] @ a[:, c])
    fit_r2 = 1.0 - float(res @ res) / max(float(np.sum((y - y.mean()) ** 2)), 1e-300)
    return {"qdd_u": names[-2], "slope": slope, "t": float(beta[c] / se),
            "lambda2": (1.0 / slope) if slope != 0 else math.inf, "vif": 1.0 / max(1.0 - r2, 1e-300), "r2": fit_r2,
            "with_bem": False}
