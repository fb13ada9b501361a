"""One contract, run against every robot: structure of the dynamics and the BEM (eq. 1–9)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from bemlearn.robots import load

CARTPOLE = """
<mujoco model="cartpole">
  <compiler angle="radian" inertiafromgeom="false"/>
  <worldbody>
    <body name="cart">
      <joint name="x" type="slide" axis="1 0 0"/>
      <inertial pos="0 0 0" mass="1.3" diaginertia="0.01 0.01 0.01"/>
      <body name="pole">
        <joint name="phi" type="hinge" axis="0 1 0"/>
        <inertial pos="0 0 0.25" mass="0.2" diaginertia="0.004 0.004 1e-9"/>
        <site name="tip" pos="0 0 0.5"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="x"/></actuator>
</mujoco>
"""


def _robot(name, tmp_path_factory):
    if name in ("cartpole", "cartpole-armature"):
        path = tmp_path_factory.mktemp("mjcf") / f"{name}.xml"
        # armature: rotor inertia MuJoCo's mass matrix holds and its RNE leaves out
        path.write_text(CARTPOLE if name == "cartpole" else CARTPOLE.replace("<joint ", '<joint armature="0.05" '))
        return load(path)
    if name == "wheel_pendulum":   # a chassis that rolls with its wheel: coordinates (wheel, pendulum)
        return load(Path(__file__).resolve().parent / "robots" / "wheel_pendulum.xml")
    if name == "two_wheeler":   # a free body on two driven wheels: coordinates (wheel, pitch from the quaternion)
        return load(Path(__file__).resolve().parent / "robots" / "two_wheeler.xml")
    return load(name)


@pytest.fixture(scope="module", params=["furuta", "furuta-analytic", "furuta-paper", "biped", "cartpole", "cartpole-armature",
                                        "wheel_pendulum", "two_wheeler"])
def robot(request, tmp_path_factory):
    return _robot(request.param, tmp_path_factory)


def _states(robot, B=40, seed=1):
    g = torch.Generator().manual_seed(seed)
    q = (torch.rand(B, robot.n, generator=g, dtype=torch.float64) - 0.5) * 2.0
    qd = (torch.rand(B, robot.n, generator=g, dtype=torch.float64) - 0.5) * 6.0
    qdd = (torch.rand(B, robot.n, generator=g, dtype=torch.float64) - 0.5) * 20.0
    return q, qd, qdd


def test_partition(robot):
    assert robot.n == len(robot.joint_names) == robot.m + 1
    assert len(robot.actuated_names) == robot.m
    assert robot.unactuated_name not in robot.actuated_names
    q = torch.arange(2 * robot.n, dtype=torch.float64).reshape(2, robot.n)
    qa, qu = robot.split(q)
    assert torch.equal(robot.join(qa, qu), q)


def test_mass_matrix_symmetric_positive_definite(robot):
    q, _, _ = _states(robot)
    D = robot.mass_matrix(q)
    assert D.shape == (q.shape[0], robot.n, robot.n)
    torch.testing.assert_close(D, D.transpose(1, 2), rtol=0, atol=1e-12)
    assert bool((torch.linalg.eigvalsh(D) > 0).all())


def test_coriolis_matches_christoffel_form_of_mass_matrix(robot):
    """C(q, q̇)q̇ = Ḋ q̇ − ½ ∂/∂q (q̇ᵀ D q̇), with Ḋ and ∂/∂q by central differences of D(q)."""
    q, qd, _ = _states(robot, B=10)
    h = 1e-6
    Ddot = (robot.mass_matrix(q + h * qd) - robot.mass_matrix(q - h * qd)) / (2 * h)
    grad = torch.zeros_like(q)
    for i in range(robot.n):
        e = torch.zeros(robot.n, dtype=torch.float64)
        e[i] = h
        Dp, Dm = robot.mass_matrix(q + e), robot.mass_matrix(q - e)
        grad[:, i] = torch.einsum("bi,bij,bj->b", qd, (Dp - Dm) / (2 * h), qd)
    coriolis = torch.einsum("bij,bj->bi", Ddot, qd) - 0.5 * grad
    from_bias = robot.bias(q, qd) - robot.bias(q, torch.zeros_like(qd))
    torch.testing.assert_close(from_bias, coriolis, rtol=1e-6, atol=1e-8)


def test_inverse_dynamics_is_mass_times_acceleration_plus_bias(robot):
    q, qd, qdd = _states(robot)
    tau = robot.inverse_dynamics(q, qd, qdd)
    ref = torch.einsum("bij,bj->bi", robot.mass_matrix(q), qdd) + robot.bias(q, qd) - robot.passive(q, qd)
    torch.testing.assert_close(tau, ref, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(robot.gamma(q, qd, qdd), tau[:, robot.unactuated_index], rtol=0, atol=0)


def test_duu_independent_of_qu(robot):
    """Lemma 1's premise ∂D_uu/∂q_u = 0."""
    if robot.name == "two_wheeler":   # D_φφ = I_b + m_b (r² + l² + 2 r l cos φ) + ...: tests/test_floating.py checks it
        pytest.skip("a body pitching on its wheels: D_uu depends on the pitch, Lemma 1's premise does not hold")
    q, _, _ = _states(robot)
    u = robot.unactuated_index
    q2 = q.clone()
    q2[:, u] += 0.37
    torch.testing.assert_close(robot.mass_matrix(q)[:, u, u], robot.mass_matrix(q2)[:, u, u], rtol=1e-12, atol=1e-14)


def test_bem_roots_have_tiny_residual(robot):
    q, qd, qdd = _states(robot, B=30, seed=3)
    qa, qad, qadd = q[:, list(robot.actuated_index)], qd[:, list(robot.actuated_index)], qdd[:, list(robot.actuated_index)] * 0.2
    res = robot.bem(qa, qad, qadd)
    assert res.qu.shape == (30,)
    assert bool(res.valid.any())
    ok = res.valid
    g0 = robot.gamma0(res.qu[ok], qa[ok], qad[ok], qadd[ok]).abs()
    assert float(g0.max()) <= 1e-10
    lo, hi = robot.qu_range
    assert bool(((res.qu[ok] >= lo) & (res.qu[ok] <= hi)).all())
    assert bool(torch.isnan(res.qu[~ok]).all())


def test_bem_at_rest_is_nominal(robot):
    """Zero actuated velocity and acceleration with the actuated joints at 0: the upright pose."""
    z = torch.zeros(1, robot.m, dtype=torch.float64)
    res = robot.bem(z, z, z)
    assert bool(res.valid.all())
    assert abs(float(res.qu[0]) - robot.qu_nominal) < 1e-12


@pytest.mark.parametrize(
    "args, match",
    [
        ((torch.zeros(3),), r"shape \(B, \d\)"),
        ((torch.full((2, 9), 0.0),), r"shape \(B, \d\)"),
        ((torch.tensor([[float("nan")] * 5]),), "non-finite"),
    ],
)
def test_bad_state_input_is_named(robot, args, match):
    x = args[0]
    if x.ndim == 2 and x.shape[1] == 5 and robot.n != 5:
        x = torch.full((1, robot.n), float("nan"))
    with pytest.raises(ValueError, match=match):
        robot.mass_matrix(x)


def test_bem_bad_inputs(robot):
    z = torch.zeros(2, robot.m, dtype=torch.float64)
    with pytest.raises(ValueError, match="qad"):
        robot.bem(z, torch.zeros(2, robot.m + 1), z)
    with pytest.raises(ValueError, match="different batch sizes"):
        robot.bem(z, torch.zeros(3, robot.m), z)
    with pytest.raises(ValueError, match="on_missing"):
        robot.bem(z, z, z, on_missing="ignore")
