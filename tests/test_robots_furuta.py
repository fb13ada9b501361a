"""Furuta pendulum: analytic model vs MuJoCo, closed forms, motor, paper variant."""

from __future__ import annotations

import math

import mujoco
import pytest
import torch

from bemlearn.apps.biped import assets as biped_assets
from bemlearn.apps.furuta import assets as furuta_assets
from bemlearn.apps.furuta.model import AnalyticFuruta, FurutaParameters, torque_to_voltage, voltage_to_torque
from bemlearn.robots import load


@pytest.fixture(scope="module")
def mj():
    return load("furuta")


@pytest.fixture(scope="module")
def analytic():
    return AnalyticFuruta()


def _random_states(B=1000, seed=0):
    g = torch.Generator().manual_seed(seed)
    q = (torch.rand(B, 2, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([2 * math.pi, 2 * math.pi])
    qd = (torch.rand(B, 2, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([20.0, 20.0])
    return q, qd


def test_mass_matrix_matches_mujoco(mj, analytic):
    q, _ = _random_states()
    D_mj, D_an = mj.mass_matrix(q), analytic.mass_matrix(q)
    rel = (D_mj - D_an).abs().amax(dim=(1, 2)) / D_an.abs().amax(dim=(1, 2))
    assert float(rel.max()) <= 1e-8


def test_bias_matches_mujoco(mj, analytic):
    q, qd = _random_states()
    b_mj, b_an = mj.bias(q, qd), analytic.bias(q, qd)
    rel = (b_mj - b_an).norm(dim=1) / b_an.norm(dim=1).clamp_min(1e-3)
    assert float(rel.max()) <= 1e-8
    torch.testing.assert_close(mj.passive(q, qd), analytic.passive(q, qd), rtol=1e-12, atol=1e-15)


def test_bem_matches_mujoco_over_rate_acceleration_grid(mj, analytic):
    thd = torch.linspace(-10, 10, 21, dtype=torch.float64)
    thdd = torch.linspace(-30, 30, 21, dtype=torch.float64)
    TD, TDD = torch.meshgrid(thd, thdd, indexing="ij")
    qad, qadd = TD.reshape(-1, 1), TDD.reshape(-1, 1)
    qa = torch.full_like(qad, 0.4)
    r_mj, r_an = mj.bem(qa, qad, qadd), analytic.bem(qa, qad, qadd)
    assert bool(r_mj.valid.all()) and bool(r_an.valid.all())
    assert float((r_mj.qu - r_an.qu).abs().max()) <= 1e-8
    assert float(r_mj.residual.max()) <= 1e-10 and float(r_an.residual.max()) <= 1e-10


@pytest.mark.parametrize("model", ["mj", "analytic"])
def test_bem_closed_form_at_zero_arm_rate(model, request):
    """θ̇ = 0: −m L_r l cos α θ̈ − m g l sin α = 0  ⇒  tan α = −L_r θ̈ / g."""
    robot = request.getfixturevalue(model)
    p = FurutaParameters()
    thdd = torch.linspace(-30, 30, 61, dtype=torch.float64)[:, None]
    res = robot.bem(torch.zeros_like(thdd), torch.zeros_like(thdd), thdd)
    expected = torch.atan(-p.L_r * thdd[:, 0] / p.g)
    assert float((res.qu - expected).abs().max()) <= 1e-12


def test_no_root_is_detected(analytic):
    qadd = torch.tensor([[30.0], [0.0]], dtype=torch.float64)
    z = torch.zeros_like(qadd)
    res = analytic.bem(z, z, qadd, qu_range=(-0.1, 0.1))
    assert res.valid.tolist() == [False, True]
    assert math.isnan(float(res.qu[0])) and abs(float(res.qu[1])) < 1e-14
    with pytest.raises(ValueError, match="no root of Γ_0.*batch index 0"):
        analytic.bem(z, z, qadd, qu_range=(-0.1, 0.1), on_missing="raise")


def test_paper_variant_differs_at_speed_and_agrees_at_rest():
    rigid, paper = AnalyticFuruta(variant="rigid"), AnalyticFuruta(variant="paper")
    qadd = torch.tensor([[10.0], [10.0], [30.0]], dtype=torch.float64)
    qad = torch.tensor([[0.0], [10.0], [10.0]], dtype=torch.float64)
    z = torch.zeros_like(qad)
    a, b = rigid.bem(z, qad, qadd).qu, paper.bem(z, qad, qadd).qu
    assert abs(float(a[0] - b[0])) < 1e-14  # K only multiplies θ̇²
    # at θ̇ = 10 rad/s the ¼ m l² approximation shifts the BEM by more than a milliradian
    assert float((a[1:] - b[1:]).abs().min()) > 1e-3


def test_motor_model_matches_mujoco_actuator(mj):
    m, d = mj.model, mujoco.MjData(mj.model)
    p = FurutaParameters()
    for V, thd in [(3.0, 0.0), (-7.5, 4.0), (10.0, -12.0), (15.0, 0.0)]:
        d.qvel[:] = [thd, 0.0]
        d.ctrl[:] = [V]
        mujoco.mj_forward(m, d)
        expected = voltage_to_torque(torch.tensor(max(-p.V_max, min(p.V_max, V)), dtype=torch.float64), torch.tensor(thd, dtype=torch.float64), p)
        assert abs(float(d.qfrc_actuator[0]) - float(expected)) < 1e-12
        assert abs(float(d.qfrc_actuator[1])) == 0.0
    tau = torch.tensor([0.3, -1.1], dtype=torch.float64)
    thd = torch.tensor([2.0, -5.0], dtype=torch.float64)
    torch.testing.assert_close(voltage_to_torque(torque_to_voltage(tau, thd), thd), tau, rtol=1e-14, atol=1e-15)


def test_motor_acts_on_arm_only(mj):
    assert mj.model.nu == 1 and mj.model.nv == 2
    assert mj.unactuated_name == "alpha" and mj.actuated_names == ("theta",)


@pytest.mark.parametrize("app", [furuta_assets, biped_assets], ids=["furuta", "biped"])
def test_shipped_assets_equal_generators(app):
    generated = app.generated_assets()
    assert generated
    for name, text in generated.items():
        assert (app.ASSETS / name).read_text() == text, name
