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
"""

from __future__ import annotations

import ast
import importlib
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["lazy_exports", "lazy_namespace"]


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
