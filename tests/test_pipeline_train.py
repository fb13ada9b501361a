"""Training runs: run folder contents, interruption, resume, learned BEM API, CLI errors."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch
import yaml
from conftest import furuta_section

from bemlearn.cli.main import main
from bemlearn.data.collect import collect
from bemlearn.data.trajectory_io import write_trajectory
from bemlearn.export import load_learned_bem
from bemlearn.models.learned_bem import LearnedBEM, srinivas_kappa
from bemlearn.pipeline.train import train_run


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    root = tmp_path_factory.mktemp("train")
    data, _ = collect("furuta", furuta_section("collect", n_trials=6, duration_s=6.0, workers=1, seed=1), progress=False)
    path = write_trajectory(data, root / "data.npz")
    from conftest import FURUTA_CONFIG

    from bemlearn.pipeline.config import load_pipeline_config

    cfg = load_pipeline_config(FURUTA_CONFIG)
    cfg = dataclasses.replace(cfg, dataset=dataclasses.replace(cfg.dataset, n_points=150), train=dataclasses.replace(cfg.train, max_iter=30))
    out = root / "run"
    metrics = train_run(cfg, path, out, progress=False)
    return cfg, path, out, metrics


def test_run_folder_contents(small):
    _cfg, _path, out, _metrics = small
    for name in ("config.yaml", "checkpoint.pt", "metrics.json", "bem_validation.png"):
        assert (out / name).is_file(), name
    assert any((out / "tb").iterdir())
    ck = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ck["format"] == "bemlearn-checkpoint-v1" and ck["kind"] == "exact"
    assert ck["metadata"]["robot"] == "furuta" and ck["metadata"]["n_train"] == 150
    saved = yaml.safe_load((out / "config.yaml").read_text())
    assert saved["dataset"]["n_points"] == 150 and saved["train"]["max_iter"] == 30
    m = json.loads((out / "metrics.json").read_text())
    for key in ("val_rmse", "val_mean_log_likelihood", "bem_heldout", "lengthscale_physical"):
        assert key in m
    assert set(m["lengthscale_physical"]) == {"qdd_theta", "qd_theta", "q_theta", "qdd_alpha", "qd_alpha"}
    assert 0 <= m["bem_heldout"]["coverage_2sigma_latent"] <= m["bem_heldout"]["coverage_2sigma_predictive"] <= 1


def test_learned_bem_api_matches_frozen_posterior(small):
    _, _, out, _ = small
    learned = load_learned_bem(out)
    qa = torch.tensor([[0.1], [-0.2]], dtype=torch.float64)
    qad = torch.tensor([[0.5], [1.0]], dtype=torch.float64)
    qadd = torch.tensor([[3.0], [-6.0]], dtype=torch.float64)
    pred = learned.bem(qa, qad, qadd)
    x = torch.cat([qadd, qad, qa, torch.zeros(2, 2, dtype=torch.float64)], 1)
    mean, latent = learned.state.predict_reference(x)
    torch.testing.assert_close(pred.mean, mean, rtol=0, atol=0)
    torch.testing.assert_close(pred.latent_std, latent, rtol=0, atol=0)
    noise = learned.state.y_std**2 * learned.state.noise
    torch.testing.assert_close(pred.std, (latent**2 + noise).sqrt(), rtol=1e-15, atol=0)
    torch.testing.assert_close(learned.bound(pred.std, kappa=2.0, zero_dynamics_gap=0.01), 2 * pred.std + 0.01)
    with pytest.raises(ValueError, match=r"qad must have shape \(B, 1\)"):
        learned.bem(qa, torch.zeros(2, 2), qadd)
    with pytest.raises(ValueError, match=r"shape \(B, 5\)"):
        learned.predict(torch.zeros(3, 4))
    assert srinivas_kappa(1.0, 10.0, 500, 0.9) > 100  # the theorem's κ is very conservative


def test_interrupt_leaves_usable_checkpoint_and_resume_continues(small, tmp_path, monkeypatch):
    cfg, path, _, _ = small
    import bemlearn.pipeline.gp_stage as tr

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(tr, "fit_gp", interrupted)
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        train_run(cfg, path, out, progress=False)
    ck = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ck["metadata"]["extra"]["interrupted"] is True
    monkeypatch.undo()
    m = train_run(cfg, path, out, resume=True, progress=False)
    assert not m["interrupted"] and m["fit"]["stop_reason"] in ("converged", "max_iter")


def test_train_cli_errors(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("robot: furuta\ntrain:\n  kindd: exact\n")
    assert main(["train", str(bad), "--data", str(tmp_path / "x.npz")]) == 2
    assert "unknown key(s) ['kindd']" in capsys.readouterr().err
    good = tmp_path / "good.yaml"
    good.write_text("robot: furuta\n")
    assert main(["train", str(good), "--data", str(tmp_path / "missing.npz")]) == 2
    assert "not found" in capsys.readouterr().err


def test_evaluate_cli(small, capsys):
    _, _, out, _ = small
    assert main(["evaluate", str(out), "--references", "2"]) == 0
    text = capsys.readouterr().out
    assert "inside ±2σ" in text and (out / "evaluation.json").is_file()


def test_training_computes_the_calibrated_band(small):
    """train_run stores c ≥ 1 and the quantization input std, reports the band and the bound."""
    import math

    from bemlearn.models.band import band_reference

    _, _, out, metrics = small
    learned = load_learned_bem(out)
    st = learned.state
    assert float(st.std_scale) >= 1.0 and float(st.std_scale) == metrics["uncertainty"]["std_scale"]
    step = 2 * math.pi / 4096  # the collect default encoder
    assert float(st.input_std[2]) == pytest.approx(step / math.sqrt(12), rel=1e-6)   # q_theta: Δ/√12
    assert float(st.input_std[0]) > float(st.input_std[1]) > float(st.input_std[2]) > 0  # q̈ > q̇ > q noise
    b = metrics["bem_heldout"]
    assert b["bound_violation"]["nominal"] == pytest.approx(1 - LearnedBEM.nominal_confidence(2.0), rel=1e-12)
    assert b["bound_violation"]["observed"] == pytest.approx(1 - b["coverage_2sigma_band"], abs=1e-12)
    assert [r["level"] for r in b["reliability"]["band"]] == [0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99]
    qa = torch.tensor([[0.1]], dtype=torch.float64)
    pred = learned.bem(qa, 0 * qa, 2 + 0 * qa)
    ref = band_reference(st, torch.tensor([[2.0, 0.0, 0.1, 0.0, 0.0]], dtype=torch.float64), n_inputs=3)
    torch.testing.assert_close(pred.band_std, ref[1], rtol=0, atol=0)
    assert 0 <= metrics["val_coverage_2sigma_band"] <= 1


def test_training_stores_the_estimator_term_and_band_bench_agrees(small):
    """The band's estimator term (eq. E2) is computed at training (K = 4 Savitzky–Golay neighbours);
    `bench band` scores the exported band on the run's references exactly as the run's evaluation did."""
    from bemlearn.bench.band_bench import format_band_bench, run_band_bench

    _, _, out, metrics = small
    st = load_learned_bem(out).state
    est = metrics["uncertainty"]["estimator_term"]
    assert st.n_estimators == 4 == len(est["estimators"]) and all(s > 0 for s in est["rms_shift"])
    assert float(st.estimator_delta.abs().max()) > 0
    (res,) = run_band_bench([out], progress=lambda *_: None)
    b = metrics["bem_heldout"]
    assert res["rmse"] == pytest.approx(b["rmse"], rel=1e-12)
    assert res["rows"]["exported band (eq. B1)"]["inside_2sigma"] == pytest.approx(b["coverage_2sigma_band"], abs=0)
    assert res["rows"]["exported band (eq. B1)"]["median_std_over_rmse"] == pytest.approx(b["median_band_std_over_rmse"], rel=1e-9)
    assert res["rows"]["latent"]["inside_2sigma"] == pytest.approx(b["coverage_2sigma_latent"], abs=0)
    assert "exported band (eq. B1)" in format_band_bench([res])
