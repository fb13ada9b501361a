"""examples/cpp_libtorch: the TorchScript predictor and the AOTInductor package loaded from C++ with
the wheel's libtorch give Python's numbers (slow: compiling and linking against libtorch takes
~30 s; `bemlearn export --format aoti` compiles six methods, 1-2 min)."""

import dataclasses
import shutil
import subprocess
from pathlib import Path

import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.cli.main import main
from bemlearn.export import BEMPredictor, load_torchscript, save_torchscript, verify_predictor, write_checkpoint
from bemlearn.export.aoti import load_aoti_predictor
from tests.file_module import load_file_module

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "cpp_libtorch" / "build.py"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not any(shutil.which(c) for c in ("c++", "g++", "clang++")), reason="no C++ compiler on PATH"),
]


@pytest.fixture(scope="module")
def exe(tmp_path_factory):
    return _build(tmp_path_factory.mktemp("cpp") / "bem_predict")


def _build(out):
    return load_file_module(EXAMPLE, "cpp_libtorch_build", register=True).build(out)


def _banded_posterior():
    state, meta = synthetic_posterior(n_train=200, m=2, seed=4)
    return dataclasses.replace(state, std_scale=torch.tensor(1.3, dtype=torch.float64), input_std=0.2 * state.x_std), meta


def test_cpp_program_matches_python(tmp_path, exe):
    state, meta = _banded_posterior()   # a calibrated band
    pt = save_torchscript(BEMPredictor(state, meta), tmp_path / "bem_predictor.pt")
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


def test_export_aoti_cli_and_cpp_program(tmp_path, exe, capsys):
    """`bemlearn export --format aoti` writes a checked six-method package; the contract's parity holds on
    it in Python; the C++ example loads it with AOTIModelPackageLoader and prints TorchScript's numbers."""
    state, meta = _banded_posterior()
    write_checkpoint(tmp_path / "run", model_state={}, predictor_state=state, metadata=meta)
    assert main(["export", str(tmp_path / "run"), "--format", "aoti"]) == 0
    package = tmp_path / "run" / "bem_predictor_aoti.pt2"
    assert capsys.readouterr().out.strip() == f"wrote {package}"
    assert main(["export", str(tmp_path / "run")]) == 0     # the TorchScript file of the same checkpoint
    pt = tmp_path / "run" / "bem_predictor.pt"
    aoti = load_aoti_predictor(package)
    dm, dv = verify_predictor(aoti, state, n=2000, seed=3)     # every method against the dense posterior
    assert dm <= 1e-10 and dv <= 1e-8
    x = (state.x_mean[:6] + 0.3 * state.x_std[:6]).tolist()
    out = {}
    for path in (pt, package):
        res = subprocess.run([str(exe), str(path), *map(repr, x)], capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        out[path.suffix] = dict(line.split(" ", 1) for line in res.stdout.splitlines())
    ts, ao = out[".pt"], out[".pt2"]
    assert ao["metadata"] == ts["metadata"]
    for key in ("bem_mean", "forward", "forward_latent"):
        for a, b in zip(map(float, ao[key].split()), map(float, ts[key].split())):
            assert abs(a - b) <= 1e-14 * max(abs(b), 1e-3), (key, a, b)
    xt = torch.tensor([x], dtype=torch.float64)
    assert float(ao["bem_mean"]) == float(aoti.bem_mean(xt)[0])
    plain = torch._inductor.aoti_load_package(str(package))       # torch alone: the default model is forward
    assert all(torch.equal(a, b) for a, b in zip(plain(xt), aoti(xt)))
    assert float(ao["bem_mean_us"]) > 0 and float(ao["forward_us"]) > 0
    bad = subprocess.run([str(exe), str(package), "nan", *map(repr, x[1:])], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 1 and "error: BEMPredictor.bem_mean: x has non-finite entries" in bad.stderr
