"""A warning family a caller can filter (issue 30): every condition a caller may act on is a
``warnings.warn`` of :mod:`bemlearn.warnings` (and its log line), listed in docs/warnings.md;
escalated, it raises; the ``bemlearn`` command shows it once."""

from __future__ import annotations

import ast
import logging
import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import torch
from linear_operator.utils.warnings import NumericalWarning as GPyTorchNumericalWarning

import bemlearn
from bemlearn import warnings as bw
from bemlearn.fitting.optimize import minimize
from bemlearn.models.solver import cholesky_policy, robust_cholesky

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "bemlearn"
DOC = (ROOT / "docs" / "warnings.md").read_text()

#: Class → the built-in warning it also is (besides UserWarning through the base).
FAMILY = {
    "DataWarning": None,
    "RobotModelWarning": None,
    "DesignWarning": None,
    "NumericalWarning": RuntimeWarning,
    "FitWarning": RuntimeWarning,
    "UncertaintyWarning": None,
    "EnvironmentWarning": RuntimeWarning,
}

#: ``log.warning`` calls that stay log lines (docs/warnings.md, "Log lines that are not warnings"): file → count.
LOG_ONLY = {
    "interrupts.py": 1, "fitting/optimize.py": 1, "pipeline/gp_stage.py": 2, "outputs.py": 2, "export/staleness.py": 1,
    "pipeline/run.py": 2, "sweep/driver.py": 3,
}
#: ``log.warning`` calls that are the log line of a warning: :func:`bemlearn.warnings.warn`'s own, and the
#: one beside GPyTorch's re-issued NumericalWarning.
WARNING_LOG_LINES = {"warnings.py": 1, "models/solver.py": 1}


def test_the_family():
    assert set(bw.__all__) == {"BemlearnWarning", *FAMILY, "warn", "shown_by_log", "issued"}
    assert bw.BemlearnWarning.__bases__ == (UserWarning,)
    for name, builtin in FAMILY.items():
        cls = getattr(bw, name)
        assert issubclass(cls, bw.BemlearnWarning) and (builtin is None or issubclass(cls, builtin)), name
        assert f"`{name}`" in DOC and name in bw.__doc__, f"{name} is not described in docs/warnings.md and the module docstring"
        assert getattr(bemlearn, name) is cls  # importable from the package, as the errors are
    assert not issubclass(bw.BemlearnWarning, bemlearn.BemlearnError)


def _calls(path: Path) -> tuple[list[str], int]:
    """The categories of the module's ``warn(Category, logger, ...)`` calls, and its count of ``<logger>.warning(...)``."""
    cats, logs = [], 0
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Name) and f.id == "warn" and node.args and isinstance(node.args[0], ast.Name):
            cats.append(node.args[0].id)
        elif isinstance(f, ast.Attribute) and f.attr == "warning" and isinstance(f.value, ast.Name) and f.value.id in ("log", "logger"):
            logs += 1
    return cats, logs


def test_every_warning_is_listed_and_every_other_log_warning_is_known():
    issued, log_only = {}, {}
    for p in sorted(PACKAGE.rglob("*.py")):
        rel = p.relative_to(PACKAGE).as_posix()
        cats, logs = _calls(p)
        if cats and rel != "warnings.py":
            issued[rel] = cats
        if logs:
            log_only[rel] = logs
    rows = [line for line in DOC.splitlines() if line.startswith("| `") and "Warning` | " in line]
    for rel, cats in issued.items():
        for cat in set(cats):
            assert any(f"| `{cat}` |" in r and f"`{rel}`" in r for r in rows), f"docs/warnings.md lists no {cat} of {rel}"
    assert sum(len(c) for c in issued.values()) == 28  # and GPyTorch's NumericalWarning re-issued by models/solver.py:
    assert "warnings.warn_explicit(NumericalWarning(" in (PACKAGE / "models" / "solver.py").read_text()
    assert log_only == {**LOG_ONLY, **WARNING_LOG_LINES}, "a new log.warning: if a caller could act on it, issue it with bemlearn.warnings.warn"
    for rel in LOG_ONLY:
        assert f"`{rel}`" in DOC.split("## Log lines that are not warnings")[1]


def _singular() -> torch.Tensor:
    v = torch.tensor([[1.0], [2.0], [3.0]], dtype=torch.float64)
    return v @ v.T  # rank 1: the Cholesky needs jitter


def test_a_warning_is_issued_at_the_callers_line_and_logged(caplog):
    with caplog.at_level(logging.WARNING, logger="bemlearn.models.solver"), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, j = robust_cholesky(_singular(), what="a rank-1 matrix")
    ours = [w for w in caught if issubclass(w.category, bw.BemlearnWarning)]
    assert j > 0 and len(ours) >= 1 and all(w.category is bw.NumericalWarning for w in ours)
    assert all(w.filename == __file__ for w in ours)  # the first frame outside bemlearn: this test
    assert "a rank-1 matrix not positive definite; added jitter" in str(ours[0].message)
    logged = [r for r in caplog.records if "a rank-1 matrix" in r.getMessage()]
    assert len(logged) == len(ours) and logged[0].funcName == "robust_cholesky"


def test_a_caller_can_escalate_or_silence_one_class():
    with warnings.catch_warnings():
        warnings.simplefilter("error", bw.NumericalWarning)
        with pytest.raises(bw.NumericalWarning, match="a rank-1 matrix not positive definite"):
            robust_cholesky(_singular(), what="a rank-1 matrix")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.simplefilter("ignore", bw.NumericalWarning)
        _, j = robust_cholesky(_singular(), what="a rank-1 matrix")
    assert j > 0 and not [w for w in caught if issubclass(w.category, bw.BemlearnWarning)]
    with warnings.catch_warnings():  # the base class escalates every member
        warnings.simplefilter("error", bw.BemlearnWarning)
        with pytest.raises(RuntimeWarning):
            robust_cholesky(_singular(), what="a rank-1 matrix")


def test_a_fit_that_fails_numerically_can_be_made_an_error():
    def problem():
        """(p − 1)², NaN once p goes below 1.5 (the fit then keeps the best p ≥ 1.5)."""
        p = torch.nn.Parameter(torch.tensor([2.0], dtype=torch.float64))
        return p, lambda: (p * float("nan")).sum() if float(p.detach()) < 1.5 else ((p - 1.0) ** 2).sum()

    p, loss = problem()
    with warnings.catch_warnings():
        warnings.simplefilter("error", bw.FitWarning)
        with pytest.raises(bw.FitWarning, match="numerical failure after"):
            minimize(loss, [p], optimizer="adam", max_iter=200, lr=1.0, tol=0.0, metrics_fn=dict)
    p, loss = problem()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", bw.FitWarning)
        res = minimize(loss, [p], optimizer="adam", max_iter=200, lr=1.0, tol=0.0, metrics_fn=dict)
    assert res.stop_reason == "numerical failure" and [w.category for w in caught] == [bw.FitWarning]
    assert float(p.detach()) >= 1.5


def test_gpytorch_numerical_warnings_are_reissued_as_bemlearns():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with cholesky_policy():
            warnings.warn("A not p.d., added jitter of 1.0e-08 to the diagonal", GPyTorchNumericalWarning, stacklevel=1)
    assert [(w.category, str(w.message)) for w in caught] == [(bw.NumericalWarning, "A not p.d., added jitter of 1.0e-08 to the diagonal")]
    with warnings.catch_warnings(), cholesky_policy():
        warnings.simplefilter("error", bw.NumericalWarning)
        with pytest.raises(bw.NumericalWarning):
            warnings.warn("A not p.d.", GPyTorchNumericalWarning, stacklevel=1)


def test_shown_by_log_hides_only_bemlearn_warnings_and_restores_the_display():
    shown: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = lambda message, *args, **kwargs: shown.append(str(message))
        display = warnings.showwarning
        with bw.shown_by_log():
            warnings.warn("shown by its log line", bw.DataWarning, stacklevel=1)
            warnings.warn("an ordinary warning", UserWarning, stacklevel=1)
        assert warnings.showwarning is display
        warnings.warn("shown again outside", bw.DataWarning, stacklevel=1)
    assert shown == ["an ordinary warning", "shown again outside"]


def _robot_with_equality(tmp_path: Path) -> Path:
    xml = (ROOT / "tests" / "robots" / "cartpole.xml").read_text()
    out = tmp_path / "cartpole_eq.xml"
    out.write_text(xml.replace("  <actuator>", '  <equality>\n    <joint joint1="slider" joint2="hinge" active="false"/>\n  </equality>\n  <actuator>'))
    return out


@pytest.mark.parametrize("escalate", [False, True])
def test_the_command_shows_a_warning_once_or_stops_on_it(tmp_path, escalate):
    robot = _robot_with_equality(tmp_path)
    flags = ["-W", "error::bemlearn.warnings.RobotModelWarning"] if escalate else []
    # -W imports the category's module at start-up, before the working directory is on sys.path
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    done = subprocess.run([sys.executable, *flags, "-m", "bemlearn", "robot", "info", str(robot)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    message = f"{robot}: equality constraints are ignored by the robot dynamics"
    if escalate:
        # (other libraries may log at start-up, e.g. PyOpenGL when MUJOCO_GL is set: only bemlearn's lines are checked)
        assert done.returncode == 2 and done.stderr.strip().splitlines()[-1] == f"bemlearn robot: error: {message}"
        assert "Traceback" not in done.stderr and done.stderr.count(message) == 1
    else:
        assert done.returncode == 0 and "upright" in done.stdout
        assert done.stderr.count(message) == 1 and re.search(rf"^WARNING bemlearn\.robots\.mujoco_robot: {re.escape(message)}$",
                                                             done.stderr, flags=re.M)
        assert "RobotModelWarning" not in done.stderr
