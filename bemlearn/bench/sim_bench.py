"""Closed-loop benchmark: the learned BEM in the EIC loop of a run's robot (``bemlearn bench sim RUN_DIR``).

The robot, its rate, gains and sensor come from the run (its checkpoint records the MJCF and
its sha256; its ``config.yaml`` the resolved closed-loop settings), so the bench is the same
for every robot.

* Balance and tracking: ``n_refs`` random composite sinusoids (components in the run's
  held-out frequency band up to 0.5 Hz, Σ amplitudes in the run's held-out amplitude range)
  × ``n_seeds`` seeds (a seed draws the initial q_u in ±0.05 and the encoder noise, σ = 0.5·10⁻³
  in the joint's unit before quantization) × BEM sources predictor / model / zero, same gains.
* Model mismatch: the controller's nominal masses and lengths (of ``bodies``, default all) off by ±20 %: the
  model-based BEM of the wrong model vs the learned BEM (trained on the true system), both
  against the true BEM on held-out references, and the tracking of each in the loop.
* Lemma 1 from the learned map (r of learned ΔΓ with Ḣ_u) and the model-side gap.
* Speed: real-time factor and the per-tick split (physics, predictor, controller).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from bemlearn.control.bem_sources import PredictorBEM
from bemlearn.errors import MissingFileError
from bemlearn.pipeline.evaluation import held_out_references
from bemlearn.pipeline.lemma import learned_lemma1
from bemlearn.sim.closed_loop import NominalConfig, ReferenceConfig, SimulateConfig, nominal_robot, simulate

__all__ = ["bench_references", "run_sim_bench", "format_sim_bench"]


def bench_references(n: int, *, frequency_hz=(0.1, 0.5), amplitude=(0.3, 0.5), base_hz: float = 0.05, seed: int = 2024) -> list[ReferenceConfig]:
    """``n`` random composite-sinusoid references (module docstring).

    Frequencies are distinct multiples of ``base_hz`` inside ``frequency_hz``, so every
    reference is periodic with period ≤ 1/base_hz (20 s) — needed for the zero-dynamics
    orbit and Lemma 1, which are computed over one period.
    """
    rng = np.random.default_rng(seed)
    grid = np.arange(math.ceil(frequency_hz[0] / base_hz - 1e-9), math.floor(frequency_hz[1] / base_hz + 1e-9) + 1) * base_hz
    refs = []
    for _ in range(n):
        k = int(rng.integers(2, 4))
        A = rng.uniform(0.05, 1.0, k)
        A = A / A.sum() * rng.uniform(*amplitude)
        f = np.sort(rng.choice(grid, size=k, replace=False))
        amps, freqs, phases = (tuple(float(v) for v in np.round(a, 4)) for a in (A, f, rng.uniform(0, 2 * math.pi, k)))
        refs.append(ReferenceConfig(amps, freqs, phases))
    return refs


def _seeded(base: SimulateConfig, seed: int) -> SimulateConfig:
    rng = np.random.default_rng(seed)
    return dataclasses.replace(base, seed=seed, initial_qu=float(rng.uniform(-0.05, 0.05)), sensor=dataclasses.replace(base.sensor, noise_std=5e-4))


def run_sim_bench(run_dir: str | Path, *, n_refs: int = 5, n_seeds: int = 5, duration_s: float = 60.0,
                  mismatch: bool = True, bodies: tuple[str, ...] | None = None, progress=print) -> dict:
    """Run the benchmark (module docstring) on the run folder ``run_dir``; returns a results dict."""
    from bemlearn.config import from_dict, load_yaml
    from bemlearn.pipeline.config import PipelineConfig
    from bemlearn.pipeline.evaluation import run_truth_robot

    run_dir = Path(run_dir)
    predictor = run_dir / "bem_predictor.pt"
    if not predictor.is_file():
        raise MissingFileError(f"{run_dir}: no bem_predictor.pt (export the run first: bemlearn export {run_dir})")
    truth, ref_rec = run_truth_robot(run_dir)
    cfg = from_dict(PipelineConfig, load_yaml(run_dir / "config.yaml"), where=str(run_dir / "config.yaml"))
    ev = cfg.evaluate
    assert ev.frequency_hz is not None  # a run folder's config.yaml is complete
    base = dataclasses.replace(cfg.simulate, duration_s=duration_s, predictor=str(predictor))
    refs = bench_references(n_refs, frequency_hz=(ev.frequency_hz[0], min(0.5, ev.frequency_hz[1])),
                            amplitude=(ev.amplitude_min, ev.amplitude_max))
    runs = []
    for i, ref in enumerate(refs):
        for seed in range(n_seeds):
            row: dict[str, Any] = {"ref": i, "seed": seed}
            for src in ("predictor", "model", "zero"):
                sim_cfg = dataclasses.replace(_seeded(base, seed), reference=ref, bem_source=src)
                m = simulate(truth, sim_cfg, progress=False).metrics
                row[src] = {k: m[k] for k in ("fell", "duration_s", "tracking_rmse", "u_max", "qu_max", "real_time_factor", "tick_us")}
            runs.append(row)
            p, mo, z = row["predictor"], row["model"], row["zero"]
            learned = "FELL" if p["fell"] else f"{p['tracking_rmse']:.4f}"
            progress(f"ref {i} seed {seed}: learned {learned} | model {mo['tracking_rmse']:.4f} | zero {z['tracking_rmse']:.4f} rad; max|V| {p['u_max']:.2f}")
    learned_ok = [r for r in runs if not r["predictor"]["fell"]]
    out: dict = {
        "references": [dataclasses.asdict(r) for r in refs],
        "runs": runs,
        "learned_all_up": len(learned_ok) == len(runs),
        "learned_max_abs_V": max(r["predictor"]["u_max"] for r in runs),
        "rmse_learned_over_model": [r["predictor"]["tracking_rmse"] / r["model"]["tracking_rmse"] for r in learned_ok],
        "rmse_learned_over_zero": [r["predictor"]["tracking_rmse"] / r["zero"]["tracking_rmse"] for r in learned_ok],
        "real_time_factor": [r["predictor"]["real_time_factor"] for r in runs],
        "tick_us": {k: float(np.median([r["predictor"]["tick_us"][k] for r in runs])) for k in ("physics", "predictor", "controller")},
    }
    out["robot"] = ref_rec
    pred = PredictorBEM(predictor)
    out["lemma1"] = []
    for ref in refs:
        lem = learned_lemma1(pred, pred.full, truth, ref.build(1), n_nodes=512)
        out["lemma1"].append({"period_s": ref.build(1).period, "r_learned_vs_hdot": lem.r_hdot, "r_learned_vs_model_delta_gamma": lem.r, "model_gap": lem.model_gap})
    if mismatch:
        out["mismatch"] = _mismatch(pred, truth, base, refs[0], ev, bodies, progress)
    return out


def _bem_rmse(fn, truth_robot, refs) -> float:
    t = np.arange(0.0, 20.0, 0.01)
    errs = []
    for ref in refs:
        qa, qad, qadd = ref.evaluate(t)
        true = truth_robot.bem(qa, qad, qadd).qu.numpy()
        errs.append(fn(np.concatenate([qadd, qad, qa], axis=1)) - true)
    e = np.concatenate(errs)
    return float(np.sqrt(np.mean(e**2)))


def _mismatch(pred: PredictorBEM, truth, base: SimulateConfig, ref: ReferenceConfig, ecfg, bodies, progress) -> list[dict]:
    from bemlearn.control.bem_sources import ModelBEM

    refs = held_out_references(ecfg, truth.m)
    rows = []
    for ms, ls in ((1.0, 1.0), (0.8, 1.0), (1.2, 1.0), (1.0, 0.8), (1.0, 1.2), (0.8, 0.8), (1.2, 1.2)):
        nom = NominalConfig(mass_scale=ms, length_scale=ls, bodies=bodies)
        wrong = ModelBEM(nominal_robot(truth, nom))
        row: dict[str, Any] = {"mass_scale": ms, "length_scale": ls,
               "bem_rmse_model": _bem_rmse(wrong, truth, refs), "bem_rmse_learned": _bem_rmse(pred, truth, refs)}
        for src in ("model", "predictor"):
            m = simulate(truth, dataclasses.replace(_seeded(base, 0), reference=ref, bem_source=src, nominal=nom), progress=False).metrics
            row[f"tracking_{src}"] = None if m["fell"] else m["tracking_rmse"]
            row[f"fell_{src}"] = m["fell"]
        rows.append(row)
        progress(f"mismatch m×{ms} l×{ls}: BEM RMSE model {row['bem_rmse_model']:.4f} / learned {row['bem_rmse_learned']:.4f} rad; "
                 f"tracking model {row['tracking_model']} / learned {row['tracking_predictor']}")
    return rows


def format_sim_bench(r: dict) -> str:
    lo = r["rmse_learned_over_model"]
    lz = r["rmse_learned_over_zero"]
    lines = [
        f"learned BEM in the loop: {'all' if r['learned_all_up'] else 'NOT all'} {len(r['runs'])} runs stayed up; max |u| = {r['learned_max_abs_V']:.2f}",
        f"tracking RMSE learned / model: median {np.median(lo):.3f}, max {np.max(lo):.3f}" if lo else "no successful learned run",
        f"tracking RMSE learned / zero:  median {np.median(lz):.4f}, max {np.max(lz):.4f}" if lz else "",
        "Lemma 1 per reference: " + "; ".join(
            f"model gap {L['model_gap']:.1e} N·m, r(learned ΔΓ, Ḣ_u) = {L['r_learned_vs_hdot']:.3f}, r(learned ΔΓ, model ΔΓ) = {L['r_learned_vs_model_delta_gamma']:.3f}"
            for L in r["lemma1"]),
        f"speed: {np.median(r['real_time_factor']):.1f}× real time (median); per tick µs: " + ", ".join(f"{k} {v:.1f}" for k, v in r["tick_us"].items()),
    ]
    if "mismatch" in r:
        lines.append("| mass × | length × | BEM RMSE model (rad) | BEM RMSE learned (rad) | tracking model (rad) | tracking learned (rad) |")
        lines.append("| --- | --- | --- | --- | --- | --- |")
        for m in r["mismatch"]:
            f = lambda v: "fell" if v is None else f"{v:.4f}"  # noqa: E731
            lines.append(f"| {m['mass_scale']} | {m['length_scale']} | {m['bem_rmse_model']:.4f} | {m['bem_rmse_learned']:.4f} | {f(m['tracking_model'])} | {f(m['tracking_predictor'])} |")
    return "\n".join(lines)
