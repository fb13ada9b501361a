"""Closed-loop MuJoCo simulation: the Furuta EIC loop and the biped walker."""

from bemlearn.sim.closed_loop import NominalConfig, ReferenceConfig, SimResult, SimulateConfig, nominal_robot, simulate
from bemlearn.sim.figures import plot_run
from bemlearn.sim.render import render_gif
from bemlearn.sim.walking import WalkConfig, WalkResult, load_walk_config, simulate_walk

__all__ = [
    "NominalConfig",
    "ReferenceConfig",
    "SimResult",
    "SimulateConfig",
    "WalkConfig",
    "WalkResult",
    "load_walk_config",
    "nominal_robot",
    "plot_run",
    "render_gif",
    "simulate",
    "simulate_walk",
]
