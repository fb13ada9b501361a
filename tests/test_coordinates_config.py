"""The config's ``coordinates:`` block (bemlearn.robots.coordinates): the MJCF's ``<custom>`` declarations written
beside the file, recorded with the run's robot."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bemlearn.config import from_dict
from bemlearn.errors import ConfigError, RobotModelError
from bemlearn.pipeline.config import PipelineConfig
from bemlearn.pipeline.robot_source import run_robot
from bemlearn.robots import MujocoRobot, RobotRef, resolve_robot
from bemlearn.robots.coordinates import CoordinatesConfig, custom_entries

ROBOTS = Path(__file__).parent / "robots"
BOOM, HUB, RADIUS = 0.8, 0.06, 0.06   # boom length (m), hub height, tyre radius


def _boom(custom: str = "") -> str:
    """A wheeled pendulum on a boom: the boom turns about the vertical at the origin (hinge ``boom``), the pendulum
    pitches about the radial axis at its end (``pitch``) and carries the driven wheel on its pivot (``wheel``).
    Rolling: BOOM ψ̇ = −r_eff (θ̇ + φ̇); the boom or the pendulum could be solved for, and neither is a slide.  A ball
    wheel: one contact point (a cylinder's two rim contacts at different distances from the boom's axis would scrub)."""
    return f"""<mujoco model="boom_wheel">
  <compiler angle="radian" inertiafromgeom="false"/>
  <option timestep="0.002"/>
  {custom}
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <geom name="ground" type="plane" size="5 5 0.1" contype="1" conaffinity="1"/>
    <body name="arm" pos="0 0 {HUB - 0.0005}">
      <joint name="boom" type="hinge" axis="0 0 1" damping="0.01"/>
      <inertial pos="{BOOM / 2} 0 0" mass="0.4" diaginertia="0.0001 0.02 0.02"/>
      <body name="body" pos="{BOOM} 0 0">
        <joint name="pitch" type="hinge" axis="1 0 0" range="-1.2 1.2"/>
        <inertial pos="0 0 0.15" mass="1.0" diaginertia="0.01 0.01 0.002"/>
        <body name="wheel"><joint name="wheel" type="hinge" axis="1 0 0"/>
          <inertial pos="0 0 0" mass="0.2" diaginertia="0.0004 0.0002 0.0002"/>
          <geom name="tyre" type="sphere" size="{RADIUS}" contype="1" conaffinity="1"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="wheel" ctrlrange="-2 2"/></actuator>
</mujoco>"""


@pytest.fixture
def boom(tmp_path) -> Path:
    path = tmp_path / "boom_wheel.xml"
    path.write_text(_boom())
    return path


def test_an_ambiguous_rolling_choice_is_refused_naming_the_choices_and_the_block(boom):
    with pytest.raises(RobotModelError, match=r"ambiguous: \(boom\) or \(pitch\).*coordinates: rolling_dependent"):
        resolve_robot(boom)


def test_the_block_names_the_rolling_joint_as_the_mjcf_custom_would(boom, tmp_path):
    robot, ref = resolve_robot(boom, coordinates={"rolling_dependent": ["boom"]})
    assert isinstance(robot, MujocoRobot) and robot.rolling is not None
    assert robot.joint_names == ("pitch", "wheel") and robot.unactuated_name == "pitch"
    assert [robot.mjcf_joint_names[j] for j in robot.rolling.dependent] == ["boom"]
    # no slip at the contact, half the penetration below the hub: turning the wheel by +θ about +x moves its hub by
    # −r_eff θ along y, and the boom's end moves by +BOOM ψ along y: BOOM ψ = −r_eff (θ + φ)
    r_eff = RADIUS - 0.5 * (RADIUS - (HUB - 0.0005))
    S = robot.Tinv_np
    np.testing.assert_allclose(S[0], [-r_eff / BOOM, -r_eff / BOOM], rtol=1e-9)
    # the same declaration in the file gives the same robot, number for number
    inline = tmp_path / "inline.xml"
    inline.write_text(_boom('<custom><text name="bemlearn_rolling_dependent" data="boom"/></custom>'))
    other = MujocoRobot.from_xml(inline)
    q, qd = np.array([0.1, -0.3]), np.array([0.4, 2.0])
    for a, b in zip(robot.terms(q, qd), other.terms(q, qd)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(robot.input_matrix_np, other.input_matrix_np)
    # recorded with the run's robot: a reload has the same coordinates
    again = RobotRef.from_dict(ref.to_dict()).load()
    assert ref.to_dict()["coordinates"] == {"rolling_dependent": ["boom"]}
    np.testing.assert_array_equal(again.Tinv_np, robot.Tinv_np)


def test_a_rolling_choice_that_does_not_fit_is_refused(boom):
    with pytest.raises(RobotModelError, match=r"rolling_dependent \['wheel'\] cannot be.*\(boom\) or \(pitch\)"):
        resolve_robot(boom, coordinates={"rolling_dependent": ["wheel"]})
    with pytest.raises(RobotModelError, match=r"names \['chassis'\], which are not joints"):
        resolve_robot(boom, coordinates={"rolling_dependent": ["chassis"]})


def test_the_block_overrides_the_upright_and_the_bracket():
    plain = resolve_robot(ROBOTS / "cartpole.xml")[0]
    robot = resolve_robot(ROBOTS / "cartpole.xml", coordinates={"qu_nominal": 0.05, "qu_range": [-0.4, 0.5]})[0]
    assert plain.qu_nominal == 0.0 and robot.qu_nominal == 0.05 and robot.qu_range == (-0.4, 0.5)
    assert "declared by the config (coordinates: qu_nominal)" in robot.qu_nominal_note


def test_a_linear_map_matches_the_mjcf_custom_numerics(tmp_path):
    """The pendubot in (shoulder, absolute = shoulder + elbow): D = T⁻ᵀ D_j T⁻¹, identical to the file's own custom."""
    T = [[1.0, 0.0], [1.0, 1.0]]
    robot = resolve_robot(ROBOTS / "pendubot.xml", coordinates={"map": T, "names": ["shoulder", "absolute"]})[0]
    text = (ROBOTS / "pendubot.xml").read_text()
    custom = ('<custom><numeric name="bemlearn_coordinates" data="1 0 1 1"/>'
              '<text name="bemlearn_coordinate_names" data="shoulder absolute"/></custom>')
    inline = tmp_path / "pendubot_abs.xml"
    inline.write_text(text.replace("<worldbody>", custom + "<worldbody>", 1))
    other = MujocoRobot.from_xml(inline)
    assert robot.joint_names == other.joint_names == ("shoulder", "absolute")
    plain = resolve_robot(ROBOTS / "pendubot.xml")[0]
    q, qd = np.array([0.2, 0.3]), np.array([-0.5, 0.7])
    Tm = np.array(T)
    D, h = robot.terms(q, qd)
    Dj, hj = plain.terms(np.linalg.solve(Tm, q), np.linalg.solve(Tm, qd))
    Ti = np.linalg.inv(Tm)
    np.testing.assert_allclose(D, Ti.T @ Dj @ Ti, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(h, Ti.T @ hj, rtol=1e-12, atol=1e-14)
    for a, b in zip(robot.terms(q, qd), other.terms(q, qd)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("block, match", [
    ({"map": [[1, 0], [1]]}, "square matrix"),
    ({"names": ["a", "b"]}, "give the map too"),
    ({"qu_range": [0.5, -0.5]}, "low < high"),
    ({"qu_nominal": float("nan")}, "finite"),
    ({"rolling_dependent": []}, "list of joint names"),
    ({"pitch": 1}, r"unknown key\(s\) \['pitch'\]"),
])
def test_bad_blocks_name_the_key(block, match):
    with pytest.raises(ConfigError, match=match):
        from_dict(PipelineConfig, {"robot": "cartpole.xml", "coordinates": block})


def test_the_block_needs_an_mjcf_path():
    with pytest.raises(ConfigError, match="names neither"):
        from_dict(PipelineConfig, {"data": "d.npz", "coordinates": {"qu_nominal": 0.0}})
    with pytest.raises(ConfigError, match="registered robot"):
        resolve_robot("furuta", coordinates={"qu_nominal": 0.0})


def test_a_run_loads_its_robot_with_the_block(boom):
    cfg = from_dict(PipelineConfig, {"robot": str(boom), "coordinates": {"rolling_dependent": ["boom"]}})
    robot, ref, truth = run_robot(cfg)
    assert robot is truth and robot.joint_names == ("pitch", "wheel")
    assert ref.coordinates == {"rolling_dependent": ["boom"]}
    assert custom_entries(CoordinatesConfig(rolling_dependent=["boom"])) == {"bemlearn_rolling_dependent": "boom"}


def test_robot_info_reads_a_config_file(boom, tmp_path):
    cfg = tmp_path / "boom.yaml"
    cfg.write_text(f"robot: {boom.name}\ncoordinates:\n  rolling_dependent: [boom]\n")
    out = subprocess.run([sys.executable, "-m", "bemlearn", "robot", "info", str(cfg)], capture_output=True, text=True,
                         check=True).stdout
    assert "unactuated pitch" in out and "rolling    boom = " in out
