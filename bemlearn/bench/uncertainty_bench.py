"""``bemlearn bench uncertainty``: candidate BEM bands side by side.

For each robot (the shipped Furuta config and data; a cart-pole MJCF generated here, with
LQR gains and excitation data collected by the simulator) one exact GP is fitted as
``bemlearn train`` does, and every candidate band σ(x) is scored on the held-out
composite-sinusoid references against the model-based BEM (eq. 9 vs 14):

* ``latent``: σ̃, the latent posterior std of eq. (12) (the exported std up to v0.x);
* ``predictive``: √(σ̃² + σ_0²), eq. (12) as printed (k* = σ_f² + σ_0²);
* ``(a) noisy-input``: √(σ̃² + ∇μᵀΣ_x∇μ) with Σ_x from the Savitzky–Golay quantization
  model (:mod:`bemlearn.models.input_noise`, N1–N3);
* ``(b) NIGP``: Σ_x learned by maximizing the marginal likelihood with heteroscedastic noise
  σ_0² + ∇μ(x_n)ᵀΣ_x∇μ(x_n) (kernel fixed), then √(σ̃_NIGP² + ∇μᵀΣ_x∇μ);
* ``(d) conformal, static q_u``: c σ̃ with c the split-conformal 95 % quantile of
  |q_u − μ(x_0^e)| / σ̃(x_0^e) on held-out samples where the pendulum is nearly at rest
  (|q̇_u|, |q̈_u| in their lowest 20 %): a model-free BEM residual proxy;
* ``(e) replicas``: c σ̃ with c from trial-split replicas (:mod:`bemlearn.fitting.calibration`);
* ``(f) estimator neighbours``: √(σ̃² + σ_est²), σ_est the BEM's spread when the training rows'
  derivatives come from the neighbouring estimators (:mod:`bemlearn.fitting.estimator_sensitivity`);
* ``chosen``: c² σ̃² + max(σ_in², σ_est²) — (e) with the larger of (a') and (f) — the band ``bemlearn train``
  computes (eq. B1).

(c) heteroscedastic noise is (b): NIGP *is* a heteroscedastic GP whose noise variance is
∇μᵀΣ_x∇μ.  Reported per band: coverage of the model BEM by μ ± 2σ, median σ / RMSE(μ), the
eq. (13)/(15) bound's violation rate at κ = 2 against its nominal 4.55 %, coverage at 50 /
90 / 99 % nominal, the held-out q_u coverage of √(σ² + σ_0²) (model-free), and the extra
training and per-query (B = 1, eager torch) costs.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from bemlearn.bench.uncertainty_cases import BenchCase, cartpole_case, config_case
from bemlearn.fitting.calibration import gaussian_quantile
from bemlearn.fitting.estimator_sensitivity import estimator_sensitivity
from bemlearn.models.band import band_reference
from bemlearn.models.input_noise import mean_gradient, quantization_input_std
from bemlearn.models.kernels import se_gram, se_kernel
from bemlearn.pipeline.reliability import reliability_table
from bemlearn.pipeline.uncertainty import calibrate_band

__all__ = ["format_seed_sweep", "format_uncertainty_bench", "run_case", "run_seed_sweep", "run_uncertainty_bench"]

def _nigp(state, x, y, g_train):
    """(b): per-column input variances s² (physical) maximizing the marginal likelihood with
    noise σ_0² + Σ_i s_i² g_i(x_n)² (kernel fixed); returns (s², posterior function)."""
    xn = state.normalize(x)
    yn = (y - state.y_mean) / state.y_std
    Kf = se_gram(xn, state.lengthscale, state.outputscale)
    gn = g_train / state.y_std                                      # ∂μ̃/∂x (physical x)
    log_s2 = torch.full((state.dim,), -12.0, dtype=torch.float64, requires_grad=True)
    log_n = torch.log(state.noise.clone()).requires_grad_(True)
    opt = torch.optim.LBFGS([log_s2, log_n], max_iter=60, line_search_fn="strong_wolfe")

    def noise():
        return log_n.exp() + (gn**2 * log_s2.exp()).sum(1)

    def closure():
        opt.zero_grad()
        L = torch.linalg.cholesky(Kf + torch.diag(noise()))
        a = torch.cholesky_solve(yn[:, None], L)
        loss = 0.5 * (yn[:, None] * a).sum() + torch.log(torch.diagonal(L)).sum()
        loss.backward()
        return loss

    opt.step(closure)
    with torch.no_grad():
        L = torch.linalg.cholesky(Kf + torch.diag(noise()))
        s2 = log_s2.exp() * 1.0

    def latent_std(xq):
        k = se_kernel(state.normalize(xq), xn, state.lengthscale, state.outputscale)
        v = torch.linalg.solve_triangular(L, k.T, upper=False)
        return state.y_std * (state.outputscale - (v**2).sum(0)).clamp_min(0).sqrt()

    return s2.detach(), latent_std, float(log_n.exp())


def _score(name, e, std, extra_train_s, extra_query_us, val=None) -> dict:
    rmse = float(np.sqrt(np.mean(e**2)))
    table = reliability_table(e, std)
    row = {"band": name, "coverage_2sigma": float(np.mean(np.abs(e) <= 2 * std)),
           "median_std_over_rmse": float(np.median(std)) / rmse,
           "violation_kappa2": float(np.mean(np.abs(e) > 2 * std)), "nominal_violation_kappa2": 1 - math.erf(2 / math.sqrt(2)),
           "reliability": table, "train_s": extra_train_s, "query_us": extra_query_us}
    if val is not None:
        row["val_coverage_2sigma"] = val
    return row


def _query_costs(state, banded) -> dict[str, float]:
    """Extra eager-torch cost of a B = 1 query over the folded mean + latent std of ``state``: scalar
    scale, gradient, and the whole calibrated band of ``banded`` as the exported ``forward`` computes it."""
    from bemlearn.export.folded_posterior import FoldedPosterior
    from bemlearn.export.variance_factor import variance_factor

    fp = FoldedPosterior(state, variance_factor(state), n_inputs=state.dim - 2)
    G = torch.randn(state.n_support + 1, state.dim, dtype=torch.float64)
    x = (state.x_mean[: state.dim - 2] + 0.1 * state.x_std[: state.dim - 2])[None].contiguous()

    def t(f, n=3000):
        for _ in range(200):
            f()
        ts = []
        for _ in range(n):
            t0 = time.perf_counter_ns()
            f()
            ts.append(time.perf_counter_ns() - t0)
        return float(np.median(ts)) / 1e3

    base = t(lambda: fp._mean_std(x))
    scaled = t(lambda: fp._mean_std(x)[1] * 1.3)
    grad = t(lambda: (torch.mm(fp._kernel(x), G) ** 2).sum(1) + fp._mean_std(x)[1])
    k = fp._kernel(x)
    only_grad = t(lambda: (torch.mm(k, G) ** 2).sum(1))
    fb = FoldedPosterior(banded, variance_factor(banded), n_inputs=banded.dim - 2)
    band = t(lambda: fb._mean_band(x))
    return {"base_us": base, "scale_us": max(0.0, scaled - base), "gradient_us": only_grad, "gradient_total_us": grad,
            "band_total_us": band, "band_us": max(0.0, band - base)}


def _oracle_rmse(state, traj, case: BenchCase, tr, x, q) -> float | None:
    """BEM RMSE of the GP (same hyperparameters, same rows and labels) conditioned on the exact q̇, q̈
    of the data's ground-truth file (``<stem>.truth<suffix>``), or ``None`` without one: how much of
    μ's error the derivative estimates cause."""
    from bemlearn.data.features import gp_inputs
    from bemlearn.data.trajectory_io import ground_truth_path, read_ground_truth
    from bemlearn.fitting.calibration import condition_state

    path = ground_truth_path(case.data_path)
    if not path.is_file():
        return None
    truth = read_ground_truth(path)
    assert truth.qd is not None and truth.qdd is not None  # read_ground_truth checks
    rows = tr.row.numpy()
    xt = torch.as_tensor(gp_inputs(truth.q[rows], truth.qd[rows], truth.qdd[rows], unactuated_index=traj.meta.unactuated_index))
    mean = condition_state(state, xt, tr.y).predict_reference(x)[0].numpy()
    return float(np.sqrt(np.mean((mean - q) ** 2)))


def run_case(case: BenchCase, *, progress=print) -> dict:
    """Fit, evaluate and score every candidate band on one robot (module docstring)."""
    from bemlearn.data import build_datasets, read_trajectory
    from bemlearn.fitting import train_gp
    from bemlearn.models import predictor_state
    from bemlearn.pipeline.evaluation import reference_queries
    from bemlearn.robots import load

    cfg = case.config
    assert cfg.robot is not None  # a bench case names its robot (config_case checks)
    traj = read_trajectory(case.data_path, robot=cfg.robot)
    ds = build_datasets(traj, cfg.dataset)
    dcfg = ds.config                  # the dataset config with the options chosen from the data written out
    pool = build_datasets(traj, dataclasses.replace(dcfg, n_points=None, n_val_points=None))
    tr, va = ds.train, pool.val
    t0 = time.perf_counter()
    model, lik, _ = train_gp(tr.x_normalized, tr.y_normalized, config=cfg.train)
    fit_s = time.perf_counter() - t0
    state = predictor_state(model, lik, x_mean=tr.x_mean, x_std=tr.x_std, y_mean=tr.y_mean, y_std=tr.y_std,
                            input_names=tr.input_names, n_train=len(tr))
    x, q = reference_queries(load(cfg.robot, coordinates=cfg.coordinates), case.evaluation)
    mean, lat = (v.numpy() for v in state.predict_reference(x))
    e = mean - q
    rmse = float(np.sqrt(np.mean(e**2)))
    progress(f"{case.name}: fit {fit_s:.1f} s on {len(tr)} points; BEM RMSE {rmse:.5f}, max {np.abs(e).max():.5f} over {e.size} points")
    noise_sd = float(state.y_std * state.noise.sqrt())
    g_val = torch.Generator().manual_seed(0)
    vrows = torch.randperm(len(va), generator=g_val)[:4000]
    xv, yv = va.x[vrows], va.y[vrows].numpy()
    mv, lv = (v.numpy() for v in state.predict_reference(xv))
    rv = yv - mv

    def val_cov(sd):
        return float(np.mean(np.abs(rv) <= 2 * np.sqrt(sd**2 + noise_sd**2)))

    # the chosen band exactly as `bemlearn train` computes it (scored last), timed as a whole and its (f) part alone
    est = dcfg.estimator()
    t0 = time.perf_counter()
    banded, summary = calibrate_band(state, traj, dcfg, train_rows=tr.row, seed=dcfg.seed)
    e_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    estimator_sensitivity(state, traj, est, tr.row, qu_window=dcfg.qu_window)
    f_s = time.perf_counter() - t0
    costs = _query_costs(state, banded)
    rows = [_score("latent σ̃", e, lat, 0.0, 0.0, val_cov(lv)),
            _score("predictive √(σ̃²+σ_0²)", e, np.sqrt(lat**2 + noise_sd**2), 0.0, costs["scale_us"], val_cov(np.sqrt(lv**2 + noise_sd**2)))]
    # (a) noisy-input, Savitzky–Golay quantization model
    t0 = time.perf_counter()
    steps = traj.quantization_steps()  # the logged values' step, also for a resampled import
    s_q = quantization_input_std(tr.input_names, {n: v for n, v in steps.items() if v is not None}, estimator=est,
                                 sample_rate_hz=traj.meta.sample_rate_hz)
    a_s = time.perf_counter() - t0
    g = mean_gradient(state, x)
    gv = mean_gradient(state, xv)
    prop = ((g * s_q) ** 2).sum(1).numpy()
    prop_v = ((gv * s_q) ** 2).sum(1).numpy()
    rows.append(_score("(a) noisy-input, SG quantization Σ_x, all d columns", e, np.sqrt(lat**2 + prop), a_s, costs["gradient_us"],
                       val_cov(np.sqrt(lv**2 + prop_v))))
    free = torch.ones(state.dim, dtype=torch.float64)
    free[-2:] = 0.0                                     # forward's inputs: q̈_u = q̇_u = 0 exactly at x_0^e
    prop_free = ((g * s_q * free) ** 2).sum(1).numpy()
    rows.append(_score("(a') noisy-input, SG quantization Σ_x, forward's 3m columns", e, np.sqrt(lat**2 + prop_free), a_s,
                       costs["gradient_us"], val_cov(np.sqrt(lv**2 + prop_v))))
    # (b) NIGP: learned Σ_x
    t0 = time.perf_counter()
    g_tr = mean_gradient(state, tr.x)
    s2, nigp_latent, nigp_noise = _nigp(state, tr.x, tr.y, g_tr)
    b_s = time.perf_counter() - t0
    lat_b = nigp_latent(x).numpy()
    prop_b = ((g**2) * s2).sum(1).numpy()
    lat_bv = nigp_latent(xv).numpy()
    prop_bv = ((gv**2) * s2).sum(1).numpy()
    rows.append(_score("(b) NIGP, learned Σ_x", e, np.sqrt(lat_b**2 + prop_b), b_s, costs["gradient_us"],
                       val_cov(np.sqrt(lat_bv**2 + prop_bv))))
    # (d) split-conformal on a static-q_u proxy (held-out samples with the pendulum nearly at rest)
    t0 = time.perf_counter()
    xa = va.x.clone()
    still = (xa[:, -1].abs() <= xa[:, -1].abs().quantile(0.2)) & (xa[:, -2].abs() <= xa[:, -2].abs().quantile(0.2))
    x0 = xa[still].clone()
    x0[:, -2:] = 0.0
    m0, s0 = state.predict_reference(x0)
    scores = ((va.y[still] - m0).abs() / s0).numpy()
    c_d = max(1.0, float(np.quantile(scores, 0.95)) / gaussian_quantile(0.95))
    d_s = time.perf_counter() - t0
    rows.append(_score(f"(d) conformal, static-q_u proxy (c = {c_d:.2f})", e, c_d * lat, d_s, costs["scale_us"], val_cov(c_d * lv)))
    # (e) trial-split replicas, (f) estimator neighbours, and the chosen band (e) with max((a'), (f)) exactly as
    # `bemlearn train` computes it
    assert banded.std_scale is not None  # filled by PredictorState.__post_init__
    c = float(banded.std_scale)
    rows.append(_score(f"(e) trial-split replicas (c = {c:.2f})", e, c * lat, e_s - f_s, costs["scale_us"], val_cov(c * lv)))
    only_f = dataclasses.replace(state, estimator_delta=banded.estimator_delta)
    n_rs = int((summary.get("resample_term") or {}).get("n_draws") or 0) > 0   # the resample column (eq. R2) rides with (f)
    rows.append(_score(f"(f) estimator neighbours, K = {banded.n_estimators - n_rs}" + (" + resample term (R2)" if n_rs else ""), e,
                       band_reference(only_f, x, n_inputs=state.dim - 2)[1].numpy(), f_s, costs["band_us"],
                       val_cov(band_reference(only_f, xv)[1].numpy())))
    no_f = dataclasses.replace(banded, estimator_delta=None)
    rows.append(_score("(e) + (a')", e, band_reference(no_f, x, n_inputs=state.dim - 2)[1].numpy(), e_s - f_s,
                       costs["gradient_us"], val_cov(band_reference(no_f, xv)[1].numpy())))
    band = band_reference(banded, x, n_inputs=state.dim - 2)[1].numpy()
    band_v = band_reference(banded, xv)[1].numpy()
    rows.append(_score(f"chosen: (e) with the larger of (a') and (f), eq. B1 (c = {c:.2f})", e, band, e_s, costs["band_us"], val_cov(band_v)))
    cal = summary["replicas"] or {}
    oracle = _oracle_rmse(state, traj, case, tr, x, q)
    if oracle is not None:
        progress(f"{case.name}: the same GP conditioned on the simulator's exact q̇, q̈ at the same rows: BEM RMSE {oracle:.5f} "
                 f"(estimated derivatives: {rmse:.5f})")
    return {"robot": case.name, "oracle_rmse": oracle, "fit_s": fit_s, "rmse": rmse, "max_abs": float(np.abs(e).max()), "n_points": int(e.size),
            "costs": costs, "rows": rows, "calibration": cal, "nigp_input_std": s2.sqrt().tolist(),
            "quantization_input_std": s_q.tolist(), "input_names": list(tr.input_names), "nigp_noise": nigp_noise}


def run_seed_sweep(case: BenchCase, seeds, *, progress=print) -> list[dict]:
    """The chosen band as ``bemlearn train`` computes it, over dataset seeds (training draw
    *and* train/validation trial split change): robustness of coverage and sharpness."""
    from bemlearn.data import build_datasets, read_trajectory
    from bemlearn.fitting import train_gp
    from bemlearn.models import predictor_state
    from bemlearn.pipeline.evaluation import (
        evaluate_bem,
        held_out_references,
    )

    cfg = case.config
    assert cfg.robot is not None  # a bench case names its robot (config_case checks)
    traj = read_trajectory(case.data_path, robot=cfg.robot)
    from bemlearn.robots import load

    robot = load(cfg.robot, coordinates=cfg.coordinates)
    ev_cfg = case.evaluation
    rows = []
    for seed in seeds:
        ds = build_datasets(traj, dataclasses.replace(cfg.dataset, seed=int(seed)))
        dcfg, tr = ds.config, ds.train
        model, lik, _ = train_gp(tr.x_normalized, tr.y_normalized, config=cfg.train)
        st = predictor_state(model, lik, x_mean=tr.x_mean, x_std=tr.x_std, y_mean=tr.y_mean, y_std=tr.y_std,
                             input_names=tr.input_names, n_train=len(tr))
        st, summary = calibrate_band(st, traj, dcfg, train_rows=tr.row, seed=int(seed))
        ev = evaluate_bem(st, robot, held_out_references(ev_cfg, robot.m), duration_s=ev_cfg.duration_s, rate_hz=ev_cfg.rate_hz)
        row = {"robot": case.name, "seed": int(seed), "rmse": ev.rmse, "latent": ev.coverage_2sigma_latent,
               "band": ev.coverage_2sigma_band, "median_over_rmse": ev.median_band_std_over_rmse,
               "c": summary["std_scale"], "violation": ev.bound_violation.observed}
        progress(f"{case.name} dataset seed {seed}: BEM RMSE {row['rmse']:.5f}, band {100 * row['band']:.1f}%")
        rows.append(row)
    return rows


def format_seed_sweep(rows: list[dict]) -> str:
    """Markdown table of :func:`run_seed_sweep` rows."""
    lines = [("| robot | dataset seed | BEM RMSE (rad) | inside ±2σ latent | inside ±2σ band | median σ / RMSE | c | "
              "bound κ = 2 violated (nominal 4.55%) |"), "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['robot']} | {r['seed']} | {r['rmse']:.5f} | {100 * r['latent']:.1f}% | {100 * r['band']:.1f}% | "
                     f"{r['median_over_rmse']:.2f} | {r['c']:.2f} | {100 * r['violation']:.1f}% |")
    return "\n".join(lines)


def run_uncertainty_bench(*, config, data, cartpole: bool = True, workdir: str | Path | None = None, seeds: int = 0,
                          progress=print) -> tuple[list[dict], list[dict]]:
    """Run :func:`run_case` on ``config`` with ``data`` and (optionally) the generated cart-pole, and
    :func:`run_seed_sweep` over dataset seeds 1..``seeds`` (0: no sweep)."""
    fur = config_case(config, data)
    results = [run_case(fur, progress=progress)]
    sweep = run_seed_sweep(fur, range(1, seeds + 1), progress=progress) if seeds else []
    if cartpole:
        with tempfile.TemporaryDirectory(prefix="bemlearn-uncertainty-") as tmp:
            case = cartpole_case(workdir or tmp)
            results.append(run_case(case, progress=progress))
            if seeds:
                sweep += run_seed_sweep(case, range(1, seeds + 1), progress=progress)
    return results, sweep


def format_uncertainty_bench(results: list[dict]) -> str:
    """One Markdown table per robot."""
    lines = []
    for r in results:
        oracle = "" if r.get("oracle_rmse") is None else f" (with the simulator's exact q̇, q̈: {r['oracle_rmse']:.5f})"
        lines += [(f"\n{r['robot']}: BEM RMSE {r['rmse']:.5f}{oracle}, max {r['max_abs']:.5f} over {r['n_points']} held-out points; "
                   f"fit {r['fit_s']:.1f} s; B = 1 eager query {r['costs']['base_us']:.1f} µs"),
                  ("| band | inside μ ± 2σ | median σ / RMSE | bound κ = 2 violated (nominal) | coverage at 50 / 90 / 99 % |"
                   " held-out q_u inside ±2√(σ²+σ_0²) | extra train (s) | extra query (µs) |"),
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for row in r["rows"]:
            rel = {round(t["level"], 2): t["coverage"] for t in row["reliability"]}
            lines.append(
                f"| {row['band']} | {100 * row['coverage_2sigma']:.1f}% | {row['median_std_over_rmse']:.2f} | "
                f"{100 * row['violation_kappa2']:.1f}% ({100 * row['nominal_violation_kappa2']:.2f}%) | "
                f"{100 * rel[0.5]:.0f} / {100 * rel[0.9]:.0f} / {100 * rel[0.99]:.0f}% | "
                f"{100 * row.get('val_coverage_2sigma', float('nan')):.1f}% | {row['train_s']:.2f} | {row['query_us']:.1f} |")
        names = r["input_names"]
        lines.append("input std s (quantization model / NIGP): " + ", ".join(
            f"{n} {a:.3g} / {b:.3g}" for n, a, b in zip(names, r["quantization_input_std"], r["nigp_input_std"])))
    return "\n".join(lines)
