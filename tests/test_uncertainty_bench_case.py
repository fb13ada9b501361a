"""``bemlearn bench uncertainty``'s generated cart-pole case builds a valid config and its data.

(The bench itself fits several GPs and runs in minutes; it is not part of the timed suite.
This guards the part that broke silently once: the case's config construction.)
"""

from __future__ import annotations

from pathlib import Path

from bemlearn.bench.uncertainty_cases import cartpole_case
from bemlearn.data import read_trajectory


def test_cartpole_case_writes_its_robot_and_data(tmp_path):
    case = cartpole_case(tmp_path, n_trials=2)
    assert case.config.robot == str(tmp_path / "cartpole_uncertainty.xml")
    traj = read_trajectory(case.data_path)
    assert traj.meta.sample_rate_hz == 400.0 and len(traj.trial_ids) == 2
    assert traj.meta.joint_kinds == ("slide", "hinge")
    assert None not in (case.evaluation.n_sines, case.evaluation.frequency_hz)   # every field set or derived


def test_bench_uncertainty_refuses_an_existing_json_before_fitting(tmp_path, capsys):
    from bemlearn.cli.main import main

    out = tmp_path / "results.json"
    out.write_text("kept")
    root = Path(__file__).resolve().parents[1]
    code = main(["bench", "uncertainty", "--config", str(root / "configs/furuta.yaml"), "--data", str(root / "data/furuta_excitation.npz"),
                 "--no-cartpole", "--json", str(out)])
    assert code != 0 and "would overwrite" in capsys.readouterr().err
    assert out.read_text() == "kept"
