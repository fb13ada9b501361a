"""Robot files against hostile content (issue 29, items 8 and 9; bemlearn.robots.mjcf_compile)."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest

from bemlearn.errors import RobotModelError
from bemlearn.robots import load, mjcf_compile

REPO = Path(__file__).resolve().parents[1]
CARTPOLE = REPO / "tests" / "robots" / "cartpole.xml"


@pytest.mark.parametrize("attr, value", [("mass", "nan"), ("mass", "inf"), ("size", "0.02 NaN"), ("pos", "0 -inf 0")])
def test_a_non_finite_attribute_is_refused_naming_the_file_and_attribute(tmp_path, attr, value):
    """Item 9: a geom with mass="nan" silently became a density mass of 0.279 kg."""
    text = CARTPOLE.read_text()
    start = text.index("<geom")
    bad = tmp_path / "nan_robot.xml"
    bad.write_text(text[:start] + f'<geom {attr}="{value}" ' + text[start + len("<geom"):].replace(f' {attr}="', ' x_old="', 1))
    with pytest.raises(RobotModelError, match=rf'nan_robot.xml: <geom( name="[^"]*")? {attr}="{value}">: {attr} is not finite'):
        load(str(bad))


def test_a_non_finite_attribute_in_an_included_file_is_refused(tmp_path):
    (tmp_path / "part.xml").write_text('<mujocoinclude><body name="extra" pos="0 0 2"><geom type="sphere" size="0.1" '
                                       'mass="-inf"/></body></mujocoinclude>')
    text = CARTPOLE.read_text()
    main = tmp_path / "with_include.xml"
    main.write_text(text.replace("<worldbody>", '<worldbody><include file="part.xml"/>', 1))
    with pytest.raises(RobotModelError, match=r'part.xml: <geom mass="-inf">: mass is not finite'):
        load(str(main))


def test_a_model_compiled_in_a_child_is_the_model(monkeypatch):
    monkeypatch.setattr(mjcf_compile, "CHILD_COMPILE_BYTES", 1)
    child = mjcf_compile.compile_mjcf(CARTPOLE)
    direct = mujoco.MjModel.from_xml_path(str(CARTPOLE))
    for name in ("body_mass", "body_inertia", "jnt_range", "actuator_gear", "geom_size", "dof_damping"):
        np.testing.assert_array_equal(getattr(child, name), getattr(direct, name))


def test_a_compile_error_in_the_child_is_one_named_error(monkeypatch, tmp_path):
    monkeypatch.setattr(mjcf_compile, "CHILD_COMPILE_BYTES", 1)
    bad = tmp_path / "bad.xml"
    bad.write_text('<mujoco><worldbody><body><joint type="nonsense"/></body></worldbody></mujoco>')
    with pytest.raises(RobotModelError, match="bad.xml: MuJoCo could not load the model"):
        mjcf_compile.compile_mjcf(bad)


def _big_mjcf(path: Path, n_bodies: int) -> Path:
    """``n_bodies`` free-standing hinged capsules: MuJoCo compiles this in O(n²) (5000: 4 s, 12000: about 20 s on an idle core here)."""
    bodies = "".join(f'<body name="b{i}" pos="{i * 0.01:.2f} 0 1"><joint name="j{i}" type="hinge" axis="0 1 0"/>'
                     f'<geom type="capsule" size="0.01 0.05" mass="0.1"/></body>' for i in range(n_bodies))
    path.write_text(f'<mujoco model="big"><option timestep="0.002"/><worldbody>{bodies}</worldbody></mujoco>')
    return path


@pytest.mark.parametrize("sig", [signal.SIGTERM, pytest.param(signal.SIGINT, marks=pytest.mark.slow)])
def test_a_signal_ends_the_command_while_mujoco_compiles(tmp_path, sig):
    """Item 8: SIGTERM waited for MuJoCo's compiler (55 s at 3·10⁴ bodies, > 10 min at 10⁵)."""
    big = _big_mjcf(tmp_path / "big.xml", 12000)
    assert big.stat().st_size > mjcf_compile.CHILD_COMPILE_BYTES
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    small = tmp_path / "small.yaml"
    small.write_text(f"robot: {CARTPOLE}\n")
    t0 = time.monotonic()   # how long the command takes without the big model: imports, derivation
    subprocess.run([sys.executable, "-m", "bemlearn", "config", "show", str(small)], cwd=tmp_path, capture_output=True,
                   check=True, env=env, timeout=300)
    startup = time.monotonic() - t0
    cfg = tmp_path / "big.yaml"
    cfg.write_text(f"robot: {big}\n")
    proc = subprocess.Popen([sys.executable, "-m", "bemlearn", "config", "show", str(cfg)], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    time.sleep(startup + 3.0)   # past the imports, inside the compilation (about 20 s)
    assert proc.poll() is None, proc.communicate()
    sent = time.monotonic()
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    elapsed = time.monotonic() - sent
    assert proc.returncode == 128 + int(sig), err[-2000:]
    assert elapsed <= 5.0, (elapsed, err[-2000:])
