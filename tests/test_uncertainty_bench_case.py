"""``bemlearn bench uncertainty``'s generated cart-pole case builds a valid config and its data.

(The bench itself fits several GPs and runs in minutes; it is not part of the timed suite.
This guards the part that broke silently once: the case's config construction.)
"""

from __future__ import annotations

from bemlearn.bench.uncertainty_cases import cartpole_case
from bemlearn.data import read_trajectory


def test_cartpole_case_writes_its_robot_and_data(tmp_path):
    case = cartpole_case(tmp_path, n_trials=2)
    assert case.config.robot == str(tmp_path / "cartpole_uncertainty.xml")
    traj = read_trajectory(case.data_path)
    assert traj.meta.sample_rate_hz == 400.0 and len(traj.trial_ids) == 2
    assert traj.meta.joint_kinds == ("slide", "hinge")
    assert None not in (case.evaluation.n_sines, case.evaluation.frequency_hz)   # every field set or derived
