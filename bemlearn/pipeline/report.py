"""The Markdown report of a full run (``report.md`` in the run folder)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["write_report"]


def _f(v, spec=".4f"):
    return format(v, spec) if isinstance(v, (int, float)) else str(v)


def write_report(out: str | Path, *, robot: str, data: dict, train: dict, export: list[Path], sim: dict) -> Path:
    """Write ``out/report.md`` from the stages' metrics; returns its path."""
    out = Path(out)
    b = train["bem_heldout"]
    lines = [
        f"# bemlearn run: {robot}",
        "",
        "## Data (excitation, Section IV-A)",
        f"{data['trials']} trials ({data['failed']} fell, kept up to the fall), {data['samples']} samples at {data['rate_hz']:g} Hz, "
        "quantized encoder angles; derivatives estimated from the angles only.",
        "",
        "## Learned BEM (eq. 11–14)",
        f"GP `{train['hyperparameters'] and 'trained'}` on {train['n_train']} points: fit {train['fit'].get('stop_reason')} in {_f(train['fit'].get('seconds', float('nan')), '.1f')} s.",
        "",
        "| held-out composite sinusoids | value |",
        "| --- | --- |",
        f"| RMSE vs model-based BEM (rad) | {_f(b['rmse'], '.5f')} |",
        f"| max error (rad) | {_f(b['max_abs'], '.5f')} |",
        f"| inside ±2σ, latent std | {100 * b['coverage_2sigma_latent']:.1f}% |",
        f"| inside ±2σ, predictive std (eq. 12 with k* = σ_f² + σ_0²) | {100 * b['coverage_2sigma_predictive']:.1f}% |",
        "",
        "![learned vs model BEM](bem_validation.png)",
        "",
        "## Exported predictor",
        *[f"- `{p.name}`" for p in export],
        "",
        "## Closed loop (EIC, eq. 3 and 8) in MuJoCo",
        "",
        "| BEM source | fell | duration (s) | tracking RMSE (rad) | max \\|α\\| (rad) | max \\|V\\| | real-time factor |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for src, m in sim.items():
        lines.append(f"| {src} | {m['fell']} | {_f(m['duration_s'], '.1f')} | {_f(m['tracking_rmse'])} | {_f(m['qu_max'], '.3f')} | {_f(m['u_max'], '.2f')} | {_f(m['real_time_factor'], '.1f')} |")
    if "predictor" in sim and "lemma1" in sim["predictor"]:
        L = sim["predictor"]["lemma1"]
        lines += ["", f"Lemma 1 along the reference: model-based max |ΔΓ − Ḣ_u − b_u q̇_u^e| = {L['model_gap']:.1e} N·m; "
                  f"learned ΔΓ vs Ḣ_u correlation r = {L['r_learned_vs_hdot']:.4f} (vs the model's ΔΓ: {L['r_learned_vs_model_delta_gamma']:.4f})."]
    lines += [""]
    for src in sim:
        lines += [f"### BEM source: {src}", "", f"![fig2 {src}](simulate/fig2_{src}.png)", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path
