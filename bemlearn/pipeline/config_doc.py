"""``docs/config.md``: every key of a pipeline config, generated from the config dataclasses.

Each section's dataclass documents its keys in its docstring (``Attributes:``); this module
walks :class:`~bemlearn.pipeline.config.PipelineConfig` and writes one table row per key with
its type, default, whether the robot's model derives it, and its description.  A test checks
that ``docs/config.md`` equals the output, so the page cannot fall behind the code.

Run ``python -m bemlearn.pipeline.config_doc > docs/config.md`` after changing a config class.
"""

from __future__ import annotations

import dataclasses
import inspect
import re
import types
import typing

from bemlearn.config import LIMITS
from bemlearn.pipeline.config import PipelineConfig

__all__ = ["config_markdown", "attribute_docs"]

_INTRO = """# Pipeline configuration

A pipeline config is one YAML file with a section per stage. Every key is checked: an unknown or
misspelt key, a repeated key, a value of the wrong type, a number that is not finite (`.nan`,
`.inf`) or outside the limits in the *type* column below (e.g. `≥ 1`, or `min ≤ max` for a
(min, max) pair), or values that contradict each other (`simulate.warmup_s` not shorter than
`simulate.duration_s`, reference lists of different lengths, gains that do not fit the robot,
…) is an error that names the file and the key path — before any command writes anything.
The smallest config names only the robot:

```yaml
robot: path/to/my_robot.xml     # or a registry name (bemlearn robot info NAME)
```

Everything else is either **derived from the robot's model** when the config does not give it
(marked *derived* below; how each is derived is printed by `bemlearn config show CONFIG`) or a
plain **default**. An explicit key always wins. Each run saves the resolved config as
`config.yaml` and every value with its origin (given / derived / default) as
`config_resolved.json`.

A model-free config names a trajectory file instead of a robot (`data: FILE`, see
docs/log-import.md); `model:` then optionally names an MJCF to compare the learned BEM with.
With `model:` the `evaluate` keys marked *derived* are derived from that model (the held-out
references along which the learned BEM is compared with the model's; nothing else is derived:
the data were recorded elsewhere, so there is no collection or closed loop).

Units follow the joint: rad, rad/s, rad/s² for hinges; m, m/s, m/s² for slides.

## Paths

A relative path written **in a file** is relative to **that file's folder**; a path given **on the
command line** is relative to the **current folder**. This holds for every file bemlearn reads: a
pipeline config (`robot:`, `data:`, `model:`, `simulate.predictor`), an application's config (its
input files, such as `walk.predictor`), and a sweep file (`base:`, and the paths of its inline
base, `overrides:` and `grid:`; a base config *file* keeps its own paths relative to its own folder).
So `configs/sweeps/example.yaml` names `../../tests/robots/cartpole.xml`, and a config works the same
from whatever folder the command runs. A value is a path when it holds a `/` or ends in a file
extension (`my.xml`, `data/rig.npz`); a bare word is a registry name (`bemlearn robot list`). The run folder's saved
`config.yaml` holds the resolved, absolute paths. A command's `CONFIG` argument may also be the name
of an example shipped with bemlearn (`bemlearn run NAME`; `bemlearn examples` lists them).

This page is generated from the config classes (`python -m bemlearn.pipeline.config_doc`).
"""


def attribute_docs(cls) -> dict[str, str]:
    """``{field: description}`` from the ``Attributes:`` section of a dataclass docstring."""
    doc = inspect.getdoc(cls) or ""
    m = re.search(r"^Attributes:\s*$(.*?)(?=^\S|\Z)", doc, flags=re.M | re.S)
    if not m:
        return {}
    out: dict[str, str] = {}
    current: list[str] = []
    text: list[str] = []
    for line in m.group(1).splitlines():
        if not line.strip():
            continue
        head = re.match(r"^    ([A-Za-z_][\w, ]*):\s*(.*)$", line)
        if head and all(re.fullmatch(r"[A-Za-z_]\w*", n.strip()) for n in head.group(1).split(",")):
            for name in current:
                out[name] = " ".join(text).strip()
            current = [n.strip() for n in head.group(1).split(",")]
            text = [head.group(2)]
        else:
            text.append(line.strip())
    for name in current:
        out[name] = " ".join(text).strip()
    return out


def _type_name(tp) -> str:
    s = str(tp).replace("typing.", "").replace("<class '", "").replace("'>", "")
    return re.sub(r"\bbemlearn\.[\w.]+\.", "", s)


def _default(f: dataclasses.Field) -> str:
    if f.default is not dataclasses.MISSING:
        v = f.default
    elif f.default_factory is not dataclasses.MISSING:
        v = f.default_factory()
        if dataclasses.is_dataclass(v):
            return "(section)"
    else:
        return "required"
    return "`null`" if v is None else f"`{list(v) if isinstance(v, tuple) else v}`"


def _rows(cls, prefix: str, rows: list[str], sections: list[tuple[str, type]]) -> None:
    from bemlearn.pipeline.derived_defaults import DERIVED_KEYS

    hints = typing.get_type_hints(cls)
    docs = attribute_docs(cls)
    for f in dataclasses.fields(cls):
        key = f"{prefix}{f.name}"
        tp = hints[f.name]
        if isinstance(tp, type) and dataclasses.is_dataclass(tp):
            sections.append((key, tp))
            continue
        if (optional := _optional_dataclass(tp)) is not None:   # an optional section: its row, then its keys
            sections.append((key, optional))
        derived = "derived" if key in DERIVED_KEYS else ""
        desc = _ROLE.sub(r"`\g<target>`", docs.get(f.name, "")).replace("|", "\\|")
        limit = LIMITS.get(cls, {}).get(f.name)
        bounds = "" if limit is None else ", ".join(b for b in (limit.describe(), "min ≤ max" if limit.ordered else "",
                                                                 f"≥ {limit.min_len} entries" if limit.min_len else "") if b)
        kind = _type_name(tp).replace('|', 'or') + (f" ({bounds})" if bounds else "")
        rows.append(f"| `{key}` | {kind} | {_default(f)} | {derived} | {desc} |")


def _optional_dataclass(tp) -> type | None:
    args = typing.get_args(tp) if typing.get_origin(tp) in (typing.Union, types.UnionType) else ()
    found = [a for a in args if isinstance(a, type) and dataclasses.is_dataclass(a)]
    return found[0] if len(found) == 1 and type(None) in args else None


#: A Sphinx role of a docstring (``:mod:`x```): a code span on this Markdown page.
_ROLE = re.compile(r":(?:py:)?(?:func|meth|attr|class|mod|data|exc|obj|const):`~?(?P<target>[^`]+)`")


def config_markdown() -> str:
    """The whole ``docs/config.md`` page."""
    out = [_INTRO]
    pending: list[tuple[str, type]] = [("", PipelineConfig)]
    while pending:
        prefix, cls = pending.pop(0)
        rows: list[str] = []
        subs: list[tuple[str, type]] = []
        _rows(cls, f"{prefix}." if prefix else "", rows, subs)
        title = prefix or "top level"
        summary = (inspect.getdoc(cls) or "").splitlines()[0]
        out += [f"## `{title}` — {cls.__name__}", "", summary, "", "| key | type | default | when not given | description |",
                "| --- | --- | --- | --- | --- |", *rows, ""]
        pending = subs + pending
    return "\n".join(out)


if __name__ == "__main__":
    print(config_markdown(), end="")
