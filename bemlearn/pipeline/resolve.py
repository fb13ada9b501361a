"""Resolve a pipeline config: what the user gave, what the model derives, what is a default.

A config may hold only ``robot: path/to/robot.xml``.  Every value it does not give is either
*derived* from the robot's model (control rate, physics step, excitation gains and amplitudes,
evaluation references, EIC gains; :mod:`bemlearn.pipeline.derived_defaults`) or a plain *default* of its
component's dataclass.  Explicit keys always win.  :func:`resolve_pipeline_config` returns the
strict, typed :class:`~bemlearn.pipeline.config.PipelineConfig` together with the origin of
every value (``given`` / ``derived`` / ``default``) and, for derived values, how they were
derived; ``bemlearn config show CONFIG`` prints it, and each run saves it next to the config.
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
from collections.abc import Iterator, Mapping
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bemlearn.config import ConfigError, config_folder, from_dict, load_yaml, rebase_paths, set_dotted, to_dict
from bemlearn.errors import BemlearnError
from bemlearn.pipeline.config import PATH_KEYS, PipelineConfig

__all__ = ["ResolvedConfig", "resolve_pipeline_config", "load_pipeline_config", "complete_section", "format_resolved", "flatten",
           "memoized_derivation"]

#: Robots and derived values kept while :func:`memoized_derivation` is active.
_MEMO: ContextVar[dict[Any, Any] | None] = ContextVar("bemlearn_resolve_memo", default=None)


@contextlib.contextmanager
def memoized_derivation() -> Iterator[None]:
    """Within the block, :func:`resolve_pipeline_config` loads each robot file once and derives its values
    once per set of given keys and given rates (all the derivation reads: see
    :func:`~bemlearn.pipeline.derived_defaults.derive_pipeline_values`): a sweep resolves thousands of
    cells that differ only in values the derivation does not read."""
    from bemlearn.config import memoized_parsing

    token = _MEMO.set({})
    try:
        with memoized_parsing():
            yield
    finally:
        _MEMO.reset(token)


#: Given keys whose values the derivation does not read (the excitation check plays its own seeds and count).
_NOT_READ_BY_DERIVATION = frozenset({"collect.seed", "collect.n_trials", "collect.workers", "simulate.seed"})


def _read_by_derivation(raw: Mapping) -> tuple[tuple[str, str], ...]:
    """The given ``collect.*`` and ``simulate.*`` values, as the derivation may read them (rates, steps, gains, the
    sensor, the fall window, the initial ranges and the trial length the excitation check plays, the closed loop's
    reference and velocity cutoff the EIC gains must hold): a memoized derivation is reused only where they agree."""
    return tuple(sorted((k, repr(v)) for k, v in flatten(raw).items()
                        if k.startswith(("collect.", "simulate.")) and k not in _NOT_READ_BY_DERIVATION))


def _robot_key(name: str) -> tuple[Any, ...]:
    path = Path(name)
    try:
        st = path.stat()
        return (str(path.resolve()), st.st_mtime_ns, st.st_size)
    except OSError:
        return (name,)

Origin = str  # "given" | "derived" | "default"


@dataclass(frozen=True)
class ResolvedConfig:
    """A pipeline config with the origin of every value.

    Attributes:
        config: the parsed, strict config (every derived value filled in).
        origins: dotted key (``collect.rate_hz``) → ``"given"``, ``"derived"`` (from the model),
            ``"data"`` (chosen from the training data when training, e.g. the Gaussian
            estimator's σ) or ``"default"``.
        notes: dotted key → one line on how a derived value was obtained.
        source: where the config came from (file path or ``"<dict>"``).
        robot_notes: what the robot's model determines beyond config keys (its coordinates when they are
            not its joints one to one: a freedom that rolls with a wheel), one line each.
    """

    config: PipelineConfig
    origins: dict[str, Origin]
    notes: dict[str, str]
    source: str
    robot_notes: tuple[str, ...] = ()

    def to_json_dict(self) -> dict[str, Any]:
        """``{key: {"value", "origin", "note"}}`` for every leaf value (saved with each run)."""
        flat = flatten(to_dict(self.config))
        return {k: {"value": v, "origin": self.origins.get(k, "default"), **({"note": self.notes[k]} if k in self.notes else {})}
                for k, v in flat.items()}


def flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    """Nested mappings → ``{"a.b.c": leaf}`` (lists are leaves)."""
    if isinstance(data, Mapping):
        out: dict[str, Any] = {}
        for k, v in data.items():
            out.update(flatten(v, f"{prefix}{k}."))
        if not data and prefix:
            out[prefix[:-1]] = {}
        return out
    return {prefix[:-1]: data}


def _has(raw: Mapping, dotted: str) -> bool:
    head, _, rest = dotted.partition(".")
    if head not in raw:
        return False
    return True if not rest else isinstance(raw[head], Mapping) and _has(raw[head], rest)


def resolve_pipeline_config(config: str | Path | Mapping[str, Any], *, derive: bool = True,
                            source: str | None = None) -> ResolvedConfig:
    """Parse ``config`` (a YAML path or a mapping) strictly and fill in what the robot's model derives.

    The relative paths of a file (``robot:``, ``data:``, ``model:``, ``simulate.predictor``) are
    relative to its folder; those of a mapping to the current folder (docs/config.md, "Paths").

    ``source`` names a mapping in error messages and in :attr:`ResolvedConfig.source` (default ``"<dict>"``).

    Raises:
        ConfigError: unknown keys, wrong types, or a config naming neither ``robot:`` nor ``data:``.
    """
    if isinstance(config, Mapping):
        raw, source = copy.deepcopy(dict(config)), source or "<dict>"
    else:
        raw, source = rebase_paths(load_yaml(config), PATH_KEYS, config_folder(config)), str(config)
    if not raw:
        raise ConfigError(f"{source}: the config is empty; it must at least name the robot "
                          "('robot: path/to/robot.xml' or a registry name) or the data ('data: FILE')")
    given = set(flatten(raw))
    parsed = from_dict(PipelineConfig, raw, where=source)  # strict check of what was given
    notes: dict[str, str] = {}
    robot_notes: tuple[str, ...] = ()
    if derive and parsed.robot is not None:
        from bemlearn.pipeline.derived_defaults import derive_pipeline_values
        from bemlearn.robots import load

        memo = _MEMO.get()
        robot_key = ("robot", _robot_key(parsed.robot), repr(parsed.coordinates))
        try:
            robot = (memo[robot_key] if memo is not None and robot_key in memo
                     else load(parsed.robot, coordinates=parsed.coordinates))
        except (BemlearnError, OSError) as exc:
            raise ConfigError(f"{source}: robot: {str(exc).removeprefix('robot: ')}") from exc
        _check_actuators(robot, source)
        _check_for_robot(parsed, robot, source)   # the given values first: the derivation runs trials with them
        derived_key = ("derived", robot_key, frozenset(given), _read_by_derivation(raw))
        if memo is not None and derived_key in memo:
            derived = memo[derived_key]
        else:
            derived = derive_pipeline_values(robot, parsed, given)
        if memo is not None:
            memo[robot_key], memo[derived_key] = robot, derived
        for key, (value, note) in derived.items():
            if not _has(raw, key):
                set_dotted(raw, key, copy.deepcopy(value))
                notes[key] = note
        parsed = from_dict(PipelineConfig, raw, where=source)
        _check_for_robot(parsed, robot, source)
        robot_notes = _robot_notes(robot)
    elif derive and parsed.model is not None:   # model-free run compared with a model: its references from the model
        from bemlearn.pipeline.derived_defaults import derive_model_values
        from bemlearn.robots import load

        try:
            model = load(parsed.model, coordinates=parsed.coordinates)
        except (BemlearnError, OSError) as exc:
            raise ConfigError(f"{source}: model: {exc}") from exc
        for key, (value, note) in derive_model_values(model, parsed, given).items():
            if not _has(raw, key):
                set_dotted(raw, key, value)
                notes[key] = note
        parsed = from_dict(PipelineConfig, raw, where=source)
    if "dataset.derivative_options" not in notes:
        est = parsed.dataset.estimator()
        if not getattr(est, "resolved", True):   # e.g. the Gaussian's σ: chosen from the data at train time
            from bemlearn.data.derivative_choice import KEPT_MOTION

            notes["dataset.derivative_options"] = (f"{est.name}: sigma_s chosen from the data when training (the width at which "
                                                   f"the smoothed q_u keeps {KEPT_MOTION:.0%} of its motion; docs/derivatives.md)")
    origins: dict[str, Origin] = {}
    for key in flatten(to_dict(parsed)):
        parts = key.split(".")
        heads = {".".join(parts[:i]) for i in range(1, len(parts) + 1)}   # the key and the sections holding it
        if key == "dataset.derivative_options" and key in notes and key not in given:
            origins[key] = "data"
        elif not heads.isdisjoint(given):
            origins[key] = "given"
        elif not heads.isdisjoint(notes):
            origins[key] = "derived"
        else:
            origins[key] = "default"
    return ResolvedConfig(parsed, origins, {k: v for k, v in notes.items()}, source, robot_notes)


def _robot_notes(robot: Any) -> tuple[str, ...]:
    """The coordinates of a robot whose freedoms roll with a wheel (``bemlearn.robots.rolling``), for ``config show``."""
    rolling = getattr(robot, "rolling", None) or getattr(robot, "floating", None)
    if rolling is None:
        return ()
    return (f"coordinates {', '.join(robot.actuated_names)} (q_a), {robot.unactuated_name} (q_u); "
            f"{rolling.describe(robot.model)}",)


def load_pipeline_config(path: str | Path) -> PipelineConfig:
    """Parse a pipeline YAML file strictly (unknown keys and bad types are errors naming the key) and
    fill in the values derived from the robot's model (:func:`resolve_pipeline_config`)."""
    return resolve_pipeline_config(path).config


def _check_actuators(robot: Any, source: str) -> None:
    """One command per actuated coordinate reaches the actuators: one actuator each, or the actuators of each
    coordinate commanded together (``MujocoRobot.actuator_mismatch``, :mod:`bemlearn.robots.actuation`).

    Raises:
        ConfigError: naming the actuators and the coordinates.
    """
    why = robot.actuator_mismatch() if hasattr(robot, "actuator_mismatch") else None
    if why is not None:
        raise ConfigError(f"{source}: robot: {why}")


def _check_for_robot(cfg: PipelineConfig, robot, source: str) -> None:
    """The rules that need the robot: the gain matrix's size, the bodies of the model mismatch.

    Raises:
        ConfigError: naming the key, what the robot needs and what was given.
    """
    gains = cfg.collect.gains
    if gains is not None and len(gains) != robot.m * 2 * robot.n:
        raise ConfigError(f"{source}.collect.gains: expected m·2n = {robot.m * 2 * robot.n} values for robot {robot.name!r} "
                          f"(k row-major (m, 2n), m = {robot.m}, n = {robot.n}), got {len(gains)}")
    bodies = cfg.simulate.nominal.bodies
    model = getattr(robot, "model", None)
    if bodies is not None and model is not None:
        import mujoco

        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(model.nbody)]
        missing = [b for b in bodies if b not in names]
        if missing:
            raise ConfigError(f"{source}.simulate.nominal.bodies: no body {missing[:5]} in robot {robot.name!r}; "
                              f"its bodies are {[n for n in names if n][:20]}")


def format_resolved(resolved: ResolvedConfig) -> str:
    """The resolved config as a table: key, value, origin, and how a derived value was derived."""
    rows = resolved.to_json_dict()
    width = max(len(k) for k in rows)
    lines = [f"# {resolved.source}: every value with its origin (given / derived from the model / data: chosen from the "
             "training data when training / default)"]
    lines += [f"# robot: {note}" for note in resolved.robot_notes]
    for key, r in rows.items():
        value = json.dumps(_shown(r["value"]), ensure_ascii=False) if not isinstance(r["value"], str) else r["value"]
        if len(value) > 60:
            value = value[:57] + "..."
        note = f"  # {r['note']}" if "note" in r else ""
        lines.append(f"{key:<{width}}  {value:<40}  {r['origin']:<8}{note}")
    return "\n".join(lines)


def _shown(value: Any) -> Any:
    """``value`` for the table: floats to 12 significant digits (``0.6000000000000001`` → ``0.6``; the
    exact values are in ``--json`` and ``config_resolved.json``)."""
    if isinstance(value, float) and math.isfinite(value):
        return float(f"{value:.12g}")
    if isinstance(value, (list, tuple)):
        return [_shown(v) for v in value]
    if isinstance(value, Mapping):
        return {k: _shown(v) for k, v in value.items()}
    return value


def _strip_none(data: Any) -> Any:
    if isinstance(data, Mapping):
        return {k: _strip_none(v) for k, v in data.items() if v is not None}
    return data


def complete_section(robot: str, section: str, value):
    """A config section (e.g. a :class:`~bemlearn.sim.collect.CollectConfig`) with its ``None``
    fields derived from ``robot``'s model, as :func:`resolve_pipeline_config` would.

    Library calls (``collect(robot, CollectConfig(n_trials=4))``) get the same derived values
    as a pipeline run; fields that are set count as given.
    """
    if not any(v is None for v in flatten(to_dict(value)).values()):
        return value
    return getattr(resolve_pipeline_config({"robot": str(robot), section: _strip_none(to_dict(value))}).config, section)
