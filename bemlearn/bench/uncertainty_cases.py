"""The robots of ``bemlearn bench uncertainty``: the shipped Furuta and a generated cart-pole.

The cart-pole (actuated slide x, m; unactuated hinge φ, rad; φ = 0 upright) is an MJCF
string written to a work directory, stabilized by a discrete LQR computed from MuJoCo's
finite-difference linearization, and excited like the Furuta (sums of sines on x, random
gain scaling per trial); the simulator writes quantized angles (4096 counts/rev, also on
the slide: 1.53 mm) at 400 Hz.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bemlearn.errors import ConfigError

if TYPE_CHECKING:
    from bemlearn.pipeline.config import PipelineConfig
    from bemlearn.pipeline.evaluation import EvaluationConfig

__all__ = ["CARTPOLE_XML", "BenchCase", "cartpole_case", "config_case"]

CARTPOLE_XML = """<mujoco model="cartpole-uncertainty">
  <compiler angle="radian" inertiafromgeom="false"/>
  <option timestep="0.00125"/>
  <worldbody>
    <body name="cart">
      <joint name="x" type="slide" axis="1 0 0" damping="0.5"/>
      <inertial pos="0 0 0" mass="1.0" diaginertia="0.01 0.01 0.01"/>
      <body name="pole">
        <joint name="phi" type="hinge" axis="0 1 0" damping="0.002"/>
        <inertial pos="0 0 0.3" mass="0.15" diaginertia="0.0045 0.0045 1e-9"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="x" ctrllimited="true" ctrlrange="-40 40"/></actuator>
</mujoco>
"""


@dataclass(frozen=True)
class BenchCase:
    """One robot of the bench: pipeline config, data file, held-out references."""

    name: str
    config: PipelineConfig
    data_path: Path
    evaluation: EvaluationConfig


def config_case(config_path: str | Path, data_path: str | Path) -> BenchCase:
    """A pipeline config and its excitation data, with the config's held-out references."""
    from bemlearn.pipeline.resolve import load_pipeline_config

    cfg = load_pipeline_config(config_path)
    if cfg.robot is None:
        raise ConfigError(f"{config_path}: the uncertainty bench needs 'robot:' (it compares with the robot's own BEM)")
    return BenchCase(Path(cfg.robot).stem, cfg, Path(data_path), cfg.evaluate)


def _lqr_gains(xml_path: Path, rate_hz: float) -> tuple[float, ...]:
    """Discrete LQR k (u = k·e) of the MJCF at rest, one control tick of 1/rate_hz s."""
    import mujoco
    from scipy.linalg import solve_discrete_are

    model = mujoco.MjModel.from_xml_path(str(xml_path))
    data = mujoco.MjData(model)
    nx = 2 * model.nv
    A = np.zeros((nx, nx))
    B = np.zeros((nx, model.nu))
    mujoco.mjd_transitionFD(model, data, 1e-6, True, A, B, None, None)
    steps = round(1.0 / rate_hz / model.opt.timestep)
    Ad, Bd = np.eye(nx), np.zeros_like(B)
    for _ in range(steps):
        Ad, Bd = A @ Ad, A @ Bd + B
    Q, R = np.diag([20.0, 10.0, 1.0, 0.1]), np.eye(model.nu) * 0.05
    P = solve_discrete_are(Ad, Bd, Q, R)
    K = np.linalg.solve(R + Bd.T @ P @ Bd, Bd.T @ P @ Ad)
    return tuple(float(v) for v in (-K).ravel())


def cartpole_case(workdir: str | Path, *, n_trials: int = 24, progress: bool = False) -> BenchCase:
    """A cart-pole (actuated slide x, m; unactuated hinge φ, rad) written to ``workdir``, LQR
    gains, 24 × 20 s of excitation collected at 400 Hz (4096-count encoders, 1.53 mm / mrad);
    held-out references of 5–10 cm, 0.1–1 Hz (|φ^e| ≲ 0.4 rad)."""
    from bemlearn.data.trajectory_io import ground_truth_path, write_trajectory
    from bemlearn.pipeline.config import PipelineConfig
    from bemlearn.pipeline.evaluation import EvaluationConfig
    from bemlearn.pipeline.resolve import complete_section
    from bemlearn.sim.collect import collect

    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    xml = workdir / "cartpole_uncertainty.xml"
    xml.write_text(CARTPOLE_XML)
    base = PipelineConfig(robot=str(xml))
    col = dataclasses.replace(base.collect, n_trials=n_trials, duration_s=20.0, rate_hz=400.0, fall_window=0.6,
                              gains=_lqr_gains(xml, 400.0), gain_scale=(0.7, 1.3), amplitude=(0.01, 0.05),
                              frequency_hz=(0.1, 1.2), initial_qa=(-0.02, 0.02), input_units="N", seed=0)
    col = complete_section(str(xml), "collect", col)   # the fields not set above, derived from the model as `run` does
    cfg = dataclasses.replace(base, collect=col)
    data_path = workdir / "cartpole.npz"
    if not data_path.is_file() or not ground_truth_path(data_path).is_file():
        data, truth = collect(str(xml), col, progress=progress)
        write_trajectory(data, data_path)
        write_trajectory(truth, ground_truth_path(data_path))   # exact q̇, q̈: the bench's oracle diagnostic
    ev = complete_section(str(xml), "evaluate", EvaluationConfig(amplitude_max=0.1, amplitude_min=0.05, frequency_hz=(0.1, 1.0)))
    return BenchCase("cartpole", cfg, data_path, ev)
