"""The whole-pipeline configuration: one YAML file with a section per stage.

.. code-block:: yaml

    robot: furuta          # registry name or MJCF path (or leave it out and give data:)
    data: FILE             # train on this trajectory file instead of collecting (model-free without robot:)
    model: path/to/robot.xml  # model-free runs only: an MJCF to compare the learned BEM with
    collect: {...}         # bemlearn.sim.collect.CollectConfig
    dataset: {...}         # bemlearn.data.dataset.DatasetConfig
    train: {...}           # bemlearn.fitting.GPConfig
    evaluate: {...}        # bemlearn.pipeline.evaluation.EvaluationConfig
    simulate: {...}        # bemlearn.sim.closed_loop.SimulateConfig

Every section is a strict dataclass defined next to its component; an unknown key
anywhere is an error naming the file and the key path, as is a value outside the limits its
component declares (:func:`bemlearn.config.config_limits`).  :class:`PipelineConfig` adds the
rules between sections (``__post_init__``): amplitude and sample budgets, a validation split
that needs two trials, and so on; :func:`bemlearn.pipeline.resolve.resolve_pipeline_config`
those that need the robot (the gain matrix's size, the mismatched bodies).  Reading a file with
the derived values filled in is :func:`bemlearn.pipeline.resolve.load_pipeline_config`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bemlearn.config import Limit, config_limits
from bemlearn.data.dataset import DatasetConfig
from bemlearn.errors import ConfigError
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.pipeline.evaluation import EvaluationConfig
from bemlearn.robots.coordinates import CoordinatesConfig
from bemlearn.sim.closed_loop import SimulateConfig
from bemlearn.sim.collect import CollectConfig

__all__ = ["PipelineConfig", "MAX_SAMPLES", "PATH_KEYS"]

#: The keys whose values name input files: in a config file, relative to the file's folder
#: (:func:`bemlearn.config.rebase_paths`; docs/config.md, "Paths").
PATH_KEYS: tuple[str, ...] = ("robot", "data", "model", "simulate.predictor")

#: Most samples a stage may produce (collect: trials × duration × rate; evaluate and simulate alike).
MAX_SAMPLES = 10**9

# The limits of the collect and evaluate sections (their dataclasses live in collect.py and evaluation.py).
config_limits(CollectConfig, n_trials=Limit(ge=1, le=10**6), duration_s=Limit(gt=0, le=1e6, unit="s"),
              rate_hz=Limit(gt=0, le=1e6, unit="Hz"), fall_window=Limit(gt=0), gain_scale=Limit(ge=0, ordered=True),
              n_sines=Limit(ge=1, le=1000, ordered=True), amplitude=Limit(ge=0, ordered=True),
              frequency_hz=Limit(ge=0, le=1e6, ordered=True, unit="Hz"), initial_qa=Limit(ordered=True),
              initial_qu=Limit(ordered=True), seed=Limit(ge=0), workers=Limit(ge=0, le=4096),
              physics_timestep=Limit(gt=0, le=1, unit="s"))
config_limits(EvaluationConfig, n_references=Limit(ge=1, le=10**5), n_sines=Limit(ge=1, le=1000, ordered=True),
              amplitude_max=Limit(gt=0), amplitude_min=Limit(ge=0), frequency_hz=Limit(gt=0, le=1e6, ordered=True, unit="Hz"),
              duration_s=Limit(gt=0, le=1e6, unit="s"), rate_hz=Limit(gt=0, le=1e6, unit="Hz"), seed=Limit(ge=0),
              design_points=Limit(ge=0, le=10**6))


@dataclass(frozen=True)
class PipelineConfig:
    """All stages' options: one YAML file with a section per stage.

    Attributes:
        robot: the robot: a registry name (``bemlearn robot list``) or the path of an MJCF file of this
            class (hinge/slide joints, exactly one no actuator drives besides those that only roll with a
            wheel, docs/wheeled.md). A path always means that file.
        data: a trajectory file to train on instead of collecting. Without ``robot`` the run is model-free.
        model: model-free runs only: a registry name or MJCF path whose model-based BEM the learned one
            is compared with (nothing is compared without it). It derives the ``evaluate`` references
            (as for ``robot:``) and weighs a torque logged on the unactuated joint against its gravity.
        coordinates: the balance coordinates of the MJCF given by ``robot:`` (or ``model:``), declared beside the
            file where its zero-config reading is ambiguous or wrong (:mod:`bemlearn.robots.coordinates`: the rolling
            joints, the upright, the BEM bracket, a linear map of the joints); ``null`` reads them from the model.
    """

    robot: str | None = None
    data: str | None = None
    model: str | None = None
    coordinates: CoordinatesConfig | None = None
    collect: CollectConfig = field(default_factory=CollectConfig)
    dataset: DatasetConfig = field(default_factory=DatasetConfig)
    train: GPConfig = field(default_factory=GPConfig)
    evaluate: EvaluationConfig = field(default_factory=EvaluationConfig)
    simulate: SimulateConfig = field(default_factory=SimulateConfig)

    def __post_init__(self) -> None:
        if self.robot is None and self.data is None:
            raise ConfigError("the config names neither 'robot:' (a registry name or an MJCF path) nor 'data:' "
                             "(a trajectory file); a config needs at least one of them")
        if self.coordinates is not None and self.robot is None and self.model is None:
            raise ConfigError("'coordinates:' declares the coordinates of the MJCF given by 'robot:' (or 'model:'); the config "
                             "names neither")
        if self.model is not None and self.robot is not None:
            raise ConfigError("'model:' is for model-free runs (data: without robot:); with 'robot:' the robot's own "
                             "model is the ground truth")
        ev, c, sim = self.evaluate, self.collect, self.simulate
        if sim.warmup_s >= sim.duration_s:
            raise ConfigError(f"simulate.warmup_s ({sim.warmup_s:g} s) must be shorter than simulate.duration_s ({sim.duration_s:g} s): "
                             "the tracking RMSE leaves out the samples before warmup_s")
        if ev.amplitude_min is not None and ev.amplitude_max is not None and ev.amplitude_min > ev.amplitude_max:
            raise ConfigError(f"evaluate.amplitude_min ({ev.amplitude_min:g}) must not exceed evaluate.amplitude_max ({ev.amplitude_max:g})")
        budgets = (("collect", c.n_trials * c.duration_s, c.rate_hz), ("evaluate", ev.n_references * ev.duration_s, ev.rate_hz),
                   ("simulate", sim.duration_s, sim.rate_hz))
        for name, seconds, rate in budgets:
            if rate is not None and seconds * rate > MAX_SAMPLES:
                raise ConfigError(f"{name}: {seconds:g} s at {rate:g} Hz is {seconds * rate:.3g} samples, more than {MAX_SAMPLES:.0e}; "
                                 "lower the duration, the number of trials or references, or the rate")
        if ev.rate_hz * ev.duration_s < 2:
            raise ConfigError(f"evaluate: duration_s × rate_hz = {ev.duration_s * ev.rate_hz:g} samples per reference; need at least 2")
        if self.data is None and self.dataset.val_fraction > 0 and c.n_trials < 2:
            raise ConfigError(f"dataset.val_fraction = {self.dataset.val_fraction:g} holds out whole trials for validation: "
                             f"collect.n_trials must be at least 2, got {c.n_trials} (or set dataset.val_fraction: 0)")

