"""The bad-input classes fuzzed by :mod:`bemlearn.bench.fuzz_bench`, and the valid files they corrupt.

Each :class:`BadInput` names its reader and writes one malformed file from a seed:
``make(folder, seed, base) -> path`` (``base``: the valid files of :func:`make_base`).
"""

from __future__ import annotations

import json
import random
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["BadInput", "BAD_INPUTS", "make_base"]


@dataclass(frozen=True)
class BadInput:
    """One class of bad input: ``make(folder, seed, base) -> path`` writes it for ``reader``."""

    reader: str
    name: str
    make: Callable[[Path, int, dict], Path]


# ---------------------------------------------------------------- valid bases to corrupt


#: A valid robot of this class for the fuzz base files: a cart on a slide carrying a pole on a hinge.
BASE_MJCF = (
    "<mujoco model='fuzzbase'><option timestep='0.002'/><worldbody>"
    "<body name='cart'><joint name='arm' type='slide' axis='1 0 0' range='-1 1' limited='true'/>"
    "<geom type='box' size='0.1 0.05 0.05' mass='1'/>"
    "<body name='pole'><joint name='pole' type='hinge' axis='0 1 0'/>"
    "<geom type='capsule' fromto='0 0 0 0 0 0.5' size='0.02' mass='0.1'/></body></body></worldbody>"
    "<actuator><motor joint='arm' ctrlrange='-10 10' ctrllimited='true'/></actuator></mujoco>"
)

#: A valid logger import map (docs/log-import.md) that the map cases break one way each.
_MAP = ("time: {column: t, unit: ms}\n"
        "joints:\n"
        "  - {name: theta, column: theta, unit: rad}\n"
        "  - {name: alpha, column: alpha, unit: deg, sign: -1, unactuated: true}\n"
        "inputs:\n"
        "  - {name: voltage, column: u, unit: V}\n")


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
_ALL_ACT = (_MJ_HEAD + "<joint name='a' type='hinge'/></body></worldbody><actuator><motor joint='a'/></actuator></mujoco>")


def _set(path: tuple[str, ...], value: Any) -> Callable[[Path, int, dict], Path]:
    def text(r: random.Random) -> str:
        import yaml

        doc = {"robot": "base.xml", "collect": {"n_trials": 4}, "train": {"kind": "exact"}}
        d: dict[str, Any] = doc
        for k in path[:-1]:
            d = d.setdefault(k, {})
        d[path[-1]] = value
        return yaml.safe_dump(doc)

    return _yaml(text)


def _mkdir(path: Path) -> Path:
    path.mkdir(exist_ok=True)
    return path


BAD_INPUTS: list[BadInput] = [
    # -- trajectory files (NPZ / CSV)
    BadInput("trajectory", "missing file", lambda f, s, b: f / f"missing{s}.npz"),
    BadInput("trajectory", "folder named .npz", lambda f, s, b: _mkdir(f / f"dir{s}.npz")),
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
    BadInput("config", "folder as config", lambda f, s, b: _mkdir(f / f"dir{s}.yaml")),
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
    BadInput("mjcf", "folder named .xml", lambda f, s, b: _mkdir(f / f"dir{s}.xml")),
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
