"""Strict, typed configuration: YAML parsed into frozen dataclasses.

Every component defines its own dataclass next to the component (e.g.
:class:`bemlearn.data.collect.CollectConfig`); this module only knows how to turn a
mapping into such a dataclass, rejecting unknown keys and wrongly typed values with an
error that names the offending key path, and how to write the resolved config back.

Example::

    cfg = from_dict(MyConfig, {"rate_hz": 400}, where="configs/furuta.yaml:collect")
"""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml

from bemlearn.errors import ConfigError
from bemlearn.files import atomic_write_text

__all__ = ["ConfigError", "from_dict", "to_dict", "load_yaml", "save_yaml", "replace_path", "set_dotted", "check_dotted_key"]

T = TypeVar("T")


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(value: Any, tp: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, where)
            except ConfigError as exc:  # try the next alternative
                errors.append(str(exc))
        raise ConfigError(f"{where}: expected {_type_name(tp)}, got {value!r}")
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{where}: expected one of {list(args)}, got {value!r}")
        return value
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping for {tp.__name__}, got {value!r}")
        return from_dict(tp, value, where=where)
    if origin in (tuple,):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if args and len(args) != len(value):
            raise ConfigError(f"{where}: expected {len(args)} entries, got {len(value)}")
        return tuple(_coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if origin in (list,):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        return [_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value)] if args else list(value)
    if origin in (dict,):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        return {k: _coerce(v, args[1], f"{where}.{k}") for k, v in value.items()} if args else dict(value)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    if tp is type(None):
        if value is not None:
            raise ConfigError(f"{where}: expected null, got {value!r}")
        return None
    raise ConfigError(f"{where}: unsupported config type {_type_name(tp)}")


def from_dict(cls: type[T], data: dict[str, Any] | None, *, where: str = "config") -> T:
    """Build dataclass ``cls`` from ``data``, rejecting unknown keys and bad types.

    Args:
        cls: a dataclass type; fields without defaults are required.
        data: the mapping read from YAML (``None`` means all defaults).
        where: a label for error messages, e.g. ``"configs/furuta.yaml:train"``.

    Raises:
        ConfigError: naming the key path, what was expected and what was found.
    """
    data = {} if data is None else data
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {unknown}; valid keys are {sorted(fields)}"
        )
    kwargs = {}
    for name, field in fields.items():
        if name in data:
            kwargs[name] = _coerce(data[name], hints[name], f"{where}.{name}")
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{where}: missing required key {name!r}")
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{where}: {exc}") from exc


def to_dict(obj: Any) -> Any:
    """The plain-YAML form of a (nested) config dataclass."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_dict(v) for k, v in obj.items()}
    if isinstance(obj, Path):
        return str(obj)
    return obj


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping, with a clear error for a missing or malformed file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text file (byte {exc.start}); expected a YAML config") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    return data


def save_yaml(obj: Any, path: str | Path) -> None:
    """Write the resolved config (a dataclass or mapping) as YAML."""
    atomic_write_text(path, yaml.safe_dump(to_dict(obj), sort_keys=False))


def replace_path(obj: T, dotted: str, value: Any) -> T:
    """Return a copy of nested dataclass ``obj`` with field ``a.b.c`` replaced."""
    head, _, rest = dotted.partition(".")
    if not rest:
        return dataclasses.replace(obj, **{head: value})
    return dataclasses.replace(obj, **{head: replace_path(getattr(obj, head), rest, value)})


def set_dotted(raw: dict[str, Any], dotted: str, value: Any) -> None:
    """Set ``raw["a"]["b"]["c"] = value`` for ``dotted = "a.b.c"`` in a config mapping, creating
    missing (or ``null``) sections.

    Raises:
        ConfigError: a section on the way holds a value that is not a mapping.
    """
    head, _, rest = dotted.partition(".")
    if not rest:
        raw[head] = value
        return
    child = raw.get(head)
    if child is None:
        child = raw[head] = {}
    if not isinstance(child, dict):
        raise ConfigError(f"{head}: expected a mapping, got {child!r}")
    set_dotted(child, rest, value)


def check_dotted_key(cls: type, dotted: str, *, where: str = "config") -> None:
    """Check that ``dotted`` (``"collect.seed"``) names a field of dataclass ``cls`` or of its
    nested config dataclasses; a key inside a free-form mapping field (``dict[str, Any]``) is accepted.

    Raises:
        ConfigError: naming ``where``, the dotted key, the first unknown part and the valid keys there.
    """
    tp: Any = cls
    parts = dotted.split(".")
    for i, part in enumerate(parts):
        inner = _dataclass_of(tp)
        if inner is None:
            if _is_mapping_type(tp):
                return
            raise ConfigError(f"{where}: {dotted}: {'.'.join(parts[:i])} is a value, not a section")
        fields = {f.name: f for f in dataclasses.fields(inner) if f.init}
        if part not in fields:
            section = ".".join(parts[:i]) or "the top level"
            raise ConfigError(f"{where}: {dotted}: unknown key {part!r} in {section}; valid keys are {sorted(fields)}")
        tp = typing.get_type_hints(inner)[part]


def _dataclass_of(tp: Any) -> type | None:
    """``tp`` itself, or the one dataclass of an optional ``X | None``; else ``None``."""
    if dataclasses.is_dataclass(tp):
        return tp
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        found = [a for a in typing.get_args(tp) if dataclasses.is_dataclass(a)]
        return found[0] if len(found) == 1 else None
    return None


def _is_mapping_type(tp: Any) -> bool:
    if tp is Any or typing.get_origin(tp) is dict or tp is dict:
        return True
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return any(_is_mapping_type(a) for a in typing.get_args(tp) if a is not type(None))
    return False
