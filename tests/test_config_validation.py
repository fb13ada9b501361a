"""Every config section and the robot file are validated before anything is written (issue 22).

One validating parse (bemlearn.config.from_dict with the components' limits, the pipeline's
rules between sections, those that need the robot) and a strict YAML reader (duplicate keys,
bounded alias expansion); the preflight of every command runs it.  Before issue 22 the cases
below passed ``config show`` and the preflight, and failed after collect and train, finished
with ``nan`` in the report, were silently ignored, or ended in a traceback naming no key.
"""

import time
from pathlib import Path

import pytest
import yaml

from bemlearn.cli.main import main
from bemlearn.config import MAX_NODES, to_dict
from bemlearn.errors import ConfigError
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.pipeline.resolve import flatten, resolve_pipeline_config

ROOT = Path(__file__).resolve().parents[1]
FURUTA_XML = ROOT / "bemlearn" / "apps" / "furuta" / "assets" / "furuta.xml"

#: (config text after "robot: furuta", the key the error must name, what it must say)
CASES = [
    ("simulate: {reference: {amplitudes: [0.1, 0.2], frequencies_hz: [0.5], phases: [0, 0]}}", "simulate.reference",
     "one entry per component"),
    ("simulate: {nominal: {mass_scale: 0}}", "simulate.nominal.mass_scale", "> 0"),
    ("simulate: {nominal: {length_scale: -1}}", "simulate.nominal.length_scale", "> 0"),
    ("collect: {n_sines: [5, 2]}", "collect.n_sines", "min ≤ max"),
    ("evaluate: {n_sines: [5, 2]}", "evaluate.n_sines", "min ≤ max"),
    ("simulate: {warmup_s: 100, duration_s: 10}", "simulate.warmup_s", "shorter than simulate.duration_s"),
    ("simulate: {bem_source: bogus}", "simulate.bem_source", "expected one of ['predictor', 'model', 'zero']"),
    ("collect: {rate_hz: .nan}", "collect.rate_hz", "expected a finite number, got nan"),
    ("collect: {n_trials: 1e26}", "collect.n_trials", "expected an integer"),
    ("collect: {n_trials: 100000000000000000000000000}", "collect.n_trials", "at most 64 bits"),
    ("collect: {n_trials: 100000000}", "collect.n_trials", "≤ 1000000"),
    ("collect: {duration_s: .inf}", "collect.duration_s", "expected a finite number, got inf"),
    ("collect: {gains: [1, 2, 3]}", "collect.gains", "expected m·2n = 4 values"),
    ("collect: {n_trials: 1}", "collect.n_trials", "must be at least 2"),
    ("evaluate: {amplitude_min: 2.0, amplitude_max: 1.0}", "evaluate.amplitude_min", "must not exceed"),
    ("evaluate: {rate_hz: 0}", "evaluate.rate_hz", "> 0"),
    ("simulate: {nominal: {mass_scale: 0.9, bodies: [nosuch]}}", "simulate.nominal.bodies", "no body ['nosuch']"),
    ("collect: {sensor: {velocity_cutoff: -5}}", "collect.sensor.velocity_cutoff", "> 0"),
    ("dataset: {derivative: bogus}", "dataset", "unknown derivative estimator 'bogus'"),
    ("collect: {n_trials: 1000000, duration_s: 100000}", "collect", "samples, more than"),
    ("train: {max_iter: 100000000000}", "train.max_iter", "≤ 10000000"),
]


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "c.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("text, key, message", CASES, ids=[c[1] + ":" + c[2][:20] for c in CASES])
def test_config_show_names_the_key(tmp_path, capsys, text, key, message):
    cfg = _write(tmp_path, f"robot: furuta\n{text}\n")
    assert main(["config", "show", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert str(cfg) in err and key.split(".")[-1] in err and message in err, err
    assert "Traceback" not in err and len(err) < 1000


@pytest.mark.parametrize("command", ["run", "train", "collect", "simulate"])
def test_the_preflight_refuses_before_writing(tmp_path, capsys, command):
    cfg = _write(tmp_path, "robot: furuta\nsimulate: {warmup_s: 100, duration_s: 10}\n")
    out = tmp_path / "out" / ("data.npz" if command == "collect" else "run")
    extra = ["--data", str(ROOT / "data/furuta_excitation.npz")] if command == "train" else []
    t0 = time.perf_counter()
    assert main([command, str(cfg), "--out", str(out), "--no-progress", *extra]) == 2
    assert time.perf_counter() - t0 < 5.0
    assert "simulate.warmup_s" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def _leaves():
    resolved = resolve_pipeline_config(ROOT / "configs/furuta.yaml")
    return {k: v for k, v in flatten(to_dict(resolved.config)).items()
            if isinstance(v, (int, float)) and not isinstance(v, bool)}


@pytest.mark.parametrize("bad", [".nan", ".inf", "-.inf", "1000000000000000000000000000000"])
def test_no_numeric_key_takes_a_non_finite_or_huge_value(tmp_path, bad):
    """Every numeric key of every section (not only the ones in CASES)."""
    base = yaml.safe_load((ROOT / "configs/furuta.yaml").read_text())
    for key in _leaves():
        raw = yaml.safe_load(yaml.safe_dump(base))
        node = raw
        *path, last = key.split(".")
        for part in path:
            node = node.setdefault(part, {})
        node[last] = "@BAD@"
        cfg = _write(tmp_path, yaml.safe_dump(raw).replace("'@BAD@'", bad))
        with pytest.raises(ConfigError) as info:
            resolve_pipeline_config(cfg, derive=False)
        assert last in str(info.value) and str(cfg) in str(info.value), (key, bad, str(info.value))


def test_a_duplicate_key_is_an_error(tmp_path, capsys):
    cfg = _write(tmp_path, "robot: furuta\ncollect:\n  n_trials: 3\n  seed: 1\n  n_trials: 30\n")
    assert main(["config", "show", str(cfg)]) == 2
    assert "line 5: duplicate key 'n_trials' (first at line 3)" in capsys.readouterr().err
    # a merge key is not a duplicate: explicit keys override the merged ones, as YAML says
    ok = _write(tmp_path, "robot: furuta\ncollect:\n  <<: {n_trials: 3, seed: 1}\n  seed: 2\n")
    assert resolve_pipeline_config(ok).config.collect.seed == 2


def test_numbers_in_exponent_notation_are_numbers(tmp_path):
    cfg = _write(tmp_path, "robot: furuta\ncollect: {sensor: {noise_std: 1e-3}}\ntrain: {jitter: 1E-8}\n")
    c = resolve_pipeline_config(cfg).config
    assert c.collect.sensor.noise_std == 1e-3 and c.train.jitter == 1e-8


def _bomb(levels: int, width: int = 10) -> str:
    """One YAML value of ~width**levels numbers: [&x0 [1.5, ...], &x1 [*x0, ...], ...]."""
    parts = ["&x0 [" + ", ".join(["1.5"] * width) + "]"]
    for k in range(1, levels):
        parts.append(f"&x{k} [" + ", ".join([f"*x{k - 1}"] * width) + "]")
    return "[" + ", ".join(parts) + "]"


def test_an_alias_bomb_is_refused_in_a_bounded_message(tmp_path, capsys):
    cfg = _write(tmp_path, f"robot: furuta\ncollect:\n  gains: {_bomb(9)}\n")   # ~10⁹ values from ~600 bytes
    assert cfg.stat().st_size < 1000
    t0 = time.perf_counter()
    assert main(["config", "show", str(cfg)]) == 2
    assert time.perf_counter() - t0 < 5.0
    out = capsys.readouterr()
    assert f"expands to more than {MAX_NODES} values" in out.err and len(out.err) + len(out.out) < 1000


def test_a_value_below_the_bound_is_quoted_in_a_bounded_prefix(tmp_path, capsys):
    cfg = _write(tmp_path, f"robot: furuta\ncollect:\n  gains: {_bomb(4)}\n")   # ~10⁴ values: under the bound
    assert main(["config", "show", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "collect" in err and len(err) < 1000, err[:2000]
    cfg = _write(tmp_path, f"robot: furuta\ncollect:\n  seed: {_bomb(4)}\n")       # the value itself in the message
    assert main(["config", "show", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "collect.seed: expected an integer, got [[" in err and "..." in err and len(err) < 1000, err[:2000]


def test_a_recursive_alias_is_refused(tmp_path, capsys):
    cfg = _write(tmp_path, "robot: furuta\ncollect:\n  gains: &g [1, *g]\n")
    assert main(["config", "show", str(cfg)]) == 2
    assert "refers to a value that contains it" in capsys.readouterr().err


@pytest.mark.parametrize("edit, message", [
    (('timestep="0.00125"', 'timestep="0"'), '<option timestep="0">: expected a positive, finite physics step'),
    (('timestep="0.00125"', 'timestep="-0.001"'), "expected a positive, finite physics step"),
    (('gravity="0 0 -9.81"', 'gravity="0 0 nan"'), "gravity"),
])
def test_a_robot_file_whose_physics_makes_no_sense_is_refused(tmp_path, capsys, monkeypatch, edit, message):
    monkeypatch.chdir(tmp_path)   # MuJoCo writes its NaN warning to ./MUJOCO_LOG.TXT
    xml = FURUTA_XML.read_text()
    assert edit[0] in xml
    (tmp_path / "r.xml").write_text(xml.replace(edit[0], edit[1]))
    cfg = _write(tmp_path, f"robot: {tmp_path / 'r.xml'}\n")
    assert main(["config", "show", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert message in err and "r.xml" in err and "Traceback" not in err, err
    assert main(["run", str(cfg), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("device", ["cpu", "cuda", "cuda:0", "cuda:12", "mps", "xpu:1", "meta", "cpu:0", "CUDA", "cuda:",
                                    "cuda:-1", "cuda:00", "cuda:+1", " cuda", "cuda:1 ", "cuda:0:1", "gpu", "tpu", ""])
def test_device_check_accepts_what_torch_device_accepts(device):
    """``train.device`` is checked without importing torch; the check agrees with ``torch.device``."""
    import warnings

    import torch

    from bemlearn.fitting.gp_config import DEVICE_PATTERN

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.device(device)
        torch_ok = True
    except RuntimeError:
        torch_ok = False
    assert bool(DEVICE_PATTERN.fullmatch(device)) == torch_ok
    if not torch_ok:
        with pytest.raises(ConfigError, match="not a torch device string"):
            GPConfig(device=device)
