"""The core knows no robot by name: imports run from the applications into the core only.

Checked on the source text (``ast``), so a lazy import inside a function counts too.
"""

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "bemlearn"
CORE = [p for p in PKG.rglob("*.py") if "apps" not in p.relative_to(PKG).parts]
ROBOT_NAMES = ("furuta", "biped", "quanser")


def _imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.append(node.module)
    return out


def _code_strings(path: Path) -> list[tuple[int, str]]:
    """String constants that are not docstrings."""
    tree = ast.parse(path.read_text(), filename=str(path))
    docs = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                docs.add(id(first.value))
    return [(n.lineno, n.value) for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs]


def test_the_core_is_found():
    assert len(CORE) > 50 and (PKG / "apps" / "furuta").is_dir() and (PKG / "apps" / "biped").is_dir()


@pytest.mark.parametrize("path", CORE, ids=lambda p: str(p.relative_to(PKG)))
def test_core_module_imports_no_application(path):
    bad = [m for m in _imports(path) if m == "bemlearn.apps" or m.startswith("bemlearn.apps.")]
    assert not bad, f"{path.relative_to(PKG)} imports application code {bad}; applications build on the core, not the reverse"


@pytest.mark.parametrize("path", CORE, ids=lambda p: str(p.relative_to(PKG)))
def test_core_module_dispatches_on_no_robot_name(path):
    bad = [(line, s) for line, s in _code_strings(path) if any(name in s.lower() for name in ROBOT_NAMES)]
    assert not bad, f"{path.relative_to(PKG)} names a robot in code: {bad}"


def test_a_planted_violation_is_caught(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text('"""doc mentions furuta, fine."""\nfrom bemlearn.apps.furuta import model\nX = "furuta"\n')
    assert _imports(bad) == ["bemlearn.apps.furuta"]
    assert _code_strings(bad) == [(3, "furuta")]
