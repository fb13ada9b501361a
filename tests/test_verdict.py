"""The run's verdict: the documented limits (bemlearn.pipeline.verdict), the model checks before
collecting (bemlearn.pipeline.feasibility), the design-region evaluation and `bemlearn run`'s
exit status and files for a robot that cannot be balanced."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from bemlearn.pipeline.design_evaluation import design_grid, evaluate_design_region, least_squares_gain
from bemlearn.pipeline.verdict import EXIT_DEGRADED_STRICT, EXIT_UNUSABLE, judge_run

ROBOTS = Path(__file__).resolve().parent / "robots"


def _design(gain=1.0, rmse=0.001, mx=0.004, cov=1.0, bound=0.2):
    return {"bem_design_region": {"n_points": 100, "bound": bound, "gain": gain, "rmse": rmse, "max_abs": mx,
                                  "coverage_2sigma_band": cov}}


_EXCITATION = {"name": "excitation", "passed": False, "severity": "degraded", "value": 1.17, "limit": 1.0,
               "text": "the excitation LQR needs 1.17× the actuator limits (ctrlrange, forcerange) for a 0.05 rad error of pole"}


def _trials(n: int, failed: int) -> dict:
    return {"file": "data.npz", "collected": True, "trials": n, "failed": failed, "samples": 1000 * n}


@pytest.mark.parametrize("metrics, status, check", [
    (_design(), "ok", None),
    (_design(gain=0.951), "ok", None),
    (_design(gain=0.949), "degraded", "design_region"),        # the gain target [0.95, 1.05]
    (_design(gain=1.06), "degraded", "design_region"),
    (_design(rmse=0.0101), "degraded", "design_region"),       # RMSE ≤ 0.01 rad at d = 0.2 rad
    (_design(mx=0.041), "degraded", "design_region"),          # max ≤ 0.04 rad
    (_design(gain=0.45), "unusable", "design_region"),
    (_design(rmse=0.051), "unusable", "design_region"),
    (_design(cov=0.7), "degraded", "band"),
    ({"data": {"collected": True, "trials": 24, "failed": 12}}, "ok", None),
    ({"data": {"collected": True, "trials": 24, "failed": 13}}, "degraded", "excitation"),
    ({"data": {"collected": True, "trials": 24, "failed": 24}}, "unusable", "excitation"),
    ({"data": {"collected": False, "trials": 24, "failed": 0}}, "ok", None),
    ({"fit": {"stop_reason": "max_iter", "steps": 100}}, "degraded", "fit"),
    ({"fit": {"stop_reason": "converged", "steps": 40}}, "ok", None),
    ({"resolution": {"ratio": 1.5, "spread": 0.001, "band_std": 0.0007, "inputs": []}}, "unusable", "resolution"),
    ({"resolution": {"ratio": 3.0, "spread": 0.002, "band_std": 0.0007, "inputs": []}}, "degraded", "resolution"),
    ({"resolution": {"ratio": 40.0, "spread": 0.03, "band_std": 0.0007, "inputs": []}}, "ok", None),
    ({"closed_loop": {"predictor": {"fell": True, "duration_s": 0.9}, "model": {"fell": True}}}, "unusable", "closed_loop"),
    ({"closed_loop": {"predictor": {"fell": False, "diverged": True}}}, "degraded", "closed_loop"),
    # both loops stay up and leave the reference (the EIC cannot track it with the exact BEM): the learned BEM is judged
    # where its loop used it, against the design region's targets (d = 0.2: RMSE ≤ 0.01, max ≤ 0.04), not by tracking
    ({**_design(), "closed_loop": {"predictor": {"fell": False, "diverged": True, "tracking_rmse": 0.0908, "tracking_max": 0.19,
                                                 "bem_vs_model_rmse": 0.0035, "bem_vs_model_max": 0.011},
                                   "model": {"fell": False, "diverged": True, "tracking_rmse": 0.0720, "tracking_max": 0.14}}},
     "ok", "closed_loop"),
    ({**_design(), "closed_loop": {"predictor": {"fell": False, "diverged": True, "tracking_rmse": 0.0354, "tracking_max": 0.080,
                                                 "bem_vs_model_rmse": 0.0101, "bem_vs_model_max": 0.03},
                                   "model": {"fell": False, "diverged": True, "tracking_rmse": 0.0357, "tracking_max": 0.076}}},
     "degraded", "closed_loop"),
    ({**_design(), "closed_loop": {"predictor": {"fell": False, "diverged": True, "tracking_rmse": 0.0354, "tracking_max": 0.080,
                                                 "bem_vs_model_rmse": 0.005, "bem_vs_model_max": 0.041},
                                   "model": {"fell": False, "diverged": True, "tracking_rmse": 0.0357, "tracking_max": 0.076}}},
     "degraded", "closed_loop"),
    # without the comparison along the loop, or without the design bound, the learned loop's divergence stands
    ({"closed_loop": {"predictor": {"fell": False, "diverged": True, "tracking_rmse": 0.0354, "tracking_max": 0.080},
                      "model": {"fell": False, "diverged": True, "tracking_rmse": 0.0357, "tracking_max": 0.076}}}, "degraded", "closed_loop"),
    ({"closed_loop": {"predictor": {"fell": False, "diverged": True, "bem_vs_model_rmse": 0.001, "bem_vs_model_max": 0.004},
                      "model": {"fell": False, "diverged": True}}}, "degraded", "closed_loop"),
    # the model BEM's loop tracked: the learned one's divergence is the learned BEM's
    ({**_design(), "closed_loop": {"predictor": {"fell": False, "diverged": True, "tracking_rmse": 0.0354, "tracking_max": 0.080,
                                                 "bem_vs_model_rmse": 0.001, "bem_vs_model_max": 0.004},
                                   "model": {"fell": False, "diverged": False, "tracking_rmse": 0.0357, "tracking_max": 0.076}}},
     "degraded", "closed_loop"),
    # a loop that stays up but takes q_u 1.5 × the design bound from the upright (its reference asks for d/2) barely holds
    ({**_design(), "closed_loop": {"predictor": {"fell": False, "diverged": False, "qu_dev_max": 0.31}}}, "degraded", "closed_loop"),
    ({**_design(), "closed_loop": {"predictor": {"fell": False, "diverged": False, "qu_dev_max": 0.29}}}, "ok", None),
    ({"closed_loop": {"predictor": {"fell": False, "diverged": False, "lemma1": {"r_learned_vs_model_delta_gamma": -0.79, "r_learned_vs_hdot": -0.79}}}},
     "degraded", "lemma1"),
    # only the damping part b_u q̇_u^e is off (r = 1 with the model's), and its error moves q_u along the reference by
    # |b − 1| · damping_qu = 3.9 × 5.8e-7 rad, below the held-out q_u error: a note (a pendubot's elbow, b_u 1.3e-4)
    ({"data_heldout": {"rmse": 8.4e-4}, "closed_loop": {"predictor": {"fell": False, "diverged": False, "lemma1": {
        "r_learned_vs_model_delta_gamma": 0.88, "r_learned_vs_hdot": 0.94, "hdot_coefficient": 0.999,
        "damping_coefficient": -2.89, "r_model_damping": 0.99999, "damping_qu": 5.8e-7}}}}, "ok", "lemma1"),
    # the same damping error where it moves q_u by more than the held-out error: the map contradicts Lemma 1
    ({"data_heldout": {"rmse": 2e-6}, "closed_loop": {"predictor": {"fell": False, "diverged": False, "lemma1": {
        "r_learned_vs_model_delta_gamma": 0.88, "r_learned_vs_hdot": 0.94, "hdot_coefficient": 0.999,
        "damping_coefficient": -2.89, "r_model_damping": 0.99999, "damping_qu": 5.8e-7}}}}, "degraded", "lemma1"),
    # Ḣ_u itself off (the damping part cannot explain it): degraded however small the damping
    ({"data_heldout": {"rmse": 8.4e-4}, "closed_loop": {"predictor": {"fell": False, "diverged": False, "lemma1": {
        "r_learned_vs_model_delta_gamma": 0.5, "r_learned_vs_hdot": 0.5, "hdot_coefficient": 0.4,
        "damping_coefficient": 1.0, "r_model_damping": 0.5, "damping_qu": 5.8e-7}}}}, "degraded", "lemma1"),
    # no held-out error to compare with: degraded
    ({"closed_loop": {"predictor": {"fell": False, "diverged": False, "lemma1": {
        "r_learned_vs_model_delta_gamma": 0.88, "r_learned_vs_hdot": 0.94, "hdot_coefficient": 0.999,
        "damping_coefficient": -2.89, "r_model_damping": 0.99999, "damping_qu": 5.8e-7}}}}, "degraded", "lemma1"),
    # the model's ΔΓ moves q_u along the reference by 4.1e-4 rad, below the held-out q_u error 6.8e-4 rad: the learned
    # ΔΓ is a difference the map does not resolve (a note); above it (2e-4 rad held-out) the correlation stands
    ({"data_heldout": {"rmse": 6.8e-4}, "closed_loop": {"predictor": {"fell": False, "diverged": False, "lemma1": {
        "r_learned_vs_model_delta_gamma": 0.87, "r_learned_vs_hdot": 0.87, "hdot_coefficient": 0.999,
        "damping_coefficient": 0.68, "r_model_damping": 0.87, "damping_qu": 1.5e-5, "delta_gamma_qu": 4.1e-4}}}}, "ok", "lemma1"),
    ({"data_heldout": {"rmse": 2e-4}, "closed_loop": {"predictor": {"fell": False, "diverged": False, "lemma1": {
        "r_learned_vs_model_delta_gamma": 0.87, "r_learned_vs_hdot": 0.87, "hdot_coefficient": 0.999,
        "damping_coefficient": 0.68, "r_model_damping": 0.87, "damping_qu": 1.5e-5, "delta_gamma_qu": 4.1e-4}}}}, "degraded", "lemma1"),
    ({"dataset": {"derivative_choice": {"qdd_noise_fraction": {"pole": 0.07}}}}, "degraded", "derivatives"),
    ({"feasibility": [{"name": "eic", "passed": False, "severity": "unusable", "text": "unstable"}]}, "unusable", "model:eic"),
    # the excitation LQR's prediction that the trials will saturate and fall: it stands before they ran and where
    # more than half of them fell; where 4 of 24 fell, the trials' own count decides (a note)
    ({"feasibility": [_EXCITATION]}, "degraded", "model:excitation"),
    ({"feasibility": [_EXCITATION], "data": _trials(24, 13)}, "degraded", "model:excitation"),
    ({"feasibility": [_EXCITATION], "data": _trials(24, 12)}, "ok", "model:excitation"),
    ({"feasibility": [_EXCITATION], "data": _trials(24, 4)}, "ok", "model:excitation"),
])
def test_limits_of_the_documented_table(metrics, status, check):
    v = judge_run(metrics)
    assert v.status == status, v.to_dict()
    assert (check is None) == (not v.findings)
    if check is not None:
        assert v.findings[0].check == check and v.reasons[0]
        assert v.to_dict()["status"] == status and v.to_dict()["reasons"] == v.reasons


def test_worst_first_and_exit_status():
    v = judge_run({**_design(gain=0.9), "fit": {"stop_reason": "max_iter", "steps": 100},
                   "closed_loop": {"predictor": {"fell": True, "duration_s": 1.0}}})
    assert v.status == "unusable" and next(f.severity for f in v.findings) == "unusable"
    assert v.exit_status() == EXIT_UNUSABLE == 3
    d = judge_run(_design(gain=0.9))
    assert d.exit_status() == 0 and d.exit_status(strict=True) == EXIT_DEGRADED_STRICT != 0
    assert judge_run({}).exit_status(strict=True) == 0 and judge_run({}).summary() == "Verdict: ok"


def test_least_squares_gain_matches_polyfit():
    rng = np.random.default_rng(0)
    model = rng.uniform(-0.2, 0.2, 500)
    learned = 0.93 * model + 0.01 + rng.normal(0, 0.002, 500)
    slope, icpt = least_squares_gain(model, learned)
    ref = np.polyfit(model, learned, 1)
    assert abs(slope - ref[0]) < 1e-12 and abs(icpt - ref[1]) < 1e-12


@pytest.fixture(scope="module")
def cartpole_state():
    """A GP fitted to the cart-pole's exact model BEM on random x_0^e (learned = model up to the fit)."""
    from bemlearn.data.normalization import Normalization
    from bemlearn.fitting import build_gp, fit_gp
    from bemlearn.fitting.gp_config import GPConfig
    from bemlearn.models import predictor_state
    from bemlearn.robots import load

    robot = load(str(ROBOTS / "cartpole.xml"))
    rng = np.random.default_rng(1)
    n = 300
    qa, qad, qadd = rng.uniform(-0.3, 0.3, (n, 1)), rng.uniform(-1, 1, (n, 1)), rng.uniform(-3, 3, (n, 1))
    qu = robot.bem(torch.from_numpy(qa), torch.from_numpy(qad), torch.from_numpy(qadd)).qu
    x = torch.from_numpy(np.concatenate([qadd, qad, qa, np.zeros((n, 2))], 1))
    x[:, -2:] = torch.from_numpy(rng.normal(0, 1e-3, (n, 2)))          # the q̈_u, q̇_u columns need some spread
    names = ("qdd_slider", "qd_slider", "q_slider", "qdd_hinge", "qd_hinge")
    norm = Normalization.fit(x, qu, names=names)
    cfg = GPConfig(kind="exact", seed=0)
    xn, yn = norm.normalize_x(x), norm.normalize_y(qu)
    model, lik = build_gp(xn, yn, config=cfg)
    fit_gp(model, lik, xn, yn, config=cfg, progress=False)
    st = predictor_state(model.eval(), lik.eval(), x_mean=norm.x_mean, x_std=norm.x_std, y_mean=norm.y_mean, y_std=norm.y_std,
                         input_names=names, n_train=n)
    return robot, st


def test_design_region_of_a_faithful_and_a_scaled_bem(cartpole_state):
    from bemlearn.pipeline.evaluation import EvaluationConfig

    robot, st = cartpole_state
    ecfg = EvaluationConfig(n_sines=(2, 3), amplitude_max=0.3, amplitude_min=0.15, frequency_hz=(0.1, 0.8))
    grid = design_grid(robot, ecfg, n_points=1024, seed=0)
    assert len(grid.qu) > 200 and np.all(np.abs(grid.qu - robot.qu_nominal) <= grid.bound) and grid.bound == 0.2
    # the acceleration range reaches past the design bound: 1.3 d / |s_a|, s_a ≈ 1/g for a cart-pole
    assert grid.box["slider"]["qdd"] > 1.3 * 0.2 * 9.81 * 0.9
    good = evaluate_design_region(st, grid)
    assert abs(good.gain - 1.0) < 0.02 and good.rmse < 0.005, good.as_dict()
    # a BEM whose deviation from y_mean is scaled by 0.8: gain 0.8 × the faithful one's (μ is linear in α)
    scaled = evaluate_design_region(dataclasses.replace(st, alpha=0.8 * st.alpha), grid)
    expected, _ = least_squares_gain(grid.qu, float(st.y_mean) + 0.8 * (good.curve.learned - float(st.y_mean)))
    assert abs(scaled.gain - expected) < 1e-9 and abs(scaled.gain - 0.8 * good.gain) < 0.01
    assert judge_run({"bem_design_region": scaled.as_dict()}).status == "degraded"


def test_model_checks_flag_the_acrobot_and_pass_the_cartpole():
    from bemlearn.pipeline.feasibility import model_feasibility
    from bemlearn.pipeline.resolve import resolve_pipeline_config
    from bemlearn.robots import load

    bad = resolve_pipeline_config({"robot": str(ROBOTS / "acrobot.xml")}).config
    checks = {c.name: c for c in model_feasibility(load(bad.robot), bad)}
    # its derived gains make the sampled loop decay, but from a d/4 error the elbow swings to its stop
    assert checks["eic"].passed and checks["eic"].value < 0
    rec = checks["eic_recovery"]
    assert not rec.passed and rec.severity == "unusable" and "falls at" in rec.text and "elbow" in rec.text
    good = resolve_pipeline_config({"robot": str(ROBOTS / "cartpole.xml")}).config
    checks = {c.name: c for c in model_feasibility(load(good.robot), good)}
    assert all(c.passed for c in checks.values()) and set(checks) == {"hold", "eic", "eic_recovery", "excitation"}
    # holding 0.2 rad on a cart-pole takes the cart's mass times g·tan(0.2) (plus the pole's): an independent figure
    assert 0.0 < checks["hold"].value < 1.0


def test_run_of_a_robot_that_cannot_be_balanced_stops_after_the_model_checks(tmp_path):
    cfg = tmp_path / "acro.yaml"
    cfg.write_text(f"robot: {ROBOTS / 'acrobot.xml'}\n")
    out = tmp_path / "run"
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "bemlearn", "run", str(cfg), "--out", str(out), "--no-progress"],
                       capture_output=True, text=True, timeout=120)
    elapsed = time.perf_counter() - t0
    assert p.returncode == 3, p.stderr[-2000:]
    assert elapsed < 30.0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["verdict"]["status"] == "unusable" and metrics["stopped_after"] == "preflight"
    assert any("cannot bring shoulder back" in r and "falls at" in r for r in metrics["verdict"]["reasons"])
    report = (out / "report.md").read_text()
    assert report.splitlines()[2] == "## Verdict: unusable"
    assert p.stdout.strip().splitlines()[-1].startswith("Verdict: unusable")
    assert not (out / "data.npz").exists() and not (out / "checkpoint.pt").exists()
    assert math.isfinite(metrics["feasibility"][0]["value"])


def test_lemma1_split_recovers_the_coefficients_of_its_two_parts():
    """ΔΓ_learned = a Ḣ_u + b (b_u q̇_u^e) + c, with Ḣ_u ∝ −ω² sin and the damping part ∝ cos (quadrature): the split
    returns a, b exactly; damping_qu = std(damping) / |Γ_q|; with the damping replaced by the model's, r = 1."""
    from bemlearn.pipeline.lemma import _split

    t = np.linspace(0, 2 * np.pi, 256, endpoint=False)
    hdot, damping = -4.0 * np.sin(t) + 0.5 * np.sin(3 * t), 0.3 * np.cos(t)
    a, b, r_md, dqu = _split(0.97 * hdot - 2.5 * damping + 1e-3, hdot, damping, gamma_q=0.6)
    assert abs(a - 0.97) < 1e-12 and abs(b + 2.5) < 1e-12
    assert abs(dqu - np.std(damping) / 0.6) < 1e-15
    assert r_md == pytest.approx(np.corrcoef(0.97 * hdot + damping, hdot + damping)[0, 1], abs=1e-12)
    a0, b0, r0, d0 = _split(1.1 * hdot, hdot, np.zeros_like(t), gamma_q=0.6)     # no damping on q_u
    assert abs(a0 - 1.1) < 1e-12 and math.isnan(b0) and math.isnan(r0) and d0 == 0.0


def test_the_compass_search_finds_a_known_maximum_and_respects_the_feasible_set():
    """(D3)'s search on f(u) = −‖u − c‖² (max at c inside the box) and on a cap at u₀ ≤ 0.3 (−1 beyond: infeasible)."""
    from bemlearn.pipeline.design_evaluation import pattern_search_max

    c = np.array([0.31, -0.52, 0.77])
    f = lambda u: -np.sum((u - c) ** 2, axis=1)  # noqa: E731
    u0 = np.array([[0.0, 0.0, 0.0], [-0.9, 0.9, -0.9]])
    u, best, n = pattern_search_max(f, u0, f(u0), step=0.05, halvings=12)
    assert np.abs(u - c).max() < 0.05 * 0.5**11 and n > 0 and np.all(best > -1e-9)
    g = lambda u: np.where(u[:, 0] <= 0.3, u[:, 0] + u[:, 1], -1.0)  # noqa: E731  # max on the cap's edge, u = (0.3, 1)
    v, top, _ = pattern_search_max(g, np.zeros((1, 3)), g(np.zeros((1, 3))), step=0.05, halvings=12,
                                   live=np.array([True, True, False]))
    assert abs(v[0, 0] - 0.3) < 0.05 * 0.5**11 and v[0, 1] == 1.0 and v[0, 2] == 0.0 and abs(top[0] - 1.3) < 1e-3


def test_the_refined_design_max_reaches_a_dense_samples_max(cartpole_state):
    """(D3): for a BEM scaled by 0.8 about its mean (its error grows toward the region's edge |q_u^e| = d), from a
    16-point sample the refined max |μ − q_u^e| comes within 2 % of a 32768-point sample's (which the 16-point sample
    alone misses), never below the sample's own, and ``worst`` is where it is: the two BEMs there, recomputed, differ
    by it."""
    from bemlearn.models.band import band_reference
    from bemlearn.pipeline.evaluation import EvaluationConfig

    robot, st = cartpole_state
    st = dataclasses.replace(st, alpha=0.8 * st.alpha)
    ecfg = EvaluationConfig(n_sines=(2, 3), amplitude_max=0.3, amplitude_min=0.15, frequency_hz=(0.1, 0.8))
    small = design_grid(robot, ecfg, n_points=16, seed=3)
    dense = evaluate_design_region(st, design_grid(robot, ecfg, n_points=32768, seed=4))
    sampled = evaluate_design_region(st, small)
    refined = evaluate_design_region(st, small, robot)
    assert sampled.max_abs < 0.9 * dense.max_abs                      # the small sample alone misses the sup
    assert refined.max_sampled == sampled.max_abs and refined.refine_evaluations > 0
    assert refined.max_abs >= 0.98 * dense.max_abs and refined.rmse == sampled.rmse and refined.gain == sampled.gain
    x = np.asarray(refined.worst["x0e"])[None, :]
    model = robot.bem(torch.from_numpy(x[:, 2:3]), torch.from_numpy(x[:, 1:2]), torch.from_numpy(x[:, 0:1])).qu.numpy()[0]
    learned = band_reference(st, torch.from_numpy(np.concatenate([x, np.zeros((1, 2))], 1)), n_inputs=3)[0].numpy()[0]
    assert abs(abs(learned - model) - refined.max_abs) < 1e-12 and abs(model - robot.qu_nominal) <= small.bound


def test_a_position_that_moves_the_bem_is_checked_to_where_it_moves_it_by_d():
    """(D1): the pendubot's shoulder (s_p ≠ 0) is checked to min(d/|s_p|, 0.8 h) whatever the references' amplitude;
    the cart-pole's cart (s_p = 0: its position does not move the BEM) to the references' amplitude."""
    from bemlearn.pipeline.evaluation import EvaluationConfig
    from bemlearn.robots import load
    from bemlearn.robots.scales import bem_slopes, qa_half_ranges

    ecfg = EvaluationConfig(n_sines=(2, 3), amplitude_max=0.05, amplitude_min=0.02, frequency_hz=(0.1, 0.8))
    pend = load(str(ROBOTS / "pendubot.xml"))
    s_p = abs(float(bem_slopes(pend)[0][0]))
    expected = min(0.2 / s_p, 0.8 * float(qa_half_ranges(pend)[0]))
    assert s_p > 0.1 and expected > 0.05
    assert abs(design_grid(pend, ecfg, n_points=64, seed=0).box["shoulder"]["q"] - expected) < 1e-12
    cart = load(str(ROBOTS / "cartpole.xml"))
    assert abs(float(bem_slopes(cart)[0][0])) < 1e-9
    assert design_grid(cart, ecfg, n_points=64, seed=0).box["slider"]["q"] == 0.05


def test_the_excited_velocities_are_checked_on_the_balance_time_scale_as_the_family_oracle_does(tmp_path):
    """(D1) with the excitation's extents (m ≥ 2): a joint's velocity is checked to min(√(a_j P_j), A_j/(1.3 λ), v_j),
    the speed of a motion on the balance's own time scale whose acceleration reaches the box's A_j/1.3, not √(a_j P_j)
    (a slow sweep that fills both extents: 1.7–2.4× faster on the robot family's two-link arms).  Checked against the
    family oracle's a_i/ω_u, computed independently (Newton on ``mj_inverse``, its own reach and ω_u), within 3 %."""
    from bemlearn.bench.family.generator import generate_robot
    from bemlearn.bench.family.oracle import Oracle
    from bemlearn.pipeline import derive
    from bemlearn.pipeline.evaluation import EvaluationConfig
    from bemlearn.robots import load
    from bemlearn.robots.scales import instability_rate

    xml, truth = generate_robot(1, 28, hold_check=False)   # a two-link arm (shoulder, elbow) balancing a pole
    path = tmp_path / "arm.xml"
    path.write_text(xml)
    robot = load(str(path))
    assert robot.m == 2
    rate = derive.control_rate(robot).value
    ext = np.asarray(derive.excitation_directions(robot, rate, derive.excitation_signals(robot, rate).value).value["excursion"])
    P, a = ext[:2], ext[2:]
    lam = instability_rate(robot)
    # the references' own velocity (Σ|A| ω) kept below the balance's, so that the excitation's extents set the box
    ecfg = EvaluationConfig(n_sines=(2, 3), amplitude_max=0.01, amplitude_min=0.005, frequency_hz=(0.1, 0.8))
    box = design_grid(robot, ecfg, n_points=64, seed=0, excursion=(*P, *a)).box
    oracle = Oracle(xml, qu_upright=truth["qu_upright"]).scales()
    for j, name in enumerate(robot.actuated_names):
        assert np.sqrt(a[j] * P[j]) > 1.3 * box[name]["qd"]           # the old extent, √(a P), is not what is checked
        assert box[name]["qd"] == pytest.approx(box[name]["qdd"] / (1.3 * lam), rel=1e-9)
        assert box[name]["qd"] == pytest.approx(oracle["vel"][truth["actuated_joints"].index(name)], rel=0.03)
