"""The torch.export (.pt2) artifact: same numbers as TorchScript, dynamic batch, input errors."""

import json
import os
import subprocess
import sys
import textwrap

import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.export import BEMPredictor, load_pt2_predictor, save_pt2, script_predictor
from tests.isolation import BLOCK_BEMLEARN

F64 = torch.float64


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    state, meta = synthetic_posterior(n_train=120, m=1, seed=8)
    eager = BEMPredictor(state, meta)
    path = save_pt2(eager, tmp_path_factory.mktemp("pt2") / "bem_predictor.pt2")
    return state, eager, script_predictor(eager), path, load_pt2_predictor(path)


def _x(state, n, width, seed=0):
    g = torch.Generator().manual_seed(seed)
    return state.x_mean[:width] + state.x_std[:width] * torch.randn(n, width, generator=g, dtype=F64)


@pytest.mark.parametrize("batch", [1, 2, 37])
def test_pt2_matches_torchscript(exported, batch):
    state, _, scripted, _, pt2 = exported
    x = _x(state, batch, 3, seed=batch)
    for a, b in zip(pt2(x), scripted(x)):
        assert a.shape == (batch,)
        assert torch.allclose(a, b, rtol=1e-14, atol=1e-15)
    assert torch.allclose(pt2.bem_mean(x), scripted.bem_mean(x), rtol=0, atol=1e-15)
    xf = _x(state, batch, 5, seed=batch + 100)
    for a, b in zip(pt2.predict_full(xf), scripted.predict_full(xf)):
        assert torch.allclose(a, b, rtol=1e-14, atol=1e-15)


def test_plain_torch_export_load_gives_forward_and_metadata(exported):
    state, eager, scripted, path, _ = exported
    extra = {"metadata.json": ""}
    program = torch.export.load(str(path), extra_files=extra)
    x = _x(state, 4, 3, seed=9)
    for a, b in zip(program.module()(x), scripted(x)):
        assert torch.allclose(a, b, rtol=1e-14, atol=1e-15)
    assert json.loads(extra["metadata.json"]) == json.loads(eager.metadata_json)


def test_pt2_input_errors(exported):
    state, _, _, _, pt2 = exported
    x = _x(state, 3, 3, seed=10)
    with pytest.raises(ValueError, match="dtype torch.float32"):
        pt2.bem_mean(x.float())
    with pytest.raises(ValueError, match=r"expected x of shape \(B, 3\).*got shape \[3, 2\]"):
        pt2(x[:, :2])
    x[1, 2] = float("nan")
    with pytest.raises(ValueError, match=r"BEMPredictor.bem_mean: x\[1, 2\] is nan"):
        pt2.bem_mean(x)
    x[1, 2] = float("inf")
    with pytest.raises(ValueError, match=r"BEMPredictor.forward: x\[1, 2\] is inf"):
        pt2(x)


def test_load_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.pt2"):
        load_pt2_predictor(tmp_path / "missing.pt2")
    junk = tmp_path / "junk.pt2"
    junk.write_bytes(b"junk")
    with pytest.raises(ValueError, match="junk.pt2: not a torch.export .pt2 archive"):
        load_pt2_predictor(junk)


_ISOLATED = BLOCK_BEMLEARN + textwrap.dedent(
    """
    from torch.export.pt2_archive._package import load_pt2

    case = torch.load("case.pt")
    extra = {"metadata.json": ""}
    mean, std = torch.export.load("bem_predictor.pt2", extra_files=extra).module()(case["x"])
    assert torch.equal(mean, case["mean"]) and torch.equal(std, case["std"]), "forward differs"
    programs = load_pt2("bem_predictor.pt2").exported_programs
    assert torch.equal(programs["bem_mean"].module()(case["x"]), case["mean"]), "bem_mean differs"
    assert json.loads(extra["metadata.json"])["m"] == 1
    assert not any(m == "bemlearn" or m.startswith("bemlearn.") for m in sys.modules)
    print("OK")
    """
)


def test_pt2_loads_without_bemlearn(exported, tmp_path):
    state, _, _, path, pt2 = exported
    x = _x(state, 6, 3, seed=11)
    mean, std = pt2(x)
    torch.save({"x": x, "mean": mean, "std": std}, tmp_path / "case.pt")
    (tmp_path / "bem_predictor.pt2").write_bytes(path.read_bytes())
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(
        [sys.executable, "-I", "-W", "ignore", "-c", _ISOLATED], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "OK"
