"""examples/c_eic_furuta: the C EIC controller with the exported C BEM balances the MuJoCo Furuta
and tracks like the Python EIC (bemlearn.sim.closed_loop.simulate) with the same gains and
reference: the resolved ``simulate`` section of configs/furuta.yaml (hand-tuned gains).

The BEM is an exact GP with fixed hyperparameters fitted to the analytic Furuta's Γ = 0 roots
(eq. 5) on 300 random states: quick to build, independent of the training pipeline.
"""

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from bemlearn.apps.furuta.model import AnalyticFuruta
from bemlearn.export import BEMPredictor, PredictorMetadata, c_sources, save_torchscript
from bemlearn.export.c_build import find_cc
from bemlearn.export.c_export import write_files
from bemlearn.models.predictor_state import PredictorState
from bemlearn.robots import load
from bemlearn.sim.closed_loop import simulate
from tests.file_module import load_file_module

pytestmark = pytest.mark.skipif(find_cc() is None, reason="no C compiler (cc, gcc, clang or $CC) on PATH")

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "c_eic_furuta" / "simulate_c_eic.py"
F64 = torch.float64


def _example():
    return load_file_module(EXAMPLE, "simulate_c_eic", register=True)   # its dataclasses look their module up by name


def _furuta_bem_gp(n: int = 300, seed: int = 0) -> tuple[PredictorState, PredictorMetadata]:
    """Exact GP on α solving Γ(α; θ̈, θ̇, α̈, α̇) = 0 (eq. 5) of the analytic Furuta, by Newton."""
    a = AnalyticFuruta()
    g = np.random.default_rng(seed)
    X = np.column_stack([15 * g.standard_normal(n), 2.5 * g.standard_normal(n), g.uniform(-0.6, 0.6, n),
                         8 * g.standard_normal(n), g.standard_normal(n)])
    tdd, td, _, add, ad = X.T
    al = np.zeros(n)
    for _ in range(50):
        s, c = np.sin(al), np.cos(al)
        f = -a._mLl * c * tdd - a._K * s * c * td**2 - a._mgl * s + a._Duu * add + a.params.B_p * ad
        df = a._mLl * s * tdd - a._K * (c * c - s * s) * td**2 - a._mgl * c
        al = al - f / df
    assert np.abs(f).max() < 1e-12
    Xt, y = torch.from_numpy(X), torch.from_numpy(al)
    names = ("qdd_theta", "qd_theta", "q_theta", "qdd_alpha", "qd_alpha")
    state = PredictorState(
        kind="exact", Z=(Xt - Xt.mean(0)) / Xt.std(0), alpha=torch.zeros(n, dtype=F64), S=torch.zeros(n, n, dtype=F64),
        lengthscale=torch.tensor([1.5, 1.5, 20.0, 1.5, 1.5], dtype=F64), outputscale=torch.tensor(1.0, dtype=F64),
        noise=torch.tensor(1e-4, dtype=F64), x_mean=Xt.mean(0), x_std=Xt.std(0), y_mean=y.mean(), y_std=y.std(),
        input_names=names, n_train=n,
    )
    L = torch.linalg.cholesky(state.gram())
    alpha = torch.cholesky_solve(((y - y.mean()) / y.std())[:, None], L)[:, 0]
    state = PredictorState(**{**state.__dict__, "alpha": alpha, "S": torch.cholesky_inverse(L)})
    meta = PredictorMetadata(
        robot="furuta", joint_names=("theta", "alpha"), actuated_names=("theta",), unactuated_name="alpha", m=1,
        input_names=names, units={nm: "rad/s^2" if nm.startswith("qdd") else "rad/s" if nm.startswith("qd") else "rad" for nm in names},
        n_train=n, n_inducing=None, hyperparameters={}, bemlearn_version="test", data_sha256="0" * 64,
    )
    return state, meta


def test_c_eic_balances_and_tracks_like_python(tmp_path):
    state, meta = _furuta_bem_gp()
    write_files(c_sources(state, meta), tmp_path)
    pt = save_torchscript(BEMPredictor(state, meta), tmp_path / "bem_predictor.pt")
    ex = _example()
    lib = ex.build(tmp_path, tmp_path / "libeic.so")
    config = ex.simulate_config(pt, duration_s=6.0)       # the Furuta's resolved simulate section (400 Hz, its gains)
    c = ex.run(lib, config)
    py = simulate(load("furuta"), config, progress=False)
    assert not c.fell and not py.fell
    assert c.alpha_max <= 0.1                                      # balanced: |α| stays small (rad)
    assert abs(c.alpha_max - py.metrics["qu_max"]) <= 0.1 * py.metrics["qu_max"]
    assert c.tracking_rmse <= 0.05                                 # rad, on a 0.3 + 0.2 rad reference
    assert abs(c.tracking_rmse - py.metrics["tracking_rmse"]) <= 0.05 * py.metrics["tracking_rmse"] + 1e-4
    # the same law on the same plant and sensor seed: the trajectories agree closely
    assert np.abs(c.theta - py.q[:, 0]).max() <= 5e-3 and np.abs(c.alpha - py.q[:, 1]).max() <= 5e-3
    assert math.isclose(c.t[-1], py.t[-1])
