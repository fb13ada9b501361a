"""The package layout is the architecture: checked on the source text (``ast``, ``tokenize``).

- The core knows no robot by name: imports run from the applications into the core only.
- No import circles, and each layer imports only the layers below it (README "Layout").
- The squared-exponential kernel is evaluated in one module.

A lazy import inside a function counts like one at the top of a module.
"""

import ast
import io
import re
import tokenize
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


# ---- the import graph: no circles, and every package imports only the layers below it --------------
#
# Nodes are the modules of ``bemlearn``; a package is the node of its ``__init__``.  Edges are the
# import statements in the source text, at module level *and* inside functions (a lazy import is a
# dependency all the same), ``if TYPE_CHECKING:`` imports included (a type a module needs is a
# dependency too, and hiding a circle behind TYPE_CHECKING is what this test is for):
#
# * ``import bemlearn.a.b`` → ``bemlearn.a.b``;
# * ``from bemlearn.a import b`` → ``bemlearn.a.b`` when ``b`` is a submodule, else ``bemlearn.a``
#   (the package's ``__init__``: ``from bemlearn.models import LearnedBEM`` depends on everything
#   ``models/__init__`` imports);
# * relative imports are resolved against the importing module's package first.
#
# ``__init__`` re-exports.  Importing ``bemlearn.a.b`` first runs ``bemlearn/a/__init__.py``.  That
# implicit step is *not* an edge: with it every package whose ``__init__`` re-exports its submodules
# would be a circle through its own ``__init__`` (``a/__init__`` → ``a.b`` → ``a/__init__``), and the
# test could only pass by not re-exporting.  An *explicit* import of the package from inside it (a
# module of ``bemlearn.a`` writing ``from bemlearn.a import x``, or ``from . import x`` for a name
# that is not a submodule) *is* an edge to ``__init__``, and so shows up as a circle when the
# ``__init__`` imports that module: at run time that is the real circle (a partly initialised
# package), so it is reported.  Sibling imports must name the sibling module.  Imports by a name
# computed at run time (``importlib.import_module``, entry points, a lazy ``__getattr__``) are not
# statements and are not seen.

#: The layers, bottom first, as the code has them (README "Layout"): a module may import modules of
#: its own layer (the no-circle test keeps those acyclic) and of the layers below it, never above.
#: ``<base>`` is the package-less modules ``bemlearn/*.py`` (errors, files, config, units, interrupts,
#: outputs, applications, ...); ``__main__`` counts as ``cli``.  The applications sit on the core.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("<base>",),
    ("examples",),
    ("robots",),
    ("data",),
    ("models",),
    ("fitting",),
    ("export",),
    ("control",),
    ("sim",),
    ("pipeline",),
    ("sweep",),
    ("bench",),
    ("cli",),
    ("apps",),
)
_RANK = {pkg: i for i, layer in enumerate(LAYERS) for pkg in layer}


def _module_name(path: Path, root: Path = PKG) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules(root: Path = PKG) -> dict[str, Path]:
    return {_module_name(p, root): p for p in sorted(root.rglob("*.py"))}


def _edges(path: Path, name: str, modules: dict[str, Path]) -> set[str]:
    """The modules of ``modules`` that ``path`` (module ``name``) imports (see the comment above)."""
    def known(target: str) -> str | None:
        while target and target not in modules:
            target = target.rpartition(".")[0]
        return target or None

    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out.update(filter(None, (known(a.name) for a in node.names)))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(up + ([node.module] if node.module else []))
            for a in node.names:
                target = known(f"{base}.{a.name}") if f"{base}.{a.name}" in modules else known(base)
                if target:
                    out.add(target)
    out.discard(name)
    return out


def import_graph(root: Path = PKG) -> dict[str, set[str]]:
    """Module → the modules it imports, over every module under ``root``."""
    modules = _modules(root)
    return {name: _edges(path, name, modules) for name, path in modules.items()}


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def layer_of(module: str) -> str:
    """The package a module belongs to for :data:`LAYERS` (``<base>`` for ``bemlearn/*.py``)."""
    parts = module.split(".")
    if len(parts) == 1 or (len(parts) == 2 and not (PKG / parts[1]).is_dir()):
        return "<base>" if parts[-1] != "__main__" else "cli"
    return parts[1]


def layering_violations(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """(importer, imported) pairs where a module imports a layer above its own."""
    return sorted((a, b) for a, targets in graph.items() for b in targets if _RANK[layer_of(b)] > _RANK[layer_of(a)])


GRAPH = import_graph()


def test_the_import_graph_is_found():
    assert len(GRAPH) > 150
    assert "bemlearn.models.kernels" in GRAPH["bemlearn.models.predictor_state"]
    assert "bemlearn.pipeline.resolve" in GRAPH["bemlearn.cli.config_cmd"]   # a function-level import counts


def test_no_import_circles():
    cycles = import_cycles(GRAPH)
    assert cycles == [], f"{len(cycles)} import circle(s): {cycles}"


def test_every_package_is_in_a_layer():
    packages = {layer_of(m) for m in GRAPH}
    assert packages <= set(_RANK), f"packages in no layer of LAYERS: {sorted(packages - set(_RANK))}"
    assert set(_RANK) <= packages


def test_each_layer_imports_only_the_layers_below_it():
    bad = layering_violations(GRAPH)
    assert bad == [], "upward imports (importer → imported): " + ", ".join(f"{a} → {b}" for a, b in bad)


def test_the_readme_layout_table_lists_the_layers_bottom_up():
    """README "Layout" describes what these tests check: its table is :data:`LAYERS` in order."""
    text = (PKG.parent / "README.md").read_text()
    section = text[text.index("## Layout"):]
    section = section[: section.index("\n## ", 1)]
    rows = [re.findall(r"`bemlearn\.(\w+)", line.split("|")[1]) for line in section.splitlines() if line.startswith("| `bemlearn.")]
    assert [tuple(dict.fromkeys(r)) for r in rows] == [layer for layer in LAYERS if layer != ("<base>",)]
    assert "bottom-up" in section and "TYPE_CHECKING" in section


def test_a_planted_circle_and_an_upward_import_are_caught(tmp_path):
    pkg = tmp_path / "bemlearn"
    for sub in ("data", "pipeline", "models"):
        (pkg / sub).mkdir(parents=True)
        (pkg / sub / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "data" / "a.py").write_text("def f():\n    from bemlearn.pipeline import b\n")   # lazy and upward
    (pkg / "pipeline" / "b.py").write_text("from bemlearn.data.a import f\n")
    (pkg / "pipeline" / "c.py").write_text("from . import b\n")
    # models/__init__ re-exports k and s; k imports its sibling s by module (fine), s reaches k's
    # name through the package (a real circle: models/__init__ is half-run when s needs it)
    (pkg / "models" / "__init__.py").write_text("from bemlearn.models.k import K\nfrom .s import S\n")
    (pkg / "models" / "k.py").write_text("from bemlearn.models.s import S\nK = S\n")
    (pkg / "models" / "s.py").write_text("import typing\nif typing.TYPE_CHECKING:\n    from bemlearn.models import K\nS = 1\n")
    graph = import_graph(pkg)
    assert graph["bemlearn.data.a"] == {"bemlearn.pipeline.b"} and graph["bemlearn.pipeline.c"] == {"bemlearn.pipeline.b"}
    assert graph["bemlearn.models"] == {"bemlearn.models.k", "bemlearn.models.s"}
    assert graph["bemlearn.models.k"] == {"bemlearn.models.s"} and graph["bemlearn.models.s"] == {"bemlearn.models"}
    assert import_cycles(graph) == [["bemlearn.data.a", "bemlearn.pipeline.b"], ["bemlearn.models", "bemlearn.models.k", "bemlearn.models.s"]]
    assert layering_violations(graph) == [("bemlearn.data.a", "bemlearn.pipeline.b")]


# ---- one formula, one place: the squared-exponential kernel is evaluated in models/kernels.py only --

#: Other code that evaluates exp(−½ ·) on purpose, and why it is not a copy of the GP kernel.
KERNEL_EXCEPTIONS = {
    "models/kernels.py": "the one implementation (se_kernel, se_gram, se_cross_covariance)",
    "models/gpdm.py": "the GPDM's own kernels (eq. 16–17: a 1-D RBF on latents, RBF + linear on lags) with its own hyperparameters",
    "data/gaussian_derivative.py": "a Gaussian smoothing window in time (docs/derivatives.md), not a GP kernel",
    "bench/predict_bench.py": "NumPy versions timed against the export, and a longdouble reference, by design",
}
_KERNEL_CALL = re.compile(r"\bexp\(\s*-\s*0?\.5\b|\bcdist\(")


def _code_lines(path: Path) -> list[tuple[int, str]]:
    """Source lines with comments and string literals blanked (so docstrings quoting a formula do not count)."""
    lines = path.read_text().splitlines()
    blank = {}
    for tok in tokenize.generate_tokens(io.StringIO(path.read_text()).readline):
        if tok.type in (tokenize.COMMENT, tokenize.STRING):
            (r0, c0), (r1, c1) = tok.start, tok.end
            for r in range(r0, r1 + 1):
                line = blank.get(r, lines[r - 1])
                a = c0 if r == r0 else 0
                b = c1 if r == r1 else len(line)
                blank[r] = line[:a] + " " * (b - a) + line[b:]
    return [(i, blank.get(i, line)) for i, line in enumerate(lines, 1)]


def kernel_copies(root: Path = PKG) -> list[str]:
    """``path:line`` of every exp(−½ ·) / cdist call outside :data:`KERNEL_EXCEPTIONS`."""
    out = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel in KERNEL_EXCEPTIONS:
            continue
        out += [f"{rel}:{i}" for i, line in _code_lines(path) if _KERNEL_CALL.search(line)]
    return out


def test_the_squared_exponential_kernel_has_one_implementation():
    copies = kernel_copies()
    assert copies == [], (f"kernel evaluations outside models/kernels.py: {copies}; call "
                          "bemlearn.models.kernels.se_kernel (or PredictorState.kernel_row / gram)")
    assert all((PKG / rel).is_file() for rel in KERNEL_EXCEPTIONS)


def test_a_planted_kernel_copy_is_caught(tmp_path):
    root = tmp_path / "bemlearn"
    (root / "export").mkdir(parents=True)
    (root / "export" / "x.py").write_text('"""k = σ² exp(-0.5 d²)."""\n# exp(-0.5 * d2) in a comment\n'
                                          "k = s * torch.exp(-0.5 * d2)\nK = torch.cdist(a, b)\n")
    assert kernel_copies(root) == ["export/x.py:3", "export/x.py:4"]
