"""Closed-loop MuJoCo simulation: the excitation experiment that collects data (`collect`), the EIC loop with a BEM source, the sensed plant both run, figures, rendering."""

from typing import TYPE_CHECKING

from bemlearn._lazy import lazy_namespace

if TYPE_CHECKING:  # imported on first use: bemlearn._lazy
    from bemlearn.sim.closed_loop import NominalConfig, ReferenceConfig, SimResult, SimulateConfig, nominal_robot, simulate
    from bemlearn.sim.figures import plot_run
    from bemlearn.sim.plant import SensedPlant
    from bemlearn.sim.render import render_gif

__all__ = [
    "NominalConfig",
    "ReferenceConfig",
    "SensedPlant",
    "SimResult",
    "SimulateConfig",
    "nominal_robot",
    "plot_run",
    "render_gif",
    "simulate",
]

__getattr__, __dir__ = lazy_namespace(__name__, __file__)
