"""The verdict of a run: ``ok``, ``degraded`` or ``unusable``, with a short reason for each finding.

A run's numbers are only as good as what it can stand behind.  :func:`judge_run` reads the
run's own metrics (``metrics.json``) and states, from checks with fixed limits (d is the design
bound, 0.2 rad for most robots):

========================  ==========================================  ======================
check                     degraded when                               unusable when
========================  ==========================================  ======================
model (preflight)         the excitation LQR saturates (> 1× ctrl)    the actuators cannot hold
                          and, once the trials ran, more than half    |q_u^e| = d, or the EIC
                          of them fell (else a note)                  is unstable at upright
excitation trials         more than half fell                         all fell
derivatives               S[q̈] noise > 4 % of its std                 —
fit                       did not converge (max_iter, numerical)      —
learned vs model BEM      gain ∉ [0.95, 1.05], RMSE > 0.05 d or       gain ∉ [0.5, 2] or
over the design region    max > 0.2 d; band covers < 80 %             RMSE > 0.25 d
equilibrium (robot runs)  —                                           gravity's stiffness Γ_q < 0
                                                                      at the equilibrium held
                                                                      (stable without control)
support of the BEM        < 90 % of the queries x_0^e supported       t < 2, or t ≤ −5 (data
queries (S1, S2)          jointly (S1) and t of q_u's slope in        from a stable equilibrium)
                          q̈_u < 5 (S2)
data resolve the BEM      its spread over the data < 4 × the larger    < 2 × that scale
                          of band σ and the held-out trials' median
                          q_u error
held-out trials           < 80 % inside the predictive ±2σ            —
closed loop               learned BEM's loop diverged, or stayed up   learned BEM's loop fell
                          with |q_u − nominal| > 1.5 d (its reference
                          asks for d/2)
failed stage              —                                           a stage after training
                                                                      raised (``failed``)
torque logged on q_u      its rms moves the model's equilibrium by    —
                          more than 0.05 d (τ_rms > 0.05 k_g d);
                          without a model: reported (a note)
Lemma 1                   learned ΔΓ vs the model's ΔΓ = Ḣ_u + b_u q̇_u^e  —
                          correlation < 0.9 (a note instead where only
                          the damping part b_u q̇_u^e is off and its
                          error moves q_u along the reference by less
                          than the held-out q_u error, or where the
                          model's ΔΓ itself moves q_u by less than it)
========================  ==========================================  ======================

The status is the worst finding's; ``reasons`` lists one sentence per finding, worst first.  A
*note* (severity ``note``) is a finding the run reports without changing its status.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from bemlearn.pipeline.run_metrics import Lemma1Info, LoopMetrics, RunMetrics, Support
from bemlearn.pipeline.verdict_types import EXIT_DEGRADED_STRICT, EXIT_UNUSABLE, SEVERITY_RANK, Finding, Verdict

#: (S1), (S2) of :mod:`bemlearn.pipeline.data_evaluation` (kept here so reading a verdict needs no torch).
SUPPORT_OK_SHARE = 0.9
EXTRAPOLATION_T = 5.0

__all__ = ["Finding", "Verdict", "judge_run", "GAIN_RANGE", "EXIT_UNUSABLE", "EXIT_DEGRADED_STRICT"]

#: Targets of the learned vs model BEM over the design region (docs/verdict.md).
GAIN_RANGE = (0.95, 1.05)
RMSE_OF_BOUND = 0.05           # RMSE ≤ 0.05 d (0.01 rad at d = 0.2 rad)
MAX_OF_BOUND = 0.2             # max ≤ 0.2 d (0.04 rad)
BAND_COVERAGE_MIN = 0.8        # the exported ±2σ band holds at least 80 % of the model BEM
def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def judge_run(metrics: RunMetrics | Mapping[str, Any]) -> Verdict:
    """The verdict of a run from its metrics (entries a run lacks are not checked).

    Reads :class:`~bemlearn.pipeline.run_metrics.RunMetrics`: ``feasibility`` (model checks of
    :mod:`bemlearn.pipeline.feasibility`), ``data`` (trials, failed), ``dataset.derivative_choice``,
    ``fit``, ``bem_design_region`` (with its ``bound``), ``resolution``, ``closed_loop`` and
    ``closed_loop.predictor.lemma1``.  A mapping (a ``metrics.json`` read from a run folder) is read
    into a :class:`RunMetrics` once.
    """
    m = metrics if isinstance(metrics, RunMetrics) else RunMetrics.from_dict(metrics)
    notes = _Notes()
    for check in _CHECKS:
        check(m, notes)
    found = sorted(notes.found, key=lambda f: -SEVERITY_RANK[f.severity])
    status = max((f.severity for f in found), key=SEVERITY_RANK.__getitem__, default="ok")
    status = "ok" if SEVERITY_RANK[status] < 0 else status   # notes alone leave the run ok
    return Verdict(status, tuple(found), tuple(notes.checked))


@dataclass
class _Notes:
    """The checks made and the findings, in the order the checks ran."""

    checked: list[str] = field(default_factory=list)
    found: list[Finding] = field(default_factory=list)

    def add(self, sev: str, check: str, reason: str) -> None:
        self.found.append(Finding(sev, check, reason))


def _check_model(m: RunMetrics, notes: _Notes) -> None:
    """The preflight checks.  The excitation LQR's check predicts that the trials will saturate and fall; once
    the trials ran, their own fall count (:func:`_check_excitation`) decides, and the prediction is a note when
    at most half of them fell."""
    data = m.data
    ran = bool(data and data.collected and data.trials)
    for c in m.feasibility or ():
        notes.checked.append(f"model:{c.name}")
        if c.passed:
            continue
        if c.name == "excitation" and str(c.severity) == "degraded" and ran:
            assert data is not None and data.trials is not None
            n, f = int(data.trials), int(data.failed or 0)
            if f <= n / 2:
                notes.add("note", f"model:{c.name}", f"{c.text}; the trials ran and {f} of {n} fell (the excitation "
                          "check counts them)")
                continue
        notes.add(str(c.severity), f"model:{c.name}", str(c.text))


def _check_excitation(m: RunMetrics, notes: _Notes) -> None:
    data = m.data
    if data and data.collected and data.trials:
        notes.checked.append("excitation")
        n, f = int(data.trials), int(data.failed or 0)
        if f == n:
            notes.add("unusable", "excitation", f"all {n} excitation trials fell: no data from balanced motion")
        elif f > n / 2:
            notes.add("degraded", "excitation", f"{f} of {n} excitation trials fell: the data come mostly from falling trials")


def _check_derivatives(m: RunMetrics, notes: _Notes) -> None:
    choice = m.dataset.derivative_choice if m.dataset else None
    if choice:
        notes.checked.append("derivatives")
        noisy = {j: v for j, v in (choice.qdd_noise_fraction or {}).items() if v > 0.04}
        if noisy:
            notes.add("degraded", "derivatives", "the estimated accelerations are noise-dominated ("
                      + ", ".join(f"{j}: quantization noise {100 * v:.0f} % of q̈'s spread" for j, v in noisy.items())
                      + "): the learned slopes are attenuated; log at a higher rate or with a finer encoder")


def _check_fit(m: RunMetrics, notes: _Notes) -> None:
    fit = m.fit
    if fit:
        notes.checked.append("fit")
        stop = fit.stop_reason
        if stop == "max_iter":
            notes.add("degraded", "fit", f"the GP fit stopped at its iteration limit ({fit.steps} evaluations) before "
                      "converging: raise train.max_iter")
        elif stop not in (None, "converged"):
            notes.add("degraded", "fit", f"the GP fit ended by {stop}: its hyperparameters are the best found before that")


def _check_design_region(m: RunMetrics, notes: _Notes) -> None:
    dr = m.bem_design_region
    if not (dr and dr.n_points):
        return
    notes.checked.append("design_region")
    d, unit = float(dr.bound or math.nan), m.unit()
    gain, rmse, mx = dr.gain, dr.rmse, dr.max_abs
    bad = []
    if _finite(gain) and not GAIN_RANGE[0] <= gain <= GAIN_RANGE[1]:  # type: ignore[operator]  # _finite: a number
        bad.append(f"gain {gain:.3f} (target {GAIN_RANGE[0]}–{GAIN_RANGE[1]})")
    if _finite(rmse) and rmse > RMSE_OF_BOUND * d:  # type: ignore[operator]
        bad.append(f"RMSE {rmse:.4f} {unit} (target ≤ {RMSE_OF_BOUND * d:.3g})")
    if _finite(mx) and mx > MAX_OF_BOUND * d:  # type: ignore[operator]
        bad.append(f"max {mx:.4f} {unit} (target ≤ {MAX_OF_BOUND * d:.3g})")
    if bad:
        severe = (_finite(gain) and not 0.5 <= gain <= 2.0) or (_finite(rmse) and rmse > 0.25 * d)  # type: ignore[operator]
        notes.add("unusable" if severe else "degraded", "design_region",
                  f"learned vs model BEM over |q_u^e| ≤ {d:g} {unit}: " + ", ".join(bad))
    cov = dr.coverage_2sigma_band
    if _finite(cov) and cov < BAND_COVERAGE_MIN:  # type: ignore[operator]
        notes.add("degraded", "band", f"the exported ±2σ band holds only {100 * cov:.0f} % of the model BEM over the design region")  # type: ignore[operator]


def _check_resolution(m: RunMetrics, notes: _Notes) -> None:
    res, held = m.resolution, m.data_heldout
    if not (res and _finite(res.spread)):
        return
    spread = float(res.spread)  # type: ignore[arg-type]  # _finite
    notes.checked.append("resolution")
    # the uncertainty the data leave on the BEM: the exported band's σ, or, if larger, the error of f on
    # trials the fit never saw (median over them; a fit that memorises its trials has a small band)
    scale, what = float(res.band_std if res.band_std is not None else math.nan), "its band's σ"
    per = [float(t.rmse) for t in ((held.per_trial if held else None) or {}).values() if _finite(t.rmse)]  # type: ignore[arg-type]
    if per:
        med = sorted(per)[len(per) // 2] if len(per) % 2 else 0.5 * sum(sorted(per)[len(per) // 2 - 1:len(per) // 2 + 1])
        if med > scale:
            scale, what = med, "the held-out trials' median q_u error"
    r = spread / scale if scale > 0 else math.inf
    if r < 4.0:
        unit = res.unit or "rad"
        text = (f"the data {'do not' if r < 2 else 'barely'} resolve the BEM: over the data's actuated motions it varies by "
                f"{spread:.3g} {unit} (std), {r:.1f}× {what} ({scale:.3g} {unit})")
        weak = [(w, 2 * scale / w.share) for w in res.inputs or () if w.share]
        weak = [(w, f) for w, f in weak if f > 1.0][:3]
        if _lockstep(m):      # more of the same motion cannot separate inputs that move together
            text += ("; more amplitude of the same motion cannot help while the inputs move in lockstep: a reference motion "
                     "that changes their ratio can (`bemlearn excite CONFIG`)")
        elif weak:
            text += "; at the learned slopes, " + ", ".join(
                f"{w.input} (±{w.amplitude:.3g} {w.unit} in the data) would need about {f:.1f}× that amplitude"
                for w, f in weak) + " to move the BEM by more than ±2× that uncertainty"
        notes.add("unusable" if r < 2 else "degraded", "resolution", text)


def _support_sentence(sup: Support) -> str:
    """Which inputs move together, and where the BEM queries have no training sample near them."""
    qdd_u = sup.qdd_u or ""
    pairs = sorted(sup.pairs or (), key=lambda p: (p.input != qdd_u, -abs(p.corr or 0.0)))
    text = ""
    if pairs:
        p = pairs[0]
        text = f"{p.input} ≈ {p.ratio:+.3g}·{p.with_} (corr {p.corr:+.3f})"
    where = ""
    if pairs:
        inp = next((i for i in sup.inputs or () if i.input == pairs[0].with_), None)
        if inp and inp.reach is not None and inp.data is not None:
            hi = max(abs(inp.data[0]), abs(inp.data[1]))
            where = (f"no training sample near {pairs[0].input} = 0 beyond |{inp.input}| ≈ {inp.reach:.3g} {inp.unit} "
                     f"(the data reach ±{hi:.3g})")
    share = float(sup.share if sup.share is not None else math.nan)
    head = f"{100 * (1 - share):.0f} % of the BEM queries (q̈_u = q̇_u = 0 at the data's actuated motions) lie beyond the training data jointly" \
        if _finite(share) else "the BEM queries lie beyond the training data jointly"
    return "; ".join(t for t in (text, head + (f": {where}" if where else "")) if t)


def _check_support(m: RunMetrics, notes: _Notes) -> None:
    """Joint support of the BEM queries (docs/verdict.md, (S1) and (S2) of bemlearn.pipeline.data_evaluation)."""
    sup = m.support
    if not (sup and _finite(sup.share)):
        return
    notes.checked.append("support")
    t = sup.t
    if not _finite(t):
        return
    assert t is not None and sup.share is not None   # _finite
    if t <= -EXTRAPOLATION_T:
        notes.add("unusable", "support", f"the data were taken about an equilibrium that is stable without control: q_u rises "
                  f"as {sup.qdd_u} falls (slope {sup.slope:.3g}, t = {t:.1f}; an upright that needs balancing gives a "
                  "positive slope 1/λ²): this is not a balanced upright, and no BEM of one can be learned from it")
        return
    if sup.share >= SUPPORT_OK_SHARE or t >= EXTRAPOLATION_T:
        return
    sev = "unusable" if t < 2.0 else "degraded"
    notes.add(sev, "support", _support_sentence(sup) + f"; and the data do not resolve how q_u depends on {sup.qdd_u} apart "
              f"from the actuated inputs (t = {t:.1f}, need ≥ {EXTRAPOLATION_T:g}): the BEM there is extrapolation the data "
              "cannot check. More amplitude along the same line cannot help; a motion of the actuated reference that changes "
              "that ratio can: play the schedule `bemlearn excite CONFIG` writes during balance and log again")


def _lockstep(m: RunMetrics) -> bool:
    """The inputs move together (|corr| ≥ 0.9 between an unactuated and an actuated input) and (S2) does not
    resolve q_u's dependence on q̈_u apart from them: more of the same motion cannot separate them."""
    sup = m.support
    if sup is None:
        return False
    together = any(abs(p.corr or 0.0) >= 0.9 for p in sup.pairs or ())
    return together and _finite(sup.t) and sup.t < EXTRAPOLATION_T  # type: ignore[operator]  # _finite


def _check_equilibrium(m: RunMetrics, notes: _Notes) -> None:
    """An equilibrium that is stable without control is never reported as balanced (its gravity stiffness Γ_q < 0)."""
    eq = m.equilibrium
    if not (eq and _finite(eq.gravity_stiffness)):
        return
    notes.checked.append("equilibrium")
    if eq.stable_without_control:
        qu = eq.qu if eq.qu is not None else math.nan
        notes.add("unusable", "equilibrium", f"the equilibrium the run held ({eq.joint or 'q_u'} = {qu:.4g} "
                  f"{eq.unit or 'rad'}) is stable without control: gravity's stiffness there Γ_q = −∂Γ₀/∂q_u = "
                  f"{eq.gravity_stiffness:.3g} < 0 (eq. 5 linearised), so it is a hanging branch, not the upright; "
                  "nothing was balanced and the learned BEM is not the upright's")


def _check_heldout(m: RunMetrics, notes: _Notes) -> None:
    held = m.data_heldout
    if held and _finite(held.coverage):
        notes.checked.append("heldout")
        cov = float(held.coverage)  # type: ignore[arg-type]  # _finite
        if cov < 0.8:
            notes.add("degraded", "heldout", f"only {100 * cov:.0f} % of the held-out trials' q_u lie inside the predictive "
                      "±2σ: the GP is overconfident away from its training trials")


def _bem_right_along_loop(m: RunMetrics, p: LoopMetrics, mdl: LoopMetrics) -> bool:
    """Both loops stayed up and left the reference, and along the learned loop's own BEM inputs the learned BEM is
    within the design region's targets of the model BEM (RMSE ≤ :data:`RMSE_OF_BOUND` d, max ≤ :data:`MAX_OF_BOUND` d,
    d the design bound): the EIC's tracking on this robot, not the learned BEM, is what falls short.

    The loops' tracking figures are not compared: where the EIC cannot track the reference with the exact BEM, the
    tracking error of a loop is sensitive to any small change of its BEM (measured: a two-link arm with a pole whose
    learned BEM is within 0.0035 rad of the model's along its loop, 100 % inside its ±2σ band, tracks with RMSE 0.091
    against the model BEM loop's 0.072; a two-link arm with joint friction: 0.0354 learned vs 0.0357 model)."""
    if not (mdl.diverged and not mdl.fell):
        return False
    d = float(m.bem_design_region.bound or math.nan) if m.bem_design_region else math.nan
    rmse, mx = p.bem_vs_model_rmse, p.bem_vs_model_max
    return (_finite(d) and _finite(rmse) and _finite(mx)
            and rmse <= RMSE_OF_BOUND * d and mx <= MAX_OF_BOUND * d)  # type: ignore[operator]  # _finite


def _off_along_loop(p: LoopMetrics) -> str:
    if _finite(p.bem_vs_model_rmse) and _finite(p.bem_vs_model_max):
        return (f" (so did the model BEM's; along the loop the learned BEM is off the model's by RMSE "
                f"{p.bem_vs_model_rmse:.3g}, max {p.bem_vs_model_max:.3g}: beyond the design region's targets)")
    return " (so did the model BEM's; the learned BEM along the loop was not compared with the model's)"


def _check_closed_loop(m: RunMetrics, notes: _Notes) -> None:
    loops = m.closed_loop or {}
    if "predictor" not in loops:
        return
    notes.checked.append("closed_loop")
    p, mdl = loops["predictor"], loops.get("model") or LoopMetrics()
    if p.fell:
        dur = p.duration_s if p.duration_s is not None else math.nan
        notes.add("unusable", "closed_loop", f"the closed loop with the learned BEM fell at {dur:.2f} s"
                  + (" (so did the model BEM's: the EIC cannot balance this robot with these gains)" if mdl.fell else ""))
    elif p.diverged and not _bem_right_along_loop(m, p, mdl):
        stable = bool(m.equilibrium and m.equilibrium.stable_without_control)
        notes.add("degraded", "closed_loop", "the closed loop with the learned BEM " + ("kept q_u near its stable equilibrium"
                  if stable else "stayed up") + " but its actuated joints left the reference"
                  + (_off_along_loop(p) if mdl.diverged and not mdl.fell else ""))
    else:
        if p.diverged:
            notes.add("note", "closed_loop", f"the EIC with these gains tracks this reference poorly with the model BEM too "
                      f"(tracking max {p.tracking_max:.3g} learned, {mdl.tracking_max:.3g} model, over twice the reference's "
                      f"peak): a limit of the controller on this robot (for example dry friction's limit cycle), not of the learned "
                      f"BEM, which stays within {p.bem_vs_model_max:.3g} {m.unit()} of the model BEM along its loop")
        raw_bound = m.bem_design_region.bound if m.bem_design_region else None
        bound = float(raw_bound) if _finite(raw_bound) else math.nan  # type: ignore[arg-type]
        dev = float(p.qu_dev_max) if _finite(p.qu_dev_max) else math.nan  # type: ignore[arg-type]
        if dev > 1.5 * bound:   # False when either is NaN
            unit = m.unit()
            mdev = mdl.qu_dev_max
            notes.add("degraded", "closed_loop", f"the closed loop with the learned BEM stayed up, but q_u strayed {dev:.3g} {unit} from "
                      f"the upright, {dev / bound:.1f}× the design bound {bound:g} {unit} (its reference asks for about half the bound): "
                      "it barely holds" + (f" (so did the model BEM's, {mdev:.3g} {unit}: the EIC with these gains barely holds this robot)"
                                           if _finite(mdev) and mdev > 1.5 * bound else ""))  # type: ignore[operator]
    lem = p.lemma1
    if lem and _finite(lem.r_learned_vs_model_delta_gamma):
        notes.checked.append("lemma1")
        r = float(lem.r_learned_vs_model_delta_gamma)  # type: ignore[arg-type]  # _finite
        if r < LEMMA1_R_MIN:
            _lemma1_finding(m, lem, r, notes)


#: The correlation of the learned ΔΓ with the model's ΔΓ = Ḣ_u + b_u q̇_u^e below which Lemma 1 (eq. 10) fails.
LEMMA1_R_MIN = 0.9


def _lemma1_finding(m: RunMetrics, lem: Lemma1Info, r: float, notes: _Notes) -> None:
    """Lemma 1's finding at correlation ``r`` < :data:`LEMMA1_R_MIN` (:mod:`bemlearn.pipeline.lemma`).

    Where the model's ΔΓ itself moves q_u along the reference by less than the learned map's held-out q_u error ε
    (``delta_gamma_qu`` < ε), the learned ΔΓ is a difference below the map's accuracy and its correlation does not
    test the lemma: a note, which says so.

    The learned ΔΓ ≈ a Ḣ_u + b (b_u q̇_u^e).  Where the rest holds once the damping part is the model's
    (``r_model_damping`` ≥ the bound) and the damping part's error moves q_u along the reference by less than the
    learned map's held-out q_u error (|b − 1| · ``damping_qu`` < ε), the data cannot show the unactuated joint's
    damping at the map's accuracy: a note, which names it.  Otherwise the learned map contradicts Lemma 1: degraded.
    """
    a, b = lem.hdot_coefficient, lem.damping_coefficient
    r_md, dqu = lem.r_model_damping, lem.damping_qu
    held = m.data_heldout
    eps = float(held.rmse) if held is not None and _finite(held.rmse) else math.nan  # type: ignore[arg-type]
    unit = m.unit()
    split = (f" (split ΔΓ_learned ≈ {float(a):.3g} Ḣ_u {'−' if float(b) < 0 else '+'} {abs(float(b)):.3g} b_u q̇_u^e)"  # type: ignore[arg-type]
             if _finite(a) and _finite(b) else "")
    dgq = lem.delta_gamma_qu
    if _finite(dgq) and float(dgq) < eps:  # type: ignore[arg-type]  # False when eps is NaN
        notes.add("note", "lemma1", f"Lemma 1 (eq. 10): the learned ΔΓ correlates with the model's ΔΓ = Ḣ_u + b_u q̇_u^e at "
                  f"r = {r:.2f}{split}, but along this reference the zero dynamics move q_u by {float(dgq):.2g} {unit} "  # type: ignore[arg-type]
                  f"from the BEM at rest, below the learned map's held-out q_u error ({eps:.2g} {unit}): the map does not "
                  "resolve ΔΓ here, and the correlation does not test the lemma")
        return
    if _finite(b) and _finite(r_md) and _finite(dqu) and float(r_md) >= LEMMA1_R_MIN:  # type: ignore[arg-type]
        moved = abs(float(b) - 1.0) * float(dqu)  # type: ignore[arg-type]
        if moved < eps:   # False when eps is NaN
            notes.add("note", "lemma1", f"Lemma 1 (eq. 10): the learned ΔΓ correlates with the model's ΔΓ = Ḣ_u + b_u q̇_u^e at "
                      f"r = {r:.2f}{split}; with the model's damping part it is r = {float(r_md):.2f}.  The learned map's "  # type: ignore[arg-type]
                      f"slope in q̇_u gives the damping part, whose error moves q_u along the reference by {moved:.2g} {unit}, "
                      f"below the map's held-out q_u error ({eps:.2g} {unit}): the data do not show the unactuated joint's "
                      "damping at this accuracy (it does not enter the BEM, where q̇_u = 0)")
            return
    notes.add("degraded", "lemma1", f"Lemma 1 (eq. 10) does not hold for the learned BEM: its ΔΓ correlates with the model's "
              f"ΔΓ = Ḣ_u + b_u q̇_u^e at r = {r:.2f}{split}")


def _check_failed(m: RunMetrics, notes: _Notes) -> None:
    failed = m.failed
    if failed is not None:
        notes.checked.append("failed")
        what = f"{failed.error_type or 'error'}: {failed.error or ''}".rstrip(": ")
        notes.add("unusable", "failed", f"the run failed at stage '{failed.stage}' ({what}): the stages after it did not "
                  f"run and its numbers are incomplete; the run folder keeps {', '.join(failed.kept or [])}")


def _check_unactuated_torque(m: RunMetrics, notes: _Notes) -> None:
    tq = m.unactuated_torque
    if not (tq is not None and _finite(tq.rms)):
        return
    notes.checked.append("unactuated_torque")
    rms = float(tq.rms)  # type: ignore[arg-type]  # _finite
    if rms == 0:
        return
    unit = tq.unit or "N·m"
    mean = tq.mean if tq.mean is not None else math.nan
    text = (f"the unactuated joint {tq.joint} carries a logged {'force' if unit == 'N' else 'torque'} of "
            f"{rms:.3g} {unit} rms (mean {mean:.3g}): the BEM assumes it unactuated (Γ_u = 0, eq. 2), "
            "so the learned map mixes it in")
    shift, target = tq.shift_rms, tq.target
    if _finite(shift) and _finite(target):
        q_unit = m.unit()
        big = float(shift) > float(target)  # type: ignore[arg-type]  # _finite checked both
        gscale = float(tq.gravity_scale) if tq.gravity_scale is not None else math.nan
        text += (f"; against the model's gravity stiffness {tq.stiffness:.3g} {tq.stiffness_unit or ''} it moves the "
                 f"equilibrium by {shift:.3g} {q_unit} rms, {'more' if big else 'less'} than the accuracy target "
                 f"{target:.3g} {q_unit} (0.05 d; {100 * rms / gscale:.2g} % of the gravity torque "
                 f"{gscale:.3g} {unit} at d)")
        if big:
            text += ": log without it (friction compensation off) or subtract its effect before learning"
        notes.add("degraded" if big else "note", "unactuated_torque", text)
    else:
        notes.add("note", "unactuated_torque", text + "; with no model it cannot be weighed against gravity (name the "
                  "robot's MJCF under model: to have it judged)")


#: The checks of the module docstring's table, in the order their findings are listed (before sorting by severity).
_CHECKS = (_check_failed, _check_model, _check_equilibrium, _check_excitation, _check_derivatives, _check_fit, _check_support,
           _check_design_region, _check_resolution, _check_heldout, _check_closed_loop, _check_unactuated_torque)
