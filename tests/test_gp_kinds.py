"""GP kinds are classes (issue 30): one registry turns a kind's name into its class, every kind's
``forward`` is the prior, and no code outside the registry compares with a kind's name."""

from __future__ import annotations

import ast
import math
from pathlib import Path
from typing import get_args, get_type_hints

import pytest
import torch

from bemlearn.fitting import FIT_RECIPES, GPConfig, fit_exact, fit_recipe, minimize, optimal_variational
from bemlearn.fitting.result import FitResult
from bemlearn.models import GP_KINDS, SGPRBEMGP, SVGPBEMGP, ExactBEMGP, as_gp, gaussian_likelihood, gp_class, gp_kind_of
from bemlearn.models.predictor_state import GPKind

PACKAGE = Path(__file__).resolve().parents[1] / "bemlearn"
#: The one module allowed to read a kind's name (it builds the name → class map).
REGISTRY = "models/gp_kinds.py"
F64 = torch.float64


# ---- no comparison with a kind's name outside the registry -----------------------------------------
def _strings(node: ast.AST) -> list[str]:
    """String constants of a comparison operand: itself, or the items of a tuple/list/set literal."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return [s for e in node.elts for s in _strings(e)]
    return []


def kind_comparisons(source: str, names: frozenset[str]) -> list[int]:
    """Lines that compare something with a kind's name: ``==``/``!=``/``in``/``is`` against the string
    (or a literal collection holding it), or a ``match`` case on it."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare):
            if any(s in names for operand in (node.left, *node.comparators) for s in _strings(operand)):
                out.append(node.lineno)
        elif isinstance(node, ast.MatchValue) and any(s in names for s in _strings(node.value)):
            out.append(node.lineno)
    return out


def test_no_code_outside_the_registry_compares_with_a_kind_name():
    names = frozenset(GP_KINDS)
    files = sorted(PACKAGE.rglob("*.py"))
    assert len(files) > 100 and (PACKAGE / REGISTRY).is_file()
    found = [f"{p.relative_to(PACKAGE).as_posix()}:{line}" for p in files if p.relative_to(PACKAGE).as_posix() != REGISTRY
             for line in kind_comparisons(p.read_text(encoding="utf-8"), names)]
    assert found == [], "compare with the kind's class (``state.sparse``, ``isinstance``), not its name:\n" + "\n".join(found)


@pytest.mark.parametrize("source", [
    'if kind == "exact":\n    pass',
    'ok = "svgp" != config.kind',
    'sparse = state.kind in ("sgpr", "svgp")',
    'x = kind not in ["exact"]',
    'match kind:\n    case "sgpr":\n        pass',
    'if kind is "exact":\n    pass',
])
def test_the_check_finds_a_planted_comparison(source):
    assert kind_comparisons(source, frozenset(GP_KINDS)) == [1 if "match" not in source else 2]


@pytest.mark.parametrize("source", [
    'GPConfig(kind="exact")',
    'name = "exact"',
    'if state.sparse:\n    pass',
    'if kind == "hinge":\n    pass',
])
def test_the_check_allows_what_is_not_a_comparison_with_a_kind(source):
    assert kind_comparisons(source, frozenset(GP_KINDS)) == []


# ---- the registry --------------------------------------------------------------------------------
def test_the_registry_is_the_one_list_of_kinds():
    assert list(GP_KINDS) == ["exact", "sgpr", "svgp"]
    assert set(get_args(GPKind)) == set(GP_KINDS)                          # the checkpoint's type
    assert set(get_args(get_type_hints(GPConfig)["kind"])) == set(GP_KINDS)  # the config's choices
    for name, cls in GP_KINDS.items():
        assert gp_class(name) is cls and cls.kind == name
        assert fit_recipe(cls) is FIT_RECIPES[cls]
    assert set(FIT_RECIPES) == set(GP_KINDS.values())
    assert [cls.sparse for cls in GP_KINDS.values()] == [False, True, True]


def test_an_unregistered_model_is_named():
    with pytest.raises(TypeError, match=r"model: expected one of \['ExactBEMGP', 'SGPRBEMGP', 'SVGPBEMGP'\], got Linear"):
        as_gp(torch.nn.Linear(2, 1))
    with pytest.raises(TypeError, match="got Linear"):
        fit_recipe(torch.nn.Linear)


def _data(n: int = 24, d: int = 3, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(n, d, generator=g, dtype=F64)
    return x, torch.sin(x[:, 0]) + 0.1 * x[:, 1]


def _models(noise: float = 1e-3) -> dict[str, tuple[torch.nn.Module, torch.nn.Module]]:
    """A model of each kind on the same data, hyperparameters at their defaults, σ_0² = ``noise``; svgp's q(v)
    at its optimum."""
    x, y = _data()
    Z = x[:8].clone()
    liks = [gaussian_likelihood() for _ in range(3)]
    for lik in liks:
        lik.noise = torch.tensor([noise], dtype=F64)
    svgp = SVGPBEMGP(Z)
    optimal_variational(svgp, liks[2], x, y)
    return {"exact": (ExactBEMGP(x, y, liks[0]), liks[0]), "sgpr": (SGPRBEMGP(x, y, liks[1], Z), liks[1]), "svgp": (svgp, liks[2])}


def _prior_reference(model, x: torch.Tensor) -> torch.Tensor:
    """K_xx = σ_f² exp(−½ Σ_j ((x_a,j − x_b,j)/ℓ_j)²), written out (eq. 11)."""
    ls = model.covar_module.base_kernel.lengthscale.detach().reshape(-1)
    sf2 = model.covar_module.outputscale.detach()
    diff = (x[:, None, :] - x[None, :, :]) / ls
    return sf2 * torch.exp(-0.5 * (diff**2).sum(-1))


@pytest.mark.parametrize("kind", list(GP_KINDS))
@pytest.mark.parametrize("mode", ["train", "eval"])
def test_forward_is_the_prior_on_every_kind(kind, mode):
    model, _ = _models()[kind]
    with torch.no_grad():
        model.covar_module.base_kernel.lengthscale = torch.tensor([[0.7, 1.3, 2.1]], dtype=F64)
        model.covar_module.outputscale = torch.tensor(1.7, dtype=F64)
    model.train(mode == "train")
    xs = _data(7, seed=3)[0]
    with torch.no_grad():
        prior = model.forward(xs)
    assert gp_kind_of(model) == kind
    assert torch.equal(prior.mean, torch.zeros(7, dtype=F64))
    torch.testing.assert_close(prior.covariance_matrix, _prior_reference(model, xs), rtol=0, atol=1e-14)


def _dense_posterior(kind: str, model, x: torch.Tensor, y: torch.Tensor, xs: torch.Tensor, noise: float):
    """μ, Σ at ``xs`` from dense solves (eq. 12; sparse: Titsias, 2009, with K_ZZ + 1e-8 I):
    exact  μ = K_sX (K_XX + σ²I)⁻¹ y,             Σ = k_ss − K_sX (K_XX + σ²I)⁻¹ K_Xs;
    sparse μ = σ⁻² K_sZ A⁻¹ K_ZX y, A = K_ZZ + σ⁻² K_ZX K_XZ,  Σ = k_ss − K_sZ K_ZZ⁻¹ K_Zs + K_sZ A⁻¹ K_Zs."""
    ls = model.covar_module.base_kernel.lengthscale.detach().reshape(-1)
    sf2 = model.covar_module.outputscale.detach()

    def k(a, b):
        return sf2 * torch.exp(-0.5 * (((a[:, None, :] - b[None, :, :]) / ls) ** 2).sum(-1))

    if kind == "exact":
        K = k(x, x) + noise * torch.eye(x.shape[0], dtype=F64)
        Ks = k(xs, x)
        return Ks @ torch.linalg.solve(K, y), torch.diagonal(k(xs, xs) - Ks @ torch.linalg.solve(K, Ks.T))
    Z = x[:8]
    Kzz = k(Z, Z) + 1e-8 * torch.eye(8, dtype=F64)
    Kzx, Ksz = k(Z, x), k(xs, Z)
    A = Kzz + Kzx @ Kzx.T / noise
    mean = Ksz @ torch.linalg.solve(A, Kzx @ y) / noise
    var = torch.diagonal(k(xs, xs) - Ksz @ torch.linalg.solve(Kzz, Ksz.T) + Ksz @ torch.linalg.solve(A, Ksz.T))
    return mean, var


@pytest.mark.parametrize("kind", list(GP_KINDS))
def test_posterior_is_the_conditioned_gp_and_not_the_prior(kind):
    """``posterior`` is the kind's posterior (dense reference); ``forward`` at the same inputs stays the prior."""
    model, _ = _models()[kind]
    x, y = _data()
    xs = _data(9, seed=5)[0]
    model.eval()
    with torch.no_grad():
        prior, post = model.forward(xs), model.posterior(xs)
    mean, var = _dense_posterior(kind, model, x, y, xs, noise=1e-3)
    torch.testing.assert_close(post.mean, mean, rtol=0, atol=1e-6)
    torch.testing.assert_close(post.variance, var, rtol=0, atol=1e-6)
    assert float(var.min()) < 0.5 * float(prior.variance.min())  # the data moved it: the two differ
    torch.testing.assert_close(prior.variance, torch.full((9,), float(model.covar_module.outputscale), dtype=F64), rtol=0, atol=1e-14)


# ---- minimize returns the FitResult -------------------------------------------------------------
def test_minimize_returns_a_fit_result():
    p = torch.nn.Parameter(torch.tensor([3.0], dtype=F64))
    res = minimize(lambda: ((p - 1.0) ** 2).sum(), [p], optimizer="lbfgs", max_iter=20, lr=1.0, tol=1e-12, metrics_fn=dict,
                   kind="quadratic")
    assert isinstance(res, FitResult) and res.kind == "quadratic" and res.stop_reason == "converged"
    assert res.loss == pytest.approx(0.0, abs=1e-20) and res.steps >= 2 and res.seconds >= 0.0
    assert res.metrics["loss"] == res.loss and math.isclose(float(p), 1.0, abs_tol=1e-10)


def test_a_fit_records_its_kind():
    model, lik = _models()["exact"]
    assert fit_exact(model, lik, max_iter=3).kind == "exact"


# ---- no private attributes of GPyTorch / torch in the GP stack -------------------------------------------------
#: NamedTuple's public API has a leading underscore.
_PUBLIC_UNDERSCORE = frozenset({"_asdict", "_replace", "_fields", "_make"})


@pytest.mark.parametrize("package", ["models", "fitting"])
def test_the_gp_stack_reads_no_private_attribute_of_another_object(package):
    found = []
    for p in sorted((PACKAGE / package).rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")
                    and node.attr not in _PUBLIC_UNDERSCORE
                    and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))):
                found.append(f"{p.relative_to(PACKAGE).as_posix()}:{node.lineno}: {ast.unparse(node)}")
    assert found == [], "\n".join(found)
