"""The Markdown report of a run (``report.md``): only what the run computed, in its robot's units."""

from __future__ import annotations

from pathlib import Path

from bemlearn.files import atomic_write_text

__all__ = ["write_report"]


def _f(v, spec=".4f"):
    return format(v, spec) if isinstance(v, (int, float)) and not isinstance(v, bool) else "—" if v is None else str(v)


def _pct(v) -> str:
    return f"{100 * v:.1f}%" if isinstance(v, (int, float)) else "—"


def write_report(out: str | Path, *, config, resolved, data: dict, train: dict, export: list[Path], sim: dict) -> Path:
    """Write ``out/report.md`` from the stages' metrics; returns its path.

    Args:
        config: the resolved :class:`~bemlearn.pipeline.config.PipelineConfig`.
        resolved: its :class:`~bemlearn.pipeline.resolve.ResolvedConfig` (origins of the values).
        data, train, sim: the metrics of the data, training and closed-loop stages.
        export: the predictor files written.
    """
    out = Path(out)
    unit = train.get("output_unit", "rad")
    robot = train.get("robot", {})
    qu = train.get("unactuated")
    title = robot.get("registry") or robot.get("name") or "data"
    lines = [f"# bemlearn run: {title}" + (" (model-free)" if config.robot is None else ""), ""]
    if robot.get("mjcf"):
        lines += [f"Robot: `{robot['mjcf']}` (sha256 `{robot['sha256'][:16]}…`)" + (f", registry name `{robot['registry']}`" if robot.get("registry") else "") + ".", ""]
    elif config.robot is None:
        lines += ["Model-free run: the BEM is learned from the data file alone; "
                  + (f"it is compared with the model `{config.model}` only because the config names it." if config.model else "nothing is compared with a model."), ""]
    derived = sorted({k.split(".")[0] + "." + k.split(".")[1] for k, o in resolved.origins.items() if o == "derived" and k.count(".") >= 1})
    if derived:
        lines += ["Values derived from the model (not given in the config; `config_resolved.json` and "
                  "`bemlearn config show` list each with how it was derived): " + ", ".join(f"`{k}`" for k in derived) + ".", ""]
    src = "collected in MuJoCo (excitation, Section IV-A)" if data["collected"] else f"read from `{data['file']}`"
    lines += ["## Data", f"{data['trials']} trials ({data['failed']} fell, kept up to the fall), {data['samples']} samples at "
              f"{data['rate_hz']:g} Hz, {src}; derivatives estimated from the positions only.", ""]
    fit = train.get("fit", {})
    lines += ["## Learned BEM (eq. 11–14)",
              f"{config.train.kind} GP on {train['n_train']} points: fit {fit.get('stop_reason')} in {_f(fit.get('seconds'), '.1f')} s"
              + (" (interrupted)" if train.get("interrupted") else "") + ".", ""]
    h = train.get("data_heldout")
    if h is not None:
        lines += ["### From the data alone (no model)", "",
                  f"Held-out trials ({len(h['per_trial'])} trials, {h['n_points']} samples the fit never saw): q_u predicted "
                  f"from f(x) (eq. 11) with RMSE {_f(h['rmse'], '.5f')} {unit} (max {_f(h['max_abs'], '.4f')} {unit}); "
                  f"{_pct(h['coverage'])} of the samples lie inside the predictive ±2σ.", "",
                  "| held-out trial | RMSE (" + unit + ") | inside ±2σ | samples |", "| --- | --- | --- | --- |",
                  *[f"| {t} | {_f(r['rmse'], '.5f')} | {_pct(r['coverage'])} | {r['n_points']} |" for t, r in h["per_trial"].items()], ""]
    sl = train.get("bem_slices")
    if sl is not None:
        sm = sl["summary"]
        lines += [f"The learned BEM μ(x₀ᵉ) ± 2σ on {sm['n_slices']} slices through the data (grey: beyond the q̈_a the "
                  f"training data cover near the slice, i.e. extrapolation). Mean predictive σ where covered "
                  f"{_f(sm['std_pred_mean_covered'], '.4f')} {unit}, where extrapolated {_f(sm['std_pred_mean_extrapolated'], '.4f')} {unit}.",
                  "", "![BEM slices](bem_slices.png)", ""]
    b = train.get("bem_heldout")
    if b is not None:
        lines += ["### Against the model-based BEM (eq. 9)", "", "| held-out references: learned vs model-based BEM | value |", "| --- | --- |",
                  f"| RMSE ({unit}) | {_f(b['rmse'], '.5f')} |",
                  f"| max error ({unit}) | {_f(b['max_abs'], '.5f')} |",
                  f"| points without a model BEM in range (excluded) | {b['no_model_root']} |",
                  f"| inside ±2σ, latent std | {_pct(b['coverage_2sigma_latent'])} |",
                  f"| inside ±2σ, predictive std (eq. 12 with k* = σ_f² + σ_0²) | {_pct(b['coverage_2sigma_predictive'])} |"]
        dr = b.get("design_region")
        if dr is not None:
            lines += [f"| RMSE / max over \\|q_u^e\\| ≤ {dr['bound']:g} {unit} ({dr['n_points']} points) | "
                      f"{_f(dr['rmse'], '.5f')} / {_f(dr['max_abs'], '.5f')} |"]
        if "coverage_2sigma_band" in b:
            v = b["bound_violation"]
            lines += [f"| inside ±2σ, calibrated band (the exported std) | {_pct(b['coverage_2sigma_band'])} |",
                      f"| median band σ / RMSE | {_f(b['median_band_std_over_rmse'], '.2f')} |",
                      f"| eq. (13)/(15) bound at κ = {v['kappa']:g}: violated / nominal | {_pct(v['observed'])} / {_pct(v['nominal'])} |"]
        lines += ["", "![learned vs model BEM](bem_validation.png)", ""]
        if (out / "reliability.png").is_file():
            lines += ["Reliability of the band: coverage of the model BEM against the nominal level (50–99 %).", "",
                      "![reliability](reliability.png)", ""]
    unc = train.get("uncertainty")
    if unc:
        est = unc.get("estimator_term") or {}
        names = est.get("estimators") or []
        med = est.get("median_shift") or [None] * len(names)
        lines += ["### The exported std (calibrated band, eq. B1)", "",
                  f"std² = c² · latent std² + max(Σ_i (s_i ∂μ/∂x_i)², mean over the neighbouring derivative estimators of the BEM's "
                  f"shift²); c = {_f(unc.get('std_scale'), '.3f')} (trial-split replicas); "
                  + ("s from the quantization steps " + ", ".join(f"{k} {v:.3g} {train.get('units', {}).get(f'q_{k}', 'rad')}" for k, v in (unc.get("quantization_step") or {}).items())
                     if unc.get("quantization_step") else "no quantization grid detected (s = 0)") + "; "
                  + (f"{len(names)} neighbouring estimators (median BEM shift at held-out queries, {unit}): "
                     + ", ".join(f"{n} {_f(m, '.2g')}" for n, m in zip(names, med)) if names else "no estimator term (the estimator has no neighbours)")
                  + ".", ""]
    lines += ["## Exported predictor", *[f"- `{p.name}`" for p in export], ""]
    if sim:
        qa_unit = "/".join(sorted({v for k, v in train.get("units", {}).items() if k.startswith("q_")})) or "rad"
        lines += ["## Closed loop (EIC, eq. 3 and 8) in MuJoCo", "",
                  f"| BEM source | outcome | duration (s) | tracking RMSE of q_a ({qa_unit}) | max \\|{qu or 'q_u'}\\| ({unit}) | "
                  f"max \\|u\\| ({data.get('input_units', 'actuator units')}) | BEM values held | real-time factor |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for name, m in sim.items():
            outcome = "fell" if m["fell"] else "diverged (q_a left the reference)" if m.get("diverged") else "stayed up"
            lines.append(f"| {name} | {outcome} | {_f(m['duration_s'], '.1f')} | {_f(m['tracking_rmse'])} | {_f(m['qu_max'], '.3f')} | "
                         f"{_f(m['u_max'], '.2f')} | {m.get('bem_rejected', 0)} | {_f(m['real_time_factor'], '.1f')} |")
        if "predictor" in sim and "lemma1" in sim["predictor"]:
            L = sim["predictor"]["lemma1"]
            lines += ["", f"Lemma 1 along the reference: model-based max |ΔΓ − Ḣ_u − b_u q̇_u^e| = {L['model_gap']:.1e}; "
                      f"learned ΔΓ vs Ḣ_u correlation r = {L['r_learned_vs_hdot']:.4f} (vs the model's ΔΓ: {L['r_learned_vs_model_delta_gamma']:.4f})."]
        lines += [""]
        for name in sim:
            lines += [f"### BEM source: {name}", "", f"![fig2 {name}](simulate/fig2_{name}.png)", ""]
    path = out / "report.md"
    atomic_write_text(path, "\n".join(lines))
    return path
