"""examples/cpp_libtorch: the TorchScript predictor loaded from C++ with the wheel's libtorch
gives Python's numbers (slow: compiling and linking against libtorch takes ~30 s)."""

import dataclasses
import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.export import BEMPredictor, load_torchscript, save_torchscript

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "cpp_libtorch" / "build.py"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not any(shutil.which(c) for c in ("c++", "g++", "clang++")), reason="no C++ compiler on PATH"),
]


def _build(out):
    spec = importlib.util.spec_from_file_location("cpp_libtorch_build", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod.build(out)


def test_cpp_program_matches_python(tmp_path):
    state, meta = synthetic_posterior(n_train=200, m=2, seed=4)
    state = dataclasses.replace(state, std_scale=torch.tensor(1.3, dtype=torch.float64), input_std=0.2 * state.x_std)   # a calibrated band
    pt = save_torchscript(BEMPredictor(state, meta), tmp_path / "bem_predictor.pt")
    exe = _build(tmp_path / "bem_predict")
    x = (state.x_mean[:6] + 0.3 * state.x_std[:6]).tolist()
    res = subprocess.run([str(exe), str(pt), *map(repr, x)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    lines = dict(line.split(" ", 1) for line in res.stdout.splitlines())
    ts = load_torchscript(pt)
    xt = torch.tensor([x], dtype=torch.float64)
    ref_mean, ref_std = ts.forward(xt)
    assert abs(float(lines["bem_mean"]) - float(ts.bem_mean(xt)[0])) <= 1e-15
    mean, std = map(float, lines["forward"].split())
    assert abs(mean - float(ref_mean[0])) <= 1e-15 and abs(std - float(ref_std[0])) <= 1e-15 * float(ref_std[0]) + 1e-18
    lmean, lstd = map(float, lines["forward_latent"].split())
    ref_lmean, ref_lstd = ts.forward_latent(xt)
    assert abs(lmean - float(ref_lmean[0])) <= 1e-15 and abs(lstd - float(ref_lstd[0])) <= 1e-15 * float(ref_lstd[0]) + 1e-18
    assert std >= 1.3 * lstd * (1 + 1e-6)      # the band: c σ plus a nonzero gradient term
    assert lines["metadata"] == ts.metadata()
    assert float(lines["bem_mean_us"]) > 0
    bad = subprocess.run([str(exe), str(pt), "nan", *map(repr, x[1:])], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 1 and "BEMPredictor.bem_mean: x[0, 0] is nan" in bad.stderr
