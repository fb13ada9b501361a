"""bemlearn installed as a user installs it: the wheel built from this tree, in a fresh virtual environment, used
from an empty folder far from the source tree.

Nothing is downloaded: the wheel is built without isolation (``pip wheel --no-deps --no-build-isolation``,
from a copy of the tree, so the source tree gets no ``build/``), and the environment sees the dependencies
already installed (``--system-site-packages``) while the wheel is installed with ``--no-deps --no-index``.
The full ``bemlearn run furuta`` in such an environment is measured once, not here (docs/timings.md).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow  # about 2 minutes on the 2-core VM: a wheel build, a venv and a GP fit in it

SKIP = shutil.ignore_patterns(".git", "runs", "site", "build", "dist", "*.egg-info", "__pycache__", ".*_cache", "*.pyc")


def _run(cmd: list[str], cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)
    assert done.returncode == 0, f"{' '.join(map(str, cmd))}: exit {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    return done


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(python of a fresh venv holding the built wheel, an empty folder outside the tree)."""
    base = tmp_path_factory.mktemp("wheel")
    src = base / "src"
    shutil.copytree(ROOT, src, symlinks=True, ignore=SKIP)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(base / "dist"), str(src)], base)
    (wheel,) = (base / "dist").glob("bemlearn-*.whl")
    env_dir = base / "venv"
    venv.EnvBuilder(system_site_packages=True, with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index", "-q", str(wheel)], base)
    empty = base / "empty"
    empty.mkdir()
    return python, empty


def test_the_wheel_is_what_runs(installed):
    python, empty = installed
    where = _run([str(python), "-c", "import bemlearn; print(bemlearn.__file__)"], empty).stdout.strip()
    assert where.startswith(str(python.parent.parent)) and "site-packages" in where, where


def test_bemlearn_examples_lists_the_shipped_configs(installed):
    python, empty = installed
    out = _run([str(python), "-m", "bemlearn", "examples"], empty).stdout
    names = [line.split()[0] for line in out.splitlines()[1:]]
    assert {"furuta", "biped", "sweeps/example"} <= set(names), out
    assert "site-packages" in out.splitlines()[0]
    shown = _run([str(python), "-m", "bemlearn", "config", "show", "furuta"], empty).stdout
    assert re.search(r"^collect\.rate_hz\s+400\.0\s+given", shown, flags=re.M), shown[:2000]  # the paper's setup, not a derived 200 Hz
    _run([str(python), "-m", "bemlearn", "sweep", "sweeps/example", "--dry-run"], empty)  # its robots found beside it
    _run([str(python), "-m", "bemlearn", "examples", "copy", "mine"], empty)
    assert (empty / "mine" / "configs" / "furuta.yaml").is_file() and (empty / "mine" / "tests" / "robots" / "cartpole.xml").is_file()
    assert (empty / "mine" / "data" / "furuta_excitation.npz").stat().st_size > 10**6
    assert not list(empty.glob("runs*"))


def test_the_readme_api_tour_runs_from_an_empty_folder(installed):
    python, empty = installed
    readme = (ROOT / "README.md").read_text()
    (tour,) = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    script = empty / "tour.py"
    script.write_text(tour)
    out = _run([str(python), str(script)], empty).stdout
    assert "tensor(" in out and "True" in out  # the BEM and its validity, then the learned mean and std
