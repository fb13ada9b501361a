"""Strict, typed configuration: YAML parsed into frozen dataclasses.

Every component defines its own dataclass next to the component (e.g.
:class:`bemlearn.sim.collect.CollectConfig`); this module only knows how to turn a
mapping into such a dataclass, rejecting unknown keys and wrongly typed values with an
error that names the offending key path, and how to write the resolved config back.

One validating parse (:func:`from_dict`) holds every value to:

- its type (``int``, ``float``, ``Literal`` names, tuples of a fixed length, ...);
- **finite numbers**: NaN and ±inf are never a config value; integers fit in 64 bits;
- the **limits** a component declares next to its dataclass with :func:`config_limits`
  (:class:`Limit`: bounds, ordered (min, max) pairs, list lengths), e.g. ``n_trials ≥ 1``,
  ``mass_scale > 0``; rules between fields stay in the dataclass's ``__post_init__``.

:func:`load_yaml` reads YAML strictly: a duplicated key is an error, as is a document whose
aliases expand to more than :data:`MAX_NODES` values (a "billion laughs" of a few hundred
bytes), and ``1e-3`` is a number (YAML 1.2) rather than a string.  Error messages quote a
bounded prefix of a value (:func:`show_value`), never a whole expansion.

Example::

    cfg = from_dict(MyConfig, {"rate_hz": 400}, where="configs/furuta.yaml:collect")
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import math
import os
import re
import reprlib
import types
import typing
from collections.abc import Callable, Iterator
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import yaml

from bemlearn.errors import ArgumentError, ConfigError
from bemlearn.files import atomic_write_text

__all__ = ["memoized_parsing", "ConfigError", "from_dict", "to_dict", "load_yaml", "save_yaml", "replace_path", "replace_checked", "Limit",
           "config_limits", "show_value", "MAX_NODES", "MAX_CONFIG_BYTES", "set_dotted", "check_dotted_key", "is_relative_path",
           "rebase_paths", "config_folder"]

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")

#: Values (mapping entries, list items, scalars) a YAML document may expand to, aliases counted each time used.
MAX_NODES = 100_000
#: Largest config file read.
MAX_CONFIG_BYTES = 4 << 20
#: Largest integer magnitude a config value may have (it must fit numpy's int64).
MAX_INT = 2**63 - 1

_SHOW = reprlib.Repr()
_SHOW.maxstring, _SHOW.maxother, _SHOW.maxlist, _SHOW.maxtuple, _SHOW.maxdict, _SHOW.maxlevel = 60, 60, 6, 6, 4, 2
_SHOW.maxlong = 40


def show_value(value: Any) -> str:
    """A bounded ``repr`` of ``value`` for error messages: at most 200 characters (long strings, lists and
    nestings are cut with ``...``; the full value is never formatted)."""
    text = _SHOW.repr(value)
    return text if len(text) <= 200 else text[:197] + "..."


@dataclass(frozen=True)
class Limit:
    """What a numeric config value (or each entry of a list of numbers) must satisfy.

    Attributes:
        ge, gt, le, lt: bounds (``None``: none).
        ordered: the value is a (min, max) pair with min ≤ max.
        min_len: at least this many entries (lists).
        unit: the value's unit, for messages.
    """

    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    ordered: bool = False
    min_len: int | None = None
    unit: str = ""

    def describe(self) -> str:
        num = lambda v: str(int(v)) if float(v).is_integer() and abs(v) < 1e16 else f"{v:g}"  # noqa: E731
        parts = [f"{op} {num(v)}" for op, v in (("≥", self.ge), (">", self.gt), ("≤", self.le), ("<", self.lt)) if v is not None]
        return " and ".join(parts) + (f" {self.unit}" if self.unit and parts else "")

    def check(self, value: Any, where: str) -> None:
        """Raise :class:`ConfigError` naming ``where`` if ``value`` (a number or a list of numbers) breaks the limit."""
        if value is None:
            return
        items = list(value) if isinstance(value, (list, tuple)) else [value]
        if self.min_len is not None and isinstance(value, (list, tuple)) and len(items) < self.min_len:
            raise ConfigError(f"{where}: expected at least {self.min_len} entries, got {len(items)}")
        for i, v in enumerate(items):
            if not isinstance(v, (int, float)) or isinstance(v, bool):
                continue
            bad = ((self.ge is not None and not v >= self.ge) or (self.gt is not None and not v > self.gt)
                   or (self.le is not None and not v <= self.le) or (self.lt is not None and not v < self.lt))
            if bad:
                at = f"{where}[{i}]" if isinstance(value, (list, tuple)) else where
                raise ConfigError(f"{at}: expected a number {self.describe()}, got {show_value(v)}")
        if self.ordered and isinstance(value, (list, tuple)) and len(items) == 2 and items[0] > items[1]:
            raise ConfigError(f"{where}: expected (min, max) with min ≤ max, got {show_value(list(items))}")


#: Limits declared by the components: dataclass → field name → :class:`Limit`.
LIMITS: dict[type, dict[str, Limit]] = {}


def config_limits(cls: type, **limits: Limit) -> None:
    """Declare the :class:`Limit` of fields of the config dataclass ``cls`` (checked by :func:`from_dict`)."""
    unknown = sorted(set(limits) - {f.name for f in dataclasses.fields(cls)})
    if unknown:
        raise ArgumentError(f"config_limits({cls.__name__}): no field(s) {unknown}")
    LIMITS.setdefault(cls, {}).update(limits)


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
        raise ConfigError(errors[0] if len(errors) == 1 else f"{where}: expected {_type_name(tp)}, got {show_value(value)}")
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{where}: expected one of {list(args)}, got {show_value(value)}")
        return value
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping for {tp.__name__}, got {show_value(value)}")
        return from_dict(tp, value, where=where)
    if origin in (tuple,):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {show_value(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if args and len(args) != len(value):
            raise ConfigError(f"{where}: expected {len(args)} entries, got {len(value)}")
        return tuple(_coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if origin in (list,):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {show_value(value)}")
        return [_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value)] if args else list(value)
    if origin in (dict,):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {show_value(value)}")
        return {k: _coerce(v, args[1], f"{where}.{k}") for k, v in value.items()} if args else dict(value)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {show_value(value)}")
        if isinstance(value, int) and abs(value) > MAX_INT:
            raise ConfigError(f"{where}: expected a finite number of at most 64 bits, got {show_value(value)}")
        if not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {value}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {show_value(value)}")
        if abs(value) > MAX_INT:
            raise ConfigError(f"{where}: expected an integer of at most 64 bits (|n| < 2⁶³), got {show_value(value)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {show_value(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {show_value(value)}")
        return value
    if tp is type(None):
        if value is not None:
            raise ConfigError(f"{where}: expected null, got {show_value(value)}")
        return None
    raise ConfigError(f"{where}: unsupported config type {_type_name(tp)}")


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


#: Parsed frozen dataclasses by (class, canonical JSON of the mapping), while :func:`memoized_parsing` is active.
_PARSED: ContextVar[dict[tuple[type, str], Any] | None] = ContextVar("bemlearn_parsed_configs", default=None)


@contextlib.contextmanager
def memoized_parsing() -> Iterator[None]:
    """Within the block, :func:`from_dict` parses each distinct mapping of a frozen dataclass once (a
    sweep's cells share most of their sections); errors are never memoized."""
    token = _PARSED.set({})
    try:
        yield
    finally:
        _PARSED.reset(token)


def from_dict(cls: type[T], data: dict[str, Any] | None, *, where: str = "config") -> T:
    memo = _PARSED.get()
    key = None
    if memo is not None and isinstance(data, dict) and getattr(getattr(cls, "__dataclass_params__", None), "frozen", False):
        try:
            key = (cls, json.dumps(data, sort_keys=True, allow_nan=True))
        except (TypeError, ValueError):  # not plain JSON (e.g. a tuple key): parse it every time
            key = None
        if key is not None and key in memo:
            return memo[key]
    parsed = _from_dict(cls, data, where=where)
    if key is not None and memo is not None:
        memo[key] = parsed
    return parsed


def _from_dict(cls: type[T], data: dict[str, Any] | None, *, where: str = "config") -> T:
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
        raise ConfigError(f"{where}: expected a mapping, got {show_value(data)}")
    hints = _type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {show_value(unknown)}; valid keys are {sorted(fields)}"
        )
    kwargs = {}
    for name, field in fields.items():
        if name in data:
            kwargs[name] = _checked_field(cls, name, hints[name], data[name], where)
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{where}: missing required key {name!r}")
    return _built(lambda: cls(**kwargs), where)


def _checked_field(cls: type, name: str, tp: Any, value: Any, where: str) -> Any:
    """``value`` coerced to field ``name``'s type ``tp`` and checked against its declared :class:`Limit`."""
    coerced = _coerce(value, tp, f"{where}.{name}")
    limit = LIMITS.get(cls, {}).get(name)
    if limit is not None:
        limit.check(coerced, f"{where}.{name}")
    return coerced


def _built(make: Callable[[], T], where: str) -> T:
    """``make()`` (a config dataclass's construction), its ``TypeError``/``ValueError`` as a ConfigError naming ``where``."""
    try:
        return make()
    except (TypeError, ValueError) as exc:
        msg = str(exc)[:500]
        if isinstance(exc, ConfigError) and msg.startswith(where.split(".")[0]):
            raise
        raise ConfigError(f"{where}: {msg}") from exc


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


class _StrictYAMLError(yaml.YAMLError):
    """A document :class:`_StrictLoader` refuses (the message says why, with the line)."""


class _StrictLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate keys and documents expanding to more than
    :data:`MAX_NODES` values, and reads ``1e-3`` / ``1E6`` as numbers (YAML 1.2)."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, int] = {}
            for key_node, _ in node.value:
                if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node)
                line = key_node.start_mark.line + 1
                if key in seen:
                    raise _StrictYAMLError(f"line {line}: duplicate key {show_value(key)} (first at line {seen[key]}); "
                                           "each key may appear once in a mapping")
                seen[key] = line
        return super().construct_mapping(node, deep=deep)

    def get_single_data(self):
        node = self.get_single_node()
        if node is None:
            return None
        _check_expansion(node)
        return self.construct_document(node)


_StrictLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))


def _check_expansion(root: yaml.Node) -> None:
    """Refuse a node graph whose aliases expand to more than :data:`MAX_NODES` values, or that refers to itself."""
    size: dict[int, int] = {}
    state: dict[int, int] = {}   # 1: being counted, 2: counted
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        children = ([n for pair in node.value for n in pair] if isinstance(node, yaml.MappingNode)
                    else list(node.value) if isinstance(node, yaml.SequenceNode) else [])
        if children_done:
            size[key] = min(MAX_NODES + 1, 1 + sum(size[id(c)] for c in children))
            state[key] = 2
            if size[key] > MAX_NODES:
                raise _StrictYAMLError(f"line {node.start_mark.line + 1}: the document expands to more than {MAX_NODES} "
                                       "values through its aliases (&anchor / *alias); a config is far smaller")
            continue
        if state.get(key) == 2:
            continue
        if state.get(key) == 1:
            raise _StrictYAMLError(f"line {node.start_mark.line + 1}: an alias refers to a value that contains it (recursive)")
        state[key] = 1
        stack.append((node, True))
        for c in children:
            if state.get(id(c)) == 1:
                raise _StrictYAMLError(f"line {c.start_mark.line + 1}: an alias refers to a value that contains it (recursive)")
            if state.get(id(c)) != 2:
                stack.append((c, False))


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping strictly (module docstring), with a clear error for a missing or malformed file.

    Raises:
        ConfigError: naming the file (and the line): missing, larger than :data:`MAX_CONFIG_BYTES`,
            not UTF-8, not YAML, a duplicate key, aliases expanding beyond :data:`MAX_NODES`
            values, or not a mapping.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    with open(path, "rb") as fh:
        raw = fh.read(MAX_CONFIG_BYTES + 1)
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{path}: larger than {MAX_CONFIG_BYTES >> 20} MiB; expected a YAML config")
    try:
        data = yaml.load(raw.decode("utf-8"), Loader=_StrictLoader)  # safe: a SafeLoader subclass
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text file (byte {exc.start}); expected a YAML config") from None
    except _StrictYAMLError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {str(exc)[:1000]}") from None
    except RecursionError:
        raise ConfigError(f"{path}: nested too deeply; expected a YAML config") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    return data


def is_relative_path(value: Any) -> bool:
    """Whether a config value names a file by a relative path: a string holding a ``/`` (or ``\\``) or
    ending in a file extension (``robot.xml``, ``../data/rig.npz``), not absolute.  A bare word
    (``furuta``: a registry name) is not a path."""
    if not isinstance(value, str) or not value or Path(value).expanduser().is_absolute():
        return False
    return "/" in value or "\\" in value or Path(value).suffix != ""


def config_folder(path: str | Path) -> Path:
    """The folder a config file's relative paths are resolved against: the file's own, symbolic links followed."""
    return Path(path).resolve().parent


def rebase_paths(raw: dict[str, Any], keys: typing.Iterable[str], folder: str | Path) -> dict[str, Any]:
    """Resolve the relative paths at the dotted ``keys`` of a config mapping against ``folder`` (in place; returned).

    The rule of every bemlearn config file (docs/config.md, "Paths"): a path written in a file is
    relative to that file's folder (:func:`config_folder`), a path given on the command line to the
    current folder.  A value is a path by :func:`is_relative_path`; a list of values (a sweep's grid)
    is rebased item by item; missing keys and other values are left as they are.  ``raw`` is nested
    (``{"simulate": {"predictor": ...}}``) or flat with dotted keys (``{"simulate.predictor": [...]}``).
    """
    base = Path(folder)

    def rebased(value: Any) -> Any:
        if isinstance(value, list):
            return [rebased(v) for v in value]
        if is_relative_path(value):
            return str(Path(os.path.normpath(base / Path(value).expanduser())))
        return value

    for key in keys:
        if key in raw:  # a flat mapping of dotted keys (a sweep's grid and overrides) or a top-level key
            raw[key] = rebased(raw[key])
            continue
        node: Any = raw
        *heads, last = key.split(".")
        for h in heads:
            node = node.get(h) if isinstance(node, dict) else None
        if isinstance(node, dict) and last in node:
            node[last] = rebased(node[last])
    return raw


def save_yaml(obj: Any, path: str | Path) -> None:
    """Write the resolved config (a dataclass or mapping) as YAML."""
    atomic_write_text(path, yaml.safe_dump(to_dict(obj), sort_keys=False))


def replace_path(obj: T, dotted: str, value: Any) -> T:
    """Return a copy of nested dataclass ``obj`` with field ``a.b.c`` replaced."""
    head, _, rest = dotted.partition(".")
    if not rest:
        return dataclasses.replace(obj, **{head: value})
    return dataclasses.replace(obj, **{head: replace_path(getattr(obj, head), rest, value)})


def replace_checked(obj: T, dotted: str, value: Any, *, where: str = "config") -> T | None:
    """``obj`` with the leaf field ``a.b.c`` set to ``value`` checked as :func:`from_dict` checks it.

    The value is coerced to the field's type and checked against its declared :class:`Limit`;
    every dataclass on the path is rebuilt (its ``__post_init__`` checks run again).  The result
    equals ``from_dict`` of the plain form of ``obj`` with the value set (a sweep builds the cells
    that differ from a resolved template only in such leaves this way).

    Returns:
        The new object, or ``None`` when ``dotted`` is not a plain leaf of ``obj``: a section, a
        mapping field, or a field inside a section that is ``None``.

    Raises:
        ConfigError: the value has the wrong type or breaks a limit (named ``where.a.b.c``).
    """
    head, _, rest = dotted.partition(".")
    cls = type(obj)
    if not dataclasses.is_dataclass(cls) or head not in _init_fields(cls):
        return None
    tp = _type_hints(cls)[head]
    if rest:
        child = getattr(obj, head)
        if child is None:
            return None
        new_child = replace_checked(child, rest, value, where=f"{where}.{head}")
        return None if new_child is None else _rebuild(obj, head, new_child, where)
    if _dataclass_of(tp) is not None or _is_mapping_type(tp) or isinstance(value, dict):
        return None
    return _rebuild(obj, head, _checked_field(cls, head, tp, value, where), where)


@functools.cache
def _init_fields(cls: type) -> frozenset[str]:
    return frozenset(f.name for f in dataclasses.fields(cls) if f.init)


def _rebuild(obj: T, name: str, value: Any, where: str) -> T:
    return _built(lambda: dataclasses.replace(obj, **{name: value}), where)


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


def _dataclass_of(tp: Any) -> type[DataclassInstance] | None:
    """``tp`` itself, or the one dataclass of an optional ``X | None``; else ``None``."""
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return tp
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        found = [a for a in typing.get_args(tp) if isinstance(a, type) and dataclasses.is_dataclass(a)]
        return found[0] if len(found) == 1 else None
    return None


def _is_mapping_type(tp: Any) -> bool:
    if tp is Any or typing.get_origin(tp) is dict or tp is dict:
        return True
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return any(_is_mapping_type(a) for a in typing.get_args(tp) if a is not type(None))
    return False
