"""No string-keyed read of a run's metrics outside the modules that spell its keys (checked on the source, ``ast``).

A run's stages hand each other typed results, and ``metrics.json`` is read into
:class:`~bemlearn.pipeline.run_metrics.RunMetrics` once (``from_dict``) and written once (``as_dict``):
a renamed key then fails at one place instead of silently skipping a check.

The rule, per module of ``bemlearn/`` (applications excepted, :data:`EXEMPT`):

1. A *metrics value* is
   (a) a name called ``metrics`` (a variable or a parameter; an attribute ``x.metrics`` is not: a stage
       result's ``metrics`` is typed (``TrainResult.metrics``, ``RunResult.metrics`` are ``RunMetrics``, which
       has no ``[]`` nor ``get``, so mypy rejects a string-keyed read), and the simulator's
       ``SimResult.metrics`` holds one loop's own figures, below the pipeline),
   (b) a call of ``read_metrics(...)`` or ``json.loads(...)`` / ``json.load(...)`` of a text whose expression
       mentions ``metrics`` (a run folder's ``metrics.json``),
   (c) anything taken from a metrics value by a key: a subscript, ``.get(...)``, ``.items()``,
       ``.values()``, ``.copy()``, ``dict(...)`` / ``list(...)`` / ``sorted(...)`` of one, ``x or {}``, a
       conditional expression with one branch a metrics value,
   (d) a name bound from a metrics value (assignment, ``for`` target, comprehension target, ``:=``), and a
       parameter of a function of ``bemlearn`` (defined in the module, or imported by name from another
       module of ``bemlearn``) that some call passes a metrics value to (positionally or by keyword),
       followed to a fixed point across modules.  An attribute of a metrics value is not one (a typed
       ``RunMetrics`` named ``metrics`` hands out typed sections).

   A call of anything else (``RunMetrics.from_dict(metrics)`` among them) gives a fresh, typed value.

2. A *violation* is a subscript load ``v["key"]`` or a call ``v.get("key", ...)`` whose ``v`` is a metrics
   value and whose key is a string constant, in a module other than the reader and writers of the file
   (:data:`SPELLERS`).

The analysis is by name, not by type: a dict called ``metrics`` that is not a run's still counts (rename it).
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "bemlearn"

#: The modules that spell ``metrics.json``'s keys: its typed reader and its writers.
SPELLERS = {
    "bemlearn.pipeline.run_metrics",   # from_dict / as_dict of every section
    "bemlearn.pipeline.results",       # the stage results' as_dict / summary, RunResult.write_metrics
    "bemlearn.pipeline.failure",       # record_failure: the metrics.json of a run that failed
}
#: Applications write metrics files of their own schema (the biped's), not a run's RunMetrics.
EXEMPT = ("bemlearn.apps",)

_METHODS = {"get", "items", "values", "copy", "setdefault", "pop"}
_WRAPPERS = {"dict", "list", "sorted", "tuple", "next", "iter", "reversed", "enumerate"}


def _module_name(path: Path, root: Path) -> str:
    rel = path.relative_to(root.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


class _Module:
    def __init__(self, name: str, tree: ast.Module) -> None:
        self.name, self.tree = name, tree
        self.functions: dict[str, list[ast.FunctionDef | ast.AsyncFunctionDef]] = {}
        self.imported: dict[str, tuple[str, str]] = {}
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                self.functions.setdefault(node.name, []).append(node)
            elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("bemlearn"):
                for a in node.names:
                    self.imported[a.asname or a.name] = (node.module, a.name)


def _params(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> list[str]:
    a = fn.args
    return [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs)]


def _own_nodes(scope: ast.AST) -> list[ast.AST]:
    """The nodes of ``scope`` outside the functions and classes defined in it (those are scopes of their own)."""
    out: list[ast.AST] = []
    todo = list(ast.iter_child_nodes(scope))
    while todo:
        node = todo.pop()
        out.append(node)
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda)):
            todo.extend(ast.iter_child_nodes(node))
    return out


#: id(scope node) -> (the node, kept alive so that its id is not reused; its own nodes), once per session
_OWN: dict[int, tuple[ast.AST, list[ast.AST]]] = {}


class _Scope:
    def __init__(self, node: ast.AST) -> None:
        self.node = node
        if id(node) not in _OWN:
            _OWN[id(node)] = (node, _own_nodes(node))
        own = _OWN[id(node)][1]
        self.binds = [n for n in own if isinstance(n, (ast.Assign, ast.AnnAssign, ast.NamedExpr, ast.For, ast.comprehension))]
        self.calls = [n for n in own if isinstance(n, ast.Call)]
        self.reads = [n for n in own if isinstance(n, (ast.Subscript, ast.Call))]
        self.names: set[str] = set()


class _Flow:
    """Metrics values of every module (rule 1), to a fixed point."""

    def __init__(self, modules: dict[str, _Module]) -> None:
        self.modules = modules
        self.tainted_params: dict[int, set[str]] = {}      # id(function node) -> parameter names
        self.scopes: dict[str, list[_Scope]] = {
            name: [_Scope(mod.tree), *(_Scope(fn) for fns in mod.functions.values() for fn in fns)]
            for name, mod in modules.items()}

    def is_metrics(self, e: ast.AST | None, names: set[str]) -> bool:
        if e is None:
            return False
        if isinstance(e, ast.Name):
            return e.id == "metrics" or e.id in names
        if isinstance(e, ast.Subscript):
            return self.is_metrics(e.value, names)
        if isinstance(e, ast.Call):
            f = e.func
            if isinstance(f, ast.Name) and f.id == "read_metrics":
                return True
            if isinstance(f, ast.Attribute) and f.attr in ("loads", "load") and isinstance(f.value, ast.Name) and f.value.id == "json":
                return any("metrics" in ast.unparse(a) for a in e.args)
            if isinstance(f, ast.Attribute) and f.attr in _METHODS:
                return self.is_metrics(f.value, names)
            if isinstance(f, ast.Name) and f.id in _WRAPPERS:
                return any(self.is_metrics(a, names) for a in e.args)
            return False
        if isinstance(e, ast.BoolOp):
            return any(self.is_metrics(v, names) for v in e.values)
        if isinstance(e, ast.IfExp):
            return self.is_metrics(e.body, names) or self.is_metrics(e.orelse, names)
        return False

    @staticmethod
    def _targets(t: ast.AST) -> list[str]:
        """The names a target binds (``x``, ``a, (b, *c)``); ``d["k"] = …`` and ``o.a = …`` bind none."""
        if isinstance(t, ast.Name):
            return [t.id]
        if isinstance(t, (ast.Tuple, ast.List)):
            return [n for e in t.elts for n in _Flow._targets(e)]
        if isinstance(t, ast.Starred):
            return _Flow._targets(t.value)
        return []

    def _callees(self, mod: _Module, call: ast.Call):
        f = call.func
        if not isinstance(f, ast.Name):
            return []
        if f.id in mod.functions:
            return mod.functions[f.id]
        if f.id in mod.imported:
            src, name = mod.imported[f.id]
            other = self.modules.get(src)
            return other.functions.get(name, []) if other else []
        return []

    def run(self) -> None:
        changed = True
        while changed:
            changed = False
            for name, mod in self.modules.items():
                for scope in self.scopes[name]:
                    scope.names |= self.tainted_params.get(id(scope.node), set())
                    changed |= self._propagate(mod, scope)

    def _propagate(self, mod: _Module, scope: _Scope) -> bool:
        names = scope.names
        grew = True
        while grew:
            grew = False
            for node in scope.binds:
                if isinstance(node, ast.Assign):
                    source, targets = node.value, node.targets
                elif isinstance(node, (ast.AnnAssign, ast.NamedExpr)):
                    source, targets = node.value, [node.target]
                else:
                    assert isinstance(node, (ast.For, ast.comprehension))
                    source, targets = node.iter, [node.target]
                new = [n for t in targets for n in self._targets(t)] if self.is_metrics(source, names) else []
                if set(new) - names:
                    names |= set(new)
                    grew = True
        changed = False
        for node in scope.calls:
            assert isinstance(node, ast.Call)
            for fn in self._callees(mod, node):
                ps = _params(fn)
                hit = {ps[i] for i, a in enumerate(node.args) if i < len(ps) and self.is_metrics(a, names)}
                hit |= {k.arg for k in node.keywords if k.arg in ps and self.is_metrics(k.value, names)}
                have = self.tainted_params.setdefault(id(fn), set())
                if hit - have:
                    have |= hit
                    changed = True
        return changed

    def violations(self) -> list[str]:
        out = []
        for name in self.modules:
            if name in SPELLERS:
                continue
            for scope in self.scopes[name]:
                for node in scope.reads:
                    key = recv = None
                    if isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Load):
                        key, recv = node.slice, node.value
                    elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get" and node.args:
                        key, recv = node.args[0], node.func.value
                    if isinstance(key, ast.Constant) and isinstance(key.value, str) and self.is_metrics(recv, scope.names):
                        out.append(f"{name}:{node.lineno}: {ast.unparse(node)[:90]}")
        return sorted(set(out))


@functools.cache
def _package(root: Path) -> dict[str, _Module]:
    """The modules of the package, parsed once per session."""
    mods = {}
    for p in sorted(root.rglob("*.py")):
        name = _module_name(p, root)
        if not name.startswith(EXEMPT):
            mods[name] = _Module(name, ast.parse(p.read_text(), filename=str(p)))
    return mods


def _modules(root: Path, extra: dict[str, str] | None = None) -> dict[str, _Module]:
    mods = dict(_package(root))
    for name, text in (extra or {}).items():
        mods[name] = _Module(name, ast.parse(text))
    return mods


def _violations(extra: dict[str, str] | None = None) -> list[str]:
    flow = _Flow(_modules(PKG, extra))
    flow.run()
    return flow.violations()


def test_no_string_keyed_read_of_a_runs_metrics():
    bad = _violations()
    assert not bad, "string-keyed reads of a run's metrics (read RunMetrics' fields instead):\n" + "\n".join(bad)


@pytest.mark.parametrize("code, lines", [
    # direct, through a name and an `or {}`, a loop and a call into another function, a file read back
    ('def f(metrics):\n    return metrics["verdict"]\n', {2}),
    ('def f(metrics):\n    dr = metrics.get("bem_design_region") or {}\n    return dr.get("gain")\n', {2, 3}),
    ('def f(m):\n    return m["fit"]\n\ndef g(metrics):\n    for src, loop in metrics.items():\n        f(loop)\n', {2}),
    ('from bemlearn.pipeline.failure import read_metrics\n\ndef f(out):\n    doc = read_metrics(out)\n    return doc["verdict"]\n', {5}),
    ('import json\n\ndef f(out):\n    return json.loads((out / "metrics.json").read_text())["data"]\n', {4}),
    # into a function of another module, by keyword
    ('from bemlearn.pipeline.report import _fit_lines\n\ndef f(metrics):\n    return _fit_lines(None, train=metrics)\n', None),
])
def test_a_planted_read_is_caught(code, lines):
    bad = _violations({"bemlearn.planted": code})
    if lines is None:   # the callee's parameter becomes a metrics value: a string-keyed read there would be flagged
        flow = _Flow(_modules(PKG, {"bemlearn.planted": code}))
        flow.run()
        fn = flow.modules["bemlearn.pipeline.report"].functions["_fit_lines"][0]
        assert "train" in flow.tainted_params[id(fn)]
        return
    assert {int(b.split(":")[1]) for b in bad if b.startswith("bemlearn.planted:")} == lines


def test_typed_reads_are_not_flagged():
    code = ('from bemlearn.pipeline.run_metrics import RunMetrics\n\n'
            'def f(metrics):\n    m = RunMetrics.from_dict(metrics)\n    units = {"q": "rad"}\n'
            '    return m.bem_design_region.gain, units["q"]\n')
    assert not [b for b in _violations({"bemlearn.planted": code}) if b.startswith("bemlearn.planted:")]


def test_metrics_json_reads_and_writes_back_unchanged():
    """``as_dict(from_dict(doc)) == doc`` key for key, in order: typed keys, keys no reader types, ``null``s, a
    section of the wrong type, an old file without most sections; and the fields read what the file holds."""
    import json

    from bemlearn.pipeline.run_metrics import LoopMetrics, RunMetrics

    doc = {"robot": {"name": "cart", "mjcf": None, "sha256": None, "registry": "cartpole"}, "fit": {"steps": 7, "x": [1, 2]},
           "support": {"share": 0.5, "pairs": [{"input": "qdd_u", "with": "qdd_a", "corr": -0.95, "ratio": 2.0}], "t": None},
           "data_heldout": {"per_trial": {"3": {"rmse": 0.1, "beyond_training": None}}, "rmse": 0.2},
           "equilibrium": "not a section", "future_key": {"a": 1},
           "closed_loop": {"predictor": {"fell": False, "lemma1": {"model_gap": 1e-9}, "bem_rejected": 0}},
           "verdict": {"status": "degraded", "reasons": ["r"], "findings": [{"severity": "degraded", "check": "c", "reason": "r"}],
                       "checked": ["c"]}}
    m = RunMetrics.from_dict(doc)
    assert json.dumps(m.as_dict()) == json.dumps(doc)
    assert m.robot is not None and m.robot.registry == "cartpole" and m.fit is not None and m.fit.steps == 7
    assert m.support is not None and m.support.pairs is not None and m.support.pairs[0].with_ == "qdd_a" and m.support.t is None
    assert m.data_heldout is not None and m.data_heldout.per_trial is not None and m.data_heldout.per_trial["3"].rmse == 0.1
    assert m.equilibrium is None                       # kept as it came, not typed
    assert m.closed_loop is not None and m.closed_loop["predictor"].lemma1 is not None
    assert m.closed_loop["predictor"].lemma1.model_gap == 1e-9
    assert m.verdict is not None and m.verdict.status == "degraded" and m.verdict.findings[0].check == "c"
    assert RunMetrics.from_dict({}).as_dict() == {}
    # a section set in memory goes after the keys read, as the writer appended them before
    m2 = RunMetrics.from_dict({"fit": {"steps": 1}})
    m2.closed_loop = {"model": LoopMetrics.from_dict({"fell": True})}
    assert list(m2.as_dict()) == ["fit", "closed_loop"] and m2.as_dict()["closed_loop"] == {"model": {"fell": True}}
