"""The C export (``bemlearn export --format c``) against the TorchScript file, compiled with the system cc.

Each case is compiled with ``cc -std=c99 -Wall -Werror -O2`` into a shared library and called
through ctypes, one query per call, on random in-range inputs; the reference is the
TorchScript file of the same posterior: float64 mean within 1e-10 rad, std within 1e-8
relative (exact, sgpr, svgp, the sparse kinds also with S factored as L⁻ᵀ C L⁻¹; m = 1, 2), for the calibrated band of ``forward`` /
``predict_full`` (eq. B1, with std_scale c ≠ 1 and nonzero input_std s; also with K = 4 random
estimator columns δ, with and without input noise) and the latent std of
``forward_latent`` / ``predict_full_latent``.  float32 is held to the tolerances the export
enforces (mean 1e-4 rad, std 1e-2 relative) and to 4× the export's own error estimate.
"""

import ctypes
import dataclasses
import json

import numpy as np
import pytest
import torch
from test_export_parity import _exact_case, _metadata, _sgpr_case, _sgpr_factored_case, _svgp_case, _svgp_factored_case

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.cli.main import main
from bemlearn.export import BEMPredictor, c_sources, export_c, load_torchscript, save_torchscript, write_checkpoint
from bemlearn.export.c_build import STRICT_FLAGS, CPredictorLibrary, compile_shared, find_cc
from bemlearn.export.c_export import write_files
from bemlearn.export.c_posterior import support_box

pytestmark = pytest.mark.skipif(find_cc() is None, reason="no C compiler (cc, gcc, clang or $CC) on PATH")

MEAN_ATOL = 1e-10   # rad
STD_RTOL = 1e-8
N_QUERY = 2000

#: The band of the tests: c = 1.7 and s_i = 0.5 x_std_i (the gradient term is 18–98 % of the band² somewhere).
STD_SCALE = 1.7
INPUT_STD_FRACTION = 0.5
#: Estimator columns of the band's estimator term in the tests with one (eq. E2; K = 4 in practice).
N_ESTIMATORS = 4

CASES = {
    "exact-m1": (_exact_case, 300, 1),
    "exact-m2": (_exact_case, 300, 2),
    "sgpr-m1": (_sgpr_case, 400, 1),
    "sgpr-m2": (_sgpr_case, 400, 2),
    "svgp-m1": (_svgp_case, 400, 1),
    "svgp-m2": (_svgp_case, 400, 2),
    # S factored as L⁻ᵀ C L⁻¹ (triangular solve, then C's eigen-factor)
    "sgpr-factored-m2": (_sgpr_factored_case, 400, 2),
    "svgp-factored-m1": (_svgp_factored_case, 400, 1),
}


def _build(state, meta, tmp_path, *, prefix="bem", dtype="float64"):
    files = write_files(c_sources(state, meta, prefix=prefix, dtype=dtype), tmp_path)
    lib = compile_shared([files[1]], tmp_path / f"lib{prefix}.so", flags=(*STRICT_FLAGS, "-O2"))
    ts = load_torchscript(save_torchscript(BEMPredictor(state, meta), tmp_path / "bem_predictor.pt"))
    return CPredictorLibrary(lib, prefix=prefix, dtype=dtype), ts


def _in_range(state, n, seed, width):
    lo, hi = support_box(state.Z, state.x_mean, state.x_std, state.lengthscale)
    g = np.random.default_rng(seed)
    x = state.x_mean.numpy() + 1.5 * state.x_std.numpy() * g.standard_normal((n, state.dim))
    return np.clip(x, lo, hi)[:, :width], lo, hi


def _banded(state):
    """``state`` with the calibrated band switched on: c = STD_SCALE, s = INPUT_STD_FRACTION · x_std."""
    return dataclasses.replace(state, std_scale=torch.tensor(STD_SCALE, dtype=torch.float64),
                               input_std=INPUT_STD_FRACTION * state.x_std)


def _estimator_term(state, x):
    """(1/K) Σ_k (y_std k_Z(x̃)ᵀ δ_k)², rad², for physical ``x (B, n)`` (columns n.. held at 0), dense."""
    x0 = np.zeros((x.shape[0], state.dim))
    x0[:, : x.shape[1]] = x
    k = state.kernel_row(torch.from_numpy(x0))
    return (state.y_std * (k @ state.estimator_delta)).square().mean(-1).numpy()


def _with_estimators(state, m, *, seed=11):
    """``state`` with N_ESTIMATORS random estimator columns δ (M, K), scaled so that on in-range BEM inputs the
    estimator term's median equals the median of c² latent² (the state's own c)."""
    g = torch.Generator().manual_seed(seed)
    delta = torch.randn(state.n_support, N_ESTIMATORS, generator=g, dtype=torch.float64)
    x, _, _ = _in_range(state, 500, seed=12, width=3 * m)
    x0 = torch.cat([torch.from_numpy(x), torch.zeros(len(x), state.dim - 3 * m, dtype=torch.float64)], 1)
    latent2 = float(state.std_scale) ** 2 * state.predict_reference(x0)[1].square().numpy()
    term = _estimator_term(dataclasses.replace(state, estimator_delta=delta), x)
    return dataclasses.replace(state, estimator_delta=delta * float(np.sqrt(np.median(latent2) / np.median(term))))


@pytest.fixture(scope="module", params=list(CASES))
def case(request, tmp_path_factory):
    build, n, m = CASES[request.param]
    _, state = build(n, m, seed=7)
    state = _banded(state)
    meta = _metadata(state, m)
    lib, ts = _build(state, meta, tmp_path_factory.mktemp(request.param))
    return state, meta, lib, ts


@pytest.mark.parametrize("full", [False, True], ids=["bem", "full"])
def test_c_matches_torchscript(case, full):
    """forward / predict_full (band) and their _latent forms against the TorchScript methods."""
    state, meta, lib, ts = case
    x, _, _ = _in_range(state, N_QUERY, seed=1, width=state.dim if full else 3 * meta.m)
    x = np.ascontiguousarray(x)
    xt = torch.from_numpy(x)
    band_ref, latent_ref = (ts.predict_full, ts.predict_full_latent) if full else (ts.forward, ts.forward_latent)
    ref_mean, ref_std = (t.numpy() for t in band_ref(xt))
    ref_latent = latent_ref(xt)[1].numpy()
    mean, std, codes = lib.forward(x, full=full)
    lmean, latent, lcodes = lib.forward(x, full=full, latent=True)
    assert np.all(codes == 0) and np.all(lcodes == 0)
    assert np.abs(mean - ref_mean).max() <= MEAN_ATOL
    assert np.abs(std / ref_std - 1).max() <= STD_RTOL
    assert np.abs(latent / ref_latent - 1).max() <= STD_RTOL
    assert np.array_equal(lmean, mean)
    assert np.array_equal(lib.mean(x, full=full), mean)      # bem_mean / bem_full_mean are exactly forward's mean
    # the inputs exercise both terms of eq. (B1): the gradient term is a sizable part of the band² somewhere
    grad_share = 1 - STD_SCALE**2 * ref_latent**2 / ref_std**2
    assert grad_share.max() >= 0.15 and grad_share.min() >= -1e-12


def test_error_codes(case):
    state, meta, lib, ts = case
    n = 3 * meta.m
    x, lo, hi = _in_range(state, 1, seed=2, width=n)
    for col in range(n):
        for bad in (np.nan, np.inf, -np.inf):
            xb = x.copy()
            xb[0, col] = bad
            for latent in (False, True):
                mean, std, code = lib.forward(xb, latent=latent)
                assert code[0] == 1 and np.isnan(mean[0]) and np.isnan(std[0])
            assert np.isnan(lib.mean(xb)[0])
            assert int(lib.lib.bem_check_input(xb.ctypes.data_as(lib._ptr))) == 1
        for side, edge in ((-1, lo[col]), (1, hi[col])):       # just outside the range: code 2, still the GP's value
            xo = x.copy()
            xo[0, col] = edge + side * 0.1 * state.x_std[col].item()
            for latent, ref in ((False, ts.forward), (True, ts.forward_latent)):
                mean, std, code = lib.forward(xo, latent=latent)
                ref_mean, ref_std = (t.numpy() for t in ref(torch.from_numpy(xo)))
                assert code[0] == 2
                assert abs(mean[0] - ref_mean[0]) <= MEAN_ATOL and abs(std[0] / ref_std[0] - 1) <= STD_RTOL
    huge = np.full((1, n), 1e300)
    mean, std, code = lib.forward(huge)
    assert code[0] == 2 and (np.isnan(mean[0]) or np.isfinite(mean[0]))
    out = np.zeros(1)
    for fn in (lib._forward, lib._forward_latent, lib._predict_full, lib._predict_full_latent):
        assert fn(None, out.ctypes.data_as(lib._ptr), out.ctypes.data_as(lib._ptr)) == 3
        assert fn(x.ctypes.data_as(lib._ptr), None, out.ctypes.data_as(lib._ptr)) == 3


def test_header_metadata_matches_torchscript(case):
    state, meta, lib, ts = case
    doc = json.loads(lib.metadata_json)
    c = doc.pop("c_export")
    assert doc == json.loads(ts.metadata())
    assert c["dtype"] == "float64" and c["error_codes"]["BEM_ERR_OUT_OF_RANGE"] == 2 and c["n_estimators"] == 0
    lo, hi = support_box(state.Z, state.x_mean, state.x_std, state.lengthscale)
    assert np.array_equal(c["input_range"]["lo"], lo[: 3 * meta.m]) and np.array_equal(c["input_range"]["full_hi"], hi)


@pytest.mark.parametrize("name", ["sgpr-m2", "svgp-m1", "exact-m1", "sgpr-factored-m2"])
@pytest.mark.parametrize("full", [False, True], ids=["bem", "full"])
def test_float32_within_its_stated_error(name, full, tmp_path):
    """float32 band and latent std (BEM and full map) within the tolerances and 4× the export's estimate."""
    build, n, m = CASES[name]
    _, state = build(n, m, seed=7)
    state = _banded(state)
    meta = _metadata(state, m)
    lib, ts = _build(state, meta, tmp_path, prefix="bem32", dtype="float32")
    est = json.loads(lib.metadata_json)["c_export"]["float32_error"]
    x, _, _ = _in_range(state, N_QUERY, seed=3, width=state.dim if full else 3 * m)
    x = x.astype(np.float32).astype(np.float64)       # the float32 inputs, exactly, for the reference
    xt = torch.from_numpy(x)
    mean, std, codes = lib.forward(x, full=full)
    _, latent, _ = lib.forward(x, full=full, latent=True)
    ref_mean, ref_std = (t.numpy() for t in (ts.predict_full if full else ts.forward)(xt))
    ref_latent = (ts.predict_full_latent if full else ts.forward_latent)(xt)[1].numpy()
    err_mean, err_std = np.abs(mean - ref_mean).max(), np.abs(std / ref_std - 1).max()
    err_latent = np.abs(latent / ref_latent - 1).max()
    assert np.all(codes == 0)
    assert np.array_equal(lib.mean(x, full=full), mean)
    assert err_mean <= 1e-4 and err_std <= 1e-2 and err_latent <= 1e-2
    assert err_mean <= 4 * est["mean_abs"] + 1e-7 and err_std <= 4 * est["std_rel"] + 1e-6
    assert err_latent <= 4 * est["latent_std_rel"] + 1e-6


def test_float32_refused_for_a_cancelling_exact_posterior():
    state, meta = synthetic_posterior(n_train=500, noise=1e-6, seed=1)   # nearly noise-free: weights cancel
    with pytest.raises(ValueError, match=r"float32.*cannot be evaluated accurately.*off by up to"):
        c_sources(state, meta, dtype="float32")


@pytest.mark.parametrize("prefix", ["9bem", "bem-1", "", "__bem", "_Bem", "bem mean"])
def test_bad_prefix_rejected(prefix):
    state, meta = synthetic_posterior(n_train=20)
    with pytest.raises(ValueError, match="prefix"):
        c_sources(state, meta, prefix=prefix)


def test_two_prefixes_link_into_one_library(tmp_path):
    a, b = synthetic_posterior(n_train=40, seed=1), synthetic_posterior(n_train=50, seed=2)
    fa = write_files(c_sources(*a, prefix="pend_a"), tmp_path)
    fb = write_files(c_sources(*b, prefix="pend_b"), tmp_path)
    so = compile_shared([fa[1], fb[1]], tmp_path / "libboth.so")
    la, lb = CPredictorLibrary(so, prefix="pend_a"), CPredictorLibrary(so, prefix="pend_b")
    x = a[0].x_mean[:3].numpy()[None]
    for lib, (state, meta) in ((la, a), (lb, b)):
        ref = BEMPredictor(state, meta).bem_mean(torch.from_numpy(x))
        assert abs(lib.mean(x)[0] - float(ref[0])) <= MEAN_ATOL


def test_export_c_never_overwrites_without_force(tmp_path, capsys):
    state, meta = synthetic_posterior(n_train=30)
    run = tmp_path / "run"
    write_checkpoint(run, model_state={}, predictor_state=state, metadata=meta)
    out = tmp_path / "c"
    paths = export_c(run, out)
    assert [p.name for p in paths] == ["bem_predictor.h", "bem_predictor.c"]
    paths[1].write_text("/* edited */")
    with pytest.raises(FileExistsError, match="force"):
        export_c(run, out)
    assert paths[1].read_text() == "/* edited */"
    assert main(["export", str(run), "--format", "c", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "would overwrite" in err and "bem_predictor.c" in err and "use --force" in err
    assert main(["export", str(run), "--format", "c", "--out", str(out), "--force", "--dtype", "float64"]) == 0
    assert paths[1].read_text().startswith("/* bem_predictor.c")
    assert sorted(p.name for p in out.iterdir()) == ["bem_predictor.c", "bem_predictor.h"]   # no temporary files left
    assert main(["export", str(run), "--format", "c"]) == 2                                  # --out is required
    assert main(["export", str(run), "--dtype", "float32"]) == 2                             # C options need --format c
    assert "apply to --format c only" in capsys.readouterr().err


def _assert_bem_forward_matches(lib, ts, state):
    """bem_forward and bem_forward_latent (m = 1) against TorchScript on 500 in-range inputs."""
    x, _, _ = _in_range(state, 500, seed=4, width=3)
    for latent, ref in ((False, ts.forward), (True, ts.forward_latent)):
        mean, std, _ = lib.forward(x, latent=latent)
        ref_mean, ref_std = (t.numpy() for t in ref(torch.from_numpy(x)))
        assert np.abs(mean - ref_mean).max() <= MEAN_ATOL and np.abs(std / ref_std - 1).max() <= STD_RTOL


def test_signed_factor_matches_torchscript(tmp_path):
    """svgp with S_u ⋠ K_ZZ: an indefinite S and the signed factor path."""
    _, state = _svgp_case(400, 1, seed=7)
    S = state.S - 0.2 * torch.linalg.matrix_norm(state.S, ord=2) * torch.eye(state.n_support, dtype=torch.float64)
    state = dataclasses.replace(_banded(state), S=S)
    meta = _metadata(state, 1)
    lib, ts = _build(state, meta, tmp_path)
    assert "bem_signs" in (tmp_path / "bem_predictor.c").read_text()
    _assert_bem_forward_matches(lib, ts, state)


def test_signed_factored_matches_torchscript(tmp_path):
    """svgp, factored S = L⁻ᵀ C L⁻¹ with an indefinite C: triangular solve, then the signed inner factor."""
    _, state = _svgp_factored_case(400, 1, seed=7)
    C = state.S_inner - 0.5 * torch.eye(state.n_support, dtype=torch.float64)
    state = dataclasses.replace(_banded(state), S_inner=C)
    meta = _metadata(state, 1)
    lib, ts = _build(state, meta, tmp_path)
    src = (tmp_path / "bem_predictor.c").read_text()
    assert "bem_signs" in src and "bem_inner" in src
    _assert_bem_forward_matches(lib, ts, state)


def test_band_without_input_noise_on_the_bem_columns(tmp_path):
    """c ≠ 1 and input noise only on q̈_u, q̇_u: forward's band is c σ (no gradient code), predict_full's is not."""
    _, state = _exact_case(300, 1, seed=7)
    s = torch.zeros(state.dim, dtype=torch.float64)
    s[3:] = INPUT_STD_FRACTION * state.x_std[3:]
    state = dataclasses.replace(state, std_scale=torch.tensor(STD_SCALE, dtype=torch.float64), input_std=s)
    meta = _metadata(state, 1)
    lib, ts = _build(state, meta, tmp_path)
    text, header = (tmp_path / "bem_predictor.c").read_text(), (tmp_path / "bem_predictor.h").read_text()
    assert "#define BEM_BANDED 0" in header
    assert "bem_full_P" in text and "bem_bem_P" not in text and "#define BEM_FULL_BANDED 1" in header
    x, _, _ = _in_range(state, 500, seed=5, width=state.dim)
    mean, std, _ = lib.forward(x[:, :3])
    ref_mean, ref_std = (t.numpy() for t in ts.forward(torch.from_numpy(np.ascontiguousarray(x[:, :3]))))
    _, latent, _ = lib.forward(x[:, :3], latent=True)
    assert np.abs(mean - ref_mean).max() <= MEAN_ATOL and np.abs(std / ref_std - 1).max() <= STD_RTOL
    assert np.abs(std / (STD_SCALE * latent) - 1).max() <= 1e-14
    fmean, fstd, _ = lib.forward(x, full=True)
    ref_fmean, ref_fstd = (t.numpy() for t in ts.predict_full(torch.from_numpy(x)))
    assert np.abs(fmean - ref_fmean).max() <= MEAN_ATOL and np.abs(fstd / ref_fstd - 1).max() <= STD_RTOL


@pytest.mark.skipif(__import__("shutil").which("size") is None, reason="binutils `size` not on PATH")
def test_footprint_counts_the_variance_factor_bytes():
    from bemlearn.bench.c_footprint import measure_footprints

    rows = measure_footprints({"exact": (40,), "sgpr": (32,)}, dtypes=("float64", "float32"))
    for r in rows:
        size = 8 if r.dtype == "float64" else 4
        factor = r.M * (r.M + 1) // 2 + (0 if r.kind == "exact" else r.M * r.M)
        assert r.rodata_std == size * factor          # packed triangle (exact), and the dense M × M C factor (sgpr)
        assert r.data == 0                            # no writable static data: reentrant
        assert r.rodata_mean >= size * r.M * (5 + 2 + 1)   # W (d × M), two offsets c, weights w


def test_bench_times_the_c_export_with_its_floor():
    from bemlearn.bench.c_timing import time_c_predictor
    from bemlearn.bench.predict_bench import format_predict_bench, run_predict_bench

    state, meta = synthetic_posterior(n_train=64)
    x = state.x_mean[:3].numpy() + 0.5 * state.x_std[:3].numpy() * np.random.default_rng(0).standard_normal((8, 3))
    for s, band in ((state, 0), (_banded(state), 3 * 64)):   # band: n M more multiply-adds in bem_forward
        rows = time_c_predictor(c_sources(s, meta), x, kind="exact", calls=20, batches=5)
        assert [r.flags for r in rows] == ["-O2", "-O3 -march=native"]
        for r in rows:
            assert (r.n_exp, r.n_fma_mean, r.n_fma_forward, r.n_fma_band) == (64, 64 * 4, 64 * 4 + 64 * 65 // 2 + band, band)
            assert 0 < r.mean_ns < r.forward_ns and 0 < r.mean_ns < r.forward_latent_ns and r.exp_ns > 0 and r.fma_ns > 0
    result = run_predict_bench(n_train=64, repeats=50, warmup=5, gpytorch_repeats=2, batch=200, n_parity=100,
                               pt2=False, progress=False, aoti=False)
    text = format_predict_bench(result)
    assert "C export, single queries in a C loop" in text and "C mean / TS bem_mean" in text
    assert len(result.c_timings) == 2
    par = result.c_parity
    assert par["n"] == 3000 and "bem_predict_full / predict_full" in text
    assert max(par["forward_mean_abs"], par["full_mean_abs"]) <= MEAN_ATOL
    assert max(par[k] for k in ("forward_std_rel", "forward_latent_std_rel", "full_std_rel", "full_latent_std_rel")) <= STD_RTOL


def test_vectorized_exp_matches_libm(tmp_path):
    """The float64 export's own exp (a branch-free block the compiler vectorizes) against libm."""
    state, meta = synthetic_posterior(n_train=40)
    write_files(c_sources(state, meta), tmp_path)
    (tmp_path / "expcheck.c").write_text(
        '#include "bem_predictor.c"\n'
        "double bem_test_exp(double x)\n{\n    double in[BEM_BLOCK], out[BEM_BLOCK];\n    int j;\n"
        "    for (j = 0; j < BEM_BLOCK; ++j)\n        in[j] = x * (1.0 - j * 1e-9);\n"
        "    bem_exp_block(in, out);\n    return out[0];\n}\n"
        "double bem_libm_exp(double x) { return exp(x); }\n"
    )
    lib = ctypes.CDLL(str(compile_shared([tmp_path / "expcheck.c"], tmp_path / "libexp.so")))
    for f in (lib.bem_test_exp, lib.bem_libm_exp):
        f.restype, f.argtypes = ctypes.c_double, [ctypes.c_double]
    xs = np.concatenate([np.linspace(-708.0, 709.0, 200_001), np.linspace(-1.0, 1.0, 20_001),
                         [-745.2, -720.0, -708.4, -708.3, 709.5, 709.7, 709.8, 710.0, 0.0, -0.0]])
    ours, ref = np.array([lib.bem_test_exp(x) for x in xs]), np.array([lib.bem_libm_exp(x) for x in xs])
    normal = np.isfinite(ref) & (ref >= np.finfo(np.float64).tiny)
    assert np.abs(ours[normal] / ref[normal] - 1).max() <= 5e-16
    tiny = np.isfinite(ref) & ~normal                                        # subnormal and 0
    assert tiny.sum() >= 3 and np.abs(ours[tiny] - ref[tiny]).max() <= 1e-322
    assert np.array_equal(ours[~np.isfinite(ref)], ref[~np.isfinite(ref)])   # overflow: libm's inf
    for special in (np.nan, np.inf, -np.inf):
        assert np.array_equal(lib.bem_test_exp(special), lib.bem_libm_exp(special), equal_nan=True)


ESTIMATOR_CASES = ["exact-m1", "sgpr-m2", "svgp-m1"]


@pytest.fixture(scope="module", params=[(name, noise) for name in ESTIMATOR_CASES for noise in (True, False)],
                ids=lambda p: f"{p[0]}-{'noise' if p[1] else 'no-noise'}")
def estimator_case(request, tmp_path_factory):
    """K = 4 estimator columns, with input noise (all three terms of eq. B1) or without (s = 0: banded only
    through the estimator term)."""
    name, noise = request.param
    build, n, m = CASES[name]
    _, state = build(n, m, seed=7)
    state = _banded(state) if noise else dataclasses.replace(state, std_scale=torch.tensor(STD_SCALE, dtype=torch.float64))
    state = _with_estimators(state, m)
    meta = _metadata(state, m)
    tmp = tmp_path_factory.mktemp(f"{name}-est")
    lib, ts = _build(state, meta, tmp)
    return state, meta, lib, ts, noise, tmp


@pytest.mark.parametrize("full", [False, True], ids=["bem", "full"])
def test_c_band_with_estimator_term_matches_torchscript(estimator_case, full):
    """bem_forward / bem_predict_full with K = 4 estimator columns against TorchScript's forward / predict_full."""
    state, meta, lib, ts, noise, _ = estimator_case
    x, _, _ = _in_range(state, N_QUERY, seed=1, width=state.dim if full else 3 * meta.m)
    x = np.ascontiguousarray(x)
    xt = torch.from_numpy(x)
    band_ref, latent_ref = (ts.predict_full, ts.predict_full_latent) if full else (ts.forward, ts.forward_latent)
    ref_mean, ref_std = (t.numpy() for t in band_ref(xt))
    ref_latent = latent_ref(xt)[1].numpy()
    mean, std, codes = lib.forward(x, full=full)
    _, latent, _ = lib.forward(x, full=full, latent=True)
    assert np.all(codes == 0)
    assert np.abs(mean - ref_mean).max() <= MEAN_ATOL
    assert np.abs(std / ref_std - 1).max() <= STD_RTOL
    assert np.abs(latent / ref_latent - 1).max() <= STD_RTOL
    assert np.array_equal(lib.mean(x, full=full), mean)
    # the estimator term (dense, independent of the export) is a sizable part of the band² somewhere
    est_share = _estimator_term(state, x) / ref_std**2
    assert est_share.max() >= 0.15
    if not noise:   # s = 0: band² = c² latent² + the estimator term alone
        np.testing.assert_allclose(std**2, STD_SCALE**2 * latent**2 + _estimator_term(state, x), rtol=1e-8, atol=0)


def test_estimator_term_header_and_constants(estimator_case):
    """N_ESTIMATORS, one shared E array; without input noise no gradient code (BANDED 0), the E term still there."""
    state, _meta, lib, _ts, noise, tmp = estimator_case
    text, header = (tmp / "bem_predictor.c").read_text(), (tmp / "bem_predictor.h").read_text()
    assert f"#define BEM_N_ESTIMATORS {N_ESTIMATORS}" in header
    assert f"static const double bem_E[{N_ESTIMATORS * state.n_support}]" in text and "bem_bem_E" not in text
    assert f"#define BEM_BANDED {int(noise)}" in header and f"#define BEM_FULL_BANDED {int(noise)}" in header
    assert ("bem_full_P" in text) == noise
    assert json.loads(lib.metadata_json)["c_export"]["n_estimators"] == N_ESTIMATORS


@pytest.mark.parametrize("name", ["sgpr-m2", "exact-m1"])
def test_float32_with_estimator_term_within_its_stated_error(name, tmp_path):
    """float32 band with K = 4 estimator columns (BEM and full map) within the tolerances and 4× the estimate."""
    build, n, m = CASES[name]
    _, state = build(n, m, seed=7)
    state = _with_estimators(_banded(state), m)
    meta = _metadata(state, m)
    lib, ts = _build(state, meta, tmp_path, prefix="bem32", dtype="float32")
    est = json.loads(lib.metadata_json)["c_export"]["float32_error"]
    for full in (False, True):
        x, _, _ = _in_range(state, N_QUERY, seed=3, width=state.dim if full else 3 * m)
        x = x.astype(np.float32).astype(np.float64)
        mean, std, codes = lib.forward(x, full=full)
        ref_mean, ref_std = (t.numpy() for t in (ts.predict_full if full else ts.forward)(torch.from_numpy(x)))
        err_mean, err_std = np.abs(mean - ref_mean).max(), np.abs(std / ref_std - 1).max()
        assert np.all(codes == 0)
        assert err_mean <= 1e-4 and err_std <= 1e-2
        assert err_mean <= 4 * est["mean_abs"] + 1e-7 and err_std <= 4 * est["std_rel"] + 1e-6
