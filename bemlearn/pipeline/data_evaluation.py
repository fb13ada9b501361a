"""Data-only evaluation of a learned BEM: no robot model, only held-out trials and the data's coverage.

(a) Held-out prediction of q_u from f(x) (eq. 11): on points x_i = [q̈_a, q̇_a, q_a, q̈_u, q̇_u]
of trials the fit never saw, the RMSE of μ(x_i) − q_u,i and the fraction of q_u,i inside
μ ± 2σ_pred, σ_pred² = σ²(x_i) + σ_0² (latent variance of eq. 12 plus the noise of eq. 11),
per trial and overall.

(c) Whether the data resolve the BEM at all (:func:`bem_resolution`): at the training points'
actuated motions x_0^e (eq. 14) the learned BEM's spread std(μ) is compared with the exported
band's median σ (eq. B1); per actuated input i, the learned slope ḡ_i = mean ∂μ/∂x_i, the data's
amplitude a_i = std(x_i) and the factor 2 σ_band / (|ḡ_i| a_i) by which the amplitude would have to
grow for the input's own share of the BEM to exceed the band's ±2σ.

(b) The learned BEM on slices (eq. 14): μ(x_0^e) and μ ± 2σ_pred against q̈_a of one actuated
joint, x_0^e = [q̈_a, q̇_a, q_a, 0, 0], at a few (q̇_a, q_a) taken from the training data's
quantiles (other actuated joints at their medians).  A grid point is *covered* when it is
supported by the training inputs jointly ((S1) below: a training point within ``radius``
nearest-neighbour spacings in the data's whitened input space); the covered q̈_a range is that
of the covered grid points, outside it the BEM is an extrapolation (shaded in the figure).

(d) Joint support of the BEM queries (:func:`design_support`): (S1) the share of the queries
x_0^e at the data's actuated motions that a training sample supports, all inputs together, and
(S2) whether the data determine the extrapolation from the samples (q̈_u ≠ 0) to the queries
(q̈_u = 0): the least-squares slope of q_u in q̈_u and its t statistic from the leverage matrix.
Inputs that move in lockstep under a balancing controller (q̈_u ≈ b q̈_a) fail both.

Units follow the joint kind (hinge: rad, rad/s, rad/s²; slide: m, m/s, m/s²).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bemlearn.data.dataset_types import BEMDataset
from bemlearn.errors import DataError
from bemlearn.models.learned_bem import LearnedBEM
from bemlearn.models.predictor_state import PredictorState
from bemlearn.pipeline.support import (
    SUPPORT_RATIO,
    _lockstep_pairs,
    _nearest,
    _whitener,
    extrapolation_leverage,
    support_of_queries,
)
from bemlearn.pipeline.verdict import EXTRAPOLATION_T, SUPPORT_OK_SHARE
from bemlearn.units import gp_input_units, joint_unit

__all__ = ["DataOnlyEvaluation", "data_only_evaluation", "SliceSpec", "bem_slice_figure", "bem_slices", "heldout_prediction", "bem_resolution", "COVERED_QUANTILES",
           "design_support", "support_of_queries", "extrapolation_leverage", "SUPPORT_RATIO", "SUPPORT_OK_SHARE",
           "EXTRAPOLATION_T"]

#: The range each input's data cover, as quantiles of the training points (the report's "data covers lo … hi"
#: in :func:`bem_resolution`).  The slices' covered range is the joint support of their queries (:func:`support_of_queries`).
COVERED_QUANTILES = (0.025, 0.975)
#: Training points at most that :func:`bem_resolution` and :func:`design_support` take as the BEM's queries.
MAX_QUERIES = 2000


def _state(model: PredictorState | LearnedBEM) -> PredictorState:
    return model.state if isinstance(model, LearnedBEM) else model


def _predict(state: PredictorState, x: torch.Tensor, chunk: int = 4096) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """μ (B,), latent σ (B,), predictive σ (B,) in physical units for physical inputs x (B, d)."""
    x = torch.as_tensor(x, dtype=torch.float64)
    st = state.to(dtype=torch.float64)
    means, stds = [], []
    for part in x.split(chunk):
        m, s = st.predict_reference(part)
        means.append(m)
        stds.append(s)
    mean, lat = torch.cat(means).numpy(), torch.cat(stds).numpy()
    noise_var = float(st.y_std**2 * st.noise)
    return mean, lat, np.sqrt(lat**2 + noise_var)


def _units_of(dataset: BEMDataset) -> tuple[dict[str, str], str]:
    """Each GP input's unit and q_u's, from the joints' kinds (hinge: rad, slide: m)."""
    meta = dataset.meta
    units = gp_input_units(dataset.input_names, meta.joint_names, [meta.kind_of(j) for j in meta.joint_names])
    return units, joint_unit(meta.kind_of(meta.unactuated))


@dataclass(frozen=True)
class DataOnlyEvaluation:
    """(a)–(d) of the module docstring for one fitted GP, as :func:`data_only_evaluation` returns them.

    Attributes:
        heldout: :func:`heldout_prediction` (``None`` without held-out points).
        resolution: :func:`bem_resolution`.
        slices: :func:`bem_slices` (with its arrays, for :func:`bem_slice_figure`).
        support: :func:`design_support`.
    """

    heldout: dict[str, Any] | None
    resolution: dict[str, Any]
    slices: dict[str, Any]
    support: dict[str, Any]


def data_only_evaluation(model: PredictorState | LearnedBEM, train: BEMDataset, heldout: BEMDataset | None,
                         units: dict[str, str], qu_unit: str) -> DataOnlyEvaluation:
    """Every data-only check of the module docstring at once: (a) on ``heldout`` when given, (c), (b) and (d).

    Args:
        model: the fitted GP.
        train: the training points.
        heldout: points of trials the fit never saw, or ``None``.
        units, qu_unit: each GP input's unit and q_u's (:func:`~bemlearn.units.gp_input_units`, as the run
            recorded them).
    """
    state = _state(model)
    return DataOnlyEvaluation(
        heldout=_heldout(state, heldout, 2.0, train, qu_unit) if heldout is not None else None,
        resolution=_resolution(state, train, MAX_QUERIES, units, qu_unit),  # do the data resolve the BEM at all?
        slices=_slices(state, train, SliceSpec(), units, qu_unit),
        support=_support(train, MAX_QUERIES, SUPPORT_RATIO, units, qu_unit, model=state),  # are its queries supported jointly?
    )


def _check_names(state: PredictorState, dataset: BEMDataset) -> None:
    if tuple(state.input_names) != tuple(dataset.input_names):
        raise DataError(
            f"the predictor's inputs {list(state.input_names)} differ from the dataset's {list(dataset.input_names)}"
        )


def heldout_prediction(model: PredictorState | LearnedBEM, heldout: BEMDataset, *, kappa: float = 2.0,
                       train: BEMDataset | None = None) -> dict[str, Any]:
    """(a) of the module docstring: q_u predicted from f(x) on held-out points.

    Args:
        model: the fitted GP (frozen posterior or learned BEM).
        heldout: points of trials not used for fitting (e.g. ``build_datasets(...).val``):
            x (N, d) physical units, y (N,) q_u in rad (or m).
        kappa: half-width of the band in σ_pred (2 → ±2σ).
        train: the training points; with them each trial also states the share of its samples
            outside the training data's range in some input (``beyond_training``).

    Returns:
        ``{"rmse", "max_abs", "coverage", "n_points", "kappa", "unit", "per_trial": {id: {"rmse",
        "coverage", "n_points", "failed", "beyond_training"}}}``; coverage is the fraction of q_u
        inside μ ± κ σ_pred; ``failed``: the trial fell (as the data file records).
    """
    return _heldout(_state(model), heldout, kappa, train, _units_of(heldout)[1])


def _heldout(state: PredictorState, heldout: BEMDataset, kappa: float, train: BEMDataset | None, qu_unit: str) -> dict[str, Any]:
    _check_names(state, heldout)
    if len(heldout) == 0:
        raise DataError("heldout_prediction: the held-out dataset is empty (val_fraction = 0?)")
    mean, _, pred = _predict(state, heldout.x)
    y = heldout.y.numpy()
    err = mean - y
    inside = np.abs(err) <= kappa * pred
    trial = heldout.trial.numpy()
    meta = heldout.meta
    beyond = None
    if train is not None and len(train):
        xt = train.x.numpy()
        xv = heldout.x.numpy()
        beyond = np.any((xv < xt.min(0)) | (xv > xt.max(0)), axis=1)
    per = {}
    for tid in np.unique(trial):
        sel = trial == tid
        per[int(tid)] = {
            "rmse": float(np.sqrt(np.mean(err[sel] ** 2))), "coverage": float(inside[sel].mean()),
            "n_points": int(sel.sum()), "failed": bool(meta.trial_failed.get(int(tid), False)),
            "beyond_training": None if beyond is None else float(beyond[sel].mean()),
        }
    return {
        "rmse": float(np.sqrt(np.mean(err**2))),
        "max_abs": float(np.abs(err).max()),
        "coverage": float(inside.mean()),
        "n_points": len(y),
        "kappa": kappa,
        "unit": qu_unit,
        "per_trial": per,
    }


@dataclass(frozen=True)
class SliceSpec:
    """Where the BEM slices are cut (quantiles of the training points).

    Attributes:
        velocity_quantiles: q̇_a levels (with q_a at its median).
        angle_quantiles: q_a levels (with q̇_a at its median); the median pair is not repeated.
        radius: a grid point is covered when a training point lies within this many times the
            training points' median nearest-neighbour spacing of it, in the data's whitened input
            space ((S1) of :func:`support_of_queries`; all inputs jointly).
        n_grid: points along q̈_a.
        extend: the q̈_a axis spans the training points' [0.5 %, 99.5 %] range widened by this
            fraction on each side.
    """

    velocity_quantiles: tuple[float, ...] = (0.1, 0.5, 0.9)
    angle_quantiles: tuple[float, ...] = (0.1, 0.9)
    radius: float = SUPPORT_RATIO
    n_grid: int = 201
    extend: float = 0.5


def bem_slices(model: PredictorState | LearnedBEM, train: BEMDataset, spec: SliceSpec = SliceSpec()) -> dict[str, Any]:
    """(b) of the module docstring: the learned BEM along q̈_a on slices, with the data's coverage.

    Args:
        model: the fitted GP.
        train: the training points (their quantiles place the slices; their spread is the coverage).
        spec: slice levels, neighbourhood radius and grid.

    Returns:
        ``{"slices": [...], "summary": {...}}``; each slice holds ``joint``, ``qd``, ``q`` (the held
        values of that joint), ``grid`` (n_grid,) q̈_a, ``mean``, ``std_latent``, ``std_pred``
        (n_grid,), ``covered`` [lo, hi] (or ``None`` when no training point is near), ``n_near``,
        ``units`` {"qdd", "qd", "q", "qu"}; ``summary`` has the mean predictive σ inside and
        outside the covered ranges.
    """
    return _slices(_state(model), train, spec, *_units_of(train))


def _slices(state: PredictorState, train: BEMDataset, spec: SliceSpec, units: dict[str, str], qu_unit: str) -> dict[str, Any]:
    _check_names(state, train)
    meta = train.meta
    act = list(meta.actuated_names)
    m = len(act)
    x = train.x.to(torch.float64).numpy()
    mu, w = _whitener(x)                     # (S1): whitened by the data's covariance, not the GP's lengthscales
    z = (x - mu) @ w
    nn = _nearest(z, z, exclude_self=True)
    spacing = float(np.median(nn[nn > 0])) if np.any(nn > 0) else 0.0
    med = np.median(x, axis=0)
    slices = []
    inside_std, outside_std = [], []
    for j, joint in enumerate(act):
        qdd_col, qd_col, q_col = j, m + j, 2 * m + j
        levels = [(float(np.quantile(x[:, qd_col], p)), float(med[q_col])) for p in spec.velocity_quantiles]
        levels += [(float(med[qd_col]), float(np.quantile(x[:, q_col], p))) for p in spec.angle_quantiles]
        lo, hi = np.quantile(x[:, qdd_col], [0.005, 0.995])
        width = hi - lo
        grid = np.linspace(lo - spec.extend * width, hi + spec.extend * width, spec.n_grid)
        for qd_level, q_level in levels:
            base = med.copy()
            base[qd_col], base[q_col] = qd_level, q_level
            base[3 * m:] = 0.0  # x_0^e: q̈_u = q̇_u = 0 (eq. 14)
            query = np.tile(base, (spec.n_grid, 1))
            query[:, qdd_col] = grid
            mean, lat, pred = _predict(state, torch.from_numpy(query))
            zq = (query - mu) @ w
            sup = _nearest(zq, z) <= spec.radius * spacing          # (S1) for each grid point
            near = _nearest(z, zq) <= spec.radius * spacing         # training points near the supported slice
            covered = None
            if sup.any():
                covered = [float(grid[sup].min()), float(grid[sup].max())]
                cov = sup
                inside_std.append(pred[cov])
                outside_std.append(pred[~cov])
            else:
                outside_std.append(pred)
            slices.append({
                "joint": joint, "qd": qd_level, "q": q_level, "grid": grid, "mean": mean, "std_latent": lat,
                "std_pred": pred, "covered": covered, "n_near": int(near.sum()),
                "units": {"qdd": units[f"qdd_{joint}"], "qd": units[f"qd_{joint}"], "q": units[f"q_{joint}"], "qu": qu_unit},
            })
    def cat(parts: list) -> float:
        return float(np.concatenate(parts).mean()) if parts else float("nan")

    return {
        "slices": slices,
        "summary": {"std_pred_mean_covered": cat(inside_std), "std_pred_mean_extrapolated": cat(outside_std),
                    "n_slices": len(slices), "radius": spec.radius},
    }


def bem_slice_figure(result: dict[str, Any], path: str | Path | None = None, *, unactuated: str = "q_u"):
    """Plot :func:`bem_slices`' result: one panel per slice, μ with its ±2σ_pred band, the covered
    q̈_a range unshaded and the extrapolated rest shaded grey.  Saved to ``path`` when given.

    Returns:
        the matplotlib figure.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sl = result["slices"]
    cols = min(3, len(sl))
    rows = -(-len(sl) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False, sharey=True)
    for ax, s in zip(axes.flat, sl):
        u = {k: v.replace("^2", "²") for k, v in s["units"].items()}
        g, mu, sd = s["grid"], s["mean"], s["std_pred"]
        ax.fill_between(g, mu - 2 * sd, mu + 2 * sd, color="C0", alpha=0.25, label="μ ± 2σ (predictive)")
        ax.plot(g, mu, "C0", lw=1.3, label="learned BEM μ (eq. 14)")
        if s["covered"] is None:
            ax.axvspan(g[0], g[-1], color="0.6", alpha=0.25, label="no training data near")
        else:
            lo, hi = s["covered"]
            ax.axvspan(g[0], lo, color="0.6", alpha=0.25, label="extrapolation")
            ax.axvspan(hi, g[-1], color="0.6", alpha=0.25)
        j = s["joint"]
        ax.set_title(f"q̇_{j} = {s['qd']:+.3g} {u['qd']}, q_{j} = {s['q']:+.3g} {u['q']}  ({s['n_near']} points near)",
                     fontsize=8)
        ax.set_xlabel(f"q̈_{j} ({u['qdd']})")
        ax.set_ylabel(f"{unactuated} ({u['qu']})")
    for ax in list(axes.flat)[len(sl):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("learned BEM on slices (data only; grey: outside the training data)", fontsize=10)
    fig.tight_layout()
    if path is not None:
        from bemlearn.files import atomic_path

        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110)
    return fig


def bem_resolution(model: PredictorState | LearnedBEM, train: BEMDataset, *, max_points: int = MAX_QUERIES) -> dict[str, Any]:
    """(c) of the module docstring: does the BEM vary over the data by more than its own band?

    Returns:
        ``{"spread", "band_std", "ratio", "unit", "inputs": [{"input", "slope", "amplitude", "range", "unit",
        "share", "factor"}]}`` with ``spread`` = std of μ(x_0^e) over the training motions, ``band_std``
        the median exported σ there, ``ratio`` = spread / band_std, and per actuated input (largest
        share first) the mean slope, the data's amplitude (std) and range ([lo, hi] at
        :data:`COVERED_QUANTILES`, the rule of the slices' covered range), the share |slope| · amplitude of
        the BEM it explains and ``factor`` (``None`` where the learned slope is 0).
    """
    return _resolution(_state(model), train, max_points, *_units_of(train))


def _resolution(state: PredictorState, train: BEMDataset, max_points: int, units: dict[str, str], qu_unit: str) -> dict[str, Any]:
    from bemlearn.models.band import band_and_gradient

    _check_names(state, train)
    x = train.x.to(torch.float64)[:max_points].clone()
    x[:, -2:] = 0.0                                           # x_0^e = [q̈_a, q̇_a, q_a, 0, 0] (eq. 14)
    mean, band, _, grad_all = band_and_gradient(state, x, n_inputs=state.dim - 2)
    grad = grad_all.mean(0).numpy()
    amp = train.x.to(torch.float64).std(0, correction=0).numpy()
    ranges = np.quantile(train.x.to(torch.float64).numpy(), COVERED_QUANTILES, axis=0)  # (2, d)
    spread, bstd = float(mean.std(correction=0)), float(band.median())
    inputs: list[dict[str, Any]] = []
    for i, name in enumerate(state.input_names[:-2]):
        share = abs(float(grad[i])) * float(amp[i])
        inputs.append({"input": name, "slope": float(grad[i]), "amplitude": float(amp[i]),
                       "range": [float(ranges[0, i]), float(ranges[1, i])], "unit": units[name],
                       "share": share, "factor": (2.0 * bstd / share) if share > 0 else None})
    inputs.sort(key=lambda r: -r["share"])
    return {"spread": spread, "band_std": bstd, "ratio": spread / bstd if bstd > 0 else float("inf"), "unit": qu_unit,
            "inputs": inputs}




def design_support(train: BEMDataset, *, max_queries: int = MAX_QUERIES, ratio: float = SUPPORT_RATIO,
                   model: PredictorState | LearnedBEM | None = None) -> dict[str, Any]:
    """Are the BEM queries x_0^e = [q̈_a, q̇_a, q_a, 0, 0] (eq. 14) at the data's actuated motions
    supported by the training inputs *jointly* (:func:`support_of_queries`, (S1))?

    The queries are the training points' own actuated motions with q̈_u = q̇_u = 0: the actuated
    ranges the data cover, where the BEM will be used.  Every column enters together, so inputs
    that each span their range but move in lockstep do not count as covering the BEM.

    Returns:
        ``{"share", "ratio_median", "ratio_q90", "limit", "spacing", "n_queries", "n_train",
        "pairs": [{"input", "with", "corr", "ratio"}] (largest |corr| first), "inputs": [{"input",
        "unit", "data": [lo, hi], "supported": [lo, hi] or None, "reach": max |x| of the supported
        queries or None}]}``; ``data`` are the training inputs' 2.5 / 97.5 % quantiles,
        ``supported`` those of the supported queries.  ``model``: the learned BEM, for (S2) where the BEM is not
        linear in the actuated inputs over the data (:func:`~bemlearn.pipeline.support.extrapolation_leverage`).
    """
    return _support(train, max_queries, ratio, *_units_of(train), model=model)


def _support(train: BEMDataset, max_queries: int, ratio: float, units: dict[str, str], qu_unit: str,
             model: PredictorState | LearnedBEM | None = None) -> dict[str, Any]:
    names = tuple(train.input_names)
    x = train.x.to(torch.float64).numpy()
    n_act = x.shape[1] - 2
    q = x[:max_queries].copy()
    q[:, n_act:] = 0.0                                               # x_0^e (eq. 14)
    res = support_of_queries(x, q, ratio=ratio)
    sup = res["supported"]
    inputs = []
    for i, name in enumerate(names[:n_act]):
        rng = [float(v) for v in np.quantile(x[:, i], [0.025, 0.975])]
        inputs.append({"input": name, "unit": units[name], "data": rng,
                       "supported": [float(v) for v in np.quantile(q[sup, i], [0.025, 0.975])] if sup.any() else None,
                       "reach": float(np.abs(q[sup, i]).max()) if sup.any() else None})
    out = {"share": res["share"], "ratio_median": res["r_median"], "ratio_q90": res["r_q90"], "limit": ratio,
           "spacing": res["spacing"], "n_queries": len(q), "n_train": len(x), "pairs": _lockstep_pairs(x, names, n_act),
           "inputs": inputs, "unit": qu_unit}
    bem = None
    if model is not None:   # (S2) where the BEM is not linear over the data: the learned μ(x_0^e) at each sample
        from bemlearn.models.band import band_reference

        state = _state(model)
        x0 = train.x.to(torch.float64).clone()
        x0[:, -2:] = 0.0
        bem = band_reference(state, x0, n_inputs=state.dim - 2)[0].numpy()
    out.update(extrapolation_leverage(x, train.y.to(torch.float64).numpy(), names, bem=bem))
    return out
