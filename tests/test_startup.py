"""``bemlearn --help`` and ``bemlearn config show`` load no heavy library they do not use (issue 23).

The start-up time of the command is set by what it imports: torch alone takes two to three
seconds here, GPyTorch, MuJoCo, SciPy and Matplotlib a few tenths each.  Each check runs in a fresh
interpreter and reads ``sys.modules`` afterwards, so it does not depend on the machine's speed
(``python scripts/measure_timings.py --only-startup`` measures the seconds).
"""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Packages whose public names are imported on first use (``bemlearn._lazy``).
LAZY_PACKAGES = ("bench", "control", "data", "fitting", "pipeline", "robots", "sim", "sweep")

_PROBE = """
import contextlib, io, json, sys
from bemlearn.cli.main import main
out = io.StringIO()
with contextlib.redirect_stdout(out):
    try:
        status = main(sys.argv[1:])
    except SystemExit as exc:  # --help exits through argparse
        status = exc.code
heavy = {heavy!r}
print(json.dumps({{"status": status, "loaded": sorted(m for m in heavy if m in sys.modules), "out": out.getvalue()}}))
"""


def _run(argv: list[str], heavy: tuple[str, ...]) -> dict:
    done = subprocess.run([sys.executable, "-c", _PROBE.format(heavy=heavy), *argv], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_help_loads_no_heavy_library():
    heavy = ("torch", "gpytorch", "linear_operator", "mujoco", "matplotlib", "scipy", "numpy", "ray",
             "pytorch_kinematics", "tqdm")
    res = _run(["--help"], heavy)
    assert res["status"] == 0 and "config" in res["out"] and "run" in res["out"]
    assert res["loaded"] == [], f"bemlearn --help imported {res['loaded']}"


def test_config_show_loads_only_what_deriving_the_defaults_needs():
    """Deriving the defaults loads the robot's MuJoCo model and works in NumPy: torch, the GP stack,
    plotting, kinematics and Ray stay unloaded; SciPy too when the config gives the excitation gains."""
    heavy = ("torch", "gpytorch", "linear_operator", "matplotlib", "ray", "pytorch_kinematics", "scipy")
    res = _run(["config", "show", "configs/furuta.yaml"], heavy)
    assert res["status"] == 0 and "collect.n_trials" in res["out"]
    assert res["loaded"] == [], f"bemlearn config show imported {res['loaded']}"


def test_config_show_of_a_robot_file_alone_loads_no_torch(tmp_path):
    """A zero-config file derives everything (the excitation LQR loads SciPy), still without torch."""
    config = tmp_path / "robot.yaml"
    config.write_text(f"robot: {ROOT / 'tests' / 'robots' / 'cartpole.xml'}\n")
    res = _run(["config", "show", str(config)], ("torch", "gpytorch", "linear_operator", "matplotlib", "ray", "pytorch_kinematics"))
    assert res["status"] == 0 and "collect.gains" in res["out"] and "derived" in res["out"]
    assert res["loaded"] == [], f"bemlearn config show imported {res['loaded']}"


@pytest.mark.parametrize("package", LAZY_PACKAGES)
def test_lazy_package_exports_every_public_name(package):
    """``__all__``, ``dir()`` and the ``if TYPE_CHECKING:`` imports (what type checkers read) agree,
    and every name resolves to the object of the module that defines it."""
    from bemlearn._lazy import lazy_exports

    mod = importlib.import_module(f"bemlearn.{package}")
    exports = lazy_exports(mod.__file__)
    assert sorted(exports) == sorted(mod.__all__)
    assert set(mod.__all__) <= set(dir(mod))
    for name, (module, attr) in exports.items():
        assert getattr(mod, name) is getattr(importlib.import_module(module), attr), name


def test_lazy_package_keeps_attribute_errors_and_submodules():
    import bemlearn.data

    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        bemlearn.data.no_such_name  # noqa: B018
    from bemlearn.data import build_datasets
    from bemlearn.data.dataset import build_datasets as direct

    assert build_datasets is direct
    assert bemlearn.data.trajectory_io.read_trajectory is bemlearn.data.read_trajectory
