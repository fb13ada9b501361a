"""``bemlearn export`` and ``bemlearn bench predict``, and the export self-check."""

import dataclasses
import json
import os

import pytest
import torch

from bemlearn.bench.predict_bench import format_predict_bench, run_predict_bench, synthetic_posterior
from bemlearn.cli.main import main
from bemlearn.export import export_run, load_torchscript, reference_posterior, verify_predictor, write_checkpoint

F64 = torch.float64


@pytest.fixture(scope="module")
def posterior():
    return synthetic_posterior(n_train=60, m=1, seed=5)


@pytest.fixture
def run_dir(tmp_path, posterior):
    state, meta = posterior
    write_checkpoint(tmp_path / "run", model_state={}, predictor_state=state, metadata=meta)
    return tmp_path / "run"


def test_export_writes_a_checked_predictor(run_dir, posterior, capsys):
    state, _ = posterior
    assert main(["export", str(run_dir)]) == 0
    path = run_dir / "bem_predictor.pt"
    assert capsys.readouterr().out.strip() == f"wrote {path}"
    module = load_torchscript(path)
    x = state.x_mean[:3] + state.x_std[:3] * torch.randn(9, 3, generator=torch.Generator().manual_seed(0), dtype=F64)
    ref_mean, _ = state.predict_reference(torch.cat([x, torch.zeros(9, 2, dtype=F64)], 1))
    assert float((module.bem_mean(x) - ref_mean).abs().max()) <= 1e-12
    assert json.loads(module.metadata())["model"] == "exact"


def test_export_out_and_both_formats(run_dir, tmp_path):
    out = tmp_path / "art" / "p.pt"
    written = export_run(run_dir / "checkpoint.pt", out=out, fmt="both")
    assert written == [out, out.with_suffix(".pt2")]
    assert all(p.is_file() for p in written)


def test_export_errors_exit_2(tmp_path, run_dir, posterior, capsys):
    assert main(["export", str(tmp_path / "missing")]) == 2
    assert "bemlearn export: error:" in capsys.readouterr().err
    state, meta = posterior
    bad = dataclasses.replace(state, S=2.0 * state.S)  # not (K + σ²I)⁻¹ of its own hyperparameters
    write_checkpoint(tmp_path / "bad", model_state={}, predictor_state=bad, metadata=meta)
    assert main(["export", str(tmp_path / "bad")]) == 2
    assert "PredictorState.S (exact) is not" in capsys.readouterr().err
    assert not (tmp_path / "bad" / "bem_predictor.pt").exists()


class _Shifted:
    """A predictor whose mean is off by ``shift`` rad."""

    def __init__(self, state, shift):
        self.state, self.shift = state, shift

    def forward(self, x):
        return self.predict_full(torch.cat([x, torch.zeros(x.shape[0], 2, dtype=F64)], 1))

    def bem_mean(self, x):
        return self.forward(x)[0]

    def predict_full(self, x):
        mean, std, _ = reference_posterior(self.state, x)
        return mean + self.shift, std


def test_verify_predictor_catches_a_wrong_mean(posterior):
    state, _ = posterior
    assert verify_predictor(_Shifted(state, 0.0), state) == (0.0, 0.0)
    with pytest.raises(ValueError, match=r"art.pt: forward disagrees .* max \|Δmean\| = 1e-06"):
        verify_predictor(_Shifted(state, 1e-6), state, where="art.pt")


def test_predict_bench_small_run(posterior):
    result = run_predict_bench(
        n_train=80, repeats=30, warmup=3, gpytorch_repeats=3, batch=500, n_parity=300, pt2=False, progress=False,
        aoti=False,
    )
    expected = {
        "torchscript forward", "torchscript bem_mean", "numpy folded bem_mean", "numpy folded forward",
        "numpy textbook bem_mean", "numpy textbook forward", "gpytorch forward", "gpytorch forward (fast_pred_var)",
        "torchscript empty call (x -> x)", "torchscript forward_latent",
    }
    assert set(result.latencies) == expected
    assert all(r.n in (30, 3) and r.p99_us >= r.median_us > 0 for r in result.latencies.values())
    assert set(result.batch_seconds) == {"torchscript forward", "torchscript bem_mean", "floor: v = L⁻¹k alone"}
    assert result.batch_threads == (os.cpu_count() or 1)
    assert result.parity["mean_abs"] <= 1e-10 and result.parity["std_rel"] <= 1e-8
    text = format_predict_bench(result)
    assert "GPyTorch forward / TorchScript forward" in text and "parity with GPyTorch on 300 inputs" in text


def test_bench_cli_rejects_bad_counts(capsys):
    assert main(["bench", "predict", "--repeats", "0"]) == 2
    assert "--repeats: expected a positive integer" in capsys.readouterr().err


class _VarScaled(_Shifted):
    """A predictor whose latent variance is off by the factor ``1 + rel``."""

    def __init__(self, state, rel):
        super().__init__(state, 0.0)
        self.rel = rel

    def predict_full(self, x):
        mean, std, _ = reference_posterior(self.state, x)
        return mean, std * (1.0 + self.rel) ** 0.5


def test_exact_rounding_bound_covers_an_ill_conditioned_export(tmp_path):
    """Inputs that barely vary along four of five lengthscales and little noise (κ₂(K) ≈ 1e9, as on a
    reaction wheel's small runs): the exported predictor's variance (Cholesky factor, then one
    triangular solve) stays inside the reference's per-input rounding bound, the check passes,
    and a variance off by 1e-3 relative is still refused."""
    from bemlearn.export.variance_factor import condition_number

    state, meta = synthetic_posterior(n_train=500, m=1, seed=3, noise=1e-7)
    state = dataclasses.replace(state, lengthscale=torch.tensor([0.3, 1e4, 1e4, 1.0, 1e4], dtype=F64))
    L = torch.linalg.cholesky(state.gram())
    y = state.Z[:, 2].sin()  # any smooth target: the check concerns the variance
    state = dataclasses.replace(state, alpha=torch.cholesky_solve(y[:, None], L)[:, 0], S=torch.cholesky_inverse(L))
    assert condition_number(state.gram()) > 1e8
    write_checkpoint(tmp_path / "run", model_state={}, predictor_state=state, metadata=meta)
    (path,) = export_run(tmp_path / "run" / "checkpoint.pt", out=tmp_path / "p.pt", fmt="torchscript", verify=False)
    module = load_torchscript(path)
    x = state.x_mean[:3] + 2 * state.x_std[:3] * torch.randn(256, 3, generator=torch.Generator().manual_seed(0), dtype=F64)
    x0 = torch.cat([x, torch.zeros(256, 2, dtype=F64)], 1)
    _, std = module.forward_latent(x)
    _, ref_std, bound = reference_posterior(state, x0)
    assert bool(((std.square() - ref_std.square()).abs() <= bound).all())
    verify_predictor(module, state, where="p.pt")
    with pytest.raises(ValueError, match="relative"):
        verify_predictor(_VarScaled(state, 1e-3), state, where="scaled")
