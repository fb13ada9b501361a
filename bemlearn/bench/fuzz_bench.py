"""Bad inputs for every reader: generated files, and whether each ends in a named error.

A *reader* takes a path (:data:`READERS`: trajectory files, configs, MJCF paths,
checkpoints, TorchScript and ``.pt2`` predictors).  A *bad-input class*
(:class:`BadInput`) writes one malformed file of a kind (truncated NPZ, non-UTF-8 YAML,
MJCF with two unactuated joints, …) from a seed.  :func:`run_case` feeds it to its
reader; the outcome is *named* when the reader raises a
:class:`~bemlearn.errors.BemlearnError` (or the documented ``FileNotFoundError`` for a
missing file) whose message names the file.  Anything else — another exception, a message
without the file, or no error at all — counts against the target (zero).

Extend with one more reader: ``register_reader("import_map", read_import_map)`` and
``BAD_INPUTS.append(BadInput("import_map", "empty file", make_fn))`` where
``make_fn(folder, seed, base)`` writes the file and returns its path.
"""

from __future__ import annotations

import json
import os
import random
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["BadInput", "Outcome", "READERS", "BAD_INPUTS", "register_reader", "run_case", "run_fuzz", "format_fuzz", "make_base"]

#: reader name → function reading one path (raises on bad input).
READERS: dict[str, Callable[[Path], Any]] = {}


def register_reader(name: str, fn: Callable[[Path], Any]) -> None:
    """Add a reader (``fn(path)``) the bad-input classes can target by ``name``."""
    READERS[name] = fn


@dataclass(frozen=True)
class BadInput:
    """One class of bad input: ``make(folder, seed, base) -> path`` writes it for ``reader``."""

    reader: str
    name: str
    make: Callable[[Path, int, dict], Path]


@dataclass(frozen=True)
class Outcome:
    """What the reader did with one generated bad input."""

    reader: str
    name: str
    named: bool
    error: str  # exception class, or "no error"
    message: str


# ---------------------------------------------------------------- readers


def _read_trajectory(path: Path) -> Any:
    from bemlearn.data.trajectory_io import read_trajectory

    return read_trajectory(path)


def _read_config(path: Path) -> Any:
    from bemlearn.pipeline.config import load_pipeline_config
    from bemlearn.pipeline.preflight import check_config_file, check_robot

    raw = check_config_file(path)
    cfg = load_pipeline_config(path)
    check_robot(raw.get("robot"), where=f"{path}: robot")
    return cfg


def _read_import_map(path: Path) -> Any:
    from bemlearn.data.import_map import load_import_map

    return load_import_map(path)


def _read_mjcf(path: Path) -> Any:
    from bemlearn.robots import load

    return load(path)


def _read_checkpoint(path: Path) -> Any:
    from bemlearn.export.checkpoint import load_checkpoint

    return load_checkpoint(path)


def _read_torchscript(path: Path) -> Any:
    from bemlearn.export.torchscript import load_torchscript

    return load_torchscript(path)


def _read_pt2(path: Path) -> Any:
    from bemlearn.export.pt2 import load_pt2_predictor

    return load_pt2_predictor(path)


def _read_predictor_metadata(path: Path) -> Any:
    from bemlearn.export.staleness import predictor_metadata

    return predictor_metadata(path)


for _name, _fn in (("trajectory", _read_trajectory), ("map", _read_import_map), ("config", _read_config), ("mjcf", _read_mjcf),
                   ("checkpoint", _read_checkpoint), ("torchscript", _read_torchscript), ("pt2", _read_pt2),
                   ("predictor_metadata", _read_predictor_metadata)):
    register_reader(_name, _fn)


# ---------------------------------------------------------------- valid bases to corrupt


def make_base(folder: Path, *, predictors: bool = True) -> dict:
    """Valid files to start from: trajectory NPZ/CSV, config, MJCF, checkpoint, predictors."""
    import torch

    from bemlearn.bench.predict_bench import synthetic_posterior
    from bemlearn.data.trajectory import Trajectory, TrajectoryMeta
    from bemlearn.data.trajectory_io import write_trajectory
    from bemlearn.export import BEMPredictor, save_pt2, save_torchscript
    from bemlearn.export.checkpoint import write_checkpoint
    folder.mkdir(parents=True, exist_ok=True)
    n = 40
    t = np.arange(n) / 100.0
    meta = TrajectoryMeta(robot="rig", joint_names=("arm", "pole"), unactuated="pole", actuator_names=("motor",),
                          sample_rate_hz=100.0, trial_failed={0: False})
    traj = Trajectory(t=t, trial=np.zeros(n, dtype=np.int64), q=np.stack([np.sin(t), 0.1 * np.cos(t)], 1), u=np.zeros((n, 1)), meta=meta)
    base = {"npz": write_trajectory(traj, folder / "base.npz"), "csv": write_trajectory(traj, folder / "base.csv")}
    base["mjcf"] = folder / "base.xml"
    base["mjcf"].write_text(BASE_MJCF)
    base["config"] = folder / "base.yaml"
    base["config"].write_text(f"robot: {base['mjcf']}\n")
    state, pmeta = synthetic_posterior(n_train=30, m=1, seed=1)
    base["checkpoint"] = write_checkpoint(folder / "checkpoint.pt", model_state={"w": torch.zeros(2)}, predictor_state=state, metadata=pmeta)
    if predictors:
        eager = BEMPredictor(state, pmeta)
        base["pt"] = save_torchscript(eager, folder / "bem_predictor.pt")
        base["pt2"] = save_pt2(eager, folder / "bem_predictor.pt2")
    return base


# ---------------------------------------------------------------- generators


def _bytes(seed: int, n: int = 200) -> bytes:
    return random.Random(seed).randbytes(n)


def _flip(data: bytes, seed: int, k: int = 8) -> bytes:
    r = random.Random(seed)
    b = bytearray(data)
    for _ in range(k):
        i = r.randrange(len(b))
        b[i] = r.randrange(256)
    return bytes(b)


def _truncate(data: bytes, seed: int) -> bytes:
    return data[: random.Random(seed).randrange(1, max(2, len(data) - 1))]


def _write(folder: Path, name: str, data: bytes | str) -> Path:
    p = folder / name
    p.write_bytes(data.encode() if isinstance(data, str) else data)
    return p


def _npz(folder: Path, name: str, arrays: dict) -> Path:
    p = folder / name
    with open(p, "wb") as fh:
        np.savez(fh, **arrays)
    return p


def _npz_arrays(base: dict) -> dict:
    with np.load(base["npz"], allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _npz_variant(change: Callable[[dict, random.Random], None]) -> Callable[[Path, int, dict], Path]:
    def make(folder: Path, seed: int, base: dict) -> Path:
        arrays = _npz_arrays(base)
        change(arrays, random.Random(seed))
        return _npz(folder, f"bad{seed}.npz", arrays)

    return make


def _meta_change(change: Callable[[dict, random.Random], Any]) -> Callable[[dict, random.Random], None]:
    def f(arrays: dict, r: random.Random) -> None:
        meta = json.loads(str(arrays["meta"]))
        out = change(meta, r)
        arrays["meta"] = np.array(json.dumps(out if out is not None else meta))

    return f


def _csv_lines(change: Callable[[list[str], random.Random], list[str]]) -> Callable[[Path, int, dict], Path]:
    def make(folder: Path, seed: int, base: dict) -> Path:
        lines = Path(base["csv"]).read_text().splitlines()
        return _write(folder, f"bad{seed}.csv", "\n".join(change(lines, random.Random(seed))) + "\n")

    return make


def _yaml(text_fn: Callable[[random.Random], str | bytes]) -> Callable[[Path, int, dict], Path]:
    return lambda folder, seed, base: _write(folder, f"bad{seed}.yaml", text_fn(random.Random(seed)))


def _mjcf(text_fn: Callable[[random.Random], str | bytes]) -> Callable[[Path, int, dict], Path]:
    return lambda folder, seed, base: _write(folder, f"bad{seed}.xml", text_fn(random.Random(seed)))


def _from_base(key: str, suffix: str, fn: Callable[[bytes, int], bytes]) -> Callable[[Path, int, dict], Path]:
    return lambda folder, seed, base: _write(folder, f"bad{seed}{suffix}", fn(Path(base[key]).read_bytes(), seed))


def _torch_saved(obj_fn: Callable[[dict, random.Random], Any]) -> Callable[[Path, int, dict], Path]:
    def make(folder: Path, seed: int, base: dict) -> Path:
        import torch

        p = folder / f"bad{seed}.pt"
        torch.save(obj_fn(base, random.Random(seed)), p)
        return p

    return make


def _ckpt_change(change: Callable[[dict, random.Random], None]) -> Callable[[dict, random.Random], Any]:
    def f(base: dict, r: random.Random) -> Any:
        import torch

        data = torch.load(base["checkpoint"], weights_only=True)
        change(data, r)
        return data

    return f


def _zip_without_metadata(folder: Path, seed: int, base: dict) -> Path:
    import zipfile

    p = folder / f"bad{seed}.pt"
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("archive/data.pkl", _bytes(seed, 50))
    return p


_MJ_HEAD = "<mujoco><worldbody><body><geom size='0.1' mass='1'/>"
_TWO_FREE = _MJ_HEAD + "<joint name='a' type='hinge'/><body pos='0 0 1'><geom size='0.1' mass='1'/><joint name='b' type='hinge'/></body></body></worldbody></mujoco>"
_FREE = "<mujoco><worldbody><body><freejoint/><geom size='0.1' mass='1'/></body></worldbody><actuator/></mujoco>"
_NO_JOINT = _MJ_HEAD + "</body></worldbody></mujoco>"
#: A valid logger import map (docs/log-import.md) that the map cases break one way each.
_MAP = ("time: {column: t, unit: ms}\n"
        "joints:\n"
        "  - {name: theta, column: theta, unit: rad}\n"
        "  - {name: alpha, column: alpha, unit: deg, sign: -1, unactuated: true}\n"
        "inputs:\n"
        "  - {name: voltage, column: u, unit: V}\n")

#: A valid robot of this class for the fuzz base files: a cart on a slide carrying a pole on a hinge.
BASE_MJCF = (
    "<mujoco model='fuzzbase'><option timestep='0.002'/><worldbody>"
    "<body name='cart'><joint name='arm' type='slide' axis='1 0 0' range='-1 1' limited='true'/>"
    "<geom type='box' size='0.1 0.05 0.05' mass='1'/>"
    "<body name='pole'><joint name='pole' type='hinge' axis='0 1 0'/>"
    "<geom type='capsule' fromto='0 0 0 0 0 0.5' size='0.02' mass='0.1'/></body></body></worldbody>"
    "<actuator><motor joint='arm' ctrlrange='-10 10' ctrllimited='true'/></actuator></mujoco>"
)

_ALL_ACT = (_MJ_HEAD + "<joint name='a' type='hinge'/></body></worldbody><actuator><motor joint='a'/></actuator></mujoco>")


def _set(path: tuple[str, ...], value: Any) -> Callable[[Path, int, dict], Path]:
    def text(r: random.Random) -> str:
        import yaml

        doc = {"robot": "base.xml", "collect": {"n_trials": 4}, "train": {"kind": "exact"}}
        d = doc
        for k in path[:-1]:
            d = d.setdefault(k, {})
        d[path[-1]] = value
        return yaml.safe_dump(doc)

    return _yaml(text)


BAD_INPUTS: list[BadInput] = [
    # -- trajectory files (NPZ / CSV)
    BadInput("trajectory", "missing file", lambda f, s, b: f / f"missing{s}.npz"),
    BadInput("trajectory", "folder named .npz", lambda f, s, b: (f / f"dir{s}.npz").mkdir(exist_ok=True) or f / f"dir{s}.npz"),
    BadInput("trajectory", "unsupported suffix", lambda f, s, b: _write(f, f"bad{s}.txt", "t,trial\n")),
    BadInput("trajectory", "empty .npz", lambda f, s, b: _write(f, f"bad{s}.npz", b"")),
    BadInput("trajectory", "empty .csv", lambda f, s, b: _write(f, f"bad{s}.csv", b"")),
    BadInput("trajectory", "random bytes .npz", lambda f, s, b: _write(f, f"bad{s}.npz", _bytes(s))),
    BadInput("trajectory", "random bytes .csv (not UTF-8)", lambda f, s, b: _write(f, f"bad{s}.csv", b"\xff\xfe" + _bytes(s))),
    BadInput("trajectory", "truncated .npz", _from_base("npz", ".npz", _truncate)),
    BadInput("trajectory", "truncated .csv", _from_base("csv", ".csv", _truncate)),
    BadInput("trajectory", "bytes flipped in .npz", _from_base("npz", ".npz", _flip)),
    BadInput("trajectory", "bytes flipped in .csv", _from_base("csv", ".csv", _flip)),
    BadInput("trajectory", "npz without a required array", _npz_variant(lambda a, r: a.pop(r.choice(["t", "trial", "q", "u", "meta"])))),
    BadInput("trajectory", "npz with an unknown array", _npz_variant(lambda a, r: a.update(extra=np.zeros(3)))),
    BadInput("trajectory", "npz meta not JSON", _npz_variant(lambda a, r: a.update(meta=np.array("{not json")))),
    BadInput("trajectory", "npz meta not an object", _npz_variant(lambda a, r: a.update(meta=np.array(r.choice(["[1, 2]", "3", "null", '"x"']))))),
    BadInput("trajectory", "npz meta without a key", _npz_variant(_meta_change(lambda m, r: m.pop(r.choice(sorted(m)))))),
    BadInput("trajectory", "npz meta with a wrong type", _npz_variant(_meta_change(lambda m, r: m.update({r.choice(sorted(set(m) - {"extra"})): {"x": [1]}})))),
    BadInput("trajectory", "npz q of the wrong shape", _npz_variant(lambda a, r: a.update(q=a["q"][:, :1]))),
    BadInput("trajectory", "npz q as strings", _npz_variant(lambda a, r: a.update(q=a["q"].astype(str)))),
    BadInput("trajectory", "npz trial as floats", _npz_variant(lambda a, r: a.update(trial=a["trial"] + 0.5))),
    BadInput("trajectory", "npz NaN in q", _npz_variant(lambda a, r: a["q"].__setitem__((r.randrange(len(a["q"])), 0), np.nan))),
    BadInput("trajectory", "npz time not increasing", _npz_variant(lambda a, r: a["t"].__setitem__(r.randrange(1, len(a["t"])), -1.0))),
    BadInput("trajectory", "npz t 2-D", _npz_variant(lambda a, r: a.update(t=a["t"][:, None]))),
    BadInput("trajectory", "csv without the magic line", _csv_lines(lambda l, r: l[1:])),
    BadInput("trajectory", "csv short row", _csv_lines(lambda l, r: l[:5] + [l[5].rsplit(",", 1)[0]] + l[6:])),
    BadInput("trajectory", "csv non-numeric cell", _csv_lines(lambda l, r: l[:6] + [l[6].replace(l[6].split(",")[2], "abc", 1)] + l[7:])),
    BadInput("trajectory", "csv unknown column", _csv_lines(lambda l, r: l[:2] + [l[2] + ",bogus"] + [x + ",0" for x in l[3:]])),
    BadInput("trajectory", "csv meta line not JSON", _csv_lines(lambda l, r: [l[0], l[1][: len(l[1]) // 2]] + l[2:])),
    BadInput("trajectory", "csv header only", _csv_lines(lambda l, r: l[:3])),
    # -- logger import maps (YAML, docs/log-import.md)
    BadInput("map", "missing file", lambda f, s, b: f / f"missing{s}.map.yaml"),
    BadInput("map", "empty", _yaml(lambda r: "")),
    BadInput("map", "not YAML", _yaml(lambda r: r.choice(["time: {column: t", "joints: [", "a: b: c"]))),
    BadInput("map", "unknown key", _yaml(lambda r: _MAP + "colour: red\n")),
    BadInput("map", "joint without a column", _yaml(lambda r: _MAP.replace("column: theta, ", ""))),
    BadInput("map", "unknown joint unit", _yaml(lambda r: _MAP.replace("unit: rad}", "unit: " + r.choice(["furlong", "counts:0", "counts:-5", "DEG"]) + "}"))),
    BadInput("map", "sign not ±1", _yaml(lambda r: _MAP.replace("sign: -1", "sign: " + r.choice(["0", "2", "-0.5", "minus"])))),
    BadInput("map", "no unactuated joint", _yaml(lambda r: _MAP.replace(", unactuated: true", ""))),
    BadInput("map", "two unactuated joints", _yaml(lambda r: _MAP.replace("unit: rad}", "unit: rad, unactuated: true}"))),
    BadInput("map", "no time and no rate", _yaml(lambda r: _MAP.replace("time: {column: t, unit: ms}\n", ""))),
    BadInput("map", "time unit unknown", _yaml(lambda r: _MAP.replace("unit: ms", "unit: " + r.choice(["fortnights", "min", ""])))),
    # -- configs (YAML)
    BadInput("config", "missing file", lambda f, s, b: f / f"missing{s}.yaml"),
    BadInput("config", "empty", _yaml(lambda r: "")),
    BadInput("config", "comments only", _yaml(lambda r: "# robot: my.xml\n# collect: {}\n")),
    BadInput("config", "not YAML", _yaml(lambda r: r.choice(["robot: [my.xml", "a: b: c", "{{", "robot: 'x\n"]))),
    BadInput("config", "not UTF-8", _yaml(lambda r: b"robot: \xff\xfe" + _bytes(r.randrange(1000), 20))),
    BadInput("config", "top level not a mapping", _yaml(lambda r: r.choice(["- robot\n- my.xml\n", "42\n", "my.xml\n"]))),
    BadInput("config", "unknown top-level key", _set(("robt",), "my.xml")),
    BadInput("config", "unknown nested key", _set(("collect", "n_trails"), 3)),
    BadInput("config", "wrong value type", _set(("collect", "n_trials"), "many")),
    BadInput("config", "section is null", _set(("collect",), None)),
    BadInput("config", "unknown robot", _set(("robot",), "no-such-robot")),
    BadInput("config", "robot MJCF missing", _set(("robot",), "no/such/robot.xml")),
    BadInput("config", "robot not a string", _set(("robot",), [1, 2])),
    BadInput("config", "folder as config", lambda f, s, b: (f / f"dir{s}.yaml").mkdir(exist_ok=True) or f / f"dir{s}.yaml"),
    # -- MJCF paths
    BadInput("mjcf", "missing .xml", lambda f, s, b: f / f"missing{s}.xml"),
    BadInput("mjcf", "empty .xml", _mjcf(lambda r: "")),
    BadInput("mjcf", "not XML", _mjcf(lambda r: "<mujoco><worldbody>" + r.choice(["<body", "</x>", "&"]))),
    BadInput("mjcf", "XML, not MJCF", _mjcf(lambda r: "<html><body/></html>")),
    BadInput("mjcf", "no joints", _mjcf(lambda r: _NO_JOINT)),
    BadInput("mjcf", "two unactuated joints", _mjcf(lambda r: _TWO_FREE)),
    BadInput("mjcf", "free joint", _mjcf(lambda r: _FREE)),
    BadInput("mjcf", "every joint actuated", _mjcf(lambda r: _ALL_ACT)),
    BadInput("mjcf", "bytes flipped in the MJCF", _from_base("mjcf", ".xml", _flip)),
    BadInput("mjcf", "folder named .xml", lambda f, s, b: (f / f"dir{s}.xml").mkdir(exist_ok=True) or f / f"dir{s}.xml"),
    # -- checkpoints
    BadInput("checkpoint", "missing file", lambda f, s, b: f / f"missing{s}.pt"),
    BadInput("checkpoint", "empty file", lambda f, s, b: _write(f, f"bad{s}.pt", b"")),
    BadInput("checkpoint", "random bytes", lambda f, s, b: _write(f, f"bad{s}.pt", _bytes(s))),
    BadInput("checkpoint", "truncated", _from_base("checkpoint", ".pt", _truncate)),
    BadInput("checkpoint", "bytes flipped", _from_base("checkpoint", ".pt", _flip)),
    BadInput("checkpoint", "not a dict", _torch_saved(lambda b, r: [1, 2, 3])),
    BadInput("checkpoint", "missing key", _torch_saved(_ckpt_change(lambda d, r: d.pop(r.choice(["format", "kind", "model_state", "predictor_state", "metadata"]))))),
    BadInput("checkpoint", "wrong format tag", _torch_saved(_ckpt_change(lambda d, r: d.update(format="other-v9")))),
    BadInput("checkpoint", "unknown kind", _torch_saved(_ckpt_change(lambda d, r: d.update(kind="deep")))),
    BadInput("checkpoint", "NaN in the posterior", _torch_saved(_ckpt_change(lambda d, r: d["predictor_state"]["alpha"].__setitem__(0, float("nan"))))),
    BadInput("checkpoint", "float32 posterior", _torch_saved(_ckpt_change(lambda d, r: d["predictor_state"].update(alpha=d["predictor_state"]["alpha"].float())))),
    BadInput("checkpoint", "metadata without a key", _torch_saved(_ckpt_change(lambda d, r: d["metadata"].pop(r.choice(["robot", "m", "input_names", "units", "n_train"]))))),
    BadInput("checkpoint", "metadata inconsistent", _torch_saved(_ckpt_change(lambda d, r: d["metadata"].update(n_train=d["metadata"]["n_train"] + 1)))),
    BadInput("checkpoint", "needs unpickling code", _torch_saved(lambda b, r: {"format": Path("x")})),
    # -- predictors
    BadInput("torchscript", "missing file", lambda f, s, b: f / f"missing{s}.pt"),
    BadInput("torchscript", "random bytes", lambda f, s, b: _write(f, f"bad{s}.pt", _bytes(s))),
    BadInput("torchscript", "truncated", _from_base("pt", ".pt", _truncate)),
    BadInput("torchscript", "zip without metadata", _zip_without_metadata),
    BadInput("torchscript", "a checkpoint instead", lambda f, s, b: b["checkpoint"]),
    BadInput("torchscript", "a .pt2 instead", lambda f, s, b: b["pt2"]),
    BadInput("pt2", "missing file", lambda f, s, b: f / f"missing{s}.pt2"),
    BadInput("pt2", "random bytes", lambda f, s, b: _write(f, f"bad{s}.pt2", _bytes(s))),
    BadInput("pt2", "truncated", _from_base("pt2", ".pt2", _truncate)),
    BadInput("pt2", "a TorchScript file instead", lambda f, s, b: b["pt"]),
    BadInput("pt2", "a checkpoint instead", lambda f, s, b: b["checkpoint"]),
    BadInput("predictor_metadata", "random bytes", lambda f, s, b: _write(f, f"bad{s}.pt", _bytes(s))),
    BadInput("predictor_metadata", "zip without metadata", _zip_without_metadata),
    BadInput("predictor_metadata", "a checkpoint instead", lambda f, s, b: b["checkpoint"]),
]


def run_case(bad: BadInput, folder: Path, seed: int, base: dict) -> Outcome:
    """Write ``bad``'s file for ``seed`` into ``folder`` and read it with its reader."""
    from bemlearn.errors import BemlearnError

    path = bad.make(folder, seed, base)
    try:
        READERS[bad.reader](path)
    except (BemlearnError, FileNotFoundError) as exc:
        msg = str(exc)
        named = path.name in msg
        return Outcome(bad.reader, bad.name, named, type(exc).__name__, msg)
    except Exception as exc:  # noqa: BLE001 - an uncaught exception is what the fuzz looks for
        return Outcome(bad.reader, bad.name, False, type(exc).__name__, str(exc)[:300])
    return Outcome(bad.reader, bad.name, False, "no error", "")


def run_fuzz(*, examples: int = 5, seed: int = 0, folder: str | os.PathLike[str] | None = None) -> list[Outcome]:
    """Every bad-input class with ``examples`` seeds; returns the outcomes (one per case)."""
    import logging

    logger = logging.getLogger("bemlearn")
    level = logger.level
    logger.setLevel(logging.ERROR)  # the readers log warnings for some bad inputs
    try:
        return _run_fuzz(examples=examples, seed=seed, folder=folder)
    finally:
        logger.setLevel(level)


def _run_fuzz(*, examples: int, seed: int, folder: str | os.PathLike[str] | None) -> list[Outcome]:
    with tempfile.TemporaryDirectory(prefix="bemlearn-fuzz-") as tmp:
        root = Path(folder) if folder is not None else Path(tmp)
        base = make_base(root / "base")
        out = []
        for bad in BAD_INPUTS:
            for k in range(examples):
                case_dir = root / "cases"
                case_dir.mkdir(exist_ok=True)
                out.append(run_case(bad, case_dir, seed + k, base))
        return out


def format_fuzz(outcomes: list[Outcome]) -> str:
    """Per-class summary and the totals: classes tried, classes whose every case ended in a named error."""
    by: dict[tuple[str, str], list[Outcome]] = {}
    for o in outcomes:
        by.setdefault((o.reader, o.name), []).append(o)
    lines = ["| reader | bad input | cases | named errors | errors seen |", "| --- | --- | --- | --- | --- |"]
    ok = 0
    for (reader, name), os_ in by.items():
        n_named = sum(o.named for o in os_)
        ok += n_named == len(os_)
        kinds = sorted({o.error for o in os_})
        lines.append(f"| {reader} | {name} | {len(os_)} | {n_named} | {', '.join(kinds)} |")
    bad = [o for o in outcomes if not o.named]
    lines.append(f"\nbad-input classes tried: {len(by)}; ending in a named error (every case): {ok}; "
                 f"cases: {len(outcomes)}, named: {len(outcomes) - len(bad)}")
    for o in bad[:20]:
        lines.append(f"NOT NAMED: {o.reader} / {o.name}: {o.error}: {o.message[:200]}")
    return "\n".join(lines)
