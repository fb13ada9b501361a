"""Queries whose kernel float64 cannot evaluate are refused, by every exported form alike (issue 22).

The rule (docs/predictor-contract.md, docs/c-export.md): with u = (x − x_mean) / (x_std ∘ ℓ),
a query with ‖u‖ > 10¹⁵⁰ is an error (TorchScript: ``ValueError`` inside the module; ``.pt2``:
:class:`~bemlearn.errors.PredictorInputError`; C: ``NAN`` and ``BEM_ERR_OUT_OF_RANGE``); any
nearer query returns the GP's value, which that far from the data is exactly the prior:
mean y_mean, latent std y_std σ_f.  Before issue 22 ``bem_mean`` of a query with an entry of
1e150 returned y_mean + 1.7 rad, and y_mean + 1e274 rad near 1e151.
"""

import dataclasses
import math

import numpy as np
import pytest
import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.errors import PredictorInputError
from bemlearn.export import BEMPredictor, c_sources, load_pt2_predictor, save_pt2, script_predictor
from bemlearn.export.c_build import STRICT_FLAGS, CPredictorLibrary, compile_shared, find_cc
from bemlearn.export.c_export import write_files

F64 = torch.float64
BOUND = 1e150
MAGNITUDES = [10.0 ** (k / 2) for k in range(280, 320)] + [1e200, 1e300, 1.7e308]


@pytest.fixture(scope="module", params=["raw", "centered"])
def forms(request, tmp_path_factory):
    """The TorchScript module, the .pt2 predictor and (with a C compiler) the C library of one posterior;
    "centered": the inputs' means far from zero in units of their spread, so the folded posterior
    takes its centered form."""
    state, meta = synthetic_posterior(n_train=40, m=1, seed=5)
    if request.param == "centered":
        state = dataclasses.replace(state, x_mean=state.x_mean + 40.0 * state.x_std)
    eager = BEMPredictor(state, meta)
    assert eager.bem.centered == (request.param == "centered")
    tmp = tmp_path_factory.mktemp(f"range-{request.param}")
    out = {"state": state, "eager": eager, "torchscript": script_predictor(eager),
           "pt2": load_pt2_predictor(save_pt2(eager, tmp / "p.pt2"))}
    if find_cc() is not None:
        files = write_files(c_sources(state, meta), tmp)
        out["c"] = CPredictorLibrary(compile_shared([files[1]], tmp / "libbem.so", flags=(*STRICT_FLAGS, "-O2")))
    return out


def _queries(state, n_inputs: int):
    """One query per (column, sign, magnitude): all columns at x_mean except one, ±magnitude."""
    base = state.x_mean[:n_inputs].clone()
    rows, norms = [], []
    for col in range(n_inputs):
        for sign in (1.0, -1.0):
            for mag in MAGNITUDES:
                x = base.clone()
                x[col] = sign * mag
                rows.append(x)
                full = torch.cat([x, torch.zeros(state.dim - n_inputs, dtype=F64)])   # x_0^e: q̈_u = q̇_u = 0
                norms.append(float(torch.linalg.vector_norm((full - state.x_mean) / (state.x_std * state.lengthscale))))
    return torch.stack(rows), norms


def _prior(state):
    return float(state.y_mean), float(state.y_std * state.outputscale.sqrt())


@pytest.mark.parametrize("method, n", [("bem_mean", 3), ("forward", 3), ("forward_latent", 3), ("full_mean", 5),
                                       ("predict_full", 5), ("predict_full_latent", 5)])
@pytest.mark.parametrize("artifact", ["torchscript", "pt2"])
def test_far_queries_give_the_prior_or_the_documented_error(forms, artifact, method, n):
    state, module = forms["state"], forms[artifact]
    y_mean, prior_std = _prior(state)
    xs, norms = _queries(state, n)
    refused = evaluated = 0
    for x, norm in zip(xs, norms):
        x = x[None]
        try:
            out = getattr(module, method)(x)
        except (torch.jit.Error, PredictorInputError) as exc:
            assert "too large to evaluate" in str(exc) and "1e150" in str(exc), str(exc)
            assert norm > BOUND * (1 - 1e-12), f"{artifact}.{method} refused ‖u‖ = {norm:.3g} (x = {x.tolist()})"
            refused += 1
            continue
        assert norm < BOUND * (1 + 1e-12), f"{artifact}.{method} evaluated ‖u‖ = {norm:.3g} (x = {x.tolist()}): {out}"
        mean = out[0] if isinstance(out, tuple) else out
        assert float(mean[0]) == y_mean, f"{artifact}.{method}(x = {x.tolist()}) = {float(mean[0])!r}, the prior mean is {y_mean!r}"
        if isinstance(out, tuple):
            assert math.isclose(float(out[1][0]), prior_std, rel_tol=1e-15), (x.tolist(), out)
        evaluated += 1
    assert refused > 0 and evaluated > 0


def test_an_entry_of_1e150_in_bem_mean(forms):
    """The issue's case: a query with one entry near 1e150 (here ‖u‖ is well above the bound)."""
    state = forms["state"]
    x = state.x_mean[:3].clone()[None]
    x[0, 0] = 1e150 / float(1.0 / (state.x_std[0] * state.lengthscale[0])) * 3.0   # ‖u‖ = 3e150
    for name in ("torchscript", "pt2"):
        with pytest.raises((torch.jit.Error, PredictorInputError), match="too large to evaluate"):
            forms[name].bem_mean(x)
    x[0, 0] = 1e150 / float(1.0 / (state.x_std[0] * state.lengthscale[0])) / 3.0   # ‖u‖ ≈ 3e149: evaluable
    assert float(forms["torchscript"].bem_mean(x)[0]) == float(state.y_mean) == float(forms["pt2"].bem_mean(x)[0])


@pytest.mark.skipif(find_cc() is None, reason="no C compiler (cc, gcc, clang or $CC) on PATH")
@pytest.mark.parametrize("full", [False, True], ids=["bem", "full"])
def test_the_c_export_applies_the_same_rule(forms, full):
    state, lib = forms["state"], forms["c"]
    n = 5 if full else 3
    y_mean, prior_std = _prior(state)
    xs, norms = _queries(state, n)
    x = xs.numpy()
    means = lib.mean(x, full=full)
    mean, std, codes = lib.forward(x, full=full, latent=True)
    for i, norm in enumerate(norms):
        if norm > BOUND * (1 + 1e-12):
            assert np.isnan(means[i]) and np.isnan(mean[i]) and np.isnan(std[i]) and codes[i] == 2, (x[i], means[i], codes[i])
        elif norm < BOUND * (1 - 1e-12):
            assert means[i] == y_mean and mean[i] == y_mean and codes[i] == 2, (x[i], means[i], mean[i], codes[i])
            assert math.isclose(std[i], prior_std, rel_tol=1e-15)
