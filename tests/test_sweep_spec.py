"""Sweep files: strict parsing, the grid's cells, their ids, validation before anything runs (issue 24).

No cell runs here (tests/test_sweep_run.py runs them).
"""

from pathlib import Path

import pytest

from bemlearn.cli.main import main
from bemlearn.config import check_dotted_key
from bemlearn.errors import ConfigError
from bemlearn.pipeline.config import PipelineConfig
from bemlearn.sweep import expand_cells, load_sweep, run_sweep

ROOT = Path(__file__).resolve().parents[1]
CARTPOLE = "tests/robots/cartpole.xml"
WHEEL = "tests/robots/reaction_wheel.xml"
TINY = {"collect": {"n_trials": 2, "duration_s": 2.0}}


def _sweep(**kw):
    return {"base": {"robot": CARTPOLE, **TINY}, **kw}


@pytest.fixture(autouse=True)
def _in_repo(monkeypatch):
    monkeypatch.chdir(ROOT)  # sweep paths are relative to the current directory, as every config's


def test_the_grid_is_the_cartesian_product_first_key_slowest():
    cells = expand_cells(load_sweep(_sweep(grid={"robot": [CARTPOLE, WHEEL], "collect.seed": [0, 1, 2]})))
    assert [(c.grid["robot"], c.grid["collect.seed"]) for c in cells] == [
        (r, s) for r in (CARTPOLE, WHEEL) for s in (0, 1, 2)]
    assert [c.index for c in cells] == list(range(6))
    assert cells[4].label == f"robot={WHEEL}, collect.seed=1"
    cfg = cells[4].config.config  # the resolved pipeline config of that cell
    assert cfg.collect.seed == 1 and Path(cfg.robot) == ROOT / WHEEL and Path(cfg.robot).is_absolute()
    assert cfg.collect.n_trials == 2 and cfg.collect.rate_hz is not None  # given, and derived from the model
    assert len({c.cell_id for c in cells}) == 6 and all(len(c.cell_id) == 12 for c in cells)


def test_a_cell_id_follows_the_resolved_config_and_the_robot_file_bytes(tmp_path):
    grid = {"collect.seed": [0, 1]}
    ids = [c.cell_id for c in expand_cells(load_sweep(_sweep(grid=grid)))]
    # the same cells again, from another grid holding them, with an absolute robot path and another
    # collect.workers (how a cell runs, not what it computes): the same ids
    other = {"base": {"robot": str(ROOT / CARTPOLE), "collect": {**TINY["collect"], "workers": 2}},
             "grid": {"collect.seed": [1, 0, 5]}}
    again = {c.grid["collect.seed"]: c.cell_id for c in expand_cells(load_sweep(other))}
    assert [again[0], again[1]] == ids and again[5] not in ids
    # a value that changes the computation changes the id
    longer = {"base": {"robot": CARTPOLE, "collect": {"n_trials": 2, "duration_s": 3.0}}, "grid": grid}
    assert not set(ids) & {c.cell_id for c in expand_cells(load_sweep(longer))}
    # a copy of the MJCF elsewhere is the same robot; one changed byte is another
    copy = tmp_path / "cartpole.xml"
    copy.write_text((ROOT / CARTPOLE).read_text())
    moved = {"base": {"robot": str(copy), **TINY}, "grid": grid}
    assert [c.cell_id for c in expand_cells(load_sweep(moved))] == ids
    copy.write_text((ROOT / CARTPOLE).read_text() + "<!-- edited -->\n")
    assert not set(ids) & {c.cell_id for c in expand_cells(load_sweep(moved))}


@pytest.mark.parametrize("sweep, message", [
    ({"base": {"robot": CARTPOLE}, "gird": {"collect.seed": [0]}}, "unknown key(s) ['gird']"),
    (_sweep(grid={"collect.seedd": [0, 1]}), "grid: collect.seedd: unknown key 'seedd' in collect; valid keys are"),
    (_sweep(grid={"colect.seed": [0, 1]}), "grid: colect.seed: unknown key 'colect' in the top level"),
    (_sweep(grid={"collect.seed.x": [0]}), "grid: collect.seed.x: collect.seed is a value, not a section"),
    (_sweep(overrides={"simulate.durations": 3.0}), "overrides: simulate.durations: unknown key 'durations' in simulate"),
    (_sweep(resources={"cpu": 2}), "resources: unknown key(s) ['cpu']"),
    (_sweep(resources={"cpus": 0}), "resources.cpus: expected an integer ≥ 1"),
    (_sweep(grid={"collect.seed": []}), "grid.collect.seed: expected a non-empty list"),
    (_sweep(grid={"collect.seed": [0, 0]}), "grid.collect.seed: the value 0 is listed twice"),
    (_sweep(stage="trian"), "unknown stage 'trian'; the stages of pipeline configs are ['run', 'simulate', 'train']"),
    ({"base": "no/such/config.yaml"}, "base: no config file no/such/config.yaml"),
])
def test_a_bad_sweep_file_is_an_error_naming_the_key(sweep, message):
    with pytest.raises(ConfigError) as exc:
        load_sweep(sweep)
    assert message in str(exc.value)


def test_a_bad_value_in_any_cell_fails_before_anything_runs(tmp_path):
    sweep = _sweep(grid={"collect.n_trials": [2, "many"]})
    out = tmp_path / "sweep"
    with pytest.raises(ConfigError) as exc:
        run_sweep(sweep, out, backend="serial", progress=False)
    assert "cell 1 (collect.n_trials=many)" in str(exc.value) and "config.collect.n_trials: expected an integer" in str(exc.value)
    assert not out.exists()
    with pytest.raises(ConfigError, match=r"cell 0 \(robot=tests/robots/nope.xml\): config: robot: .*tests/robots/nope.xml not found"):
        expand_cells(load_sweep(_sweep(grid={"robot": ["tests/robots/nope.xml"]})))
    with pytest.raises(ConfigError, match="simulate.predictor: not given; bem_source predictor needs"):
        expand_cells(load_sweep(_sweep(stage="simulate", overrides={"simulate.bem_source": "predictor"})))


def test_two_cells_with_the_same_config_are_an_error():
    sweep = _sweep(grid={"robot": [CARTPOLE, str(ROOT / CARTPOLE)]})
    with pytest.raises(ConfigError, match=r"cells 0 \(robot=tests/robots/cartpole.xml\) and 1 .* resolve to the same config"):
        expand_cells(load_sweep(sweep))


def test_dotted_keys_inside_free_form_mappings_are_accepted():
    check_dotted_key(PipelineConfig, "dataset.derivative_options.window_s")
    check_dotted_key(PipelineConfig, "simulate.nominal.mass_scale")
    check_dotted_key(PipelineConfig, "robot")


def test_the_shipped_sweep_files_validate():
    files = sorted((ROOT / "configs" / "sweeps").glob("*.yaml"))
    assert {f.stem for f in files} >= {"example", "robots", "robots-quick", "biped-bem", "furuta-mismatch"}
    for f in files:
        loaded = load_sweep(f.relative_to(ROOT))
        if f.stem == "furuta-mismatch":  # needs the predictor of a furuta run first (the error says which file)
            if not Path(loaded.base["simulate"]["predictor"]).is_file():
                # relative to the sweep file's folder: the runs/ folder next to configs/
                with pytest.raises(ConfigError, match=f"simulate.predictor: no file {ROOT.resolve()}/runs/furuta/bem_predictor.pt"):
                    expand_cells(loaded)
            continue
        if f.stem == "family":  # the generated family's files (`bemlearn bench family generate`, docs/family.md)
            robots = loaded.spec.grid["robot"]
            assert len(robots) >= 60 and all(r.startswith("runs/family/") for r in robots)
            if not Path(robots[0]).is_file():
                with pytest.raises(ConfigError, match="runs/family/fam0_000.xml not found"):
                    expand_cells(loaded)
            continue  # resolving 64 robots' derivations is the sweep's work, not this test's
        cells = expand_cells(loaded)
        n = 1
        for values in loaded.spec.grid.values():
            n *= len(values)
        assert len(cells) == n, f.name


def test_paths_in_a_sweep_file_are_relative_to_its_folder(tmp_path, monkeypatch):
    """base:, the inline base's, the overrides' and the grid's paths against the sweep file's folder; a
    base file's own paths against the base file's folder; the current folder plays no part."""
    (tmp_path / "robots").mkdir()
    (tmp_path / "sweeps" / "deep").mkdir(parents=True)
    for name in ("a.xml", "b.xml"):  # two files (a comment apart: cells are told apart by the file's sha256)
        (tmp_path / "robots" / name).write_text((ROOT / CARTPOLE).read_text() + f"<!-- {name} -->\n")
    (tmp_path / "base.yaml").write_text("robot: robots/a.xml\ncollect: {n_trials: 2, duration_s: 2.0}\n")
    (tmp_path / "sweeps" / "deep" / "s.yaml").write_text("base: ../../base.yaml\ngrid: {robot: [../../robots/a.xml, ../../robots/b.xml]}\n")
    (tmp_path / "sweeps" / "inline.yaml").write_text("base: {robot: ../robots/b.xml, collect: {n_trials: 2, duration_s: 2.0}}\n"
                                                    "overrides: {data: ../nowhere.npz}\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    loaded = load_sweep(Path("../sweeps/deep/s.yaml"))
    assert loaded.base["robot"] == str(tmp_path.resolve() / "robots" / "a.xml")
    cells = expand_cells(loaded)
    assert [c.config.config.robot for c in cells] == [str(tmp_path.resolve() / "robots" / n) for n in ("a.xml", "b.xml")]
    assert [c.label for c in cells] == ["robot=../../robots/a.xml", "robot=../../robots/b.xml"]  # as written
    inline = load_sweep(tmp_path / "sweeps" / "inline.yaml")
    assert inline.base["robot"] == str(tmp_path.resolve() / "robots" / "b.xml")
    assert inline.base["data"] == str(tmp_path.resolve() / "nowhere.npz")
    (elsewhere / "base.yaml").write_text((tmp_path / "base.yaml").read_text())  # in the current folder: not looked at
    with pytest.raises(ConfigError, match=r"base: no config file base\.yaml \(relative to the sweep file's folder"):
        (tmp_path / "sweeps" / "bad.yaml").write_text("base: base.yaml\n")
        load_sweep(tmp_path / "sweeps" / "bad.yaml")


def test_dry_run_lists_the_cells_and_resume_with_force_is_refused(tmp_path, capsys):
    sweep = tmp_path / "s.yaml"
    sweep.write_text(f"base: {{robot: {ROOT / CARTPOLE}, collect: {{n_trials: 2, duration_s: 2.0}}}}\n"
                     "grid: {collect.seed: [0, 1]}\nstage: train\n")
    assert main(["sweep", str(sweep), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "collect.seed=0" in out and "collect.seed=1" in out and "2 cells, stage train: every config is valid" in out
    assert main(["sweep", str(sweep), "--resume", "--force"]) == 2
    assert "--resume and --force: give one" in capsys.readouterr().err


def test_docs_describe_every_sweep_key_and_stage():
    import dataclasses

    from bemlearn.pipeline.config_doc import attribute_docs
    from bemlearn.sweep import SweepConfig, SweepResources, stage_names

    text = (ROOT / "docs" / "sweeps.md").read_text()
    for cls in (SweepConfig, SweepResources):
        for f in dataclasses.fields(cls):
            assert attribute_docs(cls).get(f.name), f"{cls.__name__}.{f.name} has no docstring entry"
            assert f"`{f.name}`" in text, f"docs/sweeps.md does not describe {f.name}"
    for names in stage_names().values():
        for name in names:
            assert f"| `{name}` |" in text or f"| `{name}` (" in text, name


def test_rows_differ_only_in_what_was_computed():
    from bemlearn.sweep.results import differing_columns

    a = {"cell": "x", "wall_s": 1.0, "cpu_s": 1.0, "host": "a", "closed_loop.zero.tracking_rmse": float("nan"), "m": 0.25}
    b = {**a, "wall_s": 2.0, "cpu_s": 3.0, "host": "b", "closed_loop.zero.tracking_rmse": float("nan")}
    assert differing_columns(a, b) == []
    assert differing_columns(a, {**b, "m": 0.25 + 1e-16, "status": "ok"}) == ["m", "status"]
