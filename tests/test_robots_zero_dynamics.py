"""Zero dynamics (eq. 4) and Lemma 1 (eq. 10) on the Furuta pendulum."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bemlearn.apps.furuta.model import AnalyticFuruta
from bemlearn.robots import load
from bemlearn.robots.reference import CompositeSinusoid
from bemlearn.robots.zero_dynamics import finite_zero_dynamics, lemma1, periodic_zero_dynamics, spectral_derivative

REFERENCES = [
    CompositeSinusoid.single([0.3, 0.2], [0.5, 1.0], [0.0, 0.7]),
    CompositeSinusoid.single([0.4, 0.1], [0.25, 0.75], [0.3, 1.1]),
    CompositeSinusoid.single([0.2, 0.15, 0.1], [0.2, 0.6, 1.0], [0.0, 0.5, 2.0]),
]


def test_composite_sinusoid_derivatives_and_period():
    ref = REFERENCES[2]
    assert ref.period == pytest.approx(5.0)
    t = np.linspace(0, 3, 301)
    h = 1e-5
    for order in (1, 2, 3):
        fd = (ref.derivative(t + h, order - 1) - ref.derivative(t - h, order - 1)) / (2 * h)
        torch.testing.assert_close(ref.derivative(t, order), fd, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(ref.derivative(t + ref.period, 0), ref.derivative(t, 0), rtol=0, atol=1e-12)


def test_spectral_derivative_exact_for_trig_polynomials():
    T, N = 2.0, 64
    t = np.arange(N) * T / N
    y = np.sin(2 * np.pi * t / T) + 0.3 * np.cos(6 * np.pi * t / T)
    dy = 2 * np.pi / T * np.cos(2 * np.pi * t / T) - 0.3 * 6 * np.pi / T * np.sin(6 * np.pi * t / T)
    np.testing.assert_allclose(spectral_derivative(y, T, 1), dy, atol=1e-12)


@pytest.mark.parametrize("ref", REFERENCES, ids=["ref0", "ref1", "ref2"])
def test_lemma1_identity_analytic(ref):
    robot = AnalyticFuruta()
    L = lemma1(robot, ref, n_nodes=256)
    scale = float(np.abs(L.delta_gamma).max())
    assert scale > 1e-3  # a non-trivial check: ΔΓ is not identically zero
    # eq. (4) solved to the Newton tolerance and eq. (10) holds to the same order
    assert float(np.abs(L.zero_dynamics.residual).max()) <= 1e-11
    assert float(np.abs(L.gap).max()) <= 1e-10
    # joint damping B_p on α contributes b_u q̇_u^e: the identity needs it
    np.testing.assert_allclose(L.damping, robot.params.B_p * L.qud_e, rtol=1e-12, atol=1e-15)
    assert float(np.abs(L.delta_gamma - L.hdot).max()) > 1e-5
    # Lemma 1: q_u^d stays within a bounded distance of the BEM
    assert L.max_distance < 0.25


def test_lemma1_identity_mujoco():
    L = lemma1(load("furuta"), REFERENCES[0], n_nodes=128)
    assert float(np.abs(L.gap).max()) <= 1e-10
    assert float(np.abs(L.zero_dynamics.residual).max()) <= 1e-11


def test_lemma1_without_damping_is_exactly_hdot():
    from dataclasses import replace

    robot = AnalyticFuruta(replace(AnalyticFuruta().params, B_p=0.0))
    L = lemma1(robot, REFERENCES[1], n_nodes=256)
    assert float(np.abs(L.damping).max()) == 0.0
    assert float(np.abs(L.delta_gamma - L.hdot).max()) <= 1e-10


def test_constant_acceleration_degenerates_to_bem():
    """Section III-A: constant θ̈ gives a constant BEM with q_u^d = q_u^e (ΔΓ = 0)."""
    robot = AnalyticFuruta()
    qa = torch.tensor([[0.0]], dtype=torch.float64)
    res = robot.bem(qa, qa, torch.tensor([[5.0]], dtype=torch.float64))
    qu = res.qu.expand(4)
    # Γ at the constant BEM with q̇_u = q̈_u = 0 vanishes at any arm angle under constant θ̈ (θ̇ = 0 instant)
    g = robot.gamma(robot.join(torch.zeros(4, 1, dtype=torch.float64), qu), torch.zeros(4, 2, dtype=torch.float64), robot.join(torch.full((4, 1), 5.0, dtype=torch.float64), torch.zeros(4, dtype=torch.float64)))
    assert float(g.abs().max()) <= 1e-14


def test_finite_horizon_solution_matches_periodic_orbit_in_the_interior():
    robot = AnalyticFuruta()
    ref = REFERENCES[0]
    per = periodic_zero_dynamics(robot, ref, n_nodes=256)
    fin = finite_zero_dynamics(robot, ref, 0.0, 3 * ref.period, n_nodes=600)
    assert float(np.abs(fin.residual).max()) <= 1e-5
    mid = (fin.t > ref.period) & (fin.t < 2 * ref.period)
    # interpolate the periodic orbit (trigonometric interpolation via FFT)
    N = per.t.size
    coef = np.fft.rfft(per.qu) / N
    tt = fin.t[mid] % ref.period
    k = np.arange(coef.size)
    w = np.where((k == 0) | ((N % 2 == 0) & (k == N // 2)), 1.0, 2.0)
    interp = np.real((w * coef)[None, :] * np.exp(2j * np.pi * k[None, :] * tt[:, None] / ref.period)).sum(1)
    assert float(np.abs(fin.qu[mid] - interp).max()) <= 1e-4


def test_bad_reference_dimension():
    from bemlearn.robots.reference import CompositeSinusoid as CS

    two = CS(((0.1,), (0.1,)), ((1.0,), (1.0,)), ((0.0,), (0.0,)), (0.0, 0.0))
    with pytest.raises(ValueError, match="reference has 2 actuated joints"):
        periodic_zero_dynamics(AnalyticFuruta(), two)
