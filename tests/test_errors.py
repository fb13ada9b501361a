"""One exception family (issue 23): bemlearn raises only :mod:`bemlearn.errors`, the CLI prints
those as one line and shows the traceback of anything else, and loss evaluation catches only
numerical failures."""

from __future__ import annotations

import ast
import builtins
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from linear_operator.utils.cholesky import psd_safe_cholesky

import bemlearn
from bemlearn import errors
from bemlearn.cli import config_cmd
from bemlearn.cli.main import main
from bemlearn.fitting.optimize import NumericalFailure, checked_loss, minimize

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "bemlearn"

#: Every built-in exception (and warning) class, by the name code would raise it with.
BUILTIN_EXCEPTIONS = frozenset(
    name for name, value in vars(builtins).items() if isinstance(value, type) and issubclass(value, BaseException)
)

#: ``AssertionError`` is allowed only for these internal invariants: (file under bemlearn/, function).
ASSERTION_SITES = frozenset({("export/c_source.py", "c_sources")})


# ---- the ast check ------------------------------------------------------------------------------
class _Checker:
    """Finds every ``raise`` (and every construction) of a built-in exception in one module."""

    def __init__(self, source: str, rel: str):
        self.rel = rel
        self.tree = ast.parse(source)
        self.parent: dict[ast.AST, ast.AST] = {}
        for node in ast.walk(self.tree):
            for child in ast.iter_child_nodes(node):
                self.parent[child] = node

    # scopes: the module and every function; a name is looked up innermost first (class bodies skipped,
    # as Python does for the functions inside them)
    def _scopes(self, node: ast.AST) -> list[ast.AST]:
        out = []
        while node in self.parent:
            node = self.parent[node]
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.Module)):
                out.append(node)
        return out

    def _own_nodes(self, scope: ast.AST):
        """The nodes of ``scope`` that are not inside a nested function or class."""
        stack = list(ast.iter_child_nodes(scope))
        while stack:
            node = stack.pop()
            yield node
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
                stack.extend(ast.iter_child_nodes(node))

    def _bindings(self, scope: ast.AST, name: str) -> list[ast.AST | str] | None:
        """What ``name`` is bound to in ``scope``: assigned values, ``"caught"``, ``"other"``; None if unbound."""
        found: list[ast.AST | str] = []
        if isinstance(scope, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            a = scope.args
            if any(arg.arg == name for arg in [*a.posonlyargs, *a.args, *a.kwonlyargs, a.vararg, a.kwarg] if arg):
                found.append("other")
        for node in self._own_nodes(scope):
            if isinstance(node, ast.ExceptHandler) and node.name == name:
                found.append("caught")
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.name == name:
                found.append("other")
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                if any((alias.asname or alias.name.split(".")[0]) == name for alias in node.names):
                    found.append("other")
            elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign, ast.NamedExpr)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                for t in targets:
                    if isinstance(t, ast.Name) and t.id == name and node.value is not None:
                        found.append(node.value)
                    elif any(isinstance(n, ast.Name) and n.id == name for n in ast.walk(t)):
                        found.append("unresolved")  # unpacked: cannot tell what it holds
            elif isinstance(node, (ast.For, ast.AsyncFor, ast.With, ast.AsyncWith, ast.comprehension)):
                targets = [node.target] if hasattr(node, "target") else [i.optional_vars for i in node.items]
                if any(isinstance(n, ast.Name) and n.id == name for t in targets if t for n in ast.walk(t)):
                    found.append("unresolved")
        return found or None

    def builtins_in(self, expr: ast.AST, depth: int = 0) -> set[str]:
        """The built-in exception classes ``expr`` may raise (``"?"``: cannot be resolved)."""
        if depth > 10:
            return {"?"}
        if isinstance(expr, ast.Call):  # an instance of the class called; a function's result is its own
            return self.builtins_in(expr.func, depth + 1) if self._is_classlike(expr.func) else set()
        if isinstance(expr, ast.Attribute):
            if isinstance(expr.value, ast.Name) and expr.value.id == "builtins" and expr.attr in BUILTIN_EXCEPTIONS:
                return {expr.attr}
            return set()  # a class of another module (errors.ConfigError, yaml.YAMLError, ...)
        if isinstance(expr, ast.BoolOp):
            return set().union(*(self.builtins_in(v, depth + 1) for v in expr.values))
        if isinstance(expr, ast.IfExp):
            return self.builtins_in(expr.body, depth + 1) | self.builtins_in(expr.orelse, depth + 1)
        if isinstance(expr, ast.Name):
            for scope in self._scopes(expr):
                bound = self._bindings(scope, expr.id)
                if bound is None:
                    continue
                out: set[str] = set()
                for b in bound:
                    if b == "unresolved":
                        out.add("?")
                    elif isinstance(b, ast.AST):
                        out |= self.builtins_in(b, depth + 1)
                    # "caught": re-raising the exception an enclosing handler caught; "other": not a built-in
                return out
            return {expr.id} if expr.id in BUILTIN_EXCEPTIONS else set()
        return {"?"}

    def _is_classlike(self, func: ast.AST) -> bool:
        # a call of a class (CapWords or a built-in exception name), not of a helper returning an error
        name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else None
        return name is not None and (name[:1].isupper() or name in BUILTIN_EXCEPTIONS)

    def _in_scripting_branch(self, node: ast.AST) -> bool:
        """``node`` is in the body (not the ``else``) of an ``if torch.jit.is_scripting():``."""
        child = node
        while child in self.parent:
            par = self.parent[child]
            if isinstance(par, ast.If) and ast.unparse(par.test) == "torch.jit.is_scripting()" and child in par.body:
                return True
            if isinstance(par, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                return False
            child = par
        return False

    def _function(self, node: ast.AST) -> str | None:
        while node in self.parent:
            node = self.parent[node]
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                return node.name
        return None

    def _allowed(self, node: ast.Raise, names: set[str]) -> bool:
        exc = node.exc
        if names == {"KeyboardInterrupt"}:  # the signal protocol: the bare class, nothing attached
            return isinstance(exc, ast.Name) and node.cause is None
        if names == {"ValueError"}:  # the TorchScript predictor's contract
            return isinstance(exc, ast.Call) and self._in_scripting_branch(node)
        if names == {"AttributeError"}:  # a module's __getattr__ (PEP 562): attribute look-up needs exactly it
            return self._function(node) == "__getattr__"
        if names == {"AssertionError"}:  # internal invariants, listed one by one
            return isinstance(exc, ast.Call) and (self.rel, self._function(node)) in ASSERTION_SITES
        return False

    def violations(self) -> list[str]:
        out = []
        raised_calls = set()
        for node in ast.walk(self.tree):
            if isinstance(node, ast.Raise) and node.exc is not None:
                raised_calls.update(ast.walk(node.exc))
                names = self.builtins_in(node.exc)
                if names and not self._allowed(node, names):
                    out.append(f"{self.rel}:{node.lineno}: {ast.unparse(node)[:120]}  [{', '.join(sorted(names))}]")
        for node in ast.walk(self.tree):  # a built-in exception built elsewhere (returned, stored) to be raised later
            if isinstance(node, ast.Call) and node not in raised_calls and self._is_classlike(node.func):
                names = self.builtins_in(node.func) - {"?"}
                if names and not all(issubclass(getattr(builtins, n), Warning) for n in names):
                    out.append(f"{self.rel}:{node.lineno}: {ast.unparse(node)[:120]}  [built, {', '.join(sorted(names))}]")
        return out


def builtin_raises(source: str, rel: str = "module.py") -> list[str]:
    return _Checker(source, rel).violations()


def test_bemlearn_raises_no_builtin_exception():
    files = sorted(PACKAGE.rglob("*.py"))
    assert len(files) > 100
    found = [v for p in files for v in builtin_raises(p.read_text(encoding="utf-8"), p.relative_to(PACKAGE).as_posix())]
    assert found == [], "built-in exceptions raised in bemlearn/ (raise a bemlearn.errors class):\n" + "\n".join(found)


def test_the_allowed_builtins_are_where_the_docstring_says():
    """The four exceptions of errors.py's docstring occur in the package (the allowances are not dead)."""
    allowed = {"KeyboardInterrupt": 0, "ValueError": 0, "AssertionError": 0, "AttributeError": 0}
    for p in PACKAGE.rglob("*.py"):
        checker = _Checker(p.read_text(encoding="utf-8"), p.relative_to(PACKAGE).as_posix())
        for node in ast.walk(checker.tree):
            if isinstance(node, ast.Raise) and node.exc is not None:
                names = checker.builtins_in(node.exc)
                if len(names) == 1 and next(iter(names)) in allowed:
                    allowed[next(iter(names))] += 1
    assert all(allowed.values()), allowed
    for name in allowed:
        assert f"``{name}``" in errors.__doc__


@pytest.mark.parametrize("source", [
    "raise ValueError('x')",
    "raise ValueError('x') from None",
    "def f(e):\n    raise RuntimeError('x') from e",
    "raise TypeError",
    "raise builtins.OSError('x')",
    "def f():\n    err = KeyError('k')\n    raise err",
    "Err = FileNotFoundError\ndef f():\n    raise Err('x')",
    "def f(ok):\n    raise ValueError('a') if ok else IndexError('b')",
    "def f():\n    return ValueError('built here, raised by the caller')",
    "raise KeyboardInterrupt('with a message')",
    "raise KeyboardInterrupt from None",
    "raise AssertionError('not a listed invariant')",
    "if torch.jit.is_scripting():\n    pass\nelse:\n    raise ValueError('eager code')",
    "if torch.jit.is_tracing():\n    raise ValueError('x')",
    "def f():\n    a, b = g()\n    raise a",
])
def test_the_ast_check_finds_builtin_raises(source):
    assert builtin_raises(source), source


@pytest.mark.parametrize("source", [
    "from bemlearn.errors import ConfigError\nraise ConfigError('x')",
    "raise errors.DataError('x') from None",
    "raise KeyboardInterrupt",
    "def f():\n    if torch.jit.is_scripting():\n        raise ValueError('the TorchScript contract')",
    "def f():\n    try:\n        g()\n    except OSError as exc:\n        raise (problem(exc) or exc) from None",
    "class ValueError(Exception):\n    pass\nraise ValueError('a module of its own ValueError')",
    "try:\n    g()\nexcept ValueError:\n    raise",
    "warnings.warn(RuntimeWarning('a warning is not raised'))",
])
def test_the_ast_check_allows_the_documented_cases(source):
    assert builtin_raises(source) == []


def test_assertion_error_is_allowed_only_at_its_listed_site():
    source = "def c_sources():\n    raise AssertionError('posteriors must agree')\n"
    assert builtin_raises(source, "export/c_source.py") == []
    assert len(builtin_raises(source, "export/c_export.py")) == 1


# ---- the family ------------------------------------------------------------------------------------
FAMILY = {
    "ConfigError": (ValueError,),
    "ArgumentError": (ValueError, TypeError),
    "DataError": (ValueError,),
    "TrajectoryFormatError": (ValueError,),
    "RobotModelError": (ValueError,),
    "CheckpointError": (ValueError,),
    "StalePredictorError": (ValueError,),
    "PredictorInputError": (ValueError,),
    "MissingFileError": (FileNotFoundError,),
    "OutputExistsError": (FileExistsError,),
    "OutputBusyError": (FileExistsError,),
    "NumericalError": (RuntimeError,),
    "EnvironmentProblem": (RuntimeError,),
    "SweepError": (RuntimeError,),
}


def test_every_family_class_derives_from_the_base_and_its_builtin():
    assert set(errors.__all__) == {"BemlearnError", *FAMILY}
    assert errors.BemlearnError.__bases__ == (Exception,)
    for name, bases in FAMILY.items():
        cls = getattr(errors, name)
        assert issubclass(cls, errors.BemlearnError), name
        for base in bases:
            assert issubclass(cls, base), (name, base)
        assert name in errors.__doc__, f"errors.py's docstring does not describe {name}"
        assert getattr(bemlearn, name) is cls  # importable from the package
    assert issubclass(errors.OutputBusyError, errors.OutputExistsError)
    assert issubclass(NumericalFailure, errors.NumericalError)
    # existing ``except ValueError`` code keeps catching what it caught
    with pytest.raises(ValueError):
        raise errors.ConfigError("x")
    with pytest.raises(TypeError):
        raise errors.ArgumentError("x")


# ---- the command line ------------------------------------------------------------------------------
def test_a_family_error_is_one_line_and_exit_2(tmp_path):
    """The real command line (a subprocess): one line on stderr, no traceback."""
    missing = tmp_path / "missing.yaml"
    proc = subprocess.run([sys.executable, "-m", "bemlearn", "config", "show", str(missing)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.splitlines() == [f"bemlearn config: error: {missing}: config file not found"]
    assert proc.stdout == ""


def test_an_unknown_config_key_is_one_line_and_exit_2(tmp_path, capsys):
    cfg = tmp_path / "c.yaml"
    cfg.write_text((ROOT / "configs" / "furuta.yaml").read_text() + "\nnot_a_key: 1\n")
    assert main(["config", "show", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith("bemlearn config: error: ") and "not_a_key" in err
    assert "Traceback" not in err


def test_verbose_shows_the_traceback_of_a_family_error(tmp_path, capsys):
    assert main(["-v", "config", "show", str(tmp_path / "missing.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("Traceback (most recent call last):")
    assert "bemlearn.errors.ConfigError:" in err
    assert err.splitlines()[-1] == f"bemlearn config: error: {tmp_path / 'missing.yaml'}: config file not found"


def test_any_other_exception_is_a_bug_with_its_traceback_and_exit_1(monkeypatch, capsys):
    def broken(args):
        return {}["a_key_bemlearn_forgot"]

    monkeypatch.setattr(config_cmd, "_show", broken)
    assert main(["config", "show", "configs/furuta.yaml"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("Traceback (most recent call last):")
    assert "KeyError: 'a_key_bemlearn_forgot'" in err and "in broken" in err
    assert "bemlearn config: internal error (KeyError)" in err.splitlines()[-1]
    assert "bemlearn config: error:" not in err


def test_a_builtin_value_error_is_a_bug_not_a_user_error(monkeypatch, capsys):
    def broken(args):
        _a, _b = [1, 2, 3]  # a shape bug

    monkeypatch.setattr(config_cmd, "_show", broken)
    assert main(["config", "show", "configs/furuta.yaml"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "ValueError: too many values to unpack" in err


# ---- loss evaluation -------------------------------------------------------------------------------
def _unpack_bug():
    x, y = torch.ones(3)  # a shape bug: ValueError
    return x + y


def test_checked_loss_lets_a_shape_bug_through():
    with pytest.raises(ValueError, match="too many values to unpack") as info:
        checked_loss(_unpack_bug)
    assert not isinstance(info.value, NumericalFailure)


def test_checked_loss_turns_numerical_failures_into_numerical_failure():
    not_psd = torch.tensor([[1.0, 2.0], [2.0, 1.0]], dtype=torch.float64)
    with pytest.raises(NumericalFailure) as info:
        checked_loss(lambda: psd_safe_cholesky(not_psd, max_tries=1).sum())
    assert type(info.value.__cause__).__name__ == "NotPSDError"
    with pytest.raises(NumericalFailure, match="loss is nan"):
        checked_loss(lambda: torch.tensor(float("nan")))
    with pytest.raises(NumericalFailure):
        checked_loss(lambda: torch.linalg.cholesky(not_psd).sum())  # torch.linalg.LinAlgError
    assert float(checked_loss(lambda: torch.tensor(2.0))) == 2.0


def _quadratic(bug: str):
    """A loss (p - 1)² that fails once p goes below 1.5: with a shape bug or with NaN."""
    p = torch.nn.Parameter(torch.tensor([2.0], dtype=torch.float64))

    def loss():
        if float(p.detach()) < 1.5:
            if bug == "shape":
                _a, _b = p  # ValueError: not enough values to unpack
            return (p * float("nan")).sum()
        return ((p - 1.0) ** 2).sum()

    return p, loss


@pytest.mark.parametrize("optimizer", ["lbfgs", "adam"])
def test_minimize_propagates_a_shape_bug_in_the_loss(optimizer):
    p, loss = _quadratic("shape")
    with pytest.raises(ValueError, match="not enough values to unpack") as info:
        minimize(loss, [p], optimizer=optimizer, max_iter=200, lr=1.0, tol=0.0, metrics_fn=dict)
    assert not isinstance(info.value, NumericalFailure)


@pytest.mark.parametrize("optimizer", ["lbfgs", "adam"])
def test_minimize_keeps_the_best_parameters_on_a_numerical_failure(optimizer):
    p, loss = _quadratic("nan")
    result = minimize(loss, [p], optimizer=optimizer, max_iter=200, lr=1.0, tol=0.0, metrics_fn=dict)
    final, evals, stop = result.loss, result.steps, result.stop_reason
    assert stop == "numerical failure" and evals >= 1
    assert float(p.detach()) >= 1.5 and final == pytest.approx((float(p.detach()) - 1.0) ** 2)
