"""Sparse posteriors frozen with S factored as L⁻ᵀ C L⁻¹ (``S_chol``, ``S_inner``).

References, all independent of the frozen state's own evaluation:

* the fitted model's own latent variance, :func:`bemlearn.models.predict.predict` (SGPR:
  σ_f² − VᵀV + WᵀW with V = L⁻¹k, W = L_B⁻¹V; SVGP: GPyTorch's whitened variational strategy);
* for the export: the eager ``predict_reference`` (kᵀ S k as vᵀ C v with C itself, not the
  eigen-factor the export uses), and the same posterior frozen unfactored (the explicit S),
  where that is accurate.

Tolerances: the variances are compared up to 10⁻⁸ relative plus the rounding bound 64 M ε σ_f²
of σ_f² − vᵀ C v (‖v‖² ≤ σ_f², ‖C‖ ≤ 1): near the data of a near-linear BEM σ̃² is 10⁻⁸ σ_f² and
less, and no float64 formula gets its relative error below ε σ_f² / σ̃² there.  The case with
lengthscale 30 has κ(K_ZZ) ≈ 3·10¹⁰; there the explicit S returns σ̃ = 0 at the median training
input (checked, so the tests can fail).
"""

import dataclasses

import gpytorch
import numpy as np
import pytest
import torch
from test_export_parity import _metadata

from bemlearn.export import BEMPredictor, load_checkpoint, load_pt2_predictor, save_pt2, script_predictor, write_checkpoint
from bemlearn.export.c_build import STRICT_FLAGS, CPredictorLibrary, compile_shared, find_cc
from bemlearn.export.c_export import write_files
from bemlearn.export.c_source import c_sources
from bemlearn.export.verify import reference_posterior, verify_predictor
from bemlearn.models import predictor_state
from bemlearn.models.kernels import se_gram
from bemlearn.models.predict import predict
from bemlearn.models.sgpr import SGPRBEMGP
from bemlearn.models.svgp import SVGPBEMGP

F64 = torch.float64
EPS = float(torch.finfo(F64).eps)
N, M, OUTPUTSCALE = 300, 24, 3000.0
NAMES = ("qdd_a0", "qd_a0", "q_a0", "qdd_u", "qd_u")    # m = 1: d = 5
STD_RTOL = 1e-8          # relative, on top of the rounding bound
MEAN_ATOL = 1e-10        # rad


def _data(seed=0):
    """A near-linear map with tiny noise (the cart-pole's regime): ``(N, 5)`` inputs, ``(N,)`` targets."""
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(N, 5, generator=g, dtype=F64)
    y = 0.5 * x[:, 0] - 0.2 * x[:, 2] + 0.02 * torch.sin(x[:, 1]) + 1e-3 * torch.randn(N, generator=g, dtype=F64)
    return x, y, x[torch.randperm(N, generator=g)[:M]].clone()


def _likelihood():
    lik = gpytorch.likelihoods.GaussianLikelihood(noise_constraint=gpytorch.constraints.GreaterThan(1e-10)).double()
    lik.noise = torch.tensor(1e-6, dtype=F64)
    return lik


def _set_kernel(model, lengthscale):
    model.covar_module.outputscale = torch.tensor(OUTPUTSCALE, dtype=F64)
    model.covar_module.base_kernel.lengthscale = torch.full((5,), lengthscale, dtype=F64)


def _freeze(model, lik, n_train=N):
    zeros = torch.zeros(5, dtype=F64)
    return predictor_state(model, lik, x_mean=zeros, x_std=torch.ones(5, dtype=F64), y_mean=torch.tensor(0.01, dtype=F64),
                           y_std=torch.tensor(0.05, dtype=F64), input_names=NAMES, n_train=n_train)


def _sgpr(lengthscale):
    x, y, Z = _data()
    lik = _likelihood()
    model = SGPRBEMGP(x, y, lik, Z)
    _set_kernel(model, lengthscale)
    model.eval()
    return model, lik, x, _freeze(model, lik)


def _svgp(lengthscale):
    """SVGP with q(v) = N(m, S_v) set to the SGPR's optimal whitened posterior (S_v = B⁻¹)."""
    sgpr, lik, x, _ = _sgpr(lengthscale)
    m, Sv = sgpr.whitened_posterior()
    model = SVGPBEMGP(sgpr.inducing_points.detach().clone(), jitter=sgpr.jitter).double()
    _set_kernel(model, lengthscale)
    model.set_variational(m.detach(), Sv.detach())
    model.eval()
    return model, lik, x, _freeze(model, lik)


def _bound(state):
    return 64 * state.n_support * EPS * float(state.outputscale)


def _unfactored(state):
    return dataclasses.replace(state, S_chol=None, S_inner=None)


@pytest.fixture(scope="module", params=[("sgpr", 8.0), ("sgpr", 30.0), ("svgp", 8.0), ("svgp", 30.0)],
                ids=["sgpr-ls8", "sgpr-ls30", "svgp-ls8", "svgp-ls30"])
def frozen(request):
    kind, ls = request.param
    return (_sgpr if kind == "sgpr" else _svgp)(ls)


def test_frozen_latent_variance_matches_the_fitted_model(frozen):
    """σ̃² of the frozen (factored) state at the training inputs against the model's own predict."""
    model, lik, x, state = frozen
    assert state.factored and state.S_chol.shape == (M, M) and state.S_inner.shape == (M, M)
    _, var = predict(model, lik, x)
    frozen_var = (state.predict_reference(x)[1] / state.y_std).square()
    err = (frozen_var - var).abs() / (STD_RTOL * var + _bound(state))
    assert float(err.max()) <= 1.0


def test_explicit_S_loses_the_variance_when_K_ZZ_is_ill_conditioned():
    """The same posterior with only the explicit S (as frozen before the factor): σ̃ = 0 at the median
    training input where the model has σ̃ ≈ 0.012 (κ(K_ZZ) ≈ 3·10¹⁰)."""
    model, lik, x, state = _sgpr(30.0)
    _, var = predict(model, lik, x)
    old = _unfactored(state).predict_reference(x)[1] / state.y_std
    assert float(var.sqrt().median()) > 1e-3
    assert float((old.square() - var).abs().max()) > 1e3 * (STD_RTOL * float(var.max()) + _bound(state))


def test_sgpr_factor_is_I_minus_B_inverse(frozen):
    """C of an SGPR is I − B⁻¹ (eigenvalues in [0, 1)); L Lᵀ is K_ZZ up to the jitter on the diagonal."""
    _model, _, _, state = frozen
    lam = torch.linalg.eigvalsh(state.S_inner)
    if state.kind == "sgpr":
        assert float(lam.min()) >= -1e-12 and float(lam.max()) < 1.0
    Kzz = se_gram(state.Z, state.lengthscale, state.outputscale)
    D = state.S_chol @ state.S_chol.T - Kzz
    assert float((D - torch.diag(torch.diagonal(D))).abs().max()) <= 1e-10 * OUTPUTSCALE
    assert float(torch.diagonal(D).min()) >= 0.0


@pytest.fixture(scope="module", params=["sgpr", "svgp"])
def exported(request, tmp_path_factory):
    _model, _lik, x, state = (_sgpr if request.param == "sgpr" else _svgp)(30.0)
    meta = _metadata(state, 1)
    eager = BEMPredictor(state, meta)
    tmp = tmp_path_factory.mktemp(f"factored-{request.param}")
    pt2 = load_pt2_predictor(save_pt2(eager, tmp / "bem_predictor.pt2"))
    return state, meta, x, eager, script_predictor(eager), pt2, tmp


def _queries(state, x):
    """Training inputs (physical; σ̃ smallest there), their x_0^e rows, and random inputs around them."""
    phys = x * state.x_std + state.x_mean
    g = torch.Generator().manual_seed(3)
    rand = state.x_mean + 1.5 * state.x_std * torch.randn(200, 5, generator=g, dtype=F64)
    return torch.cat([phys, rand])


def test_exported_factored_matches_eager_and_reference(exported):
    """TorchScript, torch.export and the eager module vs predict_reference (C directly) and verify's reference."""
    state, _, x, eager, scripted, pt2, _ = exported
    assert eager.full.factored and eager.full.triangular and eager.bem.factored
    q = _queries(state, x)
    ref_mean, ref_std = state.predict_reference(q)
    _vref_mean, vref_std, bound = reference_posterior(state, q)
    assert bound == pytest.approx(64 * M * EPS * float(torch.linalg.matrix_norm(state.S_inner, ord=2)) * OUTPUTSCALE
                                  * float(state.y_std) ** 2, rel=1e-12)
    var_tol = STD_RTOL * ref_std.square() + _bound(state) * float(state.y_std) ** 2
    assert float(((vref_std.square() - ref_std.square()).abs() / var_tol).max()) <= 1.0
    for module in (eager, scripted, pt2):
        mean, std = module.predict_full_latent(q)
        assert float((mean - ref_mean).abs().max()) <= MEAN_ATOL
        assert float(((std.square() - ref_std.square()).abs() / var_tol).max()) <= 1.0
    verify_predictor(scripted, state, where="scripted factored")
    verify_predictor(pt2, state, where="pt2 factored")


def test_factored_export_equals_dense_export_when_S_is_accurate():
    """Well-conditioned (lengthscale 8, κ ≈ 10⁷): the factored and the explicit-S exports agree."""
    _, _, x, state = _sgpr(8.0)
    meta = _metadata(state, 1)
    fac, dense = script_predictor(BEMPredictor(state, meta)), script_predictor(BEMPredictor(_unfactored(state), meta))
    q = _queries(state, x)
    (m1, s1), (m2, s2) = fac.predict_full_latent(q), dense.predict_full_latent(q)
    assert float((m1 - m2).abs().max()) <= MEAN_ATOL
    var_tol = 1e-6 * s2.square() + _bound(state) * float(state.y_std) ** 2 * 1e3   # the explicit S's own rounding
    assert float(((s1.square() - s2.square()).abs() / var_tol).max()) <= 1.0


@pytest.mark.skipif(find_cc() is None, reason="no C compiler (cc, gcc, clang or $CC) on PATH")
def test_c_factored_matches_torchscript(exported):
    """The C export (triangular solve, then C's eigen-factor) vs TorchScript at κ(K_ZZ) ≈ 3·10¹⁰, latent and band."""
    state, meta, x, _, scripted, _, tmp = exported
    files = write_files(c_sources(state, meta), tmp)
    assert "bem_inner" in files[1].read_text()
    lib = CPredictorLibrary(compile_shared([files[1]], tmp / "libbem.so", flags=(*STRICT_FLAGS, "-O2")))
    q = np.ascontiguousarray(_queries(state, x).numpy())
    for latent, ref in ((True, scripted.predict_full_latent), (False, scripted.predict_full)):
        mean, std, _codes = lib.forward(q, full=True, latent=latent)
        ref_mean, ref_std = (t.numpy() for t in ref(torch.from_numpy(q)))
        var_tol = STD_RTOL * ref_std**2 + _bound(state) * float(state.y_std) ** 2
        assert np.abs(mean - ref_mean).max() <= MEAN_ATOL
        assert (np.abs(std**2 - ref_std**2) / var_tol).max() <= 1.0


def test_checkpoint_round_trip_keeps_the_factor(tmp_path):
    _, _, x, state = _sgpr(30.0)
    path = write_checkpoint(tmp_path, model_state={}, predictor_state=state, metadata=_metadata(state, 1))
    loaded = load_checkpoint(path).predictor_state
    assert torch.equal(loaded.S_chol, state.S_chol) and torch.equal(loaded.S_inner, state.S_inner)
    assert torch.equal(loaded.predict_reference(x)[1], state.predict_reference(x)[1])


def test_old_checkpoint_without_the_factor_loads_and_predicts_as_before(tmp_path):
    """A checkpoint written before S_chol / S_inner: no such keys; S is used as given (kᵀ S k)."""
    _, _, x, state = _sgpr(8.0)
    old = _unfactored(state)
    path = write_checkpoint(tmp_path, model_state={}, predictor_state=old, metadata=_metadata(old, 1))
    raw = torch.load(path, weights_only=True)["predictor_state"]
    assert "S_chol" not in raw and "S_inner" not in raw
    loaded = load_checkpoint(path).predictor_state
    assert loaded.S_chol is None and not loaded.factored
    k = loaded.kernel_row(x)   # (N, M)
    dense = loaded.y_std * (loaded.outputscale - ((k @ loaded.S) * k).sum(-1)).clamp_min(0).sqrt()
    assert torch.allclose(loaded.predict_reference(x)[1], dense, rtol=1e-12, atol=0)
    predictor = BEMPredictor(loaded, _metadata(loaded, 1))
    assert not predictor.full.factored and not predictor.full.triangular


def test_bad_factor_is_rejected():
    _, _, _, state = _sgpr(8.0)
    with pytest.raises(ValueError, match="give both"):
        dataclasses.replace(state, S_inner=None)
    with pytest.raises(ValueError, match="only for the sparse kinds"):
        dataclasses.replace(state, kind="exact")
    with pytest.raises(ValueError, match="lower-triangular"):
        dataclasses.replace(state, S_chol=state.S_chol.T.contiguous())
    with pytest.raises(ValueError, match="symmetric"):
        dataclasses.replace(state, S_inner=state.S_inner + torch.triu(torch.ones(M, M, dtype=F64), 1) * 1e-3)
    with pytest.raises(ValueError, match=r"S_inner: expected shape \(24, 24\)"):
        dataclasses.replace(state, S_inner=state.S_inner[:3, :3])
    other = _sgpr(12.0)[3]       # a Cholesky factor of another K_ZZ
    with pytest.raises(ValueError, match="S_chol.*not K_ZZ"):
        BEMPredictor(dataclasses.replace(state, S_chol=other.S_chol), _metadata(state, 1))
