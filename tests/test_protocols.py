"""The robot and BEM-source protocols hold for every concrete class, at run time and for the type checker.

``isinstance`` against a ``runtime_checkable`` protocol checks that the members exist; the typed
functions at the bottom are checked by mypy (``mypy tests/test_protocols.py``): assigning a class
that does not satisfy a protocol there is a type error.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from bemlearn.apps.furuta.model import AnalyticFuruta
from bemlearn.control import BEMSource, ModelBEM, PredictorBEM, ZeroBEM
from bemlearn.export import BEMPredictor, PredictorMetadata, save_torchscript
from bemlearn.models.learned_bem import LearnedBEM
from bemlearn.models.predictor_state import PredictorState
from bemlearn.robots import BalanceRobot, ControlRobot, MujocoRobot, load

ROBOTS = Path(__file__).resolve().parent / "robots"
F64 = torch.float64


def _robots() -> list[BalanceRobot]:
    return [load("furuta"), AnalyticFuruta(), load("biped"), MujocoRobot.from_xml(ROBOTS / "cartpole.xml"),
            MujocoRobot.from_xml(ROBOTS / "acrobot.xml")]


@pytest.mark.parametrize("robot", _robots(), ids=lambda r: f"{type(r).__name__}:{r.name}")
def test_robots_satisfy_the_protocols(robot):
    assert isinstance(robot, BalanceRobot) and isinstance(robot, ControlRobot)
    # the members the protocol promises behave as documented on this robot
    assert robot.n == len(robot.joint_names) == robot.m + 1
    assert sorted((*robot.actuated_index, robot.unactuated_index)) == list(range(robot.n))
    assert robot.unactuated_name == robot.joint_names[robot.unactuated_index]
    q = torch.zeros(1, robot.n, dtype=F64)
    q[0, robot.unactuated_index] = robot.qu_nominal
    D, h = robot.terms(q[0].numpy(), np.zeros(robot.n))
    np.testing.assert_allclose(D, robot.mass_matrix(q)[0].numpy(), rtol=1e-10, atol=1e-10)
    z = torch.zeros_like(q)
    np.testing.assert_allclose(h, (robot.bias(q, z) - robot.passive(q, z))[0].numpy(), rtol=1e-10, atol=1e-10)


def test_objects_missing_members_do_not_satisfy_them():
    class PartitionOnly:
        name, joint_names, unactuated_index = "x", ("a", "b"), 1

    robot = AnalyticFuruta()
    assert not isinstance(PartitionOnly(), BalanceRobot)
    assert not isinstance(ZeroBEM(0.0), BalanceRobot)
    assert not isinstance(robot, BEMSource)          # a robot has a model BEM (.bem), not the controller's call
    assert not isinstance(lambda x: x[:, 0], BEMSource)


def _tiny_state(n: int = 12) -> PredictorState:
    """A small sparse-GP posterior (inducing points Z, any PSD S) on the Furuta's columns (its values do not matter here)."""
    g = torch.Generator().manual_seed(0)
    Z = torch.randn(n, 5, generator=g, dtype=F64)
    names = ("qdd_theta", "qd_theta", "q_theta", "qdd_alpha", "qd_alpha")
    state = PredictorState(
        kind="sgpr", Z=Z, alpha=torch.randn(n, generator=g, dtype=F64), S=0.1 * torch.eye(n, dtype=F64),
        lengthscale=torch.full((5,), 1.5, dtype=F64), outputscale=torch.tensor(1.0, dtype=F64), noise=torch.tensor(1e-3, dtype=F64),
        x_mean=torch.zeros(5, dtype=F64), x_std=torch.ones(5, dtype=F64), y_mean=torch.tensor(0.0, dtype=F64),
        y_std=torch.tensor(0.1, dtype=F64), input_names=names, n_train=n,
    )
    return state


def _tiny_predictor(tmp_path: Path, state: PredictorState) -> Path:
    """``state`` exported as a TorchScript predictor file."""
    names, n = state.input_names, state.n_train
    meta = PredictorMetadata(
        robot="furuta", joint_names=("theta", "alpha"), actuated_names=("theta",), unactuated_name="alpha", m=1,
        input_names=names, units={nm: "rad/s^2" if nm.startswith("qdd") else "rad/s" if nm.startswith("qd") else "rad" for nm in names},
        n_train=n, n_inducing=n, hyperparameters={}, bemlearn_version="test", data_sha256="0" * 64,
    )
    return save_torchscript(BEMPredictor(state, meta), tmp_path / "bem_predictor.pt")


def test_bem_sources_satisfy_the_protocol(tmp_path):
    robot = AnalyticFuruta()
    state = _tiny_state()
    learned = LearnedBEM(state, robot="furuta", actuated_names=("theta",), unactuated_name="alpha")
    exported = PredictorBEM(_tiny_predictor(tmp_path, state), robot=robot)
    sources = [ModelBEM(robot), ZeroBEM(robot.qu_nominal), exported, learned]
    x = np.array([[0.0, 0.0, 0.0], [3.0, 0.5, 0.1]])
    for src in sources:
        assert isinstance(src, BEMSource), type(src).__name__
        assert src.name in ("model", "zero", "predictor", "learned")
        assert src(x).shape == (2,) and src.full(np.concatenate([x, np.zeros((2, 2))], axis=1)).shape == (2,)
    # the model source at rest is the nominal value, as the zero source is
    np.testing.assert_allclose(sources[0](x[:1]), [robot.qu_nominal], atol=1e-12)


def test_learned_and_exported_sources_agree(tmp_path):
    """The eager learned BEM and its exported TorchScript file are the same source (eq. 14 and 11)."""
    state = _tiny_state()
    learned = LearnedBEM(state, robot="furuta", actuated_names=("theta",), unactuated_name="alpha")
    exported = PredictorBEM(_tiny_predictor(tmp_path, state))
    x = np.random.default_rng(0).normal(size=(64, 5))
    np.testing.assert_allclose(learned(x[:, :3]), exported(x[:, :3]), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(learned.full(x), exported.full(x), rtol=1e-9, atol=1e-12)
    # eq. 14 is eq. 11 at q̈_u = q̇_u = 0
    np.testing.assert_allclose(learned(x[:, :3]), learned.full(np.concatenate([x[:, :3], np.zeros((64, 2))], axis=1)), rtol=0, atol=0)


# ---- checked by mypy, not run: each assignment is a type error if the class stops satisfying the protocol ----

def _typed_robot_assignments(mj: MujocoRobot, an: AnalyticFuruta) -> list[ControlRobot]:
    balance: BalanceRobot = mj
    control: ControlRobot = an
    return [mj, an, control] if balance else []


def _typed_source_assignments(robot: ControlRobot, path: Path, learned: LearnedBEM) -> list[BEMSource]:
    return [ModelBEM(robot), ZeroBEM(robot.qu_nominal), PredictorBEM(path, robot=robot), learned]


@pytest.mark.parametrize("robot", _robots(), ids=lambda r: f"{type(r).__name__}:{r.name}")
def test_generic_single_state_path_matches_each_robots_fast_path(robot):
    """:class:`~bemlearn.robots.Robot`'s own ``terms``/``gamma0_scalar`` (through the batched torch dynamics)
    agree with the NumPy fast path every concrete robot overrides them with."""
    from bemlearn.robots import Robot

    rng = np.random.default_rng(3)
    for _ in range(3):
        q, qd = rng.normal(scale=0.3, size=robot.n), rng.normal(scale=0.5, size=robot.n)
        q[robot.unactuated_index] += robot.qu_nominal
        D_fast, h_fast = robot.terms(q, qd)
        D_gen, h_gen = Robot.terms(robot, q, qd)
        np.testing.assert_allclose(D_gen, D_fast, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(h_gen, h_fast, rtol=1e-10, atol=1e-10)
        qa, qad, qadd = (rng.normal(scale=s, size=robot.m) for s in (0.2, 0.5, 1.0))
        args = (robot.qu_nominal + 0.05, qa, qad, qadd, 0.3, -0.7)
        assert Robot.gamma0_scalar(robot, *args) == pytest.approx(robot.gamma0_scalar(*args), rel=1e-10, abs=1e-10)


def test_numpy_root_finder_is_the_torch_solvers_core():
    """:func:`~bemlearn.robots.bem.solve_bem` (torch residuals) returns what :func:`find_roots` returns for
    the same residuals in NumPy, and the roots solve a closed form: tan(x) = c on (−π/2, π/2)."""
    from bemlearn.robots.bem import find_roots, solve_bem

    c = np.array([-3.0, -0.2, 0.0, 0.7, 4.0])
    roots, valid, residual, _ = find_roots(lambda x, rows: np.tan(x) - c[rows, None], len(c), lo=-1.5, hi=1.5)
    assert valid.all()
    np.testing.assert_allclose(roots, np.arctan(c), atol=1e-13)
    assert np.all(residual <= 1e-10)
    ct = torch.from_numpy(c)
    res = solve_bem(lambda x, rows: torch.tan(x) - ct[rows, None], len(c), lo=-1.5, hi=1.5)
    np.testing.assert_array_equal(res.qu.numpy(), roots)
    res_all = solve_bem(lambda x: torch.tan(x) - ct[:, None], len(c), lo=-1.5, hi=1.5)  # residuals without `rows`
    np.testing.assert_array_equal(res_all.qu.numpy(), roots)
    # no root in range: NaN and invalid, as before
    none = find_roots(lambda x, rows: x**2 + 1.0, 2, lo=-1.0, hi=1.0)
    assert not none[1].any() and np.isnan(none[0]).all()


def test_loading_a_robot_does_not_load_torch():
    """A MuJoCo robot's model, ranges and numpy dynamics need no torch; its torch members load it on first use."""
    import subprocess
    import sys

    probe = ("import sys; from bemlearn.robots import load; r = load('furuta'); r.terms(r.T_np[0] * 0, r.T_np[0] * 0); "
             "before = 'torch' in sys.modules; r.T; print(before, 'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True).stdout.split()
    assert out == ["False", "True"]
