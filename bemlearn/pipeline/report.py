"""The Markdown report of a run (``report.md``): only what the run computed, in its robot's units."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from bemlearn.files import atomic_write_text
from bemlearn.pipeline.run_metrics import (
    DataHeldout,
    DataInfo,
    HeldoutTrial,
    LoopMetrics,
    Resolution,
    ResolutionInput,
    RunMetrics,
)

__all__ = ["write_report", "ZERO_SOURCE", "ZERO_BASELINE_NOTE"]

#: The BEM source that is a baseline (q_u^e = 0): expected to fail, labelled so in the report and on the console.
ZERO_SOURCE = "zero"
ZERO_BASELINE_NOTE = " (the baseline: expected to fail)"


def _source_label(name: str) -> str:
    return f"{name} (baseline)" if name == ZERO_SOURCE else name


def _f(v, spec=".4f"):
    return format(v, spec) if isinstance(v, (int, float)) and not isinstance(v, bool) else "—" if v is None else str(v)


def _pct(v) -> str:
    return f"{100 * v:.1f}%" if isinstance(v, (int, float)) else "—"


def _verdict_lines(train: RunMetrics) -> list[str]:
    v = train.verdict
    if not v:
        return []
    lines = [f"## Verdict: {v.status}", ""]
    if v.findings:
        lines += [f"- **{f.severity}**: {f.reason}" for f in v.findings]
    else:
        lines += ["Every check passed: " + ", ".join(v.checked) + " (limits in `bemlearn.pipeline.verdict`)."]
    return [*lines, ""]


def _feasibility_lines(train: RunMetrics) -> list[str]:
    checks = train.feasibility or ()
    if not checks:
        return []
    return ["## Model checks (before collecting)", "", "| check | value | pass when | passed | finding |", "| --- | --- | --- | --- | --- |",
            *[f"| {c.name} | {_f(c.value, '.3g')} | {'<' if c.strict else '≤'} {_f(c.limit, '.3g')} | "
              f"{'yes' if c.passed else '**no**'} | {_cell(str(c.text))} |" for c in checks], ""]


def _cell(text: str) -> str:
    """``text`` safe inside a Markdown table cell."""
    return str(text).replace("|", "\\|").replace("\n", " ")


def write_report(out: str | Path, *, config, resolved, data: DataInfo | None, train: RunMetrics, export: list[Path],
                 sim: Mapping[str, LoopMetrics]) -> Path:
    """Write ``out/report.md`` from the stages' metrics; returns its path.

    Args:
        config: the resolved :class:`~bemlearn.pipeline.config.PipelineConfig`.
        resolved: its :class:`~bemlearn.pipeline.resolve.ResolvedConfig` (origins of the values).
        data, train, sim: the data's summary, the run's metrics and the closed loops (one
            :class:`~bemlearn.pipeline.run_metrics.LoopMetrics` per BEM source, as ``simulate/metrics.json``
            holds them); ``data`` is ``None`` for a run stopped after its model checks.
        export: the predictor files written.
    """
    out = Path(out)
    unit = train.unit()
    robot = train.robot
    title = (robot.registry or robot.name if robot else None) or "data"
    lines = [f"# bemlearn run: {title}" + (" (model-free)" if config.robot is None else ""), "", *_verdict_lines(train)]
    if data is None:          # stopped after the model checks: nothing was collected or learned
        lines += [f"Robot: `{config.robot}`. The run stopped after its model checks: the robot cannot be balanced over "
                  "the design region as configured, so no data were collected and no BEM was learned.", "",
                  *_feasibility_lines(train)]
    else:
        lines += [*_source_lines(config, resolved, robot), *_feasibility_lines(train), *_data_lines(data, train),
                  *_fit_lines(config, train), *_data_only_lines(train, unit, config), *_heldout_lines(train, unit),
                  *_design_region_lines(train, unit, out), *_band_lines(train, unit),
                  "## Exported predictor", *[f"- `{p.name}`" for p in export], "", *_closed_loop_lines(sim, data, train, unit)]
    path = out / "report.md"
    atomic_write_text(path, "\n".join(lines))
    return path


def _source_lines(config, resolved, robot) -> list[str]:
    """Where the robot came from and which values were derived from its model."""
    lines: list[str] = []
    if robot is not None and robot.mjcf:
        lines += [f"Robot: `{robot.mjcf}` (sha256 `{(robot.sha256 or '')[:16]}…`)" + (f", registry name `{robot.registry}`" if robot.registry else "") + ".", ""]
    elif config.robot is None:
        lines += ["Model-free run: the BEM is learned from the data file alone; "
                  + (f"it is compared with the model `{config.model}` only because the config names it." if config.model else "nothing is compared with a model."), ""]
    derived = sorted({k.split(".")[0] + "." + k.split(".")[1] for k, o in resolved.origins.items() if o == "derived" and k.count(".") >= 1})
    if derived:
        lines += ["Values derived from the model (not given in the config; `config_resolved.json` and "
                  "`bemlearn config show` list each with how it was derived): " + ", ".join(f"`{k}`" for k in derived) + ".", ""]
    return lines


def _data_lines(data: DataInfo, train: RunMetrics) -> list[str]:
    src = "collected in MuJoCo (excitation, Section IV-A)" if data.collected else f"read from `{data.file}`"
    ds = train.dataset
    choice = ds.derivative_choice if ds else None
    deriv = "derivatives estimated from the positions only"
    if choice:
        noise = choice.qdd_noise_fraction or {}
        deriv = (f"q, q̇, q̈ and the label q_u from one Gaussian kernel (docs/derivatives.md): {choice.note}"
                 + (" (quantization noise left in q̈: " + ", ".join(f"{j} {100 * v:.1f} %" for j, v in noise.items()) + " of its spread)"
                    if noise else ""))
    elif ds and ds.estimator:
        deriv = f"derivatives estimated from the positions only, by {ds.estimator}"
    return ["## Data", f"{data.trials} trials ({data.failed} fell, kept up to the fall), {data.samples} samples at "
            f"{_f(data.rate_hz, 'g')} Hz, {src}; {deriv}.", ""]


def _fit_lines(config, train: RunMetrics) -> list[str]:
    fit = train.fit
    stop = fit.stop_reason if fit else None
    how = {"converged": "converged", "max_iter": "stopped at its iteration limit without converging",
           "epochs": "stopped after its epochs without converging"}.get(str(stop), f"ended by {stop}")
    steps = fit.steps if fit and fit.steps is not None else "—"
    return ["## Learned BEM (eq. 11–14)",
            f"{config.train.kind} GP on {train.n_train} points: the fit {how} after {steps} evaluations "
            f"in {_f(fit.seconds if fit else None, '.1f')} s" + (" (interrupted)" if train.interrupted else "") + "."
            + _prior_mean_text(fit.prior_mean if fit else None), ""]


def _prior_mean_text(pm) -> str:
    """The prior mean in a sentence (eq. L1, L2), or nothing for the zero mean asked for by the config."""
    if pm is None or (pm.chosen == "zero" and pm.nlml_zero is None):
        return ""
    plane = f"a least-squares plane in the inputs (eq. L1, explaining {_f(100 * pm.explained, '.2f')} % of the label's variance)" \
        if pm.explained is not None else "a least-squares plane in the inputs (eq. L1)"
    if pm.chosen == "linear" and pm.estimate == "generalized least squares":
        plane += "; its coefficients then by generalized least squares under the fitted kernel (eq. L4)"
    if pm.nlml_zero is None:
        return f" Prior mean: {plane}."
    compared = (f"−log p {_f(pm.nlml_linear, '.1f')} + {_f(pm.penalty, '.1f')} for its coefficients against "
                f"{_f(pm.nlml_zero, '.1f')} nats for the zero mean, eq. L2")
    return (f" Prior mean: {plane} ({compared})." if pm.chosen == "linear" else
            f" Prior mean: zero; {plane} did not pay for its coefficients ({compared}).")


def _data_only_lines(train: RunMetrics, unit: str, config=None) -> list[str]:
    """Held-out trials, slices and resolution: what the data alone say (no model)."""
    lines: list[str] = []
    h = train.data_heldout
    if h is not None:
        per = h.per_trial or {}
        lines += ["### From the data alone (no model)", "",
                  f"Held-out trials ({len(per)} trials, {h.n_points} samples the fit never saw): q_u predicted "
                  f"from f(x) (eq. 11) with RMSE {_f(h.rmse, '.5f')} {unit} (max {_f(h.max_abs, '.4f')} {unit}); "
                  f"{_pct(h.coverage)} of the samples lie inside the predictive ±2σ.", "",
                  "| held-out trial | RMSE (" + unit + ") | inside ±2σ | samples | note |", "| --- | --- | --- | --- | --- |",
                  *[f"| {t} | {_f(r.rmse, '.5f')} | {_pct(r.coverage)} | {r.n_points} | {_trial_note(r, h)} |"
                    for t, r in per.items()], ""]
    sl = train.bem_slices
    if sl is not None and sl.summary is not None:
        sm = sl.summary
        cov, ext = sm.std_pred_mean_covered, sm.std_pred_mean_extrapolated
        where = (f"Mean predictive σ where covered {_f(cov, '.4f')} {unit}" if _finite(cov) else
                 "No slice has enough training points near it to call any part covered")
        where += f", where extrapolated {_f(ext, '.4f')} {unit}." if _finite(ext) else "."
        lines += [f"The learned BEM μ(x₀ᵉ) ± 2σ on {sm.n_slices} slices through the data (grey: beyond the q̈_a the "
                  f"training data cover near the slice, i.e. extrapolation). {where}", "", "![BEM slices](bem_slices.png)", ""]
    sup = train.support
    if sup is not None and _finite(sup.share):
        pair = next((p for p in sup.pairs or () if p.input == sup.qdd_u), None)
        moved = (f" {pair.input} moves with {pair.with_} (≈ {pair.ratio:+.3g}×, corr {pair.corr:+.3f})." if pair else "")
        along = (f" Extrapolating from the samples to q̈_u = 0 along {sup.qdd_u}: least-squares slope {_f(sup.slope, '.3g')} "
               f"{unit} per {unit}/s², t = {_f(sup.t, '.1f')} (resolved when ≥ 5; 1/slope = λ̂² = {_f(sup.lambda2, '.3g')} 1/s²)."
               if _finite(sup.t) else "")
        lines += [f"Joint support of the BEM queries (q̈_u = q̇_u = 0 at the data's actuated motions, all inputs together; "
                  f"docs/verdict.md): {_pct(sup.share)} have a training sample within {_f(sup.limit, 'g')} nearest-neighbour "
                  f"spacings in the data's whitened input space.{moved}{along}", ""]
    res = train.resolution
    if res is not None:
        top = (res.inputs or ())[:3]
        lines += [f"Over the data's actuated motions the learned BEM varies by {_f(res.spread, '.3g')} {unit} (std), "
                  f"{_f(res.ratio, '.1f')}× the exported band's median σ ({_f(res.band_std, '.3g')} {unit}). The inputs that "
                  "move it most: " + ", ".join(f"{w.input} (slope {_f(w.slope, '.3g')} {unit} per {w.unit}, "
                                                f"{_data_range(w)})" for w in top) + ".", ""]
        signs = dict(getattr(getattr(config, "evaluate", None), "slope_signs", None) or {})
        lines += _slope_sign_lines(res, signs, unit)
    return lines


def _data_range(w: ResolutionInput) -> str:
    """The data's range of an input: the slices' covered-range rule (``COVERED_QUANTILES``), as the slice figure marks it."""
    r = w.range
    if r is None:
        return f"data std {_f(w.amplitude, '.3g')} {w.unit}"
    return f"data cover {_f(r[0], '.3g')} … {_f(r[1], '.3g')} {w.unit} (95 %)"


def _slope_sign_lines(res: Resolution, signs: dict, unit: str) -> list[str]:
    """The learned slopes against the sign convention the config declares (``evaluate.slope_signs``, docs/log-import.md)."""
    if not signs:
        return []
    by_name = {w.input: w for w in res.inputs or ()}
    out = []
    for name, expected in signs.items():
        w = by_name.get(name)
        if w is None:
            out.append(f"- {name}: not an input of this BEM ({', '.join(str(n) for n in by_name)}); its sign is not checked.")
            continue
        slope, factor = w.slope, w.factor
        want = "negative" if expected < 0 else "positive"
        resolved = factor is not None and factor < 1.0   # the input's share of the BEM exceeds the band's ±2σ
        if not resolved:
            out.append(f"- {name}: slope {_f(slope, '.3g')} {unit} per {w.unit} lies within the band over the data "
                       f"(expected {want}): the data cannot tell its sign.")
        elif slope is not None and slope * expected > 0:
            out.append(f"- {name}: slope {_f(slope, '.3g')} {unit} per {w.unit} is {want}, as the convention says.")
        else:
            out.append(f"- **{name}: the sign looks flipped**: slope {_f(slope, '.3g')} {unit} per {w.unit}, the convention "
                       f"(`evaluate.slope_signs`) says {want}. Check the `sign:` of the unactuated joint and of this input's "
                       "joint in the import map (docs/log-import.md, sign convention).")
    return ["Sign convention of the learned slopes (`evaluate.slope_signs`):", "", *out, ""]


def _heldout_lines(train: RunMetrics, unit: str) -> list[str]:
    """Learned vs model-based BEM along the held-out references (``bem_heldout``)."""
    b = train.bem_heldout
    if b is None:
        return []
    lines = ["### Against the model-based BEM (eq. 9)", "", "| held-out references: learned vs model-based BEM | value |", "| --- | --- |",
             f"| RMSE ({unit}) | {_f(b.rmse, '.5f')} |",
             f"| max error ({unit}) | {_f(b.max_abs, '.5f')} |",
             f"| points without a model BEM in range (excluded) | {b.no_model_root} |",
             f"| inside ±2σ, latent std | {_pct(b.coverage_2sigma_latent)} |",
             f"| inside ±2σ, predictive std (eq. 12 with k* = σ_f² + σ_0²) | {_pct(b.coverage_2sigma_predictive)} |"]
    dr = b.design_region
    if dr is not None:
        lines += [f"| RMSE / max over \\|q_u^e\\| ≤ {_f(dr.bound, 'g')} {unit} ({dr.n_points} points) | "
                  f"{_f(dr.rmse, '.5f')} / {_f(dr.max_abs, '.5f')} |"]
    if b.coverage_2sigma_band is not None:
        v = b.bound_violation
        lines += [f"| inside ±2σ, calibrated band (the exported std) | {_pct(b.coverage_2sigma_band)} |",
                  f"| median band σ / RMSE | {_f(b.median_band_std_over_rmse, '.2f')} |",
                  f"| eq. (13)/(15) bound at κ = {_f(v.kappa if v else None, 'g')}: violated / nominal | "
                  f"{_pct(v.observed if v else None)} / {_pct(v.nominal if v else None)} |"]
    return [*lines, "", "![learned vs model BEM](bem_validation.png)", ""]


def _refined_note(dr) -> str:
    """How the design region's max was found: the sample's, or refined by the compass search (D3)."""
    if not dr.refine_evaluations:
        return ""
    if dr.max_sampled is not None and dr.max_abs is not None and dr.max_abs > dr.max_sampled:
        return (f", refined by a compass search from the sample's worst points ({dr.refine_evaluations} motions; "
                f"the sample's own max {_f(dr.max_sampled, '.5f')})")
    return f", the sample's max (a compass search from its worst points, {dr.refine_evaluations} motions, found none larger)"


def _design_region_lines(train: RunMetrics, unit: str, out: Path) -> list[str]:
    """Learned vs model-based BEM over the whole design region (``bem_design_region``), and the reliability figure."""
    dr = train.bem_design_region
    if dr is None or not dr.n_points:
        return []
    bound = float(dr.bound) if dr.bound is not None else float("nan")
    box = "; ".join(f"{j}: |q| ≤ {_f(v['q'], '.3g')}, |q̇| ≤ {_f(v['qd'], '.3g')}, |q̈| ≤ {_f(v['qdd'], '.3g')}"
                    for j, v in (dr.box or {}).items())
    lines = [f"### Over the whole design region (|q_u^e| ≤ {bound:g} {unit})", "",
             f"{dr.n_points} actuated motions of a Sobol set in the box {box} (joint units; the points whose model BEM "
             "lies in the design region): learned μ(x₀ᵉ) vs the model-based BEM.", "",
             "| learned vs model BEM, design region | value | target |", "| --- | --- | --- |",
             f"| gain (least-squares slope of learned on model) | {_f(dr.gain, '.3f')} | 0.95–1.05 |",
             f"| RMSE ({unit}) | {_f(dr.rmse, '.5f')} | ≤ {0.05 * bound:.3g} |",
             f"| max error ({unit}){_refined_note(dr)} | {_f(dr.max_abs, '.5f')} | ≤ {0.2 * bound:.3g} |",
             f"| inside ±2σ, calibrated band | {_pct(dr.coverage_2sigma_band)} | ≥ 80 % |", "",
             "![design region](design_region.png)", ""]
    if (out / "reliability.png").is_file():
        lines += ["Reliability of the band: coverage of the model BEM against the nominal level (50–99 %).", "",
                  "![reliability](reliability.png)", ""]
    return lines


def _band_lines(train: RunMetrics, unit: str) -> list[str]:
    """How the exported std was calibrated (``uncertainty``)."""
    unc = train.uncertainty
    if not unc:
        return []
    est = unc.estimator_term
    names = (est.estimators if est else None) or []
    shifts: list[float | None] = list(est.median_shift) if est and est.median_shift else []
    med = shifts or [None] * len(names)
    units = train.units or {}
    return ["### The exported std (calibrated band, eq. B1)", "",
            f"std² = c² · latent std² + max(Σ_i (s_i ∂μ/∂x_i)², mean over the neighbouring derivative estimators of the BEM's "
            f"shift² + μ's deviation² from the mean of other draws of its training rows); c = {_f(unc.std_scale, '.3f')} ({_replica_text(unc)}); "
            + ("s from the quantization steps " + ", ".join(f"{k} {v:.3g} {units.get(f'q_{k}', 'rad')}" for k, v in (unc.quantization_step or {}).items())
               if unc.quantization_step else "no quantization grid detected (s = 0)") + "; "
            + (f"{len(names)} neighbouring estimators (median BEM shift at held-out queries, {unit}): "
               + ", ".join(f"{n} {_f(m, '.2g')}" for n, m in zip(names, med)) if names else "no estimator term (the estimator has no neighbours)")
            + _resample_text(unc, unit) + ".", ""]


def _resample_text(unc, unit: str) -> str:
    """The resample term (eq. R2, ``uncertainty.resample_term``): μ's deviation from the mean of other draws of its rows."""
    rs = unc.extra.get("resample_term") if isinstance(unc.extra, dict) else None
    if not isinstance(rs, dict):
        return ""
    if not rs.get("n_draws"):
        return f"; no resample term ({rs.get('reason') or 'no other draw of the training rows'})"
    return (f"; plus μ's deviation from the mean of {rs['n_draws']} other draws of its {rs.get('n_points')} training rows "
            f"(eq. R2, added to the estimator term's square; median at held-out queries {_f(rs.get('median_shift'), '.2g')} {unit}, "
            f"one draw's spread {_f(rs.get('spread'), '.2g')} {unit})")


def _replica_text(unc) -> str:
    """Which replica splits set c: each split's raw scale (``uncertainty.replicas.raw_by_split``)."""
    rep = unc.extra.get("replicas") if isinstance(unc.extra, dict) else None
    raws = rep.get("raw_by_split") if isinstance(rep, dict) else None
    if not isinstance(raws, dict) or not raws:
        return "trial-split replicas"
    return "replicas split by trials and by the residual of " + ", ".join(k for k in raws if k != "trials") + ": raw " + ", ".join(
        f"{k} {_f(v, '.2f')}" for k, v in raws.items()) if len(raws) > 1 else "trial-split replicas"


def _closed_loop_lines(sim: Mapping[str, LoopMetrics], data: DataInfo, train: RunMetrics, unit: str) -> list[str]:
    """The closed-loop table, Lemma 1 and the Fig. 2 panels per BEM source."""
    if not sim:
        return []
    qu = train.unactuated
    qa_unit = "/".join(sorted({v for k, v in (train.units or {}).items() if k.startswith("q_")})) or "rad"
    lines = ["## Closed loop (EIC, eq. 3 and 8) in MuJoCo", "",
             f"| BEM source | outcome | duration (s) | tracking RMSE of q_a ({qa_unit}) | max \\|{qu or 'q_u'}\\| ({unit}) | "
             f"max \\|u\\| ({data.input_units or 'actuator units'}) | BEM values held | real-time factor |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    eq = train.equilibrium
    stable = bool(eq and eq.stable_without_control)
    for name, m in sim.items():
        outcome = f"fell at {_f(m.duration_s, '.2f')} s" if m.fell else "diverged (q_a left the reference)" if m.diverged else \
            "stayed near an equilibrium that is stable without control (not balanced)" if stable else "stayed up"
        if name == ZERO_SOURCE:
            outcome += ZERO_BASELINE_NOTE if (m.fell or m.diverged) else " (the baseline, expected to fail, did not)"
        lines.append(f"| {_source_label(name)} | {outcome} | {_f(m.duration_s, '.1f')} | {_f(m.tracking_rmse)} | {_f(m.qu_max, '.3f')} | "
                     f"{_f(m.u_max, '.2f')} | {m.bem_rejected or 0} | {_f(m.real_time_factor, '.1f')} |")
    if stable and eq is not None:
        lines += ["", f"The equilibrium these loops held ({eq.joint} = {_f(eq.qu, '.4g')} {eq.unit}) is stable without control "
                  f"(gravity stiffness Γ_q = {_f(eq.gravity_stiffness, '.3g')} < 0): none of them balanced the robot."]
    lem = sim["predictor"].lemma1 if "predictor" in sim else None
    if lem is not None:
        lines += ["", f"Lemma 1 along the reference: model-based max |ΔΓ − Ḣ_u − b_u q̇_u^e| = {_f(lem.model_gap, '.1e')}; "
                  f"learned ΔΓ vs Ḣ_u correlation r = {_f(lem.r_learned_vs_hdot, '.4f')} (vs the model's ΔΓ: "
                  f"{_f(lem.r_learned_vs_model_delta_gamma, '.4f')})"
                  + (f"; split ΔΓ_learned ≈ {_f(lem.hdot_coefficient, '.3g')} Ḣ_u + ({_f(lem.damping_coefficient, '.3g')}) b_u q̇_u^e, "
                     f"the damping part moving q_u by {_f(lem.damping_qu, '.2g')} along the reference"
                     if _finite(lem.damping_coefficient) else "") + "."]
    if ZERO_SOURCE in sim:
        lines += ["", f"The {ZERO_SOURCE} BEM (q_u^e = 0, no BEM at all) is the baseline of the paper's Fig. 2: it is expected "
                  "to fall or diverge, and its failure is not a failure of the run."]
    lines += [""]
    for name in sim:
        lines += [f"### BEM source: {_source_label(name)}", "", f"![fig2 {name}](simulate/fig2_{name}.png)", ""]
    return lines


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and v == v and abs(v) != float("inf")


def _trial_note(r: HeldoutTrial, held: DataHeldout) -> str:
    """Why a held-out trial's error stands out: it fell, or its motions leave the training data."""
    notes = []
    if r.failed:
        notes.append("fell (its last, fastest motions are in the set)")
    b = r.beyond_training
    if b:
        notes.append(f"{100 * b:.0f} % of its samples beyond the training data's range")
    others = [float(t.rmse) for t in (held.per_trial or {}).values() if t is not r and t.rmse is not None]
    if others and r.rmse is not None and r.rmse > 5 * (sorted(others)[len(others) // 2]) and not notes:
        notes.append("error well above the other trials'")
    return "; ".join(notes) or "—"
