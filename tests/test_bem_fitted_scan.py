"""The fitted grid scan of the model BEM (``find_roots(basis=...)``, eq. 6, 7, 9) gives the roots of the
node-by-node scan it shortcuts, bit for bit, with fewer residual evaluations.

References: ``find_roots`` without a basis (the node-by-node scan, kept as it was) on the same residuals;
for the physics claim behind :func:`~bemlearn.robots.bem.hinge_basis`, Γ_0 of MuJoCo's inverse dynamics
at nodes the fit did not use.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from bemlearn.robots import load
from bemlearn.robots.bem import find_roots, hinge_basis

ROBOTS = Path(__file__).parent / "robots"
#: Robots whose q_u is a hinge in joint coordinates (the fitted scan applies), the shipped Furuta first.
HINGE_ROBOTS = ["furuta", *(str(ROBOTS / f) for f in ("cartpole.xml", "acrobot.xml", "pendubot.xml", "arm2_pole.xml",
                                                       "reaction_wheel.xml", "xy_cartpole.xml"))]


def _counted(fun):
    """``fun`` and a counter of the residuals it evaluates."""
    count = [0]

    def call(x, rows):
        count[0] += x.size
        return fun(x, rows)

    return call, count


def _trig_problems(seed: int, batch: int, extra=None):
    """Residuals c_b · (1, cos x, sin x, cos 2x, sin 2x), some with roots near 0, some far, some none;
    ``extra(x)`` added to every residual (a term outside the span)."""
    rng = np.random.default_rng(seed)
    c = rng.normal(size=(batch, 5)) * rng.choice([0.02, 0.3, 1.0], size=(batch, 1))
    c[: batch // 10, 0] = 10.0   # a large constant: no root
    c[batch // 10 : batch // 5, 0] -= (c[batch // 10 : batch // 5] @ np.array([0, 1, 0, 1, 0]))  # Γ(0) = 0: a root at a node

    def fun(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
        out = np.einsum("rkp,rp->rk", hinge_basis(x), c[rows])
        return out if extra is None else out + extra(x)

    return fun


def _same(a, b):
    for u, v in zip(a[:3], b[:3]):
        np.testing.assert_array_equal(u, v)   # NaN where invalid in both


@pytest.mark.parametrize("nominal", [0.0, 0.3, -1.2])
def test_trig_residuals_give_the_node_by_node_roots(nominal):
    fun = _trig_problems(1, 600)
    call, fitted = _counted(fun)
    plain_call, plain = _counted(fun)
    got = find_roots(call, 600, lo=-1.6, hi=1.6, nominal=nominal, basis=hinge_basis)
    ref = find_roots(plain_call, 600, lo=-1.6, hi=1.6, nominal=nominal)
    _same(got, ref)
    assert 0.3 < float(ref[1].mean()) < 1.0          # roots found and problems without one: both paths exercised
    assert fitted[0] < 0.8 * plain[0]                # fewer evaluations


def test_residuals_outside_the_span_fall_back_to_the_node_by_node_scan():
    """A spring on q_u (k x) and a cubic: the check fails, the scan goes node by node: the same roots."""
    for extra in (lambda x: 0.05 * x, lambda x: 0.2 * x**3):
        fun = _trig_problems(2, 300, extra)
        _same(find_roots(fun, 300, lo=-1.6, hi=1.6, basis=hinge_basis), find_roots(fun, 300, lo=-1.6, hi=1.6))


@pytest.mark.parametrize("name", HINGE_ROBOTS)
def test_robot_bem_equals_the_node_by_node_scan(name):
    """``robot.bem`` (the fitted scan) against ``find_roots`` without a basis on the robot's own Γ_0, over inputs that
    put the roots near upright and far from it (q̈_a up to 30 rad/s² or m/s²)."""
    robot = load(name)
    assert robot._bem_basis() is hinge_basis
    rng = np.random.default_rng(3)
    B = 400
    qa, qad = rng.uniform(-0.5, 0.5, (B, robot.m)), rng.uniform(-3, 3, (B, robot.m))
    qadd = rng.uniform(-30, 30, (B, robot.m)) * rng.choice([0.01, 1.0], size=(B, 1))
    got = robot.bem(torch.from_numpy(qa), torch.from_numpy(qad), torch.from_numpy(qadd))
    lo, hi = robot.qu_range
    ref = find_roots(robot._bem_residual(qa, qad, qadd), B, lo=lo, hi=hi, nominal=robot.qu_nominal)
    np.testing.assert_array_equal(got.qu.numpy(), ref[0])
    np.testing.assert_array_equal(got.valid.numpy(), ref[1])


@pytest.mark.parametrize("name", HINGE_ROBOTS)
def test_gamma0_of_a_hinge_is_in_the_basis(name):
    """Γ_0 along q_u at fixed (q_a, q̇_a, q̈_a): fitted on 5 nodes, it predicts 40 others to 1e-9 of its size."""
    robot = load(name)
    rng = np.random.default_rng(4)
    lo, hi = robot.qu_range
    fit, other = np.linspace(lo, hi, 5), rng.uniform(lo, hi, 40)
    for _ in range(5):
        qa, qad, qadd = rng.uniform(-0.5, 0.5, robot.m), rng.uniform(-3, 3, robot.m), rng.uniform(-30, 30, robot.m)
        gamma = lambda x: robot.gamma_rows(x, np.tile(qa, (x.size, 1)), np.tile(qad, (x.size, 1)), np.tile(qadd, (x.size, 1)))  # noqa: E731,B023
        coef = np.linalg.solve(hinge_basis(fit), gamma(fit))
        scale = np.abs(gamma(fit)).max()
        assert np.abs(hinge_basis(other) @ coef - gamma(other)).max() <= 1e-9 * scale
