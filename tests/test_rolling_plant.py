"""A rolling robot in the simulated plant, the actuator inverse and the LQR linearisation.

The plant is MuJoCo's full model (chassis slide, wheel, pendulum; soft contact), read in the robot's
coordinates (wheel, pendulum) through q = T q_j and set through q_j = S q (x = r_eff θ).  The
linearisation of MuJoCo's steps is checked against the reduced hard-constraint model's own
(robot.terms, eq. R4 of bemlearn.robots.rolling), discretised exactly (matrix exponential).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from bemlearn.control.actuator_inverse import MujocoActuatorInverse
from bemlearn.control.lqr import linearize
from bemlearn.data.sensors import SensorConfig
from bemlearn.robots import load
from bemlearn.sim.plant import SensedPlant, _coordinate_kinds

WHEEL = Path(__file__).resolve().parent / "robots" / "wheel_pendulum.xml"
R_EFF = 0.5 * (0.116 + 0.12)   # hub + half the penetration (tests/test_rolling.py)


@pytest.fixture(scope="module")
def robot():
    return load(WHEEL)


def test_the_plant_sets_the_rolling_freedom_and_reads_the_coordinates(robot):
    plant = SensedPlant(robot, rate_hz=200.0, sensor=SensorConfig(counts_per_rev=0), rng=np.random.default_rng(0), where="test")
    q0, qd0 = np.array([2.0, robot.qu_nominal + 0.01]), np.array([1.5, 0.0])
    plant.reset(q0, qd0)
    travel = robot.model.joint("travel")
    assert plant.data.qpos[travel.qposadr[0]] == pytest.approx(R_EFF * 2.0, rel=1e-12)
    assert plant.data.qvel[travel.dofadr[0]] == pytest.approx(R_EFF * 1.5, rel=1e-12)
    np.testing.assert_allclose(plant.true_q(), q0, atol=1e-15)
    qd, qdd = plant.apply(np.array([0.5]))
    assert qd.shape == qdd.shape == (2,)
    np.testing.assert_allclose(qd, qd0, atol=1e-12)
    assert _coordinate_kinds(robot) == ("hinge", "hinge")   # the encoder's steps follow the coordinates' joints


def test_the_actuator_inverse_maps_wheel_torque_to_ctrl(robot):
    inv = MujocoActuatorInverse(robot)
    q = np.array([1.0, robot.qu_nominal])
    gear = float(robot.model.actuator_gear[0, 0])
    assert inv.command(np.array([0.7]), q, np.zeros(2)) == pytest.approx([0.7 / gear])


def test_the_linearisation_of_mujoco_matches_the_reduced_model(robot):
    rate = 200.0
    A, B, substeps, _ = linearize(robot, rate_hz=rate)
    assert substeps == 5   # 1/200 Hz in steps of 1 ms
    assert A.shape == (4, 4) and B.shape == (4, 1)
    n = robot.n
    q0 = np.zeros(n)
    q0[robot.unactuated_index] = robot.qu_nominal

    def f(x: np.ndarray, u: float) -> np.ndarray:
        D, hh = robot.terms(x[:n], x[n:])
        return np.concatenate([x[n:], np.linalg.solve(D, robot.input_matrix_np[:, 0] * u - hh)])

    x0, e = np.concatenate([q0, np.zeros(n)]), 1e-6
    Ac = np.column_stack([(f(x0 + e * d, 0.0) - f(x0 - e * d, 0.0)) / (2 * e) for d in np.eye(2 * n)])
    Bc = (f(x0, e) - f(x0, -e)) / (2 * e)
    M = np.zeros((2 * n + 1, 2 * n + 1))
    M[: 2 * n, : 2 * n], M[: 2 * n, 2 * n] = Ac, Bc
    E = scipy.linalg.expm(M / rate)
    # the unstable pole: MuJoCo's soft contact rolls the pendulum's base like the hard constraint (measured 0.02 %)
    rate_mujoco = np.log(np.max(np.abs(np.linalg.eigvals(A)))) * rate
    rate_model = np.log(np.max(np.abs(np.linalg.eigvals(E[: 2 * n, : 2 * n])))) * rate
    assert rate_mujoco == pytest.approx(rate_model, rel=1e-3)
    # the input's effect on the rates within one tick: Euler substeps and the soft contact (measured 1.3 %)
    np.testing.assert_allclose(B[n:, 0], E[n: 2 * n, 2 * n], rtol=0.02)


def test_config_show_names_the_rolling_coordinates_zero_config():
    """A config naming only the robot resolves (no 'two undriven joints' refusal) and says how the coordinates came about."""
    from bemlearn.pipeline.resolve import format_resolved, resolve_pipeline_config

    resolved = resolve_pipeline_config({"robot": str(WHEEL)})
    text = format_resolved(resolved)
    assert "# robot: coordinates spin (q_a), pitch (q_u); travel = 0.118·spin (rolling without slip: tyre r_eff 0.118 m" in text


def test_the_wheel_half_range_comes_from_the_slide_it_rolls(robot):
    """The excitation and evaluation amplitudes are capped by q_a's half range: ±3 m of slide → ±3 / r_eff rad of wheel."""
    from bemlearn.robots.scales import qa_half_ranges, qa_limited

    np.testing.assert_allclose(qa_half_ranges(robot), [3.0 / R_EFF], rtol=1e-12)
    assert qa_limited(robot).tolist() == [True]


def test_robot_info_shows_the_rolling_map_and_the_cyclic_wheel(capsys):
    from bemlearn.cli.main import main

    assert main(["robot", "info", str(WHEEL)]) == 0
    out = capsys.readouterr().out
    assert "joints     spin (hinge, rad), pitch (hinge, rad)" in out
    assert "rolling    travel = 0.118·spin (rolling without slip: tyre r_eff 0.118 m (geometric 0.12 m, 2 contact points))" in out
    assert "cyclic     spin: the dynamics (D, h of eq. 1) do not depend on its position" in out
