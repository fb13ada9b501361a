"""The examples shipped inside the package: configs, test robots and sample data, usable wherever bemlearn is installed.

The folder is laid out like the repository, so every path the documentation names works in it:

* ``configs/*.yaml`` and ``configs/sweeps/*.yaml``: the paper's Furuta and biped configs and the sweep files;
* ``tests/robots/*.xml``: the MJCF robots the documentation and the sweeps use (cart-pole, acrobot, ...);
* ``data/furuta_excitation.npz``: a Furuta excitation trajectory (the model-free example);
  ``data/human_gait/``: the human gait of the biped's Fig. 5 (Apache-2.0, its README says where from).

In a source checkout these are links to the repository's own files (one copy; a built wheel holds
the files themselves).  ``bemlearn examples`` lists the example configs; a command's ``CONFIG``
argument accepts an example's name (``bemlearn run furuta`` runs ``configs/furuta.yaml`` from any
folder), and ``bemlearn examples copy DIR`` copies the whole folder to ``DIR`` to edit and run there.
Paths inside a config are relative to the config's folder (docs/config.md, "Paths"), so the copied
configs find the copied robots and data.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from bemlearn.errors import MissingFileError, OutputExistsError
from bemlearn.files import atomic_write_bytes

__all__ = ["EXAMPLES_DIR", "SHIPPED", "Example", "examples", "example_path", "config_argument", "copy_examples"]

#: The packaged examples folder (in a source checkout: links into the repository).
EXAMPLES_DIR = Path(__file__).resolve().parent
#: The top-level entries of :data:`EXAMPLES_DIR` that are examples (copied by :func:`copy_examples`).
SHIPPED: tuple[str, ...] = ("configs", "tests/robots", "data")


@dataclass(frozen=True)
class Example:
    """An example config.

    Attributes:
        name: what a command's ``CONFIG`` argument accepts: the path under ``configs/`` without
            ``.yaml`` (``furuta``, ``sweeps/example``).
        path: the packaged file.
        kind: ``"sweep"`` (a file for ``bemlearn sweep``) or ``"config"`` (``bemlearn run`` and the others).
        summary: the file's first comment line.
    """

    name: str
    path: Path
    kind: str
    summary: str


def _summary(path: Path) -> str:
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            return line.lstrip("# ").strip()
    return ""


def examples() -> dict[str, Example]:
    """Every example config by name, configs first, then sweeps, each sorted by name."""
    root = EXAMPLES_DIR / "configs"
    found = sorted(root.rglob("*.yaml"), key=lambda p: (len(p.relative_to(root).parts), str(p)))
    out: dict[str, Example] = {}
    for p in found:
        name = p.relative_to(root).with_suffix("").as_posix()
        out[name] = Example(name, p, "sweep" if name.startswith("sweeps/") else "config", _summary(p))
    return out


def example_path(relative: str) -> Path:
    """The packaged file at ``relative`` (a repository path: ``tests/robots/cartpole.xml``,
    ``data/furuta_excitation.npz``, ``configs/furuta.yaml``).

    Raises:
        MissingFileError: nothing is shipped at ``relative``; the message lists the shipped folders.
    """
    path = EXAMPLES_DIR / relative
    if not path.exists() or not any(relative == s or relative.startswith(s + "/") for s in SHIPPED):
        raise MissingFileError(f"{relative}: not a shipped example file; the examples are {', '.join(SHIPPED)} "
                               "(`bemlearn examples` lists the configs)")
    return path


def config_argument(value: str) -> Path:
    """A command's ``CONFIG`` argument: an existing file as given (relative to the current folder),
    else the example config of that name (``furuta`` → the packaged ``configs/furuta.yaml``), else the
    path as given (the command then reports it missing)."""
    path = Path(value)
    if path.is_file():
        return path
    name = value[:-5] if value.endswith(".yaml") else value
    name = name[len("configs/"):] if name.startswith("configs/") and not path.exists() else name
    found = examples().get(name)
    return found.path if found is not None else path


def _files(root: Path) -> list[Path]:
    out: list[Path] = []
    for entry in SHIPPED:
        p = root / entry
        if p.is_dir():
            out.extend(sorted(f for f in p.rglob("*") if f.is_file()))
        elif p.is_file():
            out.append(p)
    return out


def copy_examples(dest: str | os.PathLike[str], *, force: bool = False) -> list[Path]:
    """Copy the examples into ``dest`` (created if needed), laid out as in the repository; the files written.

    Raises:
        OutputExistsError: a file to write exists in ``dest`` and ``force`` is false (nothing is written).
    """
    dest = Path(dest)
    pairs = [(f, dest / f.relative_to(EXAMPLES_DIR)) for f in _files(EXAMPLES_DIR)]
    existing = [d for _, d in pairs if d.exists()]
    if existing and not force:
        shown = ", ".join(str(p) for p in existing[:5]) + (f" and {len(existing) - 5} more" if len(existing) > 5 else "")
        raise OutputExistsError(f"{dest}: would overwrite {shown}; use --force to replace")
    for src, dst in pairs:
        dst.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(dst, src.read_bytes())
    return [d for _, d in pairs]
