"""Any robot, zero configuration: a config naming only the MJCF resolves, runs and records its robot."""

import json
import shutil
from pathlib import Path

import pytest

from bemlearn.cli.main import main
from bemlearn.config import ConfigError
from bemlearn.pipeline.resolve import complete_section, resolve_pipeline_config
from bemlearn.robots import RobotRef, resolve_robot

ROBOTS = Path(__file__).resolve().parent / "robots"
CARTPOLE = ROBOTS / "cartpole.xml"


def test_a_config_naming_only_the_mjcf_resolves_with_origins():
    r = resolve_pipeline_config({"robot": str(CARTPOLE)})
    assert r.origins["robot"] == "given"
    for key in ("collect.rate_hz", "collect.gains", "collect.amplitude", "evaluate.amplitude_max",
                "simulate.gains.kp_u", "simulate.reference.amplitudes", "collect.sensor.m_per_count"):
        assert r.origins[key] == "derived" and r.notes[key], key
    assert r.origins["collect.n_trials"] == "default" and r.origins["train.kind"] == "default"
    cfg = r.config
    # the control rate is ≥ 100 Hz with a whole number of physics steps of the file's 2 ms
    n = 1.0 / (cfg.collect.rate_hz * 0.002)
    assert cfg.collect.rate_hz >= 100 and abs(n - round(n)) < 1e-9
    assert cfg.simulate.rate_hz == cfg.collect.rate_hz
    assert len(cfg.collect.gains) == 4 and cfg.collect.input_units == "N"


def test_given_values_win_and_steer_what_is_derived():
    base = resolve_pipeline_config({"robot": str(CARTPOLE)}).config
    r = resolve_pipeline_config({"robot": str(CARTPOLE), "collect": {"rate_hz": 100.0, "gains": [1.0, 2.0, 3.0, 4.0]},
                                 "simulate": {"gains": {"kp_u": 50.0}}})
    assert r.origins["collect.gains"] == "given" and r.config.collect.gains == (1.0, 2.0, 3.0, 4.0)
    assert r.config.simulate.rate_hz == 100.0  # the closed loop runs at the given collection rate
    assert r.config.simulate.gains.kp_u == 50.0 and r.origins["simulate.gains.kp_u"] == "given"
    assert r.origins["simulate.gains.kd_u"] == "derived"
    assert "the given 100 Hz" in r.notes["simulate.rate_hz"] and base.collect.rate_hz != 100.0


def test_a_coarse_file_gets_a_finer_physics_step():
    r = resolve_pipeline_config({"robot": str(ROBOTS / "cartpole_coarse.xml")})
    assert r.config.collect.physics_timestep is not None and r.config.collect.physics_timestep < 0.02
    assert r.config.collect.rate_hz >= 100
    assert "finer" in r.notes["collect.physics_timestep"]


@pytest.mark.parametrize("raw, message", [
    ({}, "the config is empty"),
    ({"collect": {"n_trials": 3}}, "names neither 'robot:'"),
    ({"robot": str(CARTPOLE), "colect": {}}, "unknown key(s) ['colect']"),
    ({"robot": "no-such-robot"}, "unknown robot 'no-such-robot'"),
])
def test_bad_configs_are_named_errors(raw, message):
    with pytest.raises((ConfigError, ValueError)) as exc:
        resolve_pipeline_config(raw)
    assert message in str(exc.value)


def test_library_calls_complete_their_section():
    from bemlearn.sim.collect import CollectConfig, collect

    with pytest.raises(ValueError, match="not set; derive them"):
        collect(str(CARTPOLE), CollectConfig(n_trials=1, duration_s=0.5, workers=1))
    cfg = complete_section(str(CARTPOLE), "collect", CollectConfig(n_trials=2, duration_s=1.0, workers=1))
    data, _ = collect(str(CARTPOLE), cfg, progress=False)
    assert data.meta.joint_kinds == ("slide", "hinge") and data.meta.units["q"] == "m|rad"


def test_a_path_always_means_that_file_even_if_it_is_called_like_a_registered_robot(tmp_path):
    mine = tmp_path / "furuta.xml"
    shutil.copy(CARTPOLE, mine)
    robot, ref = resolve_robot(mine)
    assert ref.registry is None and ref.mjcf == str(mine.resolve()) and robot.joint_names == ("slider", "hinge")
    shipped, sref = resolve_robot("furuta")
    assert sref.registry == "furuta" and sref.mjcf != ref.mjcf and shipped.joint_names == ("theta", "alpha")
    # the recorded robot refuses a file whose bytes changed
    mine.write_text(mine.read_text().replace("<mujoco", "<!-- edited -->\n<mujoco", 1))
    with pytest.raises(ValueError, match="changed since the run"):
        RobotRef.from_dict(ref.to_dict()).load()


def test_config_show_prints_every_value_with_its_origin(tmp_path, capsys):
    cfg = tmp_path / "my.yaml"
    cfg.write_text(f"robot: {CARTPOLE}\n")
    assert main(["config", "show", str(cfg), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows["robot"]["origin"] == "given" and rows["collect.gains"]["origin"] == "derived"
    assert "LQR" in rows["collect.gains"]["note"]


@pytest.mark.slow
def test_run_on_a_config_naming_only_the_file(tmp_path):
    """The whole chain on the cart-pole with only ``robot:`` given (about a minute)."""
    cfg = tmp_path / "cartpole.yaml"
    cfg.write_text(f"robot: {CARTPOLE}\n")
    assert main(["run", str(cfg), "--out", str(tmp_path / "run"), "--no-progress"]) == 0
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["robot"]["mjcf"] == str(CARTPOLE.resolve()) and m["robot"]["registry"] is None
    dr = m["bem_heldout"]["design_region"]
    assert dr["rmse"] <= 0.01 and dr["max_abs"] <= 0.04
    assert not m["closed_loop"]["predictor"]["fell"] and not m["closed_loop"]["model"]["fell"]
    assert set(m["closed_loop"]) == {"predictor", "model", "zero"}


def test_a_folder_named_like_a_registered_robot_does_not_hide_it(tmp_path, monkeypatch):
    """``bemlearn run configs/furuta.yaml --out furuta`` claims the folder ``furuta`` before loading the robot:
    ``robot: furuta`` still means the registered Furuta, not that folder."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "furuta").mkdir()
    robot, ref = resolve_robot("furuta")
    assert ref.registry == "furuta" and robot.joint_names == ("theta", "alpha")
    (tmp_path / "mine").mkdir()  # a folder that is no registered name is still reported as a missing MJCF
    with pytest.raises(FileNotFoundError, match="MJCF file mine not found"):
        resolve_robot("mine")
