"""The run's numerical hot paths give the numbers of the plain computations they replace.

* the bracket scan of the model BEM (eq. 6, 7, 9) widens its window step by step: the cell it picks is the
  one an independent scan of the whole grid picks, and it evaluates fewer nodes when roots lie near nominal;
* ``MujocoRobot.gamma_rows`` equals ``gamma0_scalar`` row by row (joint coordinates and a coordinate map);
* ``ModelBEM`` iterates its rows together: each row is the one-row Newton result, a root of Γ_0;
* export verification computes its dense references once: the same verdict and figures as computing them per file.
"""

from __future__ import annotations

import numpy as np
import pytest

from bemlearn.control.bem_sources import ModelBEM
from bemlearn.robots import load
from bemlearn.robots.bem import find_roots

ROBOTS = "tests/robots"


def _polynomial_problems(seed: int, batch: int):
    """Residuals f_b(x) = Π_i (x − r_bi) with 1–3 random roots per problem in [−1.5, 1.5] (some problems
    without a root in the range)."""
    rng = np.random.default_rng(seed)
    k = rng.integers(1, 4, size=batch)
    roots = np.full((batch, 3), np.nan)
    for b in range(batch):
        roots[b, : k[b]] = rng.uniform(-1.5, 1.5, size=k[b]) * rng.choice([0.05, 0.3, 1.0])
    roots[:10] = 5.0  # no root inside [-1.5, 1.5]

    def fun(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
        r = roots[rows]
        out = np.ones_like(x)
        for i in range(3):
            ri = r[:, i : i + 1]
            out = out * np.where(np.isnan(ri), 1.0, x - np.nan_to_num(ri))
        return out

    return roots, fun


def _nearest_cell_root(roots: np.ndarray, nodes: np.ndarray, nominal: float) -> np.ndarray:
    """Independent reference: on the whole grid, the sign-change cell nearest ``nominal`` (the leftmost of
    equally near ones) and the known root inside it; NaN where no cell changes sign."""
    out = np.full(roots.shape[0], np.nan)
    for b, r in enumerate(roots):
        r = r[np.isfinite(r)]
        f = np.prod(nodes[:, None] - r[None, :], axis=1)
        best = np.inf
        for j in range(nodes.size - 1):
            if np.sign(f[j]) * np.sign(f[j + 1]) < 0 or f[j] == 0:
                lo, hi = nodes[j], nodes[j + 1]
                dist = lo - nominal if nominal < lo else (nominal - hi if nominal > hi else 0.0)
                if dist < best:
                    best = dist
                    inside = r[(r >= lo) & (r <= hi)]
                    out[b] = inside[0] if inside.size == 1 else np.nan
    return out


@pytest.mark.parametrize("nominal", [0.0, 0.37, -1.2])
def test_widening_bracket_picks_the_whole_grid_nearest_root(nominal):
    roots, fun = _polynomial_problems(seed=int(100 * abs(nominal)), batch=400)
    lo, hi, n_grid = -1.5, 1.5, 73
    qu, valid, residual, _ = find_roots(fun, roots.shape[0], lo=lo, hi=hi, nominal=nominal, n_grid=n_grid, ftol=1e-10)
    ref = _nearest_cell_root(roots, np.linspace(lo, hi, n_grid), nominal)
    single = np.isfinite(ref)   # cells holding exactly one root: the refined root is that root
    assert single.sum() > 300
    np.testing.assert_allclose(qu[single], ref[single], atol=1e-12, rtol=0)
    assert not valid[:10].any() and np.isnan(qu[:10]).all()   # no root in the range
    assert np.all(residual[valid] <= 1e-10)


def test_widening_bracket_evaluates_few_nodes_near_nominal():
    """Roots within one grid cell of nominal: 3 nodes bracket them (the old first window took 9)."""
    rng = np.random.default_rng(4)
    roots = rng.uniform(-0.02, 0.02, size=200)
    count = [0]

    def fun(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
        count[0] += x.size
        return np.tanh(x - roots[rows, None])

    from bemlearn.robots.bem import _bracket

    nodes = np.linspace(-1.5, 1.5, 73)
    br = _bracket(fun, nodes, 0.0, roots.size)
    assert br.valid.all() and np.all((br.a <= roots) & (roots <= br.b))
    assert count[0] <= 5 * roots.size


@pytest.mark.parametrize("name", [f"{ROBOTS}/cartpole.xml", f"{ROBOTS}/acrobot.xml", "biped"])
def test_gamma_rows_is_gamma0_scalar_row_by_row(name):
    robot = load(name)
    rng = np.random.default_rng(7)
    R, m = 40, robot.m
    qu, qud, qudd = rng.uniform(-0.4, 0.4, R), rng.uniform(-1, 1, R), rng.uniform(-3, 3, R)
    qa, qad, qadd = rng.uniform(-0.4, 0.4, (R, m)), rng.uniform(-1, 1, (R, m)), rng.uniform(-3, 3, (R, m))
    rows = robot.gamma_rows(qu, qa, qad, qadd, qud, qudd)
    one = [robot.gamma0_scalar(qu[r], qa[r], qad[r], qadd[r], qud[r], qudd[r]) for r in range(R)]
    assert np.array_equal(rows, np.array(one))
    # and the torch path (eq. 5 from D, C q̇ + G, τ_p evaluated separately) within round-off
    import torch

    q = robot.join(torch.from_numpy(qa), torch.from_numpy(qu))
    qd = robot.join(torch.from_numpy(qad), torch.from_numpy(qud))
    qdd = robot.join(torch.from_numpy(qadd), torch.from_numpy(qudd))
    D, h = robot.mass_matrix(q), robot.bias(q, qd) - robot.passive(q, qd)
    ref = (torch.einsum("bij,bj->bi", D, qdd) + h)[:, robot.unactuated_index].numpy()
    np.testing.assert_allclose(rows, ref, rtol=1e-10, atol=1e-10 * float(np.abs(ref).max()))


@pytest.mark.parametrize("name", [f"{ROBOTS}/cartpole.xml", "furuta"])
def test_model_bem_rows_iterate_together_like_one_row_each(name):
    robot = load(name)
    m = robot.m
    rng = np.random.default_rng(11)
    x = np.concatenate([rng.uniform(-6, 6, (60, m)), rng.uniform(-2, 2, (60, m)), rng.uniform(-0.3, 0.3, (60, m))], axis=1)
    together = ModelBEM(robot)(x)
    alone = np.concatenate([ModelBEM(robot)(x[i : i + 1]) for i in range(x.shape[0])])
    assert np.array_equal(together, alone)
    g0 = [robot.gamma0_scalar(together[i], x[i, 2 * m :], x[i, m : 2 * m], x[i, :m]) for i in range(x.shape[0])]
    assert np.max(np.abs(g0)) <= 1e-10


def test_verification_references_computed_once_give_the_same_verdict():
    import dataclasses

    import torch

    from bemlearn.bench.predict_bench import synthetic_posterior
    from bemlearn.errors import CheckpointError
    from bemlearn.export import BEMPredictor
    from bemlearn.export.verify import reference_posterior, verification_cases, verify_predictor

    state, meta = synthetic_posterior(n_train=40, m=1, seed=3)
    predictor = BEMPredictor(state, meta)
    cases = verification_cases(state)
    assert [c.name for c in cases] == ["forward", "predict_full", "forward_latent", "predict_full_latent"]
    worst = verify_predictor(predictor, state, cases=cases)
    assert worst == verify_predictor(predictor, state)
    assert 0.0 <= worst[0] <= 1e-9 and 0.0 <= worst[1] <= 1e-6
    # the shared references are the dense posterior of eq. (12) at the verification inputs
    x0 = torch.cat([cases[0].x, torch.zeros(cases[0].x.shape[0], 2, dtype=torch.float64)], 1)
    mean, std, _ = reference_posterior(state, x0)
    assert torch.equal(cases[2].mean, mean) and torch.equal(cases[2].std, std)
    # and they still catch a predictor of another posterior
    other = BEMPredictor(dataclasses.replace(state, y_mean=state.y_mean + 1e-6), meta)
    with pytest.raises(CheckpointError, match="forward disagrees"):
        verify_predictor(other, state, cases=cases)
