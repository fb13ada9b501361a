"""Paths in a config file are relative to the file's folder (docs/config.md, "Paths"), on the command line to
the current folder; registry names stay names; a missing file is named once, with the key once."""

from __future__ import annotations

from pathlib import Path

import pytest

from bemlearn.cli.main import main
from bemlearn.config import is_relative_path, rebase_paths
from bemlearn.errors import ConfigError
from bemlearn.pipeline.resolve import resolve_pipeline_config

ROOT = Path(__file__).resolve().parents[1]
CARTPOLE = ROOT / "tests" / "robots" / "cartpole.xml"


@pytest.fixture
def tree(tmp_path, monkeypatch):
    """tmp/robots/cp.xml, tmp/data/x.npz, tmp/sub/rel.yaml naming them relative to sub/; the current folder elsewhere."""
    (tmp_path / "robots").mkdir()
    (tmp_path / "robots" / "cp.xml").write_bytes(CARTPOLE.read_bytes())
    (tmp_path / "sub").mkdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    return tmp_path


def test_is_relative_path_tells_paths_from_registry_names():
    assert [is_relative_path(v) for v in ("robot.xml", "a/b", "../x.npz", "furuta", "/abs/x.xml", "", None, 3)] == \
        [True, True, True, False, False, False, False, False]


def test_rebase_paths_nested_flat_and_lists(tmp_path):
    raw = {"robot": "r.xml", "simulate": {"predictor": "../p.pt", "rate_hz": 400.0}, "model": "furuta",
           "collect.seed": [0, 1], "data": ["a.npz", "/abs/b.npz"]}
    out = rebase_paths(raw, ("robot", "simulate.predictor", "model", "data", "collect.seed", "missing.key"), tmp_path / "cfg")
    assert out["robot"] == str(tmp_path / "cfg" / "r.xml")
    assert out["simulate"] == {"predictor": str(tmp_path / "p.pt"), "rate_hz": 400.0}
    assert out["model"] == "furuta" and out["collect.seed"] == [0, 1]
    assert out["data"] == [str(tmp_path / "cfg" / "a.npz"), "/abs/b.npz"]


def test_paths_in_a_config_file_are_relative_to_its_folder(tree):
    cfg = tree / "sub" / "rel.yaml"
    cfg.write_text("robot: ../robots/cp.xml\nsimulate: {predictor: ../runs/r/bem_predictor.pt}\n")
    resolved = resolve_pipeline_config(Path("../sub/rel.yaml"))  # given relative to the current folder
    assert resolved.config.robot == str(tree.resolve() / "robots" / "cp.xml")
    assert resolved.config.simulate.predictor == str(tree.resolve() / "runs" / "r" / "bem_predictor.pt")
    free = tree / "sub" / "free.yaml"
    free.write_text("data: ../data/x.npz\nmodel: ../robots/cp.xml\n")
    config = resolve_pipeline_config(free).config
    assert (config.data, config.model) == (str(tree.resolve() / "data" / "x.npz"), str(tree.resolve() / "robots" / "cp.xml"))
    # a mapping (a library call) keeps the current folder's meaning
    assert resolve_pipeline_config({"robot": str(CARTPOLE)}, derive=False).config.robot == str(CARTPOLE)


def test_the_preflight_of_a_command_reads_the_same_paths(tree):
    """`bemlearn run sub/rel.yaml` from another folder: the preflight loads the robot the config names."""
    from bemlearn.pipeline.preflight import preflight

    (tree / "sub" / "rel.yaml").write_text("robot: ../robots/cp.xml\n")
    checked = preflight(config=Path("../sub/rel.yaml"))
    assert checked.raw["robot"] == checked.resolved.config.robot == str(tree.resolve() / "robots" / "cp.xml")


def test_a_missing_robot_is_named_once_with_the_key_once(tree, capsys):
    """From the parent folder: the config's robot: ../../nowhere/x.xml is looked up from the config's folder."""
    (tree / "sub" / "rel.yaml").write_text("robot: ../nowhere/x.xml\n")
    with pytest.raises(ConfigError) as info:
        resolve_pipeline_config(tree / "sub" / "rel.yaml")
    msg = str(info.value)
    assert "robot: robot:" not in msg and msg.count("robot:") == 1
    assert f"MJCF file {tree.resolve() / 'nowhere' / 'x.xml'} not found" in msg
    assert main(["config", "show", "../sub/rel.yaml"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"bemlearn config: error: ../sub/rel.yaml: robot: MJCF file {tree.resolve() / 'nowhere' / 'x.xml'} not found"


def test_command_line_paths_are_relative_to_the_current_folder(tree, capsys):
    """`train --data FILE`: the current folder's file, not the config's folder's."""
    (tree / "sub" / "rel.yaml").write_text("robot: ../robots/cp.xml\n")
    (tree / "sub" / "x.npz").write_bytes(b"")  # next to the config: must not be picked for --data x.npz
    assert main(["train", "../sub/rel.yaml", "--data", "x.npz", "--out", "o"]) == 2
    err = capsys.readouterr().err
    assert "--data: trajectory file x.npz not found" in err


def test_a_biped_configs_paths_are_relative_to_its_folder(tree):
    from bemlearn.apps.biped.config import load_biped_config
    from bemlearn.apps.biped.walk_config import load_walk_config

    cfg = tree / "sub" / "biped.yaml"
    cfg.write_text("application: biped\nrobot: biped\nwalk: {predictor: ../p.pt, gait: {human: {path: gait.csv}}}\n")
    loaded = load_biped_config(cfg)
    assert loaded.walk.predictor == str(tree / "p.pt")
    assert loaded.walk.gait.human.path == str(tree.resolve() / "sub" / "gait.csv")
    assert load_walk_config(cfg).predictor == str(tree / "p.pt")
