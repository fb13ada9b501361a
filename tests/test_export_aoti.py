"""The AOTInductor package: the contract's numbers, input checks and range rule on compiled code.

Compiling takes ≈ 10–20 s per method, so the default suite compiles two (forward and bem_mean)
once per module; the whole six-method package goes through ``bemlearn export --format aoti``
in the slow ``tests/test_cpp_libtorch_example.py``.
"""

import dataclasses

import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.errors import ArgumentError, CheckpointError, PredictorInputError
from bemlearn.export import BEMPredictor, reference_posterior, script_predictor
from bemlearn.export.aoti import AotiPredictor, aoti_bytes, find_cxx, load_aoti_predictor
from bemlearn.export.export_run import export_targets
from bemlearn.export.folded_posterior import SENTINEL_BOUND

F64 = torch.float64

needs_cxx = pytest.mark.skipif(find_cxx() is None, reason="AOTInductor needs a C++ compiler (c++, g++ or clang++)")


@pytest.fixture(scope="module")
def compiled(tmp_path_factory):
    if find_cxx() is None:
        pytest.skip("AOTInductor needs a C++ compiler (c++, g++ or clang++)")
    state, meta = synthetic_posterior(n_train=90, m=1, seed=12)
    state = dataclasses.replace(state, std_scale=torch.tensor(1.2, dtype=F64), input_std=0.1 * state.x_std)   # a calibrated band
    eager = BEMPredictor(state, meta)
    data = aoti_bytes(eager, programs=("model", "bem_mean"))
    path = tmp_path_factory.mktemp("aoti") / "two_methods.pt2"
    path.write_bytes(data)
    return state, eager, script_predictor(eager), path, AotiPredictor(path, eager.metadata_json, programs=("model", "bem_mean"))


def _x(state, n, seed):
    g = torch.Generator().manual_seed(seed)
    return state.x_mean[:3] + 2 * state.x_std[:3] * torch.randn(n, 3, generator=g, dtype=F64)


@needs_cxx
@pytest.mark.parametrize("batch", [1, 2, 37])
def test_aoti_matches_dense_posterior_and_torchscript(compiled, batch):
    state, _, scripted, _, aoti = compiled
    x = _x(state, batch, seed=batch)
    mean, std = aoti(x)
    assert mean.shape == std.shape == (batch,)
    ref_mean, _, _ = reference_posterior(state, torch.cat([x, torch.zeros(batch, 2, dtype=F64)], 1))
    assert float((mean - ref_mean).abs().max()) <= 1e-10                          # the contract's parity target
    ts_mean, ts_std = scripted(x)
    assert float((mean - ts_mean).abs().max()) <= 1e-14
    assert float(((std - ts_std) / ts_std).abs().max()) <= 1e-12
    assert torch.equal(aoti.bem_mean(x), mean)


@needs_cxx
def test_aoti_input_errors_and_range_rule(compiled):
    state, _, scripted, _, aoti = compiled
    x = _x(state, 3, seed=5)
    # what the compiled code would read wrongly without the wrapper's check
    for bad, got in ((x.float(), r"got shape \[3, 3\] and dtype torch.float32"), (x[:, :2], r"got shape \[3, 2\]"),
                     (x[0], r"got shape \[3\]"), (x[:0], r"got shape \[0, 3\]"), (x[None], r"got shape \[1, 3, 3\]")):
        with pytest.raises(PredictorInputError, match=r"BEMPredictor.bem_mean: expected x of shape \(B, 3\), B >= 1.*" + got):
            aoti.bem_mean(bad)
    # non-contiguous views (transposed, a column slice of a wider tensor, a broadcast row) give the
    # numbers of their contiguous copies: the compiled code would read the strides as contiguous
    wide = torch.cat([x, torch.ones(3, 2, dtype=F64)], 1)[:, :3]
    for view in (x.T.contiguous().T, wide, x[:1].expand(4, 3)):
        assert not view.is_contiguous()
        assert float((aoti.bem_mean(view) - scripted.bem_mean(view.contiguous())).abs().max()) <= 1e-14
        assert torch.equal(aoti(view)[1], aoti(view.contiguous())[1])
    x[1, 2] = float("nan")
    with pytest.raises(PredictorInputError, match=r"BEMPredictor.bem_mean: x\[1, 2\] is nan; inputs must be finite \(1 non-finite"):
        aoti.bem_mean(x)
    x[1, 2] = -float("inf")
    with pytest.raises(PredictorInputError, match=r"BEMPredictor.forward: x\[1, 2\] is -inf"):
        aoti(x)
    # the range rule: ||u|| just above 1e150 is refused, just below gives the prior mean (as TorchScript)
    a = 1.0 / (state.x_std[2] * state.lengthscale[2])
    for factor, refused in ((1.01, True), (0.99, False)):
        xr = state.x_mean[:3].clone()[None]
        xr[0, 2] = state.x_mean[2] + factor * SENTINEL_BOUND**0.5 / float(a)
        if refused:
            with pytest.raises(PredictorInputError, match="x has finite entries too large to evaluate"):
                aoti.bem_mean(xr)
        else:
            assert float(aoti.bem_mean(xr)) == float(scripted.bem_mean(xr))
            assert float(aoti.bem_mean(xr)) == pytest.approx(float(state.y_mean), abs=1e-12)


@needs_cxx
def test_load_refuses_incomplete_and_foreign_packages(compiled, tmp_path):
    _, _, _, path, _ = compiled
    with pytest.raises(CheckpointError, match=r"not a bemlearn AOTInductor predictor \(missing \['predict_full'"):
        load_aoti_predictor(path)
    with pytest.raises(FileNotFoundError, match="missing_aoti.pt2: no such AOTInductor"):
        load_aoti_predictor(tmp_path / "missing_aoti.pt2")
    junk = tmp_path / "junk.pt2"
    junk.write_bytes(b"junk")
    with pytest.raises(CheckpointError, match="junk.pt2: not an AOTInductor package"):
        load_aoti_predictor(junk)


def test_aoti_targets(tmp_path):
    assert export_targets(tmp_path, fmt="aoti") == [tmp_path / "bem_predictor_aoti.pt2"]
    assert export_targets(tmp_path, out=tmp_path / "x.pt2", fmt="aoti") == [tmp_path / "x.pt2"]
    with pytest.raises(ArgumentError, match="must end in .pt2"):
        export_targets(tmp_path, out=tmp_path / "x.pt", fmt="aoti")
