"""Bad input gets a clear error naming the argument, row or key."""

from __future__ import annotations

import pytest
import torch

from bemlearn.config import ConfigError, from_dict
from bemlearn.fitting import GPConfig, build_gp, fit_svgp, select_inducing_points
from bemlearn.models import SGPRBEMGP, SVGPBEMGP, ExactBEMGP, gaussian_likelihood, gp_class, predict

F64 = torch.float64


def _xy(n: int = 20) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(0)
    return torch.randn(n, 5, generator=gen, dtype=F64), torch.randn(n, generator=gen, dtype=F64)


def test_wrong_shapes() -> None:
    x, y = _xy()
    with pytest.raises(ValueError, match=r"train_x: expected shape \(N, d\)"):
        ExactBEMGP(x[:, 0], y, gaussian_likelihood())
    with pytest.raises(ValueError, match=r"train_y: expected shape \(20,\)"):
        ExactBEMGP(x, y[:-1], gaussian_likelihood())
    with pytest.raises(ValueError, match="inducing_points: expected 5 columns"):
        SGPRBEMGP(x, y, gaussian_likelihood(), x[:4, :3])
    with pytest.raises(ValueError, match="train_x: expected at least one row"):
        ExactBEMGP(x[:0], y[:0], gaussian_likelihood())


def test_wrong_types_and_dtypes() -> None:
    x, y = _xy()
    with pytest.raises(TypeError, match="train_x: expected a torch.Tensor"):
        ExactBEMGP(x.numpy(), y, gaussian_likelihood())
    with pytest.raises(TypeError, match="train_y: expected dtype torch.float64"):
        ExactBEMGP(x, y.float(), gaussian_likelihood())
    with pytest.raises(TypeError, match="train_x: expected dtype torch.float64"):
        build_gp(x.float(), y.float(), config=GPConfig())
    with pytest.raises(TypeError, match="train_x: expected a floating-point tensor"):
        ExactBEMGP(x.long(), y, gaussian_likelihood())


def test_non_finite_values_name_the_row() -> None:
    x, y = _xy()
    y_bad = y.clone()
    y_bad[7] = float("nan")
    with pytest.raises(ValueError, match="train_y: 1 row.*first at row 7"):
        ExactBEMGP(x, y_bad, gaussian_likelihood())
    x_bad = x.clone()
    x_bad[3, 2] = float("inf")
    x_bad[11, 0] = float("nan")
    with pytest.raises(ValueError, match="train_x: 2 row.*first at row 3"):
        build_gp(x_bad, y, config=GPConfig())


def test_predict_checks_x() -> None:
    x, y = _xy()
    model, lik = build_gp(x, y, config=GPConfig())
    with pytest.raises(ValueError, match="x: expected 5 columns"):
        predict(model, lik, x[:, :4])
    with pytest.raises(TypeError, match="x: expected dtype torch.float64"):
        predict(model, lik, x.float())
    with pytest.raises(TypeError, match="model: expected one of"):
        predict(torch.nn.Linear(5, 1), lik, x)


def test_svgp_fit_checks_data() -> None:
    x, y = _xy()
    model = SVGPBEMGP(select_inducing_points(x, 5))
    with pytest.raises(ValueError, match=r"train_y: expected shape \(20,\)"):
        fit_svgp(model, gaussian_likelihood(), x, y[:3])
    with pytest.raises(ValueError, match="batch_size: expected a positive integer"):
        fit_svgp(model, gaussian_likelihood(), x, y, batch_size=0)


def test_unknown_kind_lists_valid_ones() -> None:
    with pytest.raises(ValueError, match=r"unknown 'gpdm'; valid kinds are \['exact', 'sgpr', 'svgp'\]"):
        gp_class("gpdm")


def test_config_parsing() -> None:
    cfg = from_dict(GPConfig, {"kind": "sgpr", "n_inducing": 512, "lr": 1}, where="train.yaml:gp")
    assert cfg.kind == "sgpr" and cfg.n_inducing == 512 and cfg.lr == 1.0 and cfg.torch_dtype == F64
    with pytest.raises(ConfigError, match=r"train.yaml:gp: unknown key\(s\) \['n_inducng'\]"):
        from_dict(GPConfig, {"n_inducng": 3}, where="train.yaml:gp")
    with pytest.raises(ConfigError, match=r"train.yaml:gp.kind: expected one of"):
        from_dict(GPConfig, {"kind": "dense"}, where="train.yaml:gp")
    with pytest.raises(ConfigError, match="train.yaml:gp.batch_size: expected an integer"):
        from_dict(GPConfig, {"batch_size": "big"}, where="train.yaml:gp")
    with pytest.raises(ConfigError, match="n_inducing: expected a positive integer, got 0"):
        from_dict(GPConfig, {"n_inducing": 0}, where="train.yaml:gp")
