"""Import a file that is not in a package (a script, an example) as a module, for the tests that call it."""

import importlib.util
import sys
from pathlib import Path
from types import ModuleType


def load_file_module(path: Path, name: str | None = None, *, register: bool = False) -> ModuleType:
    """The module defined by the Python file ``path``, named ``name`` (default: the file's stem).

    ``register`` puts it in ``sys.modules`` before it runs (a module whose dataclasses look themselves up by name).
    """
    spec = importlib.util.spec_from_file_location(name or Path(path).stem, path)
    assert spec is not None and spec.loader is not None, path
    mod = importlib.util.module_from_spec(spec)
    if register:
        sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod
