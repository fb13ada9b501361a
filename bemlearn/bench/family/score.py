"""Scoring a family run against its oracle (docs/family.md): the learned BEM vs the oracle's, balance at the true
upright, whether a non-ok verdict's first reason is true, and the per-feature table of issue 28."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bemlearn.pipeline.run_metrics import RunMetrics

__all__ = ["FEATURES", "compare_predictor", "compare_module", "balanced_at_upright", "judge_reason", "score_run", "feature_table", "format_table", "unscored_note"]

#: issue 28's bar for a right learned BEM over the design region (rad for the family's hinge q_u)
RMSE_MAX, MAX_MAX, GAIN_RANGE = 0.01, 0.04, (0.95, 1.05)
#: how far (rad) the closed loop's q_u may stray from the true upright and still count as balanced there
BALANCE_TOL = 0.3
#: features of the table, in the issue's order
FEATURES = ("actuator_kind", "friction", "m", "upright_at", "zero_by", "angle")


#: design-region queries of the oracle per robot: as many as the run's own check draws (``design_grid``'s 4096 Sobol
#: points), so that the two maxima, each a lower bound of the region's sup, are estimated with the same power
N_QUERIES = 4096


def compare_predictor(predictor_path: str | Path, xml: str, truth: dict, *, n_queries: int = N_QUERIES, seed: int = 0,
                      probe: Mapping[str, Any] | None = None, refine: bool = True) -> dict:
    """Learned BEM (the run's exported predictor, loaded with bemlearn's loader) vs the oracle's on design-region queries.

    Queries: :meth:`Oracle.design_queries` (q̇_u = q̈_u = 0 by construction of the BEM; |q_u^e − q_u*| ≤ 0.2).
    ``probe``: the run's own worst design-region point (``{"names": actuated names, "x0e": [q̈_a, q̇_a, q_a]}``, from
    ``metrics.json`` ``bem_design_region.worst``).  Moved into the oracle's box (:meth:`Oracle.clip_to_box`) and kept
    where the oracle's BEM there is within the bound, it is one more query: the run's claim about its largest error is
    checked where the oracle's random queries may not have looked (``probe_error``: the error there, NaN if not kept).
    Errors are wrapped into (−π, π] (a predictor on another 2π sheet is not penalised for it).  ``gain`` is the
    least-squares slope (with intercept) of learned − q_u* on oracle − q_u*.

    ``band_coverage`` is the share of the oracle BEM inside the exported ±2σ band (the predictor's ``forward``: mean and
    calibrated σ), which judges a run's ``band`` reason.

    ``max_abs`` is refined as the run's own check refines its max (``refine``; (D3) of
    :mod:`bemlearn.pipeline.design_evaluation`): a compass search of the error in the oracle's box from the queries'
    :data:`~bemlearn.pipeline.design_evaluation.REFINE_STARTS` worst points, over motions whose oracle BEM stays within
    the bound (``max_sampled``: the queries' max alone).  A random sample's max is a lower bound of the region's sup,
    loose in 3m dimensions; both maxima are now estimates of the sup, the oracle's over its own box.

    Returns: ``{"rmse", "max_abs", "gain", "intercept", "n_queries", "learned_at_rest_minus_upright", "band_coverage"}``
    (rad; ``band_coverage`` a share).
    """
    from bemlearn.export.torchscript import load_torchscript

    return compare_module(load_torchscript(predictor_path), xml, truth, n_queries=n_queries, seed=seed, probe=probe,
                          refine=refine, where=str(predictor_path))


def compare_module(module: Any, xml: str, truth: dict, *, n_queries: int = N_QUERIES, seed: int = 0,
                   probe: Mapping[str, Any] | None = None, refine: bool = True, where: str = "predictor") -> dict:
    """:func:`compare_predictor` on a loaded predictor: any object with the exported predictor's ``forward``
    (``module(x) -> (mean, std)`` for x = [q̈_a, q̇_a, q_a] ``(B, 3m)`` float64), ``bem_mean(x)`` and
    ``metadata()`` (JSON naming ``actuated_names``), e.g. a posterior fitted in memory.  ``where`` names it in errors.
    """
    import torch

    from bemlearn.bench.family.oracle import Oracle, wrap_angle
    from bemlearn.errors import CheckpointError

    oracle = Oracle(xml, qu_upright=truth["qu_upright"])
    q = oracle.design_queries(n_queries, seed=seed)
    n_random = len(q["bem"])
    if probe is not None:
        q = _with_probe(oracle, q, probe, truth["actuated_joints"])
    meta = json.loads(module.metadata())
    names = list(meta["actuated_names"])
    if sorted(names) != sorted(truth["actuated_joints"]):
        raise CheckpointError(f"{where}: actuated inputs {names}, the robot's actuated joints are {truth['actuated_joints']}")
    order = [truth["actuated_joints"].index(n) for n in names]
    x = np.concatenate([q["qdda"][:, order], q["qda"][:, order], q["qa"][:, order]], axis=1)
    with torch.no_grad():
        learned, band = (v.numpy() for v in module(torch.from_numpy(np.ascontiguousarray(x, dtype=np.float64))))
        z = np.zeros((1, 3 * len(names)))
        z[0, 2 * len(names):] = np.asarray(truth["qa_rest"])[order]
        at_rest = float(module.bem_mean(torch.from_numpy(z)).numpy()[0])
    qs = truth["qu_upright"]
    err = wrap_angle(learned - q["bem"])
    xo = wrap_angle(q["bem"] - qs)
    yl = wrap_angle(learned - qs)
    gain, icpt = (np.polyfit(xo, yl, 1) if xo.size > 2 and np.ptp(xo) > 0 else (float("nan"), float("nan")))
    sampled = float(np.abs(err).max()) if err.size else float("nan")
    refined = _refined_max(oracle, module, order, q, np.abs(err)) if refine and err.size else sampled
    return {"rmse": float(np.sqrt(np.mean(err**2))), "max_abs": max(sampled, refined), "max_sampled": sampled, "gain": float(gain),
            "intercept": float(icpt), "n_queries": int(err.size), "learned_at_rest_minus_upright": float(wrap_angle(at_rest - qs)),
            "band_coverage": float(np.mean(np.abs(err) <= 2 * band)) if err.size else float("nan"),
            "probe_error": float(abs(err[-1])) if err.size > n_random else float("nan")}


def _refined_max(oracle, module, order: list[int], q: dict, abs_err: np.ndarray) -> float:
    """The largest |learned − oracle BEM| a compass search finds in the oracle's box from the worst queries (D3)."""
    import torch

    from bemlearn.bench.family.oracle import DESIGN_BOUND, wrap_angle
    from bemlearn.pipeline.design_evaluation import REFINE_STARTS, pattern_search_max

    lo, hi, vel, acc = oracle._box()
    centre, half = np.concatenate([np.zeros_like(acc), np.zeros_like(vel), (lo + hi) / 2]), np.concatenate([acc, vel, (hi - lo) / 2])
    m = len(lo)

    def error(u: np.ndarray) -> np.ndarray:
        x = centre + u * half                                        # (B, 3m) [q̈_a, q̇_a, q_a] in the oracle's joint order
        qu = oracle.bem(x[:, 2 * m:], x[:, m:2 * m], x[:, :m])
        ok = np.isfinite(qu) & (np.abs(qu - oracle.qu_star) <= DESIGN_BOUND)
        xp = np.concatenate([x[:, :m][:, order], x[:, m:2 * m][:, order], x[:, 2 * m:][:, order]], axis=1)
        with torch.no_grad():
            learned = module.bem_mean(torch.from_numpy(np.ascontiguousarray(xp, dtype=np.float64))).numpy()
        return np.where(ok, np.abs(wrap_angle(learned - np.where(ok, qu, 0.0))), -1.0)

    x_all = np.concatenate([q["qdda"], q["qda"], q["qa"]], axis=1)
    starts = np.argsort(-abs_err)[:REFINE_STARTS]
    live = half > 0
    u0 = np.where(live, (x_all[starts] - centre) / np.where(live, half, 1.0), 0.0)
    _, best, _ = pattern_search_max(error, np.clip(u0, -1.0, 1.0), abs_err[starts], live=live)
    return float(best.max())


def _with_probe(oracle: Any, q: dict, probe: Mapping[str, Any], joints: list[str]) -> dict:
    """``q`` with the run's worst point appended (:func:`compare_predictor`), in the oracle's joint order."""
    from bemlearn.bench.family.oracle import DESIGN_BOUND

    names = list(probe["names"])
    x = np.asarray(probe["x0e"], dtype=np.float64)
    m = len(joints)
    if sorted(names) != sorted(joints) or x.shape != (3 * m,):
        return q
    order = [names.index(j) for j in joints]
    qdd, qd, qa = (x[k * m:(k + 1) * m][order] for k in range(3))
    qa, qd, qdd = oracle.clip_to_box(qa, qd, qdd)
    bem = oracle.bem(qa[None], qd[None], qdd[None])
    if not (np.isfinite(bem[0]) and abs(bem[0] - oracle.qu_star) <= DESIGN_BOUND):
        return q
    return {"qa": np.vstack([q["qa"], qa]), "qda": np.vstack([q["qda"], qd]), "qdda": np.vstack([q["qdda"], qdd]),
            "bem": np.concatenate([q["bem"], bem])}


def balanced_at_upright(metrics: RunMetrics | Mapping[str, Any], qu_upright: float) -> tuple[bool | None, str]:
    """Whether the run's closed loop with the learned BEM stayed up at the *true* upright.

    ``closed_loop.predictor.qu_max`` is max |q_u| over the loop in the robot's coordinates (MuJoCo's qpos;
    ``bemlearn/sim/closed_loop.py``).  A loop that did not fall balanced at q_u* only if that maximum is
    consistent with staying within ``BALANCE_TOL`` of q_u*: | qu_max − |q_u*| | ≤ BALANCE_TOL (at q_u* = 0:
    qu_max ≤ BALANCE_TOL).  How well the actuated joints tracked their reference is not part of it (the target asks
    where the robot was balanced; a loop that stayed up while its arm left the reference is named in the note, and the
    run's verdict judges the tracking against the model BEM's loop).  ``None`` when the run has no closed loop of the
    predictor.  A mapping (a run's ``metrics.json``) is read into :class:`~bemlearn.pipeline.run_metrics.RunMetrics` once.
    """
    m = metrics if isinstance(metrics, RunMetrics) else RunMetrics.from_dict(metrics)
    cl = (m.closed_loop or {}).get("predictor")
    if not cl:
        return None, "no closed loop with the learned BEM"
    if cl.fell:
        return False, "the learned-BEM loop fell"
    drift = " (its actuated joints left the reference)" if cl.diverged else ""
    qmax = cl.qu_max
    if qmax is None or not np.isfinite(qmax):
        return None, "closed loop without qu_max"
    a = abs(qu_upright)
    if (a < 1e-9 and qmax <= BALANCE_TOL) or (a >= 1e-9 and abs(qmax - a) <= BALANCE_TOL):
        return True, f"stayed up at q_u* = {qu_upright:.3f} (max |q_u| {qmax:.3f}){drift}"
    return False, f"stayed up away from the upright: max |q_u| = {qmax:.3f} rad, q_u* = {qu_upright:.3f} rad{drift}"


#: words of a verdict reason that claim the robot cannot be held, or that the learned BEM / data are at fault
#: (used when the verdict carries no finding keys)
_HOLD_WORDS = ("cannot be balanced", "cannot hold", "can not be balanced", "infeasible", "not feasible", "beyond the actuator",
               "exceeds the actuator", "outside the actuator", "limits cannot")
_LEARN_WORDS = ("held-out", "heldout", "rmse", "slope", "resolve", "coverage", "extrapolat", "not supported", "correlat",
                "gain", "flat", "design region", "lengthscale", "too few", "fewer than")
_FALL_WORDS = ("fell", "fall", "diverged")
#: the verdict's finding keys (bemlearn/pipeline/verdict.py) by what they claim
_LEARN_CHECKS = ("design_region", "resolution", "heldout", "band", "derivatives", "fit", "lemma1", "coverage", "support")


#: words by which a reason says the learned BEM or the loop sits at the wrong equilibrium
_BRANCH_WORDS = ("upright", "hanging", "branch", "stable equilibrium", "stable without control")
#: |learned BEM at rest − q_u*| (rad) beyond which the learned BEM is on another equilibrium branch
OFF_BRANCH = 0.5


def judge_reason(reason: str, *, holdable: bool, bem_right: bool | None, check: str = "",
                 off_branch: bool = False, band_coverage: float | None = None) -> tuple[bool | None, str]:
    """Is a non-ok verdict's first reason true by the oracle?  ``(None, why)`` where it cannot be judged.

    By the first finding's key (``check``) when there is one, else by the reason's words:

    * ``model:*`` (the model says the robot cannot be held / balanced) — true iff the oracle cannot hold it;
    * ``excitation`` (excitation trials fell) — true iff the oracle cannot hold it (a holdable robot whose
      excitation falls is the pipeline's failure);
    * ``closed_loop`` (the learned-BEM loop fell or wandered) — true iff the oracle cannot hold it or the learned
      BEM is off;
    * the learned BEM's own checks (design region, resolution, held-out, band, derivatives, fit, Lemma 1) — true iff
      the comparison with the oracle fails; when the learned BEM sits on another equilibrium (``off_branch``: its
      value at rest more than :data:`OFF_BRANCH` from q_u*), only a reason that says so (upright, hanging, branch,
      stable equilibrium) is true — "max 0.044 rad against the model" about a BEM π away names the wrong cause;
    * ``band`` (the exported ±2σ band holds too little of the model BEM) — true iff the band holds less than
      :data:`~bemlearn.pipeline.verdict.BAND_COVERAGE_MIN` of the oracle BEM (``band_coverage``): the reason is about
      the band, which can be too narrow around a right mean (else judged as the learned BEM's other checks).
    """
    c = check.lower()
    r = reason.lower()
    if off_branch and not c.startswith("model:") and c not in ("excitation",):
        return any(w in r for w in _BRANCH_WORDS), "the learned BEM is on another branch: true only if the reason says so"
    if c == "band" and band_coverage is not None and np.isfinite(band_coverage):
        from bemlearn.pipeline.verdict import BAND_COVERAGE_MIN

        return bool(band_coverage < BAND_COVERAGE_MIN), f"{check}: the band's coverage of the oracle BEM ({100 * band_coverage:.0f} %)"
    if c.startswith("model:"):
        return (not holdable), f"{check}: the model says it cannot be held"
    if c == "excitation":
        return (not holdable), f"{check}: blames falls during excitation"
    if c == "closed_loop":
        return ((not holdable) or (bem_right is False)), f"{check}: the learned-BEM loop"
    if c and any(c.startswith(k) for k in _LEARN_CHECKS):
        return (None if bem_right is None else not bem_right), f"{check}: claims the learned BEM is unresolved or off"
    if any(w in r for w in _HOLD_WORDS):
        return (not holdable), "claims it cannot be held"
    if any(w in r for w in _FALL_WORDS):
        return (not holdable), "blames falls"
    if any(w in r for w in _LEARN_WORDS):
        return (None if bem_right is None else not bem_right), "claims the learned BEM is unresolved or off"
    return None, f"not judged ({check or 'no key'})"


def score_run(run_dir: Path, xml: str, truth: dict, record: dict) -> dict:
    """One row of results: the run's verdict and closed loop, its learned BEM vs the oracle, the judgements."""
    row: dict = {"name": truth["name"], "topology": truth["topology"], **{f: truth["features"][f] for f in FEATURES},
                 "qu_upright": truth["qu_upright"], "holdable": bool(truth["holdable"]), "hold_reason": truth["hold"]["reason"],
                 "exit_code": record.get("exit_code"), "wall_s": record.get("wall_s"), "commit": record.get("commit")}
    mpath = run_dir / "metrics.json"
    metrics = RunMetrics.from_dict(json.loads(mpath.read_text()) if mpath.is_file() else {})
    verdict = metrics.verdict
    # no verdict: exit 2 is a named error (BemlearnError, one line), anything else a crash (traceback, timeout)
    code = record.get("exit_code")
    row["verdict"] = (verdict.status if verdict else None) or ("none" if code in (0, 3, 4) else "error" if code == 2 else "crash")
    row["first_reason"] = verdict.findings[0].reason if verdict and verdict.findings else ""
    row["first_check"] = verdict.findings[0].check if verdict and verdict.findings else ""
    if row["verdict"] in ("error", "crash"):
        row["first_reason"] = record.get("error_tail", "")
    pred = run_dir / "bem_predictor.pt"
    row.update({"rmse": None, "max_abs": None, "gain": None, "learned_at_rest_minus_upright": None, "band_coverage": None})
    if pred.is_file():
        try:
            worst = (metrics.bem_design_region.worst if metrics.bem_design_region else None) or {}
            x0e = worst.get("x0e")
            probe = {"names": list(metrics.actuated), "x0e": list(x0e)} if x0e is not None and metrics.actuated else None
            row.update(compare_predictor(pred, xml, truth, probe=probe))
        except Exception as exc:  # noqa: BLE001 - recorded: a predictor the bench cannot score is a finding, not a crash
            row["compare_error"] = f"{type(exc).__name__}: {exc}"
    bal, why = balanced_at_upright(metrics, truth["qu_upright"])
    row["balanced_at_upright"], row["balance_note"] = bal, why
    bem_right = None if row["rmse"] is None else bool(row["rmse"] <= RMSE_MAX and row["max_abs"] <= MAX_MAX
                                                      and GAIN_RANGE[0] <= row["gain"] <= GAIN_RANGE[1])
    row["bem_right"] = bem_right
    row["right"] = bool(row["verdict"] == "ok" and bem_right and bal)
    row["false_ok"] = bool(row["verdict"] == "ok" and not (bem_right and bal))
    if row["verdict"] not in ("ok",):
        off = row["learned_at_rest_minus_upright"] is not None and abs(row["learned_at_rest_minus_upright"]) > OFF_BRANCH
        row["reason_true"], row["reason_judged_as"] = judge_reason(row["first_reason"] or "", holdable=row["holdable"],
                                                                   bem_right=bem_right, check=row["first_check"], off_branch=off,
                                                                   band_coverage=row.get("band_coverage"))
        if row["verdict"] in ("error", "crash", "none"):
            row["reason_true"], row["reason_judged_as"] = False, f"{row['verdict']}: no verdict"
    else:
        row["reason_true"], row["reason_judged_as"] = None, ""
    return row


def _median(v: list) -> float | None:
    v = [x for x in v if x is not None and np.isfinite(x)]
    return float(np.median(v)) if v else None


def feature_table(rows: list[dict]) -> list[dict]:
    """Per feature value: count, holdable, ok-and-right rate among holdable, false ok, median RMSE and gain,
    first reason true (judged / non-ok)."""
    out = []
    groups: list[tuple[str, str, list[dict]]] = [("all", "", rows)]
    for f in FEATURES:
        for val in sorted({str(r[f]) for r in rows}):
            groups.append((f, val, [r for r in rows if str(r[f]) == val]))
    for f, val, rs in groups:
        hold = [r for r in rs if r["holdable"]]
        nonok = [r for r in rs if r["verdict"] != "ok"]
        judged = [r for r in nonok if r["reason_true"] is not None]
        out.append({"feature": f, "value": val, "count": len(rs), "holdable": len(hold),
                    "ok_right": sum(r["right"] for r in hold), "ok_rate": (sum(r["right"] for r in hold) / len(hold)) if hold else None,
                    "false_ok": sum(r["false_ok"] for r in rs), "median_rmse": _median([r["rmse"] for r in rs]),
                    "median_gain": _median([r["gain"] for r in rs]), "non_ok": len(nonok), "reason_judged": len(judged),
                    "reason_true": sum(bool(r["reason_true"]) for r in judged),
                    "no_verdict": sum(r["verdict"] in ("error", "crash", "none") for r in rs),
                    "verdicts": {v: sum(r["verdict"] == v for r in rs) for v in sorted({r["verdict"] for r in rs})}})
    return out


def format_table(table: list[dict]) -> str:
    """The issue's table as Markdown."""
    def num(x, fmt):
        return "–" if x is None else format(x, fmt)

    lines = ["| feature | value | n | holdable | ok & right / holdable | false ok | median RMSE (rad) | median gain | "
             "first reason true / judged (non-ok) | verdicts |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for t in table:
        rate = f"{t['ok_right']}/{t['holdable']}" + (f" ({100 * t['ok_rate']:.0f} %)" if t["ok_rate"] is not None else "")
        verd = ", ".join(f"{k} {v}" for k, v in t["verdicts"].items())
        lines.append(f"| {t['feature']} | {t['value']} | {t['count']} | {t['holdable']} | {rate} | {t['false_ok']} | "
                     f"{num(t['median_rmse'], '.3g')} | {num(t['median_gain'], '.3f')} | {t['reason_true']}/{t['reason_judged']} "
                     f"({t['non_ok']}) | {verd} |")
    return "\n".join(lines)


def unscored_note(rows: list[dict]) -> str:
    """Markdown lines naming the runs whose predictor the bench could not score (``compare_error``), or ``""``.

    Such a run has no learned-vs-oracle figures: with verdict ok it counts as a false ok (an ok the oracle cannot
    confirm), so the table's false ok says nothing of its BEM until it is scored.
    """
    bad = [r for r in rows if r.get("compare_error")]
    if not bad:
        return ""
    lines = [f"\nNot scored ({len(bad)}): the predictor could not be compared with the oracle; a run whose verdict is ok "
             "counts as a false ok until it is. A predictor written by another source tree (`--checkout TREE`) is "
             "refused by this one's loader: score it by running the bench from that tree."]
    lines += [f"- {r['name']} (verdict {r['verdict']}): {r['compare_error'][:300]}" for r in bad]
    return "\n".join(lines)
