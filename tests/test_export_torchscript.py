"""The TorchScript artifact: contract, input errors, round trip, loading without bemlearn."""

import json
import os
import subprocess
import sys
import textwrap
import warnings

import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.export import BEMPredictor, export_run, load_torchscript, save_torchscript, script_predictor, write_checkpoint
from tests.isolation import BLOCK_BEMLEARN

F64 = torch.float64
REQUIRED_KEYS = {
    "robot", "joint_names", "m", "inputs", "units", "model", "n_train", "n_inducing",
    "hyperparameters", "bemlearn_version", "data_sha256",
}


@pytest.fixture(scope="module")
def model():
    state, meta = synthetic_posterior(n_train=150, m=2, seed=4)
    eager = BEMPredictor(state, meta)
    return state, meta, eager, script_predictor(eager)


def _x(state, n, seed, width):
    g = torch.Generator().manual_seed(seed)
    return state.x_mean[:width] + state.x_std[:width] * torch.randn(n, width, generator=g, dtype=F64)


def test_scripted_matches_eager_and_reference(model):
    state, _, eager, scripted = model
    x = _x(state, 64, seed=0, width=6)
    mean, std = scripted(x)
    eager_mean, eager_std = eager(x)
    assert mean.shape == (64,) and std.shape == (64,) and mean.dtype == F64
    assert torch.allclose(mean, eager_mean, rtol=0, atol=1e-15)
    assert torch.allclose(std, eager_std, rtol=1e-14, atol=0)
    ref_mean, ref_std = state.predict_reference(torch.cat([x, torch.zeros(64, 2, dtype=F64)], 1))
    assert float((mean - ref_mean).abs().max()) <= 1e-12
    # the reference uses the explicit inverse S (≈1e-8 relative); the export solves with L
    assert float(((std - ref_std) / ref_std).abs().max()) <= 1e-6


def test_bem_mean_and_predict_full_agree_with_forward(model):
    state, _, _, scripted = model
    x = _x(state, 33, seed=1, width=6)
    mean, std = scripted(x)
    assert torch.equal(scripted.bem_mean(x), mean)
    full_mean, full_std = scripted.predict_full(torch.cat([x, torch.zeros(33, 2, dtype=F64)], 1))
    assert torch.allclose(full_mean, mean, rtol=0, atol=1e-14)
    assert torch.allclose(full_std, std, rtol=1e-12, atol=0)
    one_mean, one_std = scripted(x[5:6])
    assert torch.allclose(one_mean, mean[5:6], rtol=0, atol=1e-15) and torch.allclose(one_std, std[5:6], rtol=1e-14, atol=0)


def test_metadata_json(model):
    state, meta, _, scripted = model
    doc = json.loads(scripted.metadata())
    assert set(doc) >= REQUIRED_KEYS
    assert doc["model"] == "exact" and doc["n_inducing"] is None and doc["m"] == 2
    assert doc["inputs"] == list(meta.input_names[:6]) and doc["full_inputs"] == list(meta.input_names)
    assert doc["units"]["qdd_a1"] == "rad/s^2" and doc["units"]["q_a0"] == "rad" and doc["units"]["mean"] == "rad"
    assert doc["n_train"] == 150 and doc["data_sha256"] == meta.data_sha256
    assert doc["normalization"]["y_std"] == float(state.y_std)


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (lambda x: x.float(), r"expected x of shape \(B, 6\), B >= 1, and dtype torch.float64.*dtype torch.float32"),
        (lambda x: x[:, :5], r"got shape \[4, 5\]"),
        (lambda x: x[0], r"got shape \[6\]"),
        (lambda x: x[None], r"got shape \[1, 4, 6\]"),
        (lambda x: x[:0], r"got shape \[0, 6\]"),
        (lambda x: x.index_put((torch.tensor([2]), torch.tensor([3])), torch.tensor(float("nan"), dtype=F64)), r"x\[2, 3\] is nan"),
        (lambda x: x.index_put((torch.tensor([0]), torch.tensor([5])), torch.tensor(-float("inf"), dtype=F64)), r"x\[0, 5\] is -inf"),
        (lambda x: x[:1].index_put((torch.tensor([0]), torch.tensor([1])), torch.tensor(float("inf"), dtype=F64)), r"x\[0, 1\] is inf"),
        (lambda x: torch.full_like(x, 1e160), r"finite entries too large to evaluate"),
    ],
)
@pytest.mark.parametrize("method", ["forward", "bem_mean"])
def test_bad_input_raises_inside_the_module(model, bad, message, method):
    state, _, eager, scripted = model
    x = bad(_x(state, 4, seed=2, width=6))
    with pytest.raises(torch.jit.Error, match=f"ValueError: BEMPredictor.{method}: .*{message}"):
        getattr(scripted, method)(x)
    with pytest.raises(ValueError, match=message):
        getattr(eager, method)(x)


def test_predict_full_checks_its_width(model):
    state, _, _, scripted = model
    with pytest.raises(torch.jit.Error, match=r"predict_full: expected x of shape \(B, 8\)"):
        scripted.predict_full(_x(state, 3, seed=0, width=6))


def test_save_load_round_trip(model, tmp_path):
    state, _, eager, scripted = model
    path = save_torchscript(eager, tmp_path / "sub" / "bem_predictor.pt")
    loaded = load_torchscript(path)
    x = _x(state, 10, seed=3, width=6)
    for a, b in zip(loaded(x), scripted(x)):
        assert torch.equal(a, b)
    assert loaded.metadata() == eager.metadata_json
    extra = {"metadata.json": ""}
    torch.jit.load(str(path), _extra_files=extra)
    assert json.loads(extra["metadata.json"]) == json.loads(eager.metadata_json)


def test_load_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.pt"):
        load_torchscript(tmp_path / "nope.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="junk.pt: not a TorchScript file"):
        load_torchscript(junk)


_ISOLATED = BLOCK_BEMLEARN + textwrap.dedent(
    """
    try:
        import bemlearn  # noqa: F401
    except ImportError:
        pass
    else:
        raise SystemExit("bemlearn was importable")
    module = torch.jit.load("bem_predictor.pt")
    case = torch.load("case.pt")
    mean, std = module(case["x"])
    assert torch.equal(mean, case["mean"]) and torch.equal(std, case["std"]), "forward differs"
    assert torch.equal(module.bem_mean(case["x"]), case["mean"]), "bem_mean differs"
    full_mean, _ = module.predict_full(case["x_full"])
    assert torch.equal(full_mean, case["full_mean"]), "predict_full differs"
    assert json.loads(module.metadata())["m"] == 2
    try:
        module(case["x"].float())
    except Exception as exc:
        assert "expected x of shape (B, 6)" in str(exc), str(exc)
    else:
        raise SystemExit("float32 input accepted")
    assert not any(m == "bemlearn" or m.startswith("bemlearn.") for m in sys.modules)
    print("OK")
    """
)


def test_loads_and_runs_without_bemlearn(model, tmp_path):
    state, _, eager, scripted = model
    save_torchscript(eager, tmp_path / "bem_predictor.pt")
    x = _x(state, 5, seed=5, width=6)
    x_full = _x(state, 5, seed=6, width=8)
    mean, std = scripted(x)
    torch.save({"x": x, "mean": mean, "std": std, "x_full": x_full, "full_mean": scripted.predict_full(x_full)[0]}, tmp_path / "case.pt")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(
        [sys.executable, "-I", "-W", "ignore", "-c", _ISOLATED], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "OK"


def test_full_mean_equals_predict_full_mean(model):
    """``full_mean`` (the loop path of momentum-corrected EIC) is ``predict_full``'s mean."""
    state, _, _, scripted = model
    x = _x(state, 17, seed=3, width=8)
    mean, _ = scripted.predict_full(x)
    torch.testing.assert_close(scripted.full_mean(x), mean, rtol=0, atol=1e-15)
    with pytest.raises(Exception, match="full_mean"):
        scripted.full_mean(x[:, :6])


def test_export_emits_no_torch_jit_deprecation_warning(model, tmp_path):
    """torch 2.13 warns "`torch.jit.script` is deprecated" (and .freeze/.save/.load); bemlearn silences
    exactly those at its call sites, so exporting and loading the .pt shows none even with every
    warning enabled (pyproject's test filter is overridden by ``simplefilter("always")``)."""
    state, meta, _, _ = model
    write_checkpoint(tmp_path / "run", model_state={}, predictor_state=state, metadata=meta)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        (path,) = export_run(tmp_path / "run", fmt="torchscript")
        load_torchscript(path)
        warnings.warn("`torch.jit.probe` is deprecated. Please switch to `torch.export`.", DeprecationWarning, stacklevel=1)  # the recorder works
    jit = [str(w.message) for w in caught if issubclass(w.category, DeprecationWarning) and "torch.jit" in str(w.message)]
    assert jit == ["`torch.jit.probe` is deprecated. Please switch to `torch.export`."]
