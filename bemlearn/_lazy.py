"""Lazy package namespaces (PEP 562): a package's public names are imported on first use.

A package whose modules pull in torch, GPyTorch or MuJoCo lists its public names as ordinary
imports under ``if TYPE_CHECKING:`` (what type checkers, linters and the API reference read)
and ends with::

    __getattr__, __dir__ = lazy_namespace(__name__, __file__)

so ``import bemlearn.data`` (and therefore importing any one of its modules, which imports the
package first) costs nothing, while ``from bemlearn.data import build_datasets`` imports
``bemlearn.data.dataset`` at that moment.  ``bemlearn --help`` and ``bemlearn config show``
stay fast this way (``tests/test_startup.py``).  The ``from … import …`` lines are read from
the package's own source, so the names are written once.

A module that uses torch only inside its functions writes, instead of ``import torch``::

    if TYPE_CHECKING:
        import torch
    else:
        torch = lazy_module("torch")

so importing it (to read a config dataclass, or to load a robot's MuJoCo model) does not load
torch; the first attribute looked up (``torch.zeros``) does.
"""

from __future__ import annotations

import ast
import importlib
import sys
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["lazy_exports", "lazy_namespace", "lazy_module", "LazyModule"]


def lazy_exports(init_file: str | Path) -> dict[str, tuple[str, str]]:
    """``{public name: (module, name in that module)}`` from the ``if TYPE_CHECKING:`` imports of ``init_file``.

    Only absolute ``from MODULE import NAME [as ALIAS]`` statements directly inside a top-level
    ``if TYPE_CHECKING:`` block count.
    """
    tree = ast.parse(Path(init_file).read_text(encoding="utf-8"), filename=str(init_file))
    out: dict[str, tuple[str, str]] = {}
    for node in tree.body:
        if not (isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"):
            continue
        for stmt in node.body:
            if isinstance(stmt, ast.ImportFrom) and stmt.module and stmt.level == 0:
                for alias in stmt.names:
                    out[alias.asname or alias.name] = (stmt.module, alias.name)
    return out


def lazy_namespace(package: str, init_file: str | Path) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The module-level ``__getattr__`` and ``__dir__`` of a lazy package.

    ``__getattr__(name)`` imports the module that defines ``name``, binds the value in the
    package (later look-ups cost nothing) and returns it; a name that is neither exported nor a
    submodule raises :class:`AttributeError` as usual.

    Args:
        package: the package's ``__name__``.
        init_file: the package's ``__file__`` (its ``__init__.py``).
    """
    exports = lazy_exports(init_file)
    namespace = sys.modules[package].__dict__

    def __getattr__(name: str) -> Any:
        if name in exports:
            module, attr = exports[name]
            value = getattr(importlib.import_module(module), attr)
            namespace[name] = value
            return value
        if name.startswith("__"):  # __path__, __wrapped__, ...: never a submodule
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        try:  # a submodule not imported yet: `bemlearn.data.trajectory_io` after `import bemlearn.data`
            return importlib.import_module(f"{package}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{package}.{name}":
                raise
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__


class LazyModule:
    """A stand-in for the module ``name`` that imports it on the first attribute look-up.

    After the import the module's namespace is copied onto the stand-in, so later look-ups cost
    what a module attribute costs; names the module defines later (submodules imported on
    demand) are still found through :meth:`__getattr__`.  ``sys.modules`` is not touched: a
    plain ``import name`` elsewhere behaves as usual.
    """

    def __init__(self, name: str) -> None:
        object.__setattr__(self, "_lazy_name", name)

    def _lazy_load(self) -> types.ModuleType:
        module = importlib.import_module(self._lazy_name)
        self.__dict__.update(module.__dict__)
        object.__setattr__(self, "_lazy_module", module)
        return module

    def __getattr__(self, attr: str) -> Any:
        if attr.startswith("_lazy_"):
            raise AttributeError(attr)
        module = self.__dict__.get("_lazy_module") or self._lazy_load()
        return getattr(module, attr)

    def __repr__(self) -> str:
        state = "loaded" if "_lazy_module" in self.__dict__ else "not loaded yet"
        return f"<lazy module {self._lazy_name!r} ({state})>"


def lazy_module(name: str) -> Any:
    """``name`` itself when it is imported already, else a :class:`LazyModule` that imports it on first use."""
    return sys.modules.get(name) or LazyModule(name)
