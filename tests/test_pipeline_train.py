"""Training runs: run folder contents, interruption, resume, learned BEM API, CLI errors.

References: the learned BEM's mean, stds and band against eq. (12) and (B1) solved densely
(``torch.linalg.solve``) on the training set the fit saw, with the fitted hyperparameters;
the bound of eq. (15) against Gaussian sampling; Srinivas et al.'s κ against Theorem 6 evaluated
by hand.
"""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
import torch
import yaml
from conftest import furuta_section

from bemlearn.cli.main import main
from bemlearn.data.trajectory_io import write_trajectory
from bemlearn.export import load_learned_bem
from bemlearn.models.learned_bem import LearnedBEM, srinivas_kappa
from bemlearn.pipeline.train import train_run
from bemlearn.sim.collect import collect

#: run folder → the normalized training set (X̃, ỹ) its fit saw, recorded by the fixture.
TRAIN_SET: dict = {}


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    root = tmp_path_factory.mktemp("train")
    data, _ = collect("furuta", furuta_section("collect", n_trials=6, duration_s=6.0, workers=1, seed=1), progress=False)
    path = write_trajectory(data, root / "data.npz")
    from conftest import FURUTA_CONFIG

    from bemlearn.pipeline.resolve import load_pipeline_config

    cfg = load_pipeline_config(FURUTA_CONFIG)
    cfg = dataclasses.replace(cfg, dataset=dataclasses.replace(cfg.dataset, n_points=150), train=dataclasses.replace(cfg.train, max_iter=30))
    out = root / "run"
    import bemlearn.pipeline.gp_stage as stage

    seen = {}
    fit_gp = stage.fit_gp

    def recording_fit(model, lik, x, y, **kwargs):  # the normalized training set the posterior is conditioned on
        seen["x"], seen["y"] = x.detach().clone(), y.detach().clone()
        return fit_gp(model, lik, x, y, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(stage, "fit_gp", recording_fit)
        metrics = train_run(cfg, path, out, progress=False).metrics.as_dict()   # as metrics.json holds it
    assert seen, "train_run did not fit through gp_stage.fit_gp"
    TRAIN_SET[out] = (seen["x"], seen["y"])
    return cfg, path, out, metrics


def _dense_posterior(state, train_set, x: torch.Tensor):
    """Eq. (12) by ``torch.linalg.solve`` (LU) on the training set, with the state's hyperparameters only.

    Returns μ (B,), the latent and predictive variances (B,) in physical units and the SE kernel
    row k(x̃, X̃) (B, N)."""
    X, Y = train_set
    ell, sf2, s02 = state.lengthscale, state.outputscale, state.noise

    def se(a, b):  # eq. (11): σ_f² exp(−½ Σ_j (a_j − b_j)² / ℓ_j²)
        return sf2 * torch.exp(-0.5 * (((a[:, None, :] - b[None, :, :]) / ell) ** 2).sum(-1))

    K = se(X, X) + s02 * torch.eye(X.shape[0], dtype=X.dtype)
    k = se((x - state.x_mean) / state.x_std, X)
    mean = state.y_mean + state.y_std * (k @ torch.linalg.solve(K, Y))
    latent_var = state.y_std**2 * (sf2 - (k * torch.linalg.solve(K, k.T).T).sum(-1))
    return mean, latent_var, latent_var + state.y_std**2 * s02, k


def test_run_folder_contents(small):
    _, _, out, _ = small
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


def test_learned_bem_api_matches_the_dense_posterior(small):
    _, _, out, _ = small
    learned = load_learned_bem(out)
    qa = torch.tensor([[0.1], [-0.2]], dtype=torch.float64)
    qad = torch.tensor([[0.5], [1.0]], dtype=torch.float64)
    qadd = torch.tensor([[3.0], [-6.0]], dtype=torch.float64)
    pred = learned.bem(qa, qad, qadd)
    x = torch.cat([qadd, qad, qa, torch.zeros(2, 2, dtype=torch.float64)], 1)  # x_0^e of eq. (14)
    st = learned.state
    mean, latent_var, pred_var, _ = _dense_posterior(st, TRAIN_SET[out], x)
    # tolerance: a millionth of the posterior std the dense solve states (LU and the state's
    # Cholesky of the same K agree to rounding, far below that)
    torch.testing.assert_close(pred.mean, mean, rtol=0, atol=1e-6 * float(latent_var.sqrt().min()))
    torch.testing.assert_close(pred.latent_std**2, latent_var, rtol=1e-6, atol=0)
    torch.testing.assert_close(pred.std**2, pred_var, rtol=1e-6, atol=0)
    with pytest.raises(ValueError, match=r"qad must have shape \(B, 1\)"):
        learned.bem(qa, torch.zeros(2, 2), qadd)
    with pytest.raises(ValueError, match=r"shape \(B, 5\)"):
        learned.predict(torch.zeros(3, 4))
    # Theorem 6 of Srinivas et al. (2012) by hand: κ² = 2 B² + 300 γ ln³(N / (1 − η)) with B = 1, γ = 10,
    # N = 500, η = 0.9: ln 5000 = 8.517193, cubed 617.8592, κ² = 2 + 1,853,577.5 → κ = 1361.462
    assert srinivas_kappa(1.0, 10.0, 500, 0.9) == pytest.approx(1361.4623, rel=1e-7)


def test_bound_holds_at_its_stated_confidence():
    """Eq. (13)/(15): |q_u^d − μ| ≤ κ σ + gap with probability ≥ η = erf(κ/√2), for a Gaussian error
    of std σ on top of any offset within ±gap; checked by sampling (tolerance: 5 binomial stds)."""
    gen = torch.Generator().manual_seed(0)
    n = 400_000
    std = 0.002 + 0.01 * torch.rand(n, generator=gen, dtype=torch.float64)
    for kappa, gap in ((2.0, 0.0), (1.0, 0.0), (2.0, 0.003)):
        offset = gap * (2 * torch.rand(n, generator=gen, dtype=torch.float64) - 1)
        err = offset + std * torch.randn(n, generator=gen, dtype=torch.float64)
        inside = float((err.abs() <= LearnedBEM.bound(std, kappa=kappa, zero_dynamics_gap=gap)).double().mean())
        eta = LearnedBEM.nominal_confidence(kappa)
        tol = 5 * math.sqrt(eta * (1 - eta) / n)
        if gap == 0:
            assert inside == pytest.approx(eta, abs=tol)   # exactly η without an offset
        else:
            assert inside >= eta - tol                     # at least η with one
    assert LearnedBEM.nominal_confidence(2.0) == pytest.approx(0.954499736, rel=1e-9)  # the normal table's 95.45 %


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
    m = train_run(cfg, path, out, resume=True, progress=False).metrics
    assert m.fit is not None and not m.interrupted and m.fit.stop_reason in ("converged", "max_iter")


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
    # the band of eq. (B1) from the dense posterior: ∂μ/∂x by autograd of the dense mean over the
    # 3m BEM columns, the estimator term from the state's δ and the dense kernel row
    qa, qad, qadd = (torch.tensor(v, dtype=torch.float64) for v in ([[0.1], [-0.05]], [[0.0], [0.4]], [[2.0], [2.0]]))
    pred = learned.bem(qa, qad, qadd)
    x = torch.cat([qadd, qad, qa, torch.zeros(2, 2, dtype=torch.float64)], 1).requires_grad_(True)
    mean, latent_var, _, k = _dense_posterior(st, TRAIN_SET[out], x)
    (grad,) = torch.autograd.grad(mean.sum(), x)
    sigma_in2 = ((grad[:, :3] * st.input_std[:3]) ** 2).sum(1)
    sigma_est2 = ((st.y_std * k.detach() @ st.estimator_delta) ** 2).mean(1)
    dense_band2 = st.std_scale**2 * latent_var.detach() + torch.maximum(sigma_in2, sigma_est2)
    torch.testing.assert_close(pred.band_std**2, dense_band2, rtol=1e-6, atol=0)  # a millionth, as above
    assert bool((sigma_in2 > 0).all() and (sigma_est2 > 0).all())  # both terms are live in this run


def test_training_stores_the_estimator_term_and_band_bench_agrees(small):
    """The band's estimator term (eq. E2) is computed at training (K = 4 Savitzky–Golay neighbours, and the resample
    column of eq. R2);
    `bench band` scores the exported band on the run's references exactly as the run's evaluation did."""
    from bemlearn.bench.band_bench import format_band_bench, run_band_bench

    _, _, out, metrics = small
    st = load_learned_bem(out).state
    est = metrics["uncertainty"]["estimator_term"]
    assert len(est["estimators"]) == 4 and all(s > 0 for s in est["rms_shift"])
    rs = metrics["uncertainty"]["resample_term"]   # eq. R2: one more column, μ's deviation from 16 other draws of its rows
    assert st.n_estimators == 4 + 1 and rs["n_draws"] == 16 and rs["rms_shift"] > 0 and rs["spread"] > 0
    assert float(st.estimator_delta.abs().max()) > 0
    (res,) = run_band_bench([out], progress=lambda *_: None)
    b = metrics["bem_heldout"]
    assert res["rmse"] == pytest.approx(b["rmse"], rel=1e-12)
    assert res["rows"]["exported band (eq. B1)"]["inside_2sigma"] == pytest.approx(b["coverage_2sigma_band"], abs=0)
    assert res["rows"]["exported band (eq. B1)"]["median_std_over_rmse"] == pytest.approx(b["median_band_std_over_rmse"], rel=1e-9)
    assert res["rows"]["latent"]["inside_2sigma"] == pytest.approx(b["coverage_2sigma_latent"], abs=0)
    assert "exported band (eq. B1)" in format_band_bench([res])


def test_evaluate_reads_the_excitation_extents_the_run_checked(small, tmp_path):
    """``bemlearn evaluate`` widens the design region's box to the extents the run's data were collected with (m ≥ 2:
    ``collect.excursion`` in the data file the checkpoint names), as the run's own check did; a data file that is
    gone is said, not silently replaced by the references' box."""
    import dataclasses
    from types import SimpleNamespace

    from bemlearn.cli.evaluate_cmd import _collected_excursion
    from bemlearn.data.trajectory_io import read_trajectory, write_trajectory
    from bemlearn.export.checkpoint import load_checkpoint

    _, data, out, _ = small
    assert _collected_excursion(load_checkpoint(out)) == (None, "")     # m = 1: the paper's excitation has no extents
    ck = SimpleNamespace(metadata=SimpleNamespace(extra={}))
    assert _collected_excursion(ck) == (None, "")                       # a checkpoint that names no data file
    traj = read_trajectory(data)
    wide = dataclasses.replace(traj, meta=dataclasses.replace(traj.meta, extra={"collect_config": {"excursion": [0.3, 4.0]}}))
    path = tmp_path / "wide.npz"
    write_trajectory(wide, path)
    ck.metadata.extra["data_file"] = str(path)
    assert _collected_excursion(ck) == ((0.3, 4.0), "")
    path.unlink()
    excursion, why = _collected_excursion(ck)
    assert excursion is None and str(path) in why and "not there" in why
